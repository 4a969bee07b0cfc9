"""Optional C++ point kernels (FPS, ball-query and 3-NN selection, CFAR's tie-tolerant FPS and 3-NN, the
max-with-index of the fused BatchNorm+max, the passes of the fused train-mode BatchNorm+ReLU), compiled on
first use with ``load_inline``.

The build is cached under ``TORCH_EXTENSIONS_DIR`` (torch's default: ``~/.cache/torch_extensions``), in
``floaff_zoo/<name>_<tag>`` with one tag per torch install (``build.ninja`` holds that install's include
paths, so two environments sharing one cache would otherwise rebuild each other's kernel on every switch).
Only the first process of an install pays the one-off g++ compile (~40-60 s). Builds are serialised by an
OS file lock that is released when its holder dies, which also clears the plain ``lock`` file torch leaves
when a compile is killed (torch alone would wait on it forever). Any failure (no compiler, no ninja,
read-only cache) is remembered and callers fall back to pure torch.
Set ``FLOAFF_ZOO_FPS_BACKEND=torch`` to skip the kernels altogether (``FLOAFF_ZOO_CPU_PATHS=portable`` also skips
the other CPU-only paths: ``floaff_zoo.nn.ops.cpu_fast_paths``).

FPS matches the torch fallback bit for bit: squared distances are ``(dx*dx + dy*dy) + dz*dz`` in
float32 with FMA contraction disabled, ties go to the lowest index, invalid points carry distance
-1 so they are never selected. The ball-query and 3-NN kernels compute each query's row of squared
distances as ``ops.square_distance`` rounds it (the K = 3 GEMM of ``-2 src`` and ``dst^T`` is an fma
chain in MKL and oneDNN, then the squared norms from torch are added), so they select the torch path's
neighbours without writing the [B, S, N] matrix; ball query scans each row once for every scale and
stops once each holds K neighbours.

The loops that carry the work (FPS, distance rows, the ball scan) are compiled for AVX-512, AVX2+FMA
and the baseline on x86-64 with GCC and picked at run time from the CPU (``kernel_isa``); every build
gives the same results (tested).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

#: loops compiled once per instruction set (``namespace isa_<name>``, ``vf`` = one vector register of floats
#: through the GCC/Clang vector extension) and picked at run time by ``ISA_CALL``: on x86-64 with GCC,
#: AVX-512 and AVX2+FMA builds besides the baseline (SSE2; NEON on arm64). Same results on every one: plain
#: float ops without contraction (-ffp-contract=off), explicit fma only where the torch path has one.
_ISA_BODY = r"""
namespace isa_@NAME@ {
typedef float vf __attribute__((vector_size(@VBYTES@)));
typedef int32_t vi __attribute__((vector_size(@VBYTES@)));
constexpr int64_t W = @VBYTES@ / 4;

// FPS of one cloud from its first valid point `far`: x, y, z [N] (SoA), dist [N] (1e10 valid, -1 invalid)
// -> o [npoint]. d = (dx*dx + dy*dy) + dz*dz in float32 without FMA, as the torch fallback rounds it.
void fps_cloud(const float* x, const float* y, const float* z, float* dist, int64_t N, int64_t far, int64_t npoint,
               int64_t* o) {
  for (int64_t j = 0; j < npoint; ++j) {
    o[j] = far;
    const float cx = x[far], cy = y[far], cz = z[far];
    // W points per step: new distances, and per lane the maximum with its first index (invalid points hold
    // -1 and min(-1, d) keeps them there, d >= 0); then the lanes' maximum, ties to the lowest index
    vf vbest = vf{} - 2.0f;
    vi vbi = vi{}, vidx = vi{};
    for (int64_t l = 0; l < W; ++l) vidx[l] = int32_t(l);
    int64_t i0 = 0;
    for (; i0 + W <= N; i0 += W) {
      vf vx, vy, vz, vd;
      std::memcpy(&vx, x + i0, sizeof(vf));
      std::memcpy(&vy, y + i0, sizeof(vf));
      std::memcpy(&vz, z + i0, sizeof(vf));
      std::memcpy(&vd, dist + i0, sizeof(vf));
      const vf dx = vx - cx, dy = vy - cy, dz = vz - cz;
      const vf d = (dx * dx + dy * dy) + dz * dz;
      const vf nd = d < vd ? d : vd;
      std::memcpy(dist + i0, &nd, sizeof(vf));
      const auto gt = nd > vbest;
      vbest = gt ? nd : vbest;
      vbi = gt ? vidx : vbi;
      vidx += int32_t(W);
    }
    float best = -2.0f;
    int64_t besti = 0;
    for (int64_t l = 0; l < W; ++l) {
      if (vbest[l] > best || (vbest[l] == best && vbi[l] < besti)) { best = vbest[l]; besti = vbi[l]; }
    }
    for (int64_t i = i0; i < N; ++i) {
      const float dx = x[i] - cx, dy = y[i] - cy, dz = z[i] - cz;
      const float d = (dx * dx + dy * dy) + dz * dz;
      const float nd = d < dist[i] ? d : dist[i];
      dist[i] = nd;
      if (nd > best) { best = nd; besti = i; }
    }
    far = besti;
  }
}

// d [N]: squared distances of one query to a cloud, rounded as ops.square_distance rounds them:
// (fma(s2, z, fma(s1, y, s0 x)) + ss) + q, with s = -2 * query, ss = |query|^2 and q = |point|^2 (+inf where
// masked). The fma chain is how MKL's and oneDNN's float GEMM sum a K = 3 product (tested bit for bit).
void sq_dist_row(const float* __restrict__ x, const float* __restrict__ y, const float* __restrict__ z,
                 const float* __restrict__ q, float s0, float s1, float s2, float ss, float* __restrict__ d, int64_t N) {
  for (int64_t i = 0; i < N; ++i) d[i] = (__builtin_fmaf(s2, z[i], __builtin_fmaf(s1, y[i], s0 * x[i])) + ss) + q[i];
}

// Ball query on one row of distances d [N], several scales (rr[s], K[s]) in one scan that stops once every
// scale holds K[s] hits: the first K[s] indices with d <= rr[s], ascending. An empty ball takes the nearest
// point (lowest index on ties; index 0 when every point is masked); slots past the count repeat the first.
// A block of W points is read element by element only when one of them is inside the widest ball.
void ball_scan(const float* d, int64_t N, const float* rr, const int64_t* K, int64_t ns, int64_t* const* o) {
  float rmax = rr[0];
  for (int64_t s = 1; s < ns; ++s) rmax = rr[s] > rmax ? rr[s] : rmax;
  int64_t cnt[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  int64_t open = ns;
  auto take = [&](int64_t i) {
    const float v = d[i];
    if (!(v <= rmax)) return;
    for (int64_t s = 0; s < ns; ++s) {
      if (cnt[s] < K[s] && v <= rr[s]) {
        o[s][cnt[s]++] = i;
        if (cnt[s] == K[s]) --open;
      }
    }
  };
  int64_t i0 = 0;
  for (; i0 + W <= N && open > 0; i0 += W) {
    vf v;
    std::memcpy(&v, d + i0, sizeof(vf));
    const auto hit = v <= rmax;  // -1 in the lanes inside the widest ball
    uint64_t bits[W / 2];
    std::memcpy(bits, &hit, sizeof(bits));
    uint64_t any = 0;
    for (int64_t l = 0; l < W / 2; ++l) any |= bits[l];
    if (!any) continue;
    for (int64_t i = i0; i < i0 + W && open > 0; ++i) take(i);
  }
  for (int64_t i = i0; i < N && open > 0; ++i) take(i);
  for (int64_t s = 0; s < ns; ++s) {
    if (cnt[s] == 0) {
      float best = std::numeric_limits<float>::infinity();
      int64_t besti = 0;
      for (int64_t i = 0; i < N; ++i) {
        if (d[i] < best) { best = d[i]; besti = i; }
      }
      o[s][0] = besti;
      cnt[s] = 1;
    }
    for (int64_t j = cnt[s]; j < K[s]; ++j) o[s][j] = o[s][0];
  }
}
}  // namespace isa_@NAME@
"""

_ISA_DISPATCH = r"""
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define FLOAFF_MULTI_ISA 1
#pragma GCC push_options
#pragma GCC target("avx512f,avx512vl,avx512bw,avx512dq,avx2,fma")
@AVX512@
#pragma GCC pop_options
#pragma GCC push_options
#pragma GCC target("avx2,fma")
@AVX2@
#pragma GCC pop_options
#endif
@BASE@

// The instruction set the kernels run: 2 = AVX-512, 1 = AVX2 + FMA, 0 = baseline; the best the CPU has
// unless set_kernel_isa lowered it (tests compare the builds).
static int g_isa = -1;
static int best_isa() {
#ifdef FLOAFF_MULTI_ISA
  __builtin_cpu_init();
  const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  if (avx2 && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
      __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq")) return 2;
  if (avx2) return 1;
#endif
  return 0;
}
static int isa_level() {
  if (g_isa < 0) g_isa = best_isa();
  return g_isa;
}
#ifdef FLOAFF_MULTI_ISA
#define ISA_CALL(fn, ...) \
  (isa_level() == 2 ? isa_avx512::fn(__VA_ARGS__) : isa_level() == 1 ? isa_avx2::fn(__VA_ARGS__) : isa_base::fn(__VA_ARGS__))
#else
#define ISA_CALL(fn, ...) isa_base::fn(__VA_ARGS__)
#endif

// level < 0: report; else use min(level, the best the CPU has). Returns the level now in use.
int64_t kernel_isa(int64_t level) {
  if (level >= 0) g_isa = std::min<int>(int(level), best_isa());
  return isa_level();
}
"""


def _isa_bodies() -> str:
    """The per-instruction-set loops and their dispatch, for ``_CPP_SOURCE``."""

    def body(name: str, vbytes: int) -> str:
        return _ISA_BODY.replace("@NAME@", name).replace("@VBYTES@", str(vbytes))

    return (
        _ISA_DISPATCH.replace("@AVX512@", body("avx512", 64))
        .replace("@AVX2@", body("avx2", 32))
        .replace("@BASE@", body("base", 16))
    )


_CPP_SOURCE = r"""
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <algorithm>
#include <cstring>
#include <limits>
#include <vector>

@ISA_BODIES@

// The checked inputs and the output of both FPS kernels: xyz [B, N, 3] float, mask [B, N] bool -> out [B, npoint].
struct FpsIO {
  torch::Tensor xyz, mask, out;
  int64_t B, N;
  const float* P; const bool* M; int64_t* O;
  FpsIO(torch::Tensor xyz_, torch::Tensor mask_, int64_t npoint) {
    TORCH_CHECK(xyz_.dim() == 3 && xyz_.size(2) == 3, "xyz must be [B, N, 3]");
    TORCH_CHECK(mask_.dim() == 2 && mask_.size(0) == xyz_.size(0) && mask_.size(1) == xyz_.size(1), "mask must be [B, N]");
    xyz = xyz_.to(torch::kFloat).contiguous();
    mask = mask_.to(torch::kBool).contiguous();
    B = xyz.size(0); N = xyz.size(1);
    out = torch::zeros({B, npoint}, torch::kLong);
    P = xyz.data_ptr<float>(); M = mask.data_ptr<bool>(); O = out.data_ptr<int64_t>();
  }
};

torch::Tensor fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint) {
  const FpsIO io(xyz, mask, npoint);
  const int64_t B = io.B, N = io.N;
  TORCH_CHECK(N < (int64_t(1) << 31), "fps: at most 2^31 - 1 points per cloud");
  const float* P = io.P;
  const bool* M = io.M;
  int64_t* O = io.O;
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
      ISA_CALL(fps_cloud, x.data(), y.data(), z.data(), dist.data(), N, far, npoint, O + b * npoint);
    }
  });
  return io.out;
}

// The three smallest of d [N] ascending, ties to the lowest index; missing slots (fewer than 3 finite
// values): distance +inf, index 0.
static void three_smallest(const float* d, int64_t N, float* od, int64_t* oi) {
  const float inf = std::numeric_limits<float>::infinity();
  float d0 = inf, d1 = inf, d2 = inf;
  int64_t i0 = 0, i1 = 0, i2 = 0;
  for (int64_t i = 0; i < N; ++i) {
    const float v = d[i];
    if (!(v < d2)) continue;
    if (v < d1) {
      d2 = d1; i2 = i1;
      if (v < d0) { d1 = d0; i1 = i0; d0 = v; i0 = i; } else { d1 = v; i1 = i; }
    } else { d2 = v; i2 = i; }
  }
  od[0] = d0; od[1] = d1; od[2] = d2;
  oi[0] = d0 == inf ? 0 : i0; oi[1] = d1 == inf ? 0 : i1; oi[2] = d2 == inf ? 0 : i2;
}

// The direct neighbour kernels take src2 [B, S, 3] (= -2 * the query points, exact), ssq [B, S] and dsq [B, N]
// (squared norms, from torch) and dst [B, N, 3] with mask [B, N]. Per cloud the points are laid out as
// x, y, z and dsq (+inf where masked, so a masked point is never in a ball nor among the nearest).
struct Direct {
  int64_t B, S, N;
  torch::Tensor soa;  // [B, 4, N]
  const float* src2; const float* ssq; const float* Q;
  Direct(torch::Tensor& src2_, torch::Tensor& ssq_, torch::Tensor& dst_, torch::Tensor& dsq_, torch::Tensor& mask_) {
    TORCH_CHECK(src2_.dim() == 3 && src2_.size(2) == 3 && src2_.scalar_type() == torch::kFloat && src2_.is_contiguous(),
                "src2 must be contiguous float [B, S, 3]");
    TORCH_CHECK(dst_.dim() == 3 && dst_.size(2) == 3 && dst_.size(0) == src2_.size(0) && dst_.scalar_type() == torch::kFloat,
                "dst must be float [B, N, 3]");
    B = src2_.size(0); S = src2_.size(1); N = dst_.size(1);
    TORCH_CHECK(ssq_.is_contiguous() && ssq_.numel() == B * S && ssq_.scalar_type() == torch::kFloat, "ssq must be float [B, S]");
    TORCH_CHECK(dsq_.numel() == B * N && dsq_.scalar_type() == torch::kFloat, "dsq must be float [B, N]");
    TORCH_CHECK(mask_.numel() == B * N && mask_.scalar_type() == torch::kBool, "mask must be bool [B, N]");
    const auto inf = torch::full({}, std::numeric_limits<float>::infinity(), dsq_.options());
    auto dq = torch::where(mask_.reshape({B, 1, N}), dsq_.reshape({B, 1, N}), inf);
    soa = torch::cat({dst_.transpose(1, 2), dq}, 1).contiguous();
    src2 = src2_.data_ptr<float>(); ssq = ssq_.data_ptr<float>(); Q = soa.data_ptr<float>();
  }
  const float* cloud(int64_t r) const { return Q + (r / S) * 4 * N; }
};

// Ball query (ops.ball_query_multi) for several (r2, K) scales: per centre its distance row, then one scan
// (isa::ball_scan). Returns one [B, S, K] index tensor per scale.
std::vector<torch::Tensor> ball_direct(torch::Tensor src2, torch::Tensor ssq, torch::Tensor dst, torch::Tensor dsq,
                                       torch::Tensor mask, std::vector<double> r2, std::vector<int64_t> K) {
  const Direct in(src2, ssq, dst, dsq, mask);
  TORCH_CHECK(r2.size() == K.size() && !r2.empty() && r2.size() <= 8, "one to eight (r2, K) scales");
  const int64_t B = in.B, S = in.S, N = in.N, ns = int64_t(r2.size());
  std::vector<torch::Tensor> outs;
  std::vector<int64_t*> O;
  std::vector<float> rr;
  for (int64_t s = 0; s < ns; ++s) {
    TORCH_CHECK(K[s] >= 1, "K must be >= 1");
    outs.push_back(torch::empty({B, S, K[s]}, torch::kLong));
    O.push_back(outs.back().data_ptr<int64_t>());
    rr.push_back(static_cast<float>(r2[s]));
  }
  at::parallel_for(0, B * S, 16, [&](int64_t r0, int64_t r1) {
    std::vector<float> d(N);
    int64_t* o[8];
    for (int64_t r = r0; r < r1; ++r) {
      const float* q = in.cloud(r);
      const float* c = in.src2 + 3 * r;
      ISA_CALL(sq_dist_row, q, q + N, q + 2 * N, q + 3 * N, c[0], c[1], c[2], in.ssq[r], d.data(), N);
      for (int64_t s = 0; s < ns; ++s) o[s] = O[s] + r * K[s];
      ISA_CALL(ball_scan, d.data(), N, rr.data(), K.data(), ns, o);
    }
  });
  return outs;
}

// Three nearest valid points (ops.three_nn) of every query: per query its distance row, then three_smallest.
// Returns (sq_dist [B, S, 3], idx [B, S, 3]).
std::vector<torch::Tensor> three_nn_direct(torch::Tensor src2, torch::Tensor ssq, torch::Tensor dst, torch::Tensor dsq,
                                           torch::Tensor mask) {
  const Direct in(src2, ssq, dst, dsq, mask);
  const int64_t B = in.B, S = in.S, N = in.N;
  auto dist = torch::empty({B, S, 3}, torch::kFloat);
  auto idx = torch::empty({B, S, 3}, torch::kLong);
  float* OD = dist.data_ptr<float>();
  int64_t* OI = idx.data_ptr<int64_t>();
  at::parallel_for(0, B * S, 16, [&](int64_t r0, int64_t r1) {
    std::vector<float> d(N);
    for (int64_t r = r0; r < r1; ++r) {
      const float* q = in.cloud(r);
      const float* c = in.src2 + 3 * r;
      ISA_CALL(sq_dist_row, q, q + N, q + 2 * N, q + 3 * N, c[0], c[1], c[2], in.ssq[r], d.data(), N);
      three_smallest(d.data(), N, OD + 3 * r, OI + 3 * r);
    }
  });
  return {dist, idx};
}

// One row of weighted_gather3: o = (f0 w0 + f1 w1) + f2 w2, each product rounded first (no FMA), the order of
// torch's (gathered * w).sum over the three neighbours. A plain function with restrict pointers so it vectorises.
template <typename scalar_t>
__attribute__((noinline)) void gather3_row(const scalar_t* __restrict__ f0, const scalar_t* __restrict__ f1,
                                           const scalar_t* __restrict__ f2, scalar_t w0, scalar_t w1, scalar_t w2,
                                           scalar_t* __restrict__ o, int64_t C) {
  for (int64_t c = 0; c < C; ++c) o[c] = (f0[c] * w0 + f1[c] * w1) + f2[c] * w2;
}

// out [B, n, C] = sum over k of w[b, i, k] * feat[b, idx[b, i, k], :] (k = 0, 1, 2): 3-NN interpolation's gather
// and weighted sum in one pass, without the [B, n, 3, C] gathered tensor.
torch::Tensor weighted_gather3(torch::Tensor feat, torch::Tensor idx, torch::Tensor w) {
  TORCH_CHECK(feat.dim() == 3 && feat.is_contiguous(), "feat must be a contiguous [B, m, C] tensor");
  TORCH_CHECK(idx.dim() == 3 && idx.size(2) == 3 && idx.size(0) == feat.size(0) && idx.is_contiguous() &&
              idx.scalar_type() == torch::kLong, "idx must be a contiguous int64 [B, n, 3] tensor");
  TORCH_CHECK(w.sizes() == idx.sizes() && w.is_contiguous() && w.scalar_type() == feat.scalar_type(),
              "w must be a contiguous [B, n, 3] tensor of feat's dtype");
  const int64_t B = feat.size(0), m = feat.size(1), C = feat.size(2), n = idx.size(1);
  TORCH_CHECK(idx.numel() == 0 || (idx.min().item<int64_t>() >= 0 && idx.max().item<int64_t>() < m),
              "idx out of range [0, ", m, ")");
  auto out = torch::empty({B, n, C}, feat.options());
  AT_DISPATCH_FLOATING_TYPES(feat.scalar_type(), "weighted_gather3", [&] {
    const scalar_t* F = feat.data_ptr<scalar_t>();
    const scalar_t* Wt = w.data_ptr<scalar_t>();
    const int64_t* I = idx.data_ptr<int64_t>();
    scalar_t* O = out.data_ptr<scalar_t>();
    at::parallel_for(0, B * n, 64, [&](int64_t r0, int64_t r1) {
      for (int64_t r = r0; r < r1; ++r) {
        const scalar_t* f = F + (r / n) * m * C;
        const int64_t* i = I + 3 * r;
        const scalar_t* wr = Wt + 3 * r;
        gather3_row(f + i[0] * C, f + i[1] * C, f + i[2] * C, wr[0], wr[1], wr[2], O + r * C, C);
      }
    });
  });
  return out;
}

// Tie-tolerant FPS (nn/cfar.py tolerant_fps): candidates within tol of the farthest distance are tied and
// the lowest index wins. d = ((dx*dx + dy*dy) + dz*dz) in float32; invalid points keep -1.
torch::Tensor tolerant_fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint, double tol) {
  const FpsIO io(xyz, mask, npoint);
  const int64_t B = io.B, N = io.N;
  const float* P = io.P;
  const bool* M = io.M;
  int64_t* O = io.O;
  const float inf = std::numeric_limits<float>::infinity();
  const float ftol = static_cast<float>(tol);
  at::parallel_for(0, B, 1, [&](int64_t b0, int64_t b1) {
    std::vector<float> dist(N);
    for (int64_t b = b0; b < b1; ++b) {
      const float* p = P + b * N * 3;
      const bool* m = M + b * N;
      int64_t cur = -1;
      for (int64_t i = 0; i < N; ++i) {
        dist[i] = m[i] ? inf : -1.0f;
        if (cur < 0 && m[i]) cur = i;
      }
      if (cur < 0) continue;  // no valid point: caller validates before calling
      for (int64_t j = 0; j < npoint; ++j) {
        O[b * npoint + j] = cur;
        const float cx = p[3 * cur], cy = p[3 * cur + 1], cz = p[3 * cur + 2];
        float best = -2.0f;
        for (int64_t i = 0; i < N; ++i) {
          if (!m[i]) continue;
          const float dx = p[3 * i] - cx, dy = p[3 * i + 1] - cy, dz = p[3 * i + 2] - cz;
          const float d = (dx * dx + dy * dy) + dz * dz;
          if (d < dist[i]) dist[i] = d;
          if (dist[i] > best) best = dist[i];
        }
        const float bar = best - ftol;
        for (int64_t i = 0; i < N; ++i) {
          if (dist[i] >= bar) { cur = i; break; }
        }
      }
    }
  });
  return io.out;
}

// Three neighbours chosen without float-noise flips (nn/cfar.py stable_three_interpolate): in float64,
// each pick is the lowest index within tol of the nearest remaining distance. Fewer than 3 points:
// missing slots +inf / index 0. Returns (sq_dist [B, n, k] float64, idx [B, n, k]), k = min(3, m).
std::vector<torch::Tensor> stable_three_nn(torch::Tensor unknown, torch::Tensor known, double tol) {
  TORCH_CHECK(unknown.dim() == 3 && unknown.size(2) == 3 && known.dim() == 3 && known.size(2) == 3, "points must be [B, N, 3]");
  unknown = unknown.to(torch::kDouble).contiguous();
  known = known.to(torch::kDouble).contiguous();
  const int64_t B = unknown.size(0), n = unknown.size(1), m = known.size(1);
  const int64_t k = m < 3 ? m : 3;
  auto dist = torch::empty({B, n, k}, torch::kDouble);
  auto idx = torch::empty({B, n, k}, torch::kLong);
  const double* U = unknown.data_ptr<double>();
  const double* Kp = known.data_ptr<double>();
  double* OD = dist.data_ptr<double>();
  int64_t* OI = idx.data_ptr<int64_t>();
  const double inf = std::numeric_limits<double>::infinity();
  at::parallel_for(0, B * n, 16, [&](int64_t r0, int64_t r1) {
    std::vector<double> d(m);
    for (int64_t r = r0; r < r1; ++r) {
      const double* u = U + r * 3;
      const double* kp = Kp + (r / n) * m * 3;
      for (int64_t i = 0; i < m; ++i) {
        const double dx = u[0] - kp[3 * i], dy = u[1] - kp[3 * i + 1], dz = u[2] - kp[3 * i + 2];
        d[i] = (dx * dx + dy * dy) + dz * dz;
      }
      for (int64_t s = 0; s < k; ++s) {
        double best = inf;
        for (int64_t i = 0; i < m; ++i) if (d[i] < best) best = d[i];
        int64_t pick = 0;
        for (int64_t i = 0; i < m; ++i) if (d[i] <= best + tol) { pick = i; break; }
        OD[r * k + s] = d[pick];
        OI[r * k + s] = pick;
        d[pick] = inf;
      }
    }
  });
  return {dist, idx};
}

// One row of extreme_over_dim: keep c = sign * z where it beats the kept value (or is the first NaN), with
// its row index k. A plain function with restrict pointers, so that the compiler vectorises it (inside the
// dispatch lambda it did not: measured 7x slower).
template <typename scalar_t>
__attribute__((noinline)) void extreme_step(const scalar_t* __restrict__ zk, const scalar_t* __restrict__ sign,
                                            scalar_t* __restrict__ v, scalar_t* __restrict__ x, int64_t I, scalar_t k) {
  for (int64_t i = 0; i < I; ++i) {
    const scalar_t c = sign[i] * zk[i], w = v[i];
    const bool take = (c > w) | ((c != c) & (w == w));
    v[i] = take ? c : w;
    x[i] = take ? k : x[i];
  }
}

// Max (or, per channel, min) over the middle dim of z [O, K, I] with the index of the first extreme, as
// torch.max(dim=1) does (NaN wins and stays): one pass over z, where torch's max-with-index over a middle
// dim runs ~7x slower than its amax. take_min [I] bool picks min for a channel.
std::vector<torch::Tensor> extreme_over_dim(torch::Tensor z, torch::Tensor take_min) {
  TORCH_CHECK(z.dim() == 3, "z must be [O, K, I]");
  TORCH_CHECK(z.size(1) > 0 && z.size(1) < (1 << 24), "the reduced dim must hold 1 to 2^24 - 1 entries");
  TORCH_CHECK(take_min.dim() == 1 && take_min.size(0) == z.size(2), "take_min must be [I]");
  z = z.contiguous();
  auto tmin = take_min.to(torch::kBool).contiguous();
  const int64_t O = z.size(0), K = z.size(1), I = z.size(2);
  auto vals = torch::empty({O, I}, z.options());
  auto idx = torch::empty({O, I}, torch::kLong);
  const bool* TM = tmin.data_ptr<bool>();
  AT_DISPATCH_FLOATING_TYPES(z.scalar_type(), "extreme_over_dim", [&] {
    const scalar_t* Z = z.data_ptr<scalar_t>();
    scalar_t* V = vals.data_ptr<scalar_t>();
    int64_t* X = idx.data_ptr<int64_t>();
    at::parallel_for(0, O, 16, [&](int64_t o0, int64_t o1) {
      // the running index is kept as scalar_t (exact for K < 2^24), so value and index lanes have the same
      // width and the loop vectorises into compare + blend
      std::vector<scalar_t> sign(I), v(I), x(I);
      for (int64_t i = 0; i < I; ++i) sign[i] = TM[i] ? scalar_t(-1) : scalar_t(1);
      for (int64_t o = o0; o < o1; ++o) {
        const scalar_t* zo = Z + o * K * I;
        for (int64_t i = 0; i < I; ++i) { v[i] = sign[i] * zo[i]; x[i] = 0; }
        for (int64_t k = 1; k < K; ++k) {
          extreme_step(zo + k * I, sign.data(), v.data(), x.data(), I, scalar_t(k));
        }
        scalar_t* vo = V + o * I;
        int64_t* xo = X + o * I;
        for (int64_t i = 0; i < I; ++i) { vo[i] = v[i] * sign[i]; xo[i] = int64_t(x[i]); }
      }
    });
  });
  return {vals, idx};
}

// Train-mode BatchNorm + ReLU of z [R, C] (rows = samples) with the batch statistics given: the forward
// writes y = max(a z + c, 0) in one pass; the backward reads dy, y and z twice (the two per-channel sums,
// then the gradient) and writes the gradient over z, where torch's ReLU and BN backward passes allocate
// and write two tensors of z's size. Helpers with restrict pointers so the row loops vectorise.
template <typename scalar_t>
__attribute__((noinline)) void affine_relu_row(const scalar_t* __restrict__ z, const scalar_t* __restrict__ a,
                                               const scalar_t* __restrict__ c, scalar_t* __restrict__ y, int64_t C) {
  for (int64_t i = 0; i < C; ++i) {
    const scalar_t v = a[i] * z[i] + c[i];
    y[i] = v > scalar_t(0) ? v : scalar_t(0);
  }
}

template <typename scalar_t>
__attribute__((noinline)) void relu_grad_sums_row(const scalar_t* __restrict__ dy, const scalar_t* __restrict__ y,
                                                  const scalar_t* __restrict__ z, const scalar_t* __restrict__ mean,
                                                  scalar_t* __restrict__ sg, scalar_t* __restrict__ sgx, int64_t C) {
  for (int64_t i = 0; i < C; ++i) {
    const scalar_t d = dy[i];  // loaded unconditionally: a conditional load blocks vectorisation
    const scalar_t g = y[i] > scalar_t(0) ? d : scalar_t(0);
    sg[i] += g;
    sgx[i] += g * (z[i] - mean[i]);
  }
}

template <typename scalar_t>
__attribute__((noinline)) void bn_relu_grad_row(const scalar_t* __restrict__ dy, const scalar_t* __restrict__ y,
                                                scalar_t* __restrict__ zio, const scalar_t* __restrict__ k,
                                                const scalar_t* __restrict__ A, const scalar_t* __restrict__ B,
                                                int64_t C) {
  for (int64_t i = 0; i < C; ++i) {
    const scalar_t kd = k[i] * dy[i], r = A[i] * zio[i] + B[i];
    zio[i] = y[i] > scalar_t(0) ? r + kd : r;
  }
}

static void check_rows(const torch::Tensor& t, const torch::Tensor& like, const char* name) {
  TORCH_CHECK(t.dim() == 2 && t.sizes() == like.sizes() && t.is_contiguous() && t.scalar_type() == like.scalar_type(),
              name, " must be a contiguous [R, C] tensor like z");
}

static void check_channels(const torch::Tensor& t, const torch::Tensor& z, const char* name) {
  TORCH_CHECK(t.dim() == 1 && t.size(0) == z.size(1) && t.is_contiguous() && t.scalar_type() == z.scalar_type(),
              name, " must be a contiguous [C] tensor of z's dtype");
}

template <typename scalar_t>
__attribute__((noinline)) void add_row(const scalar_t* __restrict__ z, scalar_t* __restrict__ s, int64_t C) {
  for (int64_t i = 0; i < C; ++i) s[i] += z[i];
}

template <typename scalar_t>
__attribute__((noinline)) void add_centred_square_row(const scalar_t* __restrict__ z, const scalar_t* __restrict__ mu,
                                                      scalar_t* __restrict__ s, int64_t C) {
  for (int64_t i = 0; i < C; ++i) {
    const scalar_t d = z[i] - mu[i];
    s[i] += d * d;
  }
}

// Per-channel sums over the rows of z [R, C], in fixed blocks of 1024 rows (block sums in scalar_t, added in
// block order in double: the result does not depend on the thread count). With mean given, the sums of
// (z - mean)^2.
static torch::Tensor block_column_sums(const torch::Tensor& z, const torch::Tensor* mean) {
  const int64_t R = z.size(0), C = z.size(1), BLOCK = 1024, NB = (R + BLOCK - 1) / BLOCK;
  auto part = torch::zeros({NB, C}, z.options());
  AT_DISPATCH_FLOATING_TYPES(z.scalar_type(), "block_column_sums", [&] {
    const scalar_t* Z = z.data_ptr<scalar_t>();
    const scalar_t* MU = mean ? mean->data_ptr<scalar_t>() : nullptr;
    scalar_t* P = part.data_ptr<scalar_t>();
    at::parallel_for(0, NB, 1, [&](int64_t b0, int64_t b1) {
      for (int64_t b = b0; b < b1; ++b) {
        const int64_t e = std::min(R, (b + 1) * BLOCK);
        for (int64_t r = b * BLOCK; r < e; ++r) {
          if (MU) add_centred_square_row(Z + r * C, MU, P + b * C, C);
          else add_row(Z + r * C, P + b * C, C);
        }
      }
    });
  });
  return part.to(torch::kDouble).sum(0);
}

// (biased variance [C], mean [C]) over the rows of z [R, C]: a centred two-pass computation
std::vector<torch::Tensor> column_var_mean(torch::Tensor z) {
  TORCH_CHECK(z.dim() == 2 && z.is_contiguous() && z.size(0) > 0, "z must be a contiguous [R, C] tensor, R > 0");
  const double R = double(z.size(0));
  auto mean = (block_column_sums(z, nullptr) / R).to(z.scalar_type());
  auto var = (block_column_sums(z, &mean) / R).to(z.scalar_type());
  return {var, mean};
}

// y [R, C] = max(a z + c, 0), a and c [C]
torch::Tensor affine_relu(torch::Tensor z, torch::Tensor a, torch::Tensor c) {
  TORCH_CHECK(z.dim() == 2 && z.is_contiguous(), "z must be a contiguous [R, C] tensor");
  check_channels(a, z, "a");
  check_channels(c, z, "c");
  auto y = torch::empty_like(z);
  const int64_t R = z.size(0), C = z.size(1);
  AT_DISPATCH_FLOATING_TYPES(z.scalar_type(), "affine_relu", [&] {
    const scalar_t *Z = z.data_ptr<scalar_t>(), *Ap = a.data_ptr<scalar_t>(), *Cp = c.data_ptr<scalar_t>();
    scalar_t* Y = y.data_ptr<scalar_t>();
    at::parallel_for(0, R, 256, [&](int64_t r0, int64_t r1) {
      for (int64_t r = r0; r < r1; ++r) affine_relu_row(Z + r * C, Ap, Cp, Y + r * C, C);
    });
  });
  return y;
}

// Per channel sum_g and sum_g (z - mean), g = dy where y > 0 else 0. Rows are summed in fixed blocks of
// 1024 (block sums in scalar_t, then added in block order in double), so the result does not depend on
// the thread count.
std::vector<torch::Tensor> relu_grad_sums(torch::Tensor dy, torch::Tensor y, torch::Tensor z, torch::Tensor mean) {
  TORCH_CHECK(z.dim() == 2 && z.is_contiguous(), "z must be a contiguous [R, C] tensor");
  check_rows(dy, z, "dy");
  check_rows(y, z, "y");
  check_channels(mean, z, "mean");
  const int64_t R = z.size(0), C = z.size(1), BLOCK = 1024, NB = (R + BLOCK - 1) / BLOCK;
  auto part = torch::zeros({NB, 2, C}, z.options());
  AT_DISPATCH_FLOATING_TYPES(z.scalar_type(), "relu_grad_sums", [&] {
    const scalar_t *DY = dy.data_ptr<scalar_t>(), *Y = y.data_ptr<scalar_t>(), *Z = z.data_ptr<scalar_t>();
    const scalar_t* MU = mean.data_ptr<scalar_t>();
    scalar_t* P = part.data_ptr<scalar_t>();
    at::parallel_for(0, NB, 1, [&](int64_t b0, int64_t b1) {
      for (int64_t b = b0; b < b1; ++b) {
        scalar_t *sg = P + b * 2 * C, *sgx = sg + C;
        const int64_t e = std::min(R, (b + 1) * BLOCK);
        for (int64_t r = b * BLOCK; r < e; ++r) relu_grad_sums_row(DY + r * C, Y + r * C, Z + r * C, MU, sg, sgx, C);
      }
    });
  });
  auto sums = part.to(torch::kDouble).sum(0);
  return {sums[0].to(z.scalar_type()), sums[1].to(z.scalar_type())};
}

// In place: z [R, C] <- A z + B + (y > 0 ? k dy : 0), the BatchNorm + ReLU input gradient
void bn_relu_grad_(torch::Tensor z, torch::Tensor dy, torch::Tensor y, torch::Tensor k, torch::Tensor A,
                   torch::Tensor B) {
  TORCH_CHECK(z.dim() == 2 && z.is_contiguous(), "z must be a contiguous [R, C] tensor");
  check_rows(dy, z, "dy");
  check_rows(y, z, "y");
  check_channels(k, z, "k");
  check_channels(A, z, "A");
  check_channels(B, z, "B");
  const int64_t R = z.size(0), C = z.size(1);
  AT_DISPATCH_FLOATING_TYPES(z.scalar_type(), "bn_relu_grad_", [&] {
    const scalar_t *DY = dy.data_ptr<scalar_t>(), *Y = y.data_ptr<scalar_t>();
    const scalar_t *K = k.data_ptr<scalar_t>(), *Ap = A.data_ptr<scalar_t>(), *Bp = B.data_ptr<scalar_t>();
    scalar_t* Z = z.data_ptr<scalar_t>();
    at::parallel_for(0, R, 256, [&](int64_t r0, int64_t r1) {
      for (int64_t r = r0; r < r1; ++r) bn_relu_grad_row(DY + r * C, Y + r * C, Z + r * C, K, Ap, Bp, C);
    });
  });
  // an in-place write: autograd's version check then catches a later use of z's old values
  z.unsafeGetTensorImpl()->bump_version();
}
"""

_CPP_SOURCE = _CPP_SOURCE.replace("@ISA_BODIES@", _isa_bodies())

_CPP_DECL = """
int64_t kernel_isa(int64_t level);
torch::Tensor fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint);
std::vector<torch::Tensor> ball_direct(torch::Tensor src2, torch::Tensor ssq, torch::Tensor dst, torch::Tensor dsq,
                                       torch::Tensor mask, std::vector<double> r2, std::vector<int64_t> K);
std::vector<torch::Tensor> three_nn_direct(torch::Tensor src2, torch::Tensor ssq, torch::Tensor dst, torch::Tensor dsq,
                                           torch::Tensor mask);
torch::Tensor weighted_gather3(torch::Tensor feat, torch::Tensor idx, torch::Tensor w);
torch::Tensor tolerant_fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint, double tol);
std::vector<torch::Tensor> stable_three_nn(torch::Tensor unknown, torch::Tensor known, double tol);
std::vector<torch::Tensor> extreme_over_dim(torch::Tensor z, torch::Tensor take_min);
torch::Tensor affine_relu(torch::Tensor z, torch::Tensor a, torch::Tensor c);
std::vector<torch::Tensor> relu_grad_sums(torch::Tensor dy, torch::Tensor y, torch::Tensor z, torch::Tensor mean);
void bn_relu_grad_(torch::Tensor z, torch::Tensor dy, torch::Tensor y, torch::Tensor k, torch::Tensor A, torch::Tensor B);
std::vector<torch::Tensor> column_var_mean(torch::Tensor z);
"""

_NAME = "floaff_zoo_point_ops_v20"
_lock = threading.Lock()
_state: dict[str, Any] = {"module": None, "error": None}


def backend_requested() -> str:
    """The FPS backend asked for by ``FLOAFF_ZOO_FPS_BACKEND``: ``auto`` (default), ``cpp`` or ``torch``."""
    value = os.environ.get("FLOAFF_ZOO_FPS_BACKEND", "auto").strip().lower() or "auto"
    if value not in ("auto", "cpp", "torch"):
        raise ValueError(f"FLOAFF_ZOO_FPS_BACKEND={value!r}: choose auto, cpp or torch")
    return value


def build_directory() -> Path:
    """This torch install's build folder: ``<TORCH_EXTENSIONS_DIR or torch's root>/floaff_zoo/<name>_<tag>``."""
    import torch
    from torch.utils.cpp_extension import get_default_build_root

    install = (
        f"{torch.__version__}|{Path(torch.__file__).resolve().parent}|{sys.version}|{getattr(sys, 'abiflags', '')}"
    )
    tag = hashlib.sha1(install.encode()).hexdigest()[:10]
    root = os.environ.get("TORCH_EXTENSIONS_DIR") or get_default_build_root()
    return Path(root) / "floaff_zoo" / f"{_NAME}_{tag}"


@contextlib.contextmanager
def build_guard(folder: Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``<folder>.flock`` and clear a baton no live build owns.

    torch's own baton (``<folder>/lock``) is a plain file: a compile killed half-way leaves it behind and every
    later ``load_inline`` sleeps on it forever. Each build of ours takes this kernel lock first, and the kernel
    drops it when the holder exits however it exits, so whoever holds it knows any baton left is stale.
    """
    folder.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # not POSIX: torch's baton alone, as before
        yield
        return
    with open(folder.parent / f"{folder.name}.flock", "a+") as handle:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
        try:
            baton = folder / "lock"
            if baton.exists():
                warnings.warn(
                    f"floaff_zoo: removing the stale build lock {baton} (left by a killed compile)", stacklevel=3
                )
                baton.unlink(missing_ok=True)
            yield
        finally:
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


def _build(load_inline: Any, folder: Path) -> Any:
    """Compile (or load the cached build of) the kernels into ``folder``."""
    return load_inline(
        name=folder.name,
        build_directory=str(folder),
        cpp_sources=[_CPP_DECL, _CPP_SOURCE],
        functions=[
            "kernel_isa",
            "fps_forward",
            "ball_direct",
            "three_nn_direct",
            "weighted_gather3",
            "tolerant_fps_forward",
            "stable_three_nn",
            "extreme_over_dim",
            "affine_relu",
            "relu_grad_sums",
            "bn_relu_grad_",
            "column_var_mean",
        ],
        # -fopenmp: at::parallel_for is OpenMP in these headers, serial without it; the
        # runtime is the libgomp torch has already loaded (same soname), so one thread pool.
        # -fno-trapping-math lets selects vectorise (no reassociation, no FMA: same results)
        extra_cflags=["-O3", "-ffp-contract=off", "-fno-trapping-math", "-fopenmp"],
        extra_ldflags=["-fopenmp"],
        verbose=False,
    )


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

                folder = build_directory()
                with build_guard(folder):
                    _state["module"] = _build(load_inline, folder)
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
