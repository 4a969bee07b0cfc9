"""Optional C++ farthest-point-sampling kernel, compiled on first use with ``load_inline``.

The build is cached in ``TORCH_EXTENSIONS_DIR`` (torch's default: ``~/.cache/torch_extensions``),
so only the first process on a machine pays the one-off g++ compile (~25 s). Any failure (no
compiler, no ninja, read-only cache) is remembered and callers fall back to the pure-torch loop.
Set ``FLOAFF_ZOO_FPS_BACKEND=torch`` to skip the kernel altogether.

The arithmetic matches the torch fallback bit for bit: squared distances are
``(dx*dx + dy*dy) + dz*dz`` in float32 with FMA contraction disabled, ties go to the lowest index,
invalid points carry distance -1 so they are never selected.
"""

from __future__ import annotations

import os
import threading
import warnings
from typing import Any

_CPP_SOURCE = r"""
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <vector>

torch::Tensor fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint) {
  TORCH_CHECK(xyz.dim() == 3 && xyz.size(2) == 3, "xyz must be [B, N, 3]");
  TORCH_CHECK(mask.dim() == 2 && mask.size(0) == xyz.size(0) && mask.size(1) == xyz.size(1), "mask must be [B, N]");
  xyz = xyz.to(torch::kFloat).contiguous();
  mask = mask.to(torch::kBool).contiguous();
  const int64_t B = xyz.size(0), N = xyz.size(1);
  auto out = torch::zeros({B, npoint}, torch::kLong);
  const float* P = xyz.data_ptr<float>();
  const bool* M = mask.data_ptr<bool>();
  int64_t* O = out.data_ptr<int64_t>();
  at::parallel_for(0, B, 1, [&](int64_t b0, int64_t b1) {
    std::vector<float> x(N), y(N), z(N), dist(N);
    for (int64_t b = b0; b < b1; ++b) {
      const float* p = P + b * N * 3;
      const bool* m = M + b * N;
      int64_t far = -1;
      for (int64_t i = 0; i < N; ++i) {
        x[i] = p[3 * i]; y[i] = p[3 * i + 1]; z[i] = p[3 * i + 2];
        dist[i] = m[i] ? 1e10f : -1.0f;
        if (far < 0 && m[i]) far = i;
      }
      if (far < 0) continue;  // no valid point: caller validates before calling
      for (int64_t j = 0; j < npoint; ++j) {
        O[b * npoint + j] = far;
        const float cx = x[far], cy = y[far], cz = z[far];
        float best = -2.0f;
        int64_t besti = 0;
        for (int64_t i = 0; i < N; ++i) {
          const float dx = x[i] - cx, dy = y[i] - cy, dz = z[i] - cz;
          const float d = (dx * dx + dy * dy) + dz * dz;
          const float cur = dist[i];
          const float nd = cur < 0.0f ? cur : (d < cur ? d : cur);
          dist[i] = nd;
          if (nd > best) { best = nd; besti = i; }
        }
        far = besti;
      }
    }
  });
  return out;
}
"""

_CPP_DECL = "torch::Tensor fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint);"

_lock = threading.Lock()
_state: dict[str, Any] = {"module": None, "error": None}


def backend_requested() -> str:
    """The FPS backend asked for by ``FLOAFF_ZOO_FPS_BACKEND``: ``auto`` (default), ``cpp`` or ``torch``."""
    value = os.environ.get("FLOAFF_ZOO_FPS_BACKEND", "auto").strip().lower() or "auto"
    if value not in ("auto", "cpp", "torch"):
        raise ValueError(f"FLOAFF_ZOO_FPS_BACKEND={value!r}: choose auto, cpp or torch")
    return value


def load_kernel() -> Any | None:
    """Compile (first call) or load the cached kernel; ``None`` when it cannot be built.

    Raises:
        RuntimeError: only when ``FLOAFF_ZOO_FPS_BACKEND=cpp`` demands the kernel and it fails.
    """
    want = backend_requested()
    if want == "torch":
        return None
    with _lock:
        if _state["module"] is None and _state["error"] is None:
            try:
                from torch.utils.cpp_extension import load_inline

                _state["module"] = load_inline(
                    name="floaff_zoo_fps_v1",
                    cpp_sources=[_CPP_DECL, _CPP_SOURCE],
                    functions=["fps_forward"],
                    extra_cflags=["-O3", "-ffp-contract=off"],
                    verbose=False,
                )
            except Exception as exc:  # noqa: BLE001 - any build failure means "use the fallback"
                _state["error"] = f"{type(exc).__name__}: {exc}"
                if want == "auto":
                    warnings.warn(
                        "floaff_zoo: C++ FPS kernel unavailable, using the pure-torch loop "
                        f"({_state['error'].splitlines()[0][:200]})",
                        stacklevel=3,
                    )
        if _state["module"] is None and want == "cpp":
            raise RuntimeError(f"FLOAFF_ZOO_FPS_BACKEND=cpp but the C++ FPS kernel failed to build: {_state['error']}")
        return _state["module"]
