"""Optional C++ point kernels (FPS, ball-query and 3-NN selection, CFAR's tie-tolerant FPS and 3-NN, the
max-with-index of the fused BatchNorm+max, the passes of the fused train-mode BatchNorm+ReLU), compiled on
first use with ``load_inline``.

The build is cached in ``TORCH_EXTENSIONS_DIR`` (torch's default: ``~/.cache/torch_extensions``),
so only the first process on a machine pays the one-off g++ compile (~25-40 s). Any failure (no
compiler, no ninja, read-only cache) is remembered and callers fall back to pure torch.
Set ``FLOAFF_ZOO_FPS_BACKEND=torch`` to skip the kernels altogether.

FPS matches the torch fallback bit for bit: squared distances are ``(dx*dx + dy*dy) + dz*dz`` in
float32 with FMA contraction disabled, ties go to the lowest index, invalid points carry distance
-1 so they are never selected. The selection kernels take the torch matmul ``-2 src.dst`` and add
the squared norms in the order of ``ops.square_distance`` (plain float adds, no FMA), so they see
the same distances as the torch path; they replace the mask/``where``/``topk`` passes over the
[B, S, N] matrix by one scan that stops once K neighbours are found.
"""

from __future__ import annotations

import os
import threading
import warnings
from typing import Any

_CPP_SOURCE = r"""
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <algorithm>
#include <cstring>
#include <limits>
#include <vector>

// 4 floats: GCC/Clang vector extension, one SSE2/NEON register (the baseline of x86-64 and arm64)
typedef float v4sf __attribute__((vector_size(16)));

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
      for (int64_t j = 0; j < npoint; ++j) {
        O[b * npoint + j] = far;
        const float cx = x[far], cy = y[far], cz = z[far];
        // pass 1, 4 points per step (GCC/Clang vector extension): new distances and their maximum;
        // invalid points hold -1 and min(-1, d) keeps them there (d >= 0).
        // pass 2: the first index holding the maximum (ties to the lowest index).
        v4sf vbest = {-2.0f, -2.0f, -2.0f, -2.0f};
        int64_t i0 = 0;
        for (; i0 + 4 <= N; i0 += 4) {
          v4sf vx, vy, vz, vd;
          std::memcpy(&vx, &x[i0], sizeof(v4sf));
          std::memcpy(&vy, &y[i0], sizeof(v4sf));
          std::memcpy(&vz, &z[i0], sizeof(v4sf));
          std::memcpy(&vd, &dist[i0], sizeof(v4sf));
          const v4sf dx = vx - cx, dy = vy - cy, dz = vz - cz;
          const v4sf d = (dx * dx + dy * dy) + dz * dz;
          const v4sf nd = d < vd ? d : vd;
          std::memcpy(&dist[i0], &nd, sizeof(v4sf));
          vbest = nd > vbest ? nd : vbest;
        }
        float best = -2.0f;
        for (int l = 0; l < 4; ++l) best = vbest[l] > best ? vbest[l] : best;
        for (int64_t i = i0; i < N; ++i) {
          const float dx = x[i] - cx, dy = y[i] - cy, dz = z[i] - cz;
          const float d = (dx * dx + dy * dy) + dz * dz;
          const float nd = d < dist[i] ? d : dist[i];
          dist[i] = nd;
          best = nd > best ? nd : best;
        }
        int64_t besti = 0;
        for (int64_t i = 0; i < N; ++i) {
          if (dist[i] == best) { besti = i; break; }
        }
        far = besti;
      }
    }
  });
  return io.out;
}

// The inputs of the selection kernels: mm [B, S, N] (torch matmul of -2*src and dst^T), ssq [B, S] and
// dsq [B, N] (squared norms), mask [B, N]; Row r = b * S + j gives the distances of centre j of cloud b.
struct Selection {
  int64_t B, S, N;
  const float* mm; const float* ssq; const float* dsq; const bool* mask;
  Selection(torch::Tensor& mm_, torch::Tensor& ssq_, torch::Tensor& dsq_, torch::Tensor& mask_) {
    TORCH_CHECK(mm_.dim() == 3 && mm_.scalar_type() == torch::kFloat && mm_.is_contiguous(), "mm must be contiguous float [B, S, N]");
    B = mm_.size(0); S = mm_.size(1); N = mm_.size(2);
    TORCH_CHECK(ssq_.is_contiguous() && ssq_.numel() == B * S && ssq_.scalar_type() == torch::kFloat, "ssq must be float [B, S]");
    TORCH_CHECK(dsq_.is_contiguous() && dsq_.numel() == B * N && dsq_.scalar_type() == torch::kFloat, "dsq must be float [B, N]");
    TORCH_CHECK(mask_.is_contiguous() && mask_.numel() == B * N && mask_.scalar_type() == torch::kBool, "mask must be bool [B, N]");
    mm = mm_.data_ptr<float>(); ssq = ssq_.data_ptr<float>(); dsq = dsq_.data_ptr<float>(); mask = mask_.data_ptr<bool>();
  }
};

// First K valid points (index order) with d <= r2, d = (mm + ssq) + dsq summed in this order so it
// equals ops.square_distance bit for bit (mm = the torch matmul of -2*src and dst^T). Empty ball ->
// nearest valid point (lowest index on ties); slots past the count repeat the first neighbour.
torch::Tensor ball_select(torch::Tensor mm, torch::Tensor ssq, torch::Tensor dsq, torch::Tensor mask,
                          double r2, int64_t K) {
  const Selection sel(mm, ssq, dsq, mask);
  const int64_t B = sel.B, S = sel.S, N = sel.N;
  auto out = torch::empty({B, S, K}, torch::kLong);
  int64_t* O = out.data_ptr<int64_t>();
  const float rr = static_cast<float>(r2);
  at::parallel_for(0, B * S, 16, [&](int64_t r0, int64_t r1) {
    for (int64_t r = r0; r < r1; ++r) {
      const float* row = sel.mm + r * N;
      const float* t = sel.dsq + (r / S) * N;
      const bool* m = sel.mask + (r / S) * N;
      const float s = sel.ssq[r];
      int64_t* o = O + r * K;
      int64_t cnt = 0;
      for (int64_t i = 0; i < N && cnt < K; ++i) {
        const float d = (row[i] + s) + t[i];
        if (m[i] && d <= rr) o[cnt++] = i;
      }
      if (cnt == 0) {  // no valid point in the ball: nearest valid point
        float best = 0.0f;
        int64_t besti = -1;
        for (int64_t i = 0; i < N; ++i) {
          if (!m[i]) continue;
          const float d = (row[i] + s) + t[i];
          if (besti < 0 || d < best) { best = d; besti = i; }
        }
        o[0] = besti < 0 ? 0 : besti;
        cnt = 1;
      }
      for (int64_t j = cnt; j < K; ++j) o[j] = o[0];
    }
  });
  return out;
}

// Three nearest valid points, d = (mm + ssq) + dsq as above, ascending, ties to the lowest index.
// Missing slots (fewer than 3 valid points): distance +inf, index 0.
std::vector<torch::Tensor> three_nn_select(torch::Tensor mm, torch::Tensor ssq, torch::Tensor dsq, torch::Tensor mask) {
  const Selection sel(mm, ssq, dsq, mask);
  const int64_t B = sel.B, S = sel.S, N = sel.N;
  auto dist = torch::empty({B, S, 3}, torch::kFloat);
  auto idx = torch::empty({B, S, 3}, torch::kLong);
  float* OD = dist.data_ptr<float>();
  int64_t* OI = idx.data_ptr<int64_t>();
  const float inf = std::numeric_limits<float>::infinity();
  at::parallel_for(0, B * S, 16, [&](int64_t r0, int64_t r1) {
    for (int64_t r = r0; r < r1; ++r) {
      const float* row = sel.mm + r * N;
      const float* t = sel.dsq + (r / S) * N;
      const bool* m = sel.mask + (r / S) * N;
      const float s = sel.ssq[r];
      float d0 = inf, d1 = inf, d2 = inf;
      int64_t i0 = 0, i1 = 0, i2 = 0;
      for (int64_t i = 0; i < N; ++i) {
        const float d = (row[i] + s) + t[i];
        if (!m[i] || !(d < d2)) continue;
        if (d < d1) {
          d2 = d1; i2 = i1;
          if (d < d0) { d1 = d0; i1 = i0; d0 = d; i0 = i; } else { d1 = d; i1 = i; }
        } else { d2 = d; i2 = i; }
      }
      OD[3 * r] = d0; OD[3 * r + 1] = d1; OD[3 * r + 2] = d2;
      OI[3 * r] = d0 == inf ? 0 : i0; OI[3 * r + 1] = d1 == inf ? 0 : i1; OI[3 * r + 2] = d2 == inf ? 0 : i2;
    }
  });
  return {dist, idx};
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

_CPP_DECL = """
torch::Tensor fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint);
torch::Tensor ball_select(torch::Tensor mm, torch::Tensor ssq, torch::Tensor dsq, torch::Tensor mask, double r2, int64_t K);
std::vector<torch::Tensor> three_nn_select(torch::Tensor mm, torch::Tensor ssq, torch::Tensor dsq, torch::Tensor mask);
torch::Tensor tolerant_fps_forward(torch::Tensor xyz, torch::Tensor mask, int64_t npoint, double tol);
std::vector<torch::Tensor> stable_three_nn(torch::Tensor unknown, torch::Tensor known, double tol);
std::vector<torch::Tensor> extreme_over_dim(torch::Tensor z, torch::Tensor take_min);
torch::Tensor affine_relu(torch::Tensor z, torch::Tensor a, torch::Tensor c);
std::vector<torch::Tensor> relu_grad_sums(torch::Tensor dy, torch::Tensor y, torch::Tensor z, torch::Tensor mean);
void bn_relu_grad_(torch::Tensor z, torch::Tensor dy, torch::Tensor y, torch::Tensor k, torch::Tensor A, torch::Tensor B);
std::vector<torch::Tensor> column_var_mean(torch::Tensor z);
"""

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
                    name="floaff_zoo_point_ops_v17",
                    cpp_sources=[_CPP_DECL, _CPP_SOURCE],
                    functions=[
                        "fps_forward",
                        "ball_select",
                        "three_nn_select",
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
