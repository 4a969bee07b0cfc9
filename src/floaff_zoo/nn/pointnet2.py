"""PointNet++ building blocks in channels-last form (Linear + BatchNorm1d, docs/background.md §6).

Layer semantics follow the classic PyTorch port (``yanx27/Pointnet_Pointnet2_pytorch``, on which
the public NavAff code relies): MSG levels group ``[features, xyz - centre]``, SSG levels group
``[xyz - centre, features]``, FP concatenates ``[skip features, interpolated]``. Each shared MLP
layer is ``Linear(bias=True)`` + ``BatchNorm1d`` + ``ReLU`` (not in-place: in-place ReLU on reshaped
views costs ~17 % of a step), parameter-for-parameter the Conv 1x1 + BN layout of the port, so
weights convert one to one (``Conv2d.weight[:, :, 0, 0]`` = ``Linear.weight``).

FPS indices can be computed up front (``PointNet2Encoder.sample``), outside any compiled
region or autocast, and passed to ``forward``.

Speed (docs/performance.md), all exact up to float rounding: a set-abstraction MLP pools before its
last ReLU, and in training fuses its last BatchNorm with the max (``_BatchNormMax``); levels with
``GATHER_AFTER_FIRST_LAYER`` or more input channels run their first Linear per point before
grouping; Linear layers with few inputs take a faster weight-gradient GEMM (``_NarrowLinear``); without
gradients the large eval-mode layers run oneDNN's fused Linear+ReLU (``inference_linear``), and a
set-abstraction level whose MLP has no batch statistics runs in chunks of ``CHUNK_ROWS`` grouped rows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from types import EllipsisType

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.nn.ops import (
    ball_query_multi,
    check_features,
    check_points,
    cpu_fast_paths,
    extreme_over_dim,
    farthest_point_sample,
    index_points,
    point_kernel,
    three_interpolate,
)

#: feature channels from which a set-abstraction level runs its first Linear before grouping
#: (cheaper once the input is wider than a few channels; level 1 with 1-4 channels groups first)
GATHER_AFTER_FIRST_LAYER = 16

__all__ = [
    "CHUNK_ROWS",
    "GATHER_AFTER_FIRST_LAYER",
    "FeaturePropagation",
    "PointNet2Encoder",
    "PointNet2Seg",
    "SetAbstraction",
    "SharedMLP",
    "masked_max",
    "on_valid_rows",
]


class SharedMLP(nn.Module):
    """Per-point MLP on the last dim: (Linear -> BatchNorm1d -> ReLU) per layer.

    Args:
        in_channels: input width; widths: output width of each layer; last_act: apply BN+ReLU on
            the last layer too (True for PointNet++ MLPs).
    """

    def __init__(self, in_channels: int, widths: Sequence[int], last_act: bool = True) -> None:
        super().__init__()
        # True built a layer of 1; 2.5 or -1 failed inside nn.Linear. A width of 0 builds: the models'
        # check_layer_sizes refuses it naming the model and the layer, which this class cannot
        check_integer("in_channels", in_channels, 1, owner="SharedMLP")
        for w in widths:
            check_integer("widths: a layer's width", w, 0, owner="SharedMLP")
        self.linears = nn.ModuleList()
        self.norms = nn.ModuleList()
        c = in_channels
        for i, w in enumerate(widths):
            self.linears.append(nn.Linear(c, w))
            act = last_act or i < len(widths) - 1
            self.norms.append(nn.BatchNorm1d(w) if act else nn.Identity())
            c = w
        self.out_channels = c

    def forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
        """x [..., C_in] -> [..., C_out]; ``mask`` [...] bool (False = padding), optional.

        With a mask and batch statistics in use (a training-mode BatchNorm), only the valid rows run and the
        padding rows of the output are 0, so padding never enters the batch or running statistics. Without
        batch statistics every row is independent of the others and all run.
        """
        if mask is not None:
            check_row_mask("SharedMLP", x, mask)
        if mask is None or self.rowwise():
            return self._run(x, pre=False)
        return on_valid_rows(lambda rows: self._run(rows, pre=False), x, mask)

    def pooled(self, x: Tensor, dim: int, mask: Tensor | None = None, first: Tensor | None = None) -> Tensor:
        """``masked_max(self(x), mask, dim)`` with the last ReLU after the max (exact: ReLU is monotonic).

        Pooling before the last activation skips a ReLU and its backward over the largest tensor,
        and ``max`` (one winner) backpropagates with a scatter where ``amax`` needs a tie count.
        ``first`` (optional) is the first layer's pre-activation, already computed (see
        ``SetAbstraction``); ``x`` is then ignored. In training ``first`` is consumed: the backward may
        write its gradient into ``first``'s memory, so pass a tensor nothing else reads.

        Args:
            x: [..., C_in]; dim: the pooled dim of the output; mask: broadcast over the last dim
                (False = ignored), shaped like the output without its last dim.
        Returns:
            the output with ``dim`` removed.
        """
        if mask is None and self._fusable(first):
            h = self._run(x if first is None else first, pre=first is not None, stop=len(self.linears) - 1)
            lin, norm = self.linears[-1], self.norms[-1]
            track = norm.track_running_stats  # False: batch statistics only (e.g. PFAL's frozen teacher)
            if track:
                norm.num_batches_tracked.add_(1)
            stats = (norm.running_mean, norm.running_var) if track else (None, None)
            z = train_linear(h.reshape(-1, h.shape[-1]), lin.weight).reshape(*h.shape[:-1], -1)
            # z is private to this call, so the backward may write its gradient over it
            reuse = not torch.compiler.is_compiling()
            pooled = _BatchNormMax.apply(
                z, lin.bias, norm.weight, norm.bias, *stats, norm.momentum or 0.0, norm.eps, dim, reuse
            )
            return F.relu(pooled)
        last = self._last_affine()
        if last is not None and (first is None or len(self.linears) > 1):
            # eval-mode BN (folded) or none: max(z + b) = max(z) + b, so the bias is added after the pool
            h = self._run(x if first is None else first, pre=first is not None, stop=len(self.linears) - 1)
            weight, bias = last
            h = _pool(inference_linear(h, weight), mask, dim)
            h = h + bias.to(h.dtype)
        else:
            h = _pool(self._run(x if first is None else first, pre=first is not None, last_relu=False), mask, dim)
        return F.relu(h) if self.last_act() else h

    def _last_affine(self) -> tuple[Tensor, Tensor] | None:
        """(weight [O, I], bias [O]) of the last layer when it is affine (BN in eval mode, folded, or no BN)."""
        lin, norm = self.linears[-1], self.norms[-1]
        if lin.bias is None:
            return None
        if _eval_batch_norm(norm):
            return _fold_bn(lin, norm)
        return (lin.weight, lin.bias) if isinstance(norm, nn.Identity) else None

    def rowwise(self) -> bool:
        """Whether each row's output depends on that row only: no BatchNorm uses batch statistics
        (every norm is an eval-mode BN with running statistics, or none)."""
        return all(isinstance(n, nn.Identity) or _eval_batch_norm(n) for n in self.norms)

    def folded_layers(self) -> list[tuple[Tensor, Tensor]]:
        """(weight [O, I], bias [O]) of every layer with its eval-mode BN folded in; for ``rowwise`` MLPs."""
        out = []
        for lin, norm in zip(self.linears, self.norms):
            bias = lin.bias if lin.bias is not None else lin.weight.new_zeros(lin.out_features)
            out.append(_fold_bn(lin, norm) if isinstance(norm, nn.BatchNorm1d) else (lin.weight, bias))
        return out

    def last_act(self) -> bool:
        """Whether the last layer has BN + ReLU (PointNet++ MLPs) or is a bare Linear."""
        return not isinstance(self.norms[-1], nn.Identity)

    def first_linear(self) -> tuple[Tensor, Tensor]:
        """(weight [O, I], bias [O]) of the first layer, BN folded in eval mode (as ``forward`` uses)."""
        lin, norm = self.linears[0], self.norms[0]
        if _eval_batch_norm(norm):
            return _fold_bn(lin, norm)
        return lin.weight, lin.bias

    def _fusable(self, first: Tensor | None) -> bool:
        """Whether ``pooled`` may fuse the last BatchNorm with the max (train-mode BN, fp32/64, no autocast).

        Also without gradients (a teacher on batch statistics), so that it computes what the student does.
        """
        norm, lin = self.norms[-1], self.linears[-1]
        return (
            isinstance(norm, nn.BatchNorm1d)
            and norm.training
            and (norm.momentum is not None or not norm.track_running_stats)
            and norm.affine
            and lin.bias is not None
            and not torch.is_autocast_enabled(lin.weight.device.type)
            and lin.weight.dtype in (torch.float32, torch.float64)
            and (first is None or len(self.linears) > 1)
        )

    def _run(self, h: Tensor, pre: bool, last_relu: bool = True, stop: int | None = None) -> Tensor:
        """h [..., C_in] -> [..., C_out] (layers before ``stop`` only, when given: all with their ReLU).

        With ``pre``, h is already the first Linear's output.
        """
        shape = h.shape[:-1]
        h = h.reshape(-1, h.shape[-1])
        last = len(self.linears) - 1 if stop is None else stop
        # no grad: ReLU in place on a fresh GEMM/BN output saves a big allocation
        inplace = not torch.is_grad_enabled()
        for i, (lin, norm) in enumerate(zip(self.linears[:stop], self.norms[:stop])):
            skip = pre and i == 0
            act = i < last or (last_relu and self.last_act()) or stop is not None
            if _eval_batch_norm(norm):
                if not skip and act and inplace:  # eval, no grad: BN folded, ReLU fused into the GEMM
                    h = inference_linear(h, *_fold_bn(lin, norm), relu=True)
                    continue
                h = h if skip else inference_linear(h, *_fold_bn(lin, norm))  # eval: BN folded into the Linear
            elif _train_batch_norm(norm):
                # the Linear's bias is left out (train-mode BN cancels it; it enters the running mean only);
                # with ``pre`` the first layer's output, bias included, is given
                z = h if skip else _linear(h, lin, with_bias=False)
                bias = lin.bias if not skip and lin.bias is not None else z.new_zeros(z.shape[-1])
                if act and _fused_bn_relu_ok(z):
                    h = _batch_norm_relu(z, bias, norm)
                    continue
                h = _batch_norm_absorbing_bias(z, bias, norm)
            else:
                h = h if skip else _linear(h, lin)
                h = norm(h) if isinstance(norm, nn.BatchNorm1d) else h
            if act:
                h = torch.relu_(h) if inplace and not skip else F.relu(h)
        return h.reshape(*shape, h.shape[-1])


def check_row_mask(owner: str, x: Tensor, mask: Tensor) -> None:
    """Raise ``ValueError`` unless ``mask`` is x [*S, C]'s [*S] (shape only: no device sync); a [B, 1] or a
    transposed mask of x's row count had its rows run, or kept out, at other positions."""
    if mask.shape != x.shape[:-1]:
        raise ValueError(f"{owner}: mask must be {list(x.shape[:-1])} for x {list(x.shape)}, got {list(mask.shape)}")


def on_valid_rows(fn: Callable[[Tensor], Tensor], x: Tensor, mask: Tensor) -> Tensor:
    """``fn`` on the valid rows of x [*S, C] only (mask [*S] bool) -> [*S, *O], 0 on the other rows.

    For a per-row ``fn`` whose only coupling across rows is a training-mode BatchNorm, the valid rows get what
    ``fn`` gives a batch of the valid rows alone: the padding is neither normalised with them nor counted in
    the statistics.
    """
    check_row_mask("on_valid_rows", x, mask)
    if bool(mask.all()):
        return fn(x)
    # gather / scatter by index: their backward needs no boolean indexing (which torch.compile cannot lower)
    flat = mask.reshape(-1).nonzero().squeeze(1)  # [R]
    rows = fn(x.reshape(-1, x.shape[-1]).index_select(0, flat))  # [R, *O]
    out = rows.new_zeros(mask.numel(), *rows.shape[1:]).index_copy(0, flat, rows)
    return out.reshape(*mask.shape, *rows.shape[1:])


#: Linear layers this narrow take ``_NarrowLinear``'s weight gradient
NARROW_IN_FEATURES = 8


def repeat_sources(idx: Tensor | None) -> Tensor | None:
    """Where each centre of idx [B, S] (FPS indices) takes its row from: [B, S] int64, 0 for a repeat, else its own
    position; None where nothing repeats (or idx is None).

    FPS over a cloud with fewer valid points than centres repeats its first centre once the valid points run out
    (``ops.farthest_point_sample``, CFAR's ``tolerant_fps`` and their C++ / Triton kernels: the first valid point
    wins every tie at distance 0), so a repeat is an entry equal to ``idx[:, 0]`` after position 0.
    """
    if idx is None or idx.shape[1] < 2:
        return None
    repeat = idx == idx[:, :1]
    repeat[:, 0] = False
    if not bool(repeat.any()):
        return None
    own = torch.arange(idx.shape[1], device=idx.device).expand_as(idx)
    return torch.where(repeat, torch.zeros_like(own), own)


def copy_to_repeats(x: Tensor, src: Tensor | None) -> Tensor:
    """x [B, S, C] with every repeated centre's row replaced by its first occurrence's (``repeat_sources`` src)."""
    return x if src is None else x.gather(1, src[..., None].expand(-1, -1, x.shape[-1]))


def kept_centres(src: Tensor | None) -> Tensor | None:
    """[B, S] bool, False on repeated centres (``repeat_sources``), or None when nothing repeats."""
    return None if src is None else src == torch.arange(src.shape[1], device=src.device)


def _linear(h: Tensor, lin: nn.Linear, with_bias: bool = True) -> Tensor:
    """``lin(h)`` (without its bias unless ``with_bias``) for h [R, C_in]; narrow inputs (xyz + a flag)
    train through ``_NarrowLinear``."""
    bias = lin.bias if with_bias else None
    if (
        lin.in_features <= NARROW_IN_FEATURES
        and torch.is_grad_enabled()
        and not torch.is_autocast_enabled(h.device.type)  # autocast casts inside forward only
    ):
        return _NarrowLinear.apply(h, lin.weight, bias)
    if bias is None:
        return train_linear(h, lin.weight)
    return F.linear(h, lin.weight, bias)


def _onednn_ok(h: Tensor, weight: Tensor) -> bool:
    """Whether oneDNN's Linear serves h [..., C_in]: CPU fp32, no autocast, eager, at least ONEDNN_MIN_ROWS rows."""
    return (
        _ONEDNN_LINEAR
        and cpu_fast_paths(h.device)
        and h.dtype == weight.dtype == torch.float32
        and not torch.is_autocast_enabled("cpu")
        and h.numel() >= ONEDNN_MIN_ROWS * h.shape[-1]
    )


def train_linear(h: Tensor, weight: Tensor) -> Tensor:
    """``F.linear(h, weight)`` (no bias) for h [R, C_in] -> [R, C_out], differentiable.

    Where oneDNN serves it (``_onednn_ok``) the product and its input gradient run on oneDNN's GEMM
    (``_OneDNNLinear``): on the 2-core benchmark machine 1.3-2.6x faster than the default GEMM for a
    training step's tall, narrow shapes (e.g. [262 K, 64] x [64, 128]); equal up to float rounding.
    """
    if _onednn_ok(h, weight) and h.ndim == 2:
        return _OneDNNLinear.apply(h, weight)
    return F.linear(h, weight)


class _OneDNNLinear(torch.autograd.Function):
    """``F.linear(x, weight)`` without bias on oneDNN: forward and input gradient (``dy W`` is the Linear of
    dy with ``W^T``); the weight gradient ``dy^T x`` stays on the default GEMM (a long reduction over rows)."""

    @staticmethod
    def forward(ctx, x: Tensor, weight: Tensor) -> Tensor:
        """x [R, I], weight [O, I] -> [R, O]."""
        ctx.save_for_backward(x, weight)
        return torch.ops.mkldnn._linear_pointwise(x.contiguous(), weight, None, "none", [], "")

    @staticmethod
    def backward(ctx, grad: Tensor):
        x, weight = ctx.saved_tensors
        gx = gw = None
        if ctx.needs_input_grad[0]:
            gx = torch.ops.mkldnn._linear_pointwise(grad.contiguous(), weight.t().contiguous(), None, "none", [], "")
        if ctx.needs_input_grad[1]:
            gw = grad.t().mm(x)
        return gx, gw


#: oneDNN's fused Linear(+ReLU) for CPU inference (the GEMM kernel Inductor uses): on the 2-core
#: benchmark machine 1.1-1.8x faster than the default fp32 GEMM at PointNet++'s narrow widths, and it
#: writes bias and ReLU in the same pass (no bias copy before the GEMM, no ReLU pass after)
_ONEDNN_LINEAR = torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_linear_pointwise")
#: rows below which the default GEMM is kept: oneDNN's per-call overhead outweighs the gain there (2-core
#: machine: 2-10 % faster than the default GEMM from 256 to 2,048 rows at PointNet++'s widths, 6 % slower at 64)
ONEDNN_MIN_ROWS = 256


def inference_linear(h: Tensor, weight: Tensor, bias: Tensor | None = None, relu: bool = False) -> Tensor:
    """``F.linear(h, weight, bias)`` (then ReLU when ``relu``) for h [..., C_in] -> [..., C_out].

    Without gradients, on CPU in fp32 (no autocast, not compiling) it runs oneDNN's fused kernel, equal
    to the default GEMM up to float rounding (summation order); elsewhere the plain ops.
    """
    if not torch.is_grad_enabled() and _onednn_ok(h, weight):
        flat = h.reshape(-1, h.shape[-1])
        post, scalars = ("relu", [None]) if relu else ("none", [])
        out = torch.ops.mkldnn._linear_pointwise(flat, weight, bias, post, scalars, "")
        return out.reshape(*h.shape[:-1], weight.shape[0])
    out = F.linear(h, weight, bias)
    return torch.relu_(out) if relu else out


def _eval_batch_norm(norm: nn.Module) -> bool:
    """Whether ``norm`` is an eval-mode BatchNorm on running statistics (an affine map per channel)."""
    return isinstance(norm, nn.BatchNorm1d) and not norm.training and norm.running_mean is not None


def _train_batch_norm(norm: nn.Module) -> bool:
    """Whether ``norm`` is a train-mode BatchNorm (affine, exponential running average): its output does not
    depend on a bias added before it."""
    return (
        isinstance(norm, nn.BatchNorm1d)
        and norm.training
        and norm.affine
        and norm.momentum is not None
        and norm.momentum < 1.0
    )


def _fused_bn_relu_ok(z: Tensor) -> bool:
    """Whether ``_BatchNormReLU`` serves z [R, C]: the C++ kernels (CPU, eager), fp32/64, no autocast."""
    return (
        z.dtype in (torch.float32, torch.float64)
        and not torch.is_autocast_enabled(z.device.type)
        and point_kernel(z.device) is not None
    )


def _update_running_stats(
    norm_stats: tuple[Tensor | None, Tensor | None], mean: Tensor, var: Tensor, bias: Tensor, n: int, momentum: float
) -> None:
    """BatchNorm's running-statistics update from the batch (mean [C], biased var [C]) of z = x W^T, whose
    Linear bias [C] was left out (it shifts the mean only); the variance is stored unbiased, as BatchNorm does."""
    running_mean, running_var = norm_stats
    if running_mean is not None and running_var is not None:
        running_mean.mul_(1 - momentum).add_((mean + bias) * momentum)
        running_var.mul_(1 - momentum).add_(var * (n / max(n - 1, 1)) * momentum)


def _batch_norm_relu(z: Tensor, bias: Tensor, norm: nn.BatchNorm1d) -> Tensor:
    """``relu(norm(z + bias))`` in train mode for z [R, C] private to the caller (its memory is reused)."""
    track = norm.track_running_stats
    if track:
        norm.num_batches_tracked.add_(1)
    stats = (norm.running_mean, norm.running_var) if track else (None, None)
    reuse = not torch.compiler.is_compiling()
    return _BatchNormReLU.apply(z, bias, norm.weight, norm.bias, *stats, norm.momentum, norm.eps, reuse)


class _BatchNormReLU(torch.autograd.Function):
    """``relu(BatchNorm(z + bias))`` in train mode, for a hidden layer of a shared MLP, on the C++ kernels.

    Same values, gradients and running statistics as ``F.relu(norm(lin(x)))``: the Linear's bias is not
    added (train-mode BN removes it; it enters the running mean only and its gradient is zero), the output
    is written in one pass, and the backward (ReLU and BN together) reads dy, y and z twice and writes the
    input gradient over z when ``reuse_z`` (z is referenced nowhere else), instead of allocating two
    tensors of z's size.
    """

    @staticmethod
    def forward(
        ctx,
        z: Tensor,
        bias: Tensor,
        weight: Tensor,
        beta: Tensor,
        running_mean: Tensor | None,
        running_var: Tensor | None,
        momentum: float,
        eps: float,
        reuse_z: bool = False,
    ) -> Tensor:
        """z [R, C] = x @ W^T (no bias), bias [C] of that Linear, BN weight/beta/stats [C] -> y [R, C] >= 0."""
        kernel = point_kernel(z.device)
        z = z.contiguous()
        n = z.shape[0]
        var, mean = batch_mean_var(z)
        invstd = torch.rsqrt(var + eps)
        _update_running_stats((running_mean, running_var), mean, var, bias, n, momentum)
        scale = weight * invstd
        y = kernel.affine_relu(z, scale.contiguous(), (beta - mean * scale).contiguous())
        ctx.save_for_backward(z, y, weight, mean, invstd)
        ctx.n, ctx.reuse_z = n, reuse_z
        return y

    @staticmethod
    def backward(ctx, grad: Tensor):
        z, y, weight, mean, invstd = ctx.saved_tensors
        kernel, n = point_kernel(z.device), ctx.n
        grad = grad.contiguous()
        sum_g, sum_gx = kernel.relu_grad_sums(grad, y, z, mean.contiguous())  # sum_gx: sum of g (z - mean)
        k = weight * invstd
        # dz = k (g - sum_g / n - xhat sum(g xhat) / n) = A z + B + k g, with sum(g xhat) = invstd sum_gx
        a = -k * invstd * invstd * sum_gx / n
        b = -k * sum_g / n - a * mean
        dz = z if ctx.reuse_z else z.clone()
        kernel.bn_relu_grad_(dz, grad, y, k.contiguous(), a.contiguous(), b.contiguous())
        return dz, torch.zeros_like(weight), invstd * sum_gx, sum_g, None, None, None, None, None


def _batch_norm_absorbing_bias(z: Tensor, bias: Tensor, norm: nn.BatchNorm1d) -> Tensor:
    """``norm(z + bias)`` in train mode for z [R, C], without writing ``z + bias``.

    Train-mode BN subtracts the batch mean, so the bias cancels in the output (its gradient is exactly
    zero, kept in the graph so every parameter still receives one, as DDP expects); it only enters the
    running mean, which is corrected here. Saves a pass over the layer's output and the bias-gradient
    reduction, per hidden layer.
    """
    if z.shape[0] == 1:
        return one_row_batch_norm(z, bias, norm)
    track = norm.track_running_stats
    m = norm.momentum
    if track:
        norm.num_batches_tracked.add_(1)
        # BN then sets (1 - m) r + m mean(z); adding m b / (1 - m) first makes it (1 - m) r + m mean(z + b).
        # BN saves the running stats for its backward: written through .data, which leaves their version
        # alone (as BN's own update does), a second forward before the first backward keeps the first graph valid
        with torch.no_grad():
            norm.running_mean.data.add_(bias.to(norm.running_mean.dtype), alpha=m / (1.0 - m))
    stats = (norm.running_mean, norm.running_var) if track else (None, None)
    return F.batch_norm(z, *stats, norm.weight, norm.bias + 0.0 * bias, True, m, norm.eps)


def one_row_batch_norm(z: Tensor, bias: Tensor, norm: nn.BatchNorm1d) -> Tensor:
    """``norm(z + bias)`` in train mode for a batch of one row, z [1, C], which ``nn.BatchNorm1d`` refuses.

    A batch of one view with one floor point reaches the per-floor-point layers as one row. Its batch mean is
    the row itself, so the output is BatchNorm's shift and the batch variance is 0; the running statistics take
    that mean and variance, as the fused CPU kernel (``_BatchNormReLU``) does, where torch's kernel would store
    a NaN variance. The zero-valued terms keep every parameter in the graph (DDP expects a gradient for each).
    """
    if norm.track_running_stats:
        norm.num_batches_tracked.add_(1)
        m = norm.momentum if norm.momentum is not None else 1.0 / float(norm.num_batches_tracked)
        with torch.no_grad():
            row = z[0].detach().to(norm.running_mean.dtype)
            _update_running_stats((norm.running_mean, norm.running_var), row, torch.zeros_like(row), bias, 1, m)
    return norm.bias + 0.0 * (z + bias) * norm.weight


class _NarrowLinear(torch.autograd.Function):
    """``F.linear`` whose weight gradient is ``(x^T dy)^T``: the GEMM library handles a [R, 4] input
    several times faster in that order than autograd's ``dy^T x`` (measured ~7x at R = 262 K on CPU)."""

    @staticmethod
    def forward(ctx, x: Tensor, weight: Tensor, bias: Tensor | None) -> Tensor:
        """x [R, I], weight [O, I], bias [O] or None -> [R, O]."""
        ctx.save_for_backward(x, weight)
        return F.linear(x, weight, bias)

    @staticmethod
    def backward(ctx, grad: Tensor):
        x, weight = ctx.saved_tensors
        gx = grad @ weight if ctx.needs_input_grad[0] else None
        gw = (x.t() @ grad).t() if ctx.needs_input_grad[1] else None
        gb = grad.sum(0) if len(ctx.needs_input_grad) > 2 and ctx.needs_input_grad[2] else None
        return gx, gw, gb


class _BatchNormMax(torch.autograd.Function):
    """``max(BatchNorm(z + bias), dim)`` in train mode, for the last layer of a pooled MLP.

    Same values, gradients and running statistics as ``norm(lin(x)).max(dim)``, with less memory
    traffic: the Linear's bias is not added to the big tensor (train-mode BN subtracts it again; it
    only enters the running mean, and its gradient is exactly zero), the normalised tensor is not
    written (the max of an affine map is read off z), and the backward writes the input gradient
    in one pass (the BN gradient of rows that lost the max is affine in z) plus a scatter for the
    winners, instead of a zero-filled output gradient followed by the two passes of the BN backward.
    """

    @staticmethod
    def forward(
        ctx,
        z: Tensor,
        bias: Tensor,
        weight: Tensor,
        beta: Tensor,
        running_mean: Tensor | None,
        running_var: Tensor | None,
        momentum: float,
        eps: float,
        dim: int,
        reuse_z: bool = False,
    ) -> Tensor:
        """z [..., C] = x @ W^T (no bias), bias [C] of that Linear, BN weight/beta/stats [C] -> [...] w/o ``dim``.

        ``reuse_z``: z is referenced nowhere else, so the backward writes the gradient into z's memory
        (saves allocating and page-faulting the largest tensor of the step; a second backward through the
        same graph then fails on autograd's version check instead of reading a stale z).
        """
        c = z.shape[-1]
        flat = z.reshape(-1, c)
        n = flat.shape[0]
        var, mean = batch_mean_var(flat)
        invstd = torch.rsqrt(var + eps)
        _update_running_stats((running_mean, running_var), mean, var, bias, n, momentum)
        # BN is a per-channel affine map a z + b: its max over `dim` is at z's max where a >= 0, else at
        # z's min, so the normalised tensor is never written
        scale = weight * invstd
        vals, idx = extreme_over_dim(z, dim, scale < 0)
        vals = torch.addcmul(beta - mean * scale, vals, scale)
        ctx.save_for_backward(z, weight, mean, invstd, idx)
        ctx.dim, ctx.n, ctx.reuse_z = dim, n, reuse_z
        return vals

    @staticmethod
    def backward(ctx, grad: Tensor):
        z, weight, mean, invstd, idx = ctx.saved_tensors
        dim, n = ctx.dim, ctx.n
        c = z.shape[-1]
        at = idx.unsqueeze(dim)
        xhat_win = (z.gather(dim, at).squeeze(dim) - mean) * invstd  # normalised winners
        sum_dy = grad.reshape(-1, c).sum(0)
        sum_dy_xhat = (grad * xhat_win).reshape(-1, c).sum(0)
        k = weight * invstd
        # dz = k (dy - sum_dy / n - xhat sum_dy_xhat / n): affine in z where dy = 0 (one pass), plus k dy
        # at the winners (relative rounding ~ eps |mean| / std, as in any BN backward)
        alpha = -k * invstd * sum_dy_xhat / n
        dz = torch.addcmul(-k * sum_dy / n - alpha * mean, z, alpha, out=z if ctx.reuse_z else None)
        dz.scatter_add_(dim, at, (k * grad).unsqueeze(dim))
        return dz, torch.zeros_like(weight), sum_dy_xhat, sum_dy, None, None, None, None, None, None


#: rows per chunk of ``batch_mean_var``'s second pass (a chunk of 128 channels stays in a 1 MB cache)
STATS_CHUNK_ROWS = 2048


def batch_mean_var(flat: Tensor) -> tuple[Tensor, Tensor]:
    """Per-channel (biased variance, mean) of flat [R, C], reduced over the rows.

    Two passes (a sum, then centred squares): on CPU one C++ kernel (``column_var_mean``, fixed row
    blocks summed in double, so independent of the thread count), else chunked torch ops whose temporary
    stays in cache. Both are about 10x faster than ``torch.var_mean(flat, 0)``, whose reduction over the
    outer dim is not vectorised on CPU, and as accurate as a centred two-pass sum (relative error ~1e-7
    in fp32; BatchNorm's own ~1e-5). On other devices and under ``torch.compile`` it is
    ``torch.var_mean`` (fast there; the chunk loop would only add kernel launches or unroll into the graph).
    Not differentiable on the kernel path (callers are autograd Functions' forwards).
    Returns:
        (var [C], mean [C]), the order of ``torch.var_mean``.
    """
    if not cpu_fast_paths(flat.device):
        return torch.var_mean(flat, dim=0, correction=0)
    kernel = point_kernel(flat.device)
    if kernel is not None and flat.dtype in (torch.float32, torch.float64) and flat.shape[0] > 0:
        var, mean = kernel.column_var_mean(flat.contiguous())
        return var, mean
    n = flat.shape[0]
    mean = flat.sum(0) / n
    acc = torch.zeros_like(mean)
    for chunk in flat.split(STATS_CHUNK_ROWS):
        d = chunk - mean
        acc += (d * d).sum(0)
    return acc / n, mean


def _fold_bn(lin: nn.Linear, norm: nn.BatchNorm1d) -> tuple[Tensor, Tensor]:
    """(weight [O, I], bias [O]) of ``norm(lin(x))`` with BN in eval mode (running statistics).

    Folding is exact up to float rounding (~1e-7 relative) and removes one pass over the
    activations; recomputed every call (O x I work), so it always follows the current weights.
    """
    scale = norm.running_var.add(norm.eps).rsqrt()
    if norm.weight is not None:
        scale = scale * norm.weight
    bias = -norm.running_mean if lin.bias is None else lin.bias - norm.running_mean
    bias = bias * scale
    if norm.bias is not None:
        bias = bias + norm.bias
    return lin.weight * scale[:, None], bias


def _pool(h: Tensor, mask: Tensor | None, dim: int) -> Tensor:
    """Max of h over ``dim``, masked entries (False) ignored; ``max`` (one winner, backward is a scatter)
    when a gradient is needed, ``amax`` (the faster forward-only reduction) otherwise."""
    if mask is not None:
        h = h.masked_fill(~mask[..., None], torch.finfo(h.dtype).min)
    return h.max(dim=dim).values if torch.is_grad_enabled() and h.requires_grad else h.amax(dim=dim)


def masked_max(x: Tensor, mask: Tensor | None, dim: int) -> Tensor:
    """Max over ``dim`` ignoring entries where ``mask`` is False (mask broadcast over the last dim)."""
    if mask is None:
        return x.amax(dim=dim)
    neg = torch.finfo(x.dtype).min
    return x.masked_fill(~mask[..., None], neg).amax(dim=dim)


#: grouped rows (B x centres x K) per chunk when a set-abstraction level runs row by row (see
#: ``_centres_per_chunk``): a chunk's activations stay in the CPU caches between its layers
CHUNK_ROWS = 4096
#: fewest centres worth a chunk: below this the per-chunk calls cost more than the cache saves (2-core
#: benchmark machine: a B = 1 PointNet++ predict, 128 centres per chunk, 2-7 % faster; B = 8 validation
#: batches, 16 centres per chunk, 3-5 % slower, so batches run in one pass)
MIN_CHUNK_CENTRES = 128


def _centres_per_chunk(mlp: SharedMLP, idx: Tensor) -> int:
    """Centres per chunk of a level with groups idx [B, S, K]: all S unless the level may run in chunks.

    Chunks only where they change nothing: without gradients, on CPU, eager, and when every row's output
    depends on that row alone (``SharedMLP.rowwise``: no batch statistics, which a chunk would change); and
    only where a chunk holds at least ``MIN_CHUNK_CENTRES`` centres.
    """
    b, s, k = idx.shape
    if torch.is_grad_enabled() or not cpu_fast_paths(idx.device) or not mlp.rowwise():
        return max(s, 1)
    step = CHUNK_ROWS // max(1, b * k)
    return step if step >= MIN_CHUNK_CENTRES else max(s, 1)


def _pool_rows(layers: list[tuple[Tensor, Tensor]], h: Tensor, pre: bool) -> Tensor:
    """Max over dim 2 of a row-wise MLP's last pre-activation, without its last bias.

    Args:
        layers: (weight [O, I], bias [O]) per layer, BN folded (``SharedMLP.folded_layers``); h: [B, S, K, C_in],
            or with ``pre`` the first layer's pre-activation [B, S, K, C1] (bias included).
    Returns:
        [B, S, C_out]: max_k of ``h_{L-1} W_L^T``; the caller adds the last bias and activation once.
    """
    for j, (w, b) in enumerate(layers[:-1]):
        h = torch.relu_(h) if pre and j == 0 else inference_linear(h, w, b, relu=True)
    return inference_linear(h, layers[-1][0]).amax(dim=2)


class SetAbstraction(nn.Module):
    """One PointNet++ set-abstraction level: FPS centres, ball query per scale, shared MLP, max-pool.

    Args:
        npoint: centres (ignored when ``group_all``); radii / nsamples: one entry per scale;
        in_channels: feature channels D of the input (xyz not counted); mlps: one width list per
        scale; group_all: pool the whole cloud into one centre (final SSG level);
        xyz_first: channel order of the grouped input: ``[xyz, feat]`` (SSG port) or
        ``[feat, xyz]`` (MSG port).
    """

    def __init__(
        self,
        npoint: int,
        radii: Sequence[float],
        nsamples: Sequence[int],
        in_channels: int,
        mlps: Sequence[Sequence[int]],
        group_all: bool = False,
        xyz_first: bool = False,
    ) -> None:
        super().__init__()
        if not group_all and not (len(radii) == len(nsamples) == len(mlps)):
            raise ValueError(f"radii {radii}, nsamples {nsamples}, mlps {mlps}: one entry per scale needed")
        # a negative count built a narrower first layer that failed at the first batch
        check_integer("in_channels", in_channels, 0, owner="SetAbstraction")
        if group_all and len(mlps) != 1:  # an IndexError at the first batch, or extra MLPs that never ran
            raise ValueError(f"SetAbstraction: a group-all level takes one MLP, got mlps {[list(m) for m in mlps]}")
        if not group_all:  # checked here, not at the first batch
            if not mlps:  # no scale: 0 output channels, and torch.cat of nothing at the first batch
                raise ValueError("SetAbstraction: a level needs at least one scale (radius, nsample, mlp)")
            # whole numbers: int() cut 2.5 centres or neighbours to 2, and True was 1
            check_integer("npoints: a level's centres", npoint, 1)
            for k in nsamples:
                check_integer("nsamples: a ball's neighbours", k, 1)
            for r in radii:  # True was a radius of 1 m, a text a TypeError naming no argument
                check_number("radii: a ball's radius", r, strict=True)
            if any(len(m) < 1 for m in mlps):  # an IndexError at the first batch
                raise ValueError(f"mlps: every scale needs >= 1 width, got {[list(m) for m in mlps]}")
        self.npoint = int(npoint)
        self.radii = [float(r) for r in radii]
        self.nsamples = [int(k) for k in nsamples]
        self.group_all = group_all
        self.xyz_first = xyz_first
        self.in_channels = in_channels
        self.mlps = nn.ModuleList(SharedMLP(in_channels + 3, m) for m in mlps)
        self.out_channels = sum(m.out_channels for m in self.mlps)

    def _cat(self, rel: Tensor, feat: Tensor | None) -> Tensor:
        if feat is None:
            return rel
        return torch.cat([rel, feat] if self.xyz_first else [feat, rel], dim=-1)

    def sample(self, xyz: Tensor, mask: Tensor | None) -> Tensor | None:
        """FPS centre indices [B, npoint] (None for group-all)."""
        return None if self.group_all else farthest_point_sample(xyz, mask, self.npoint)

    def forward(
        self,
        xyz: Tensor,
        feat: Tensor | None,
        mask: Tensor | None = None,
        fps_idx: Tensor | None = None,
        src: Tensor | None | EllipsisType = ...,
    ) -> tuple[Tensor, Tensor]:
        """xyz [B,N,3], feat [B,N,D] | None, mask [B,N] | None, fps_idx [B,S] | None, src [B,S] | None: fps_idx's
        ``repeat_sources`` when the caller has them (None: no centre repeats); ``...`` (default): found here, a host
        sync, only when a batch-statistics MLP needs them.

        Returns (new_xyz [B,S,3], new_feat [B,S,C_out]).
        """
        check_points("SetAbstraction: xyz", xyz)
        check_features("SetAbstraction", "feat", feat, xyz, self.in_channels)
        if fps_idx is not None and list(fps_idx.shape) != [xyz.shape[0], self.npoint]:
            # another count of centres ran silently (the MLP does not care how many)
            raise ValueError(
                f"SetAbstraction: fps_idx must be [{xyz.shape[0]}, {self.npoint}], got {list(fps_idx.shape)}"
            )
        if self.group_all:
            grouped = self._cat(xyz, feat)  # classic port: raw xyz, centre at the origin
            mlp = self.mlps[0]
            if mask is not None and not mlp.rowwise():  # masked rows (repeated centres) stay out of the statistics
                out = masked_max(mlp(grouped, mask), mask, 1)[:, None]
            else:
                out = mlp.pooled(grouped, dim=1, mask=mask)[:, None]
            return xyz.new_zeros(xyz.shape[0], 1, 3), out
        if fps_idx is None:
            fps_idx = farthest_point_sample(xyz, mask, self.npoint)
        new_xyz = index_points(xyz, fps_idx)
        groups = ball_query_multi(self.radii, self.nsamples, xyz, new_xyz, mask)
        # a repeated centre groups the same neighbours as its first occurrence, so it has the same features; with
        # batch statistics it would still count again in them (a 150-point floor under 256 centres: 40 % of the rows)
        if src is ...:
            src = repeat_sources(fps_idx) if not all(m.rowwise() for m in self.mlps) else None
        outs = []
        for idx, mlp in zip(groups, self.mlps):
            per_point = None
            if feat is not None and self.in_channels >= GATHER_AFTER_FIRST_LAYER:
                per_point = self._first_layer_per_point(mlp, xyz, feat)
            step = _centres_per_chunk(mlp, idx)
            # a one-layer MLP given its (gathered) first layer has nothing left to chunk
            if step >= idx.shape[1] or (per_point is not None and len(mlp.linears) == 1):
                outs.append(self._group_pool(mlp, xyz, feat, new_xyz, idx, per_point, None if mlp.rowwise() else src))
                continue
            layers = mlp.folded_layers()  # folded once for all chunks
            parts = []
            for s in range(0, idx.shape[1], step):
                c, i = new_xyz[:, s : s + step], idx[:, s : s + step]
                if per_point is None:
                    parts.append(_pool_rows(layers, self._grouped(xyz, feat, c, i), pre=False))
                else:
                    parts.append(_pool_rows(layers, self._gathered_first(per_point, c, i), pre=True))
            out = torch.cat(parts, dim=1) + layers[-1][1]
            outs.append(torch.relu_(out) if mlp.last_act() else out)
        return new_xyz, outs[0] if len(outs) == 1 else torch.cat(outs, dim=-1)

    def _grouped(self, xyz: Tensor, feat: Tensor | None, new_xyz: Tensor, idx: Tensor) -> Tensor:
        """The grouped input of the neighbours idx [B,S,K] of new_xyz [B,S,3]: [B, S, K, 3 + D] (xyz relative)."""
        rel = index_points(xyz, idx) - new_xyz[:, :, None]  # [B, S, K, 3]
        return self._cat(rel, index_points(feat, idx) if feat is not None else None)

    @staticmethod
    def _gathered_first(per_point: tuple[Tensor, Tensor], new_xyz: Tensor, idx: Tensor) -> Tensor:
        """The first layer's pre-activation of the grouped rows from its per-point values: [B, S, K, C1]."""
        first, w_xyz = per_point
        return index_points(first, idx) - F.linear(new_xyz, w_xyz)[:, :, None]

    def _group_pool(
        self,
        mlp: SharedMLP,
        xyz: Tensor,
        feat: Tensor | None,
        new_xyz: Tensor,
        idx: Tensor,
        per_point: tuple[Tensor, Tensor] | None,
        src: Tensor | None = None,
    ) -> Tensor:
        """Group the neighbours ``idx`` [B,S,K] of the centres new_xyz [B,S,3], run ``mlp`` and max-pool: [B,S,C].

        With ``per_point`` (see ``_first_layer_per_point``) the first Linear is gathered, not recomputed:
        ``W [p - c, f] + b = (W [p, f] + b)[idx] - W_xyz c`` (equal up to float rounding). With ``src`` [B,S]
        (``repeat_sources``) only first occurrences run, and each repeat copies its first occurrence's row.
        """
        if per_point is not None:
            x, first = None, self._gathered_first(per_point, new_xyz, idx)
        else:
            x, first = self._grouped(xyz, feat, new_xyz, idx), None
        if src is None:
            return mlp.pooled(x, dim=2, first=first)
        keep = kept_centres(src)  # [B, S]
        rows = mlp.pooled(
            None if x is None else x[keep][None], dim=2, first=None if first is None else first[keep][None]
        )
        out = rows.new_zeros(*keep.shape, rows.shape[-1]).masked_scatter(keep[..., None], rows[0])
        return copy_to_repeats(out, src)

    def _first_layer_per_point(self, mlp: SharedMLP, xyz: Tensor, feat: Tensor) -> tuple[Tensor, Tensor]:
        """The first Linear of ``[p, f]`` on the N input points, not on the S x K grouped rows.

        Args:
            xyz [B,N,3], feat [B,N,D].
        Returns:
            (W [p, f] + b [B, N, C1], W_xyz [C1, 3]: the weight columns of the relative xyz).
        """
        w, b = mlp.first_linear()
        w_xyz = w[:, :3] if self.xyz_first else w[:, -3:]
        return F.linear(self._cat(xyz, feat.to(xyz.dtype)), w, b), w_xyz


class FeaturePropagation(nn.Module):
    """PointNet++ feature propagation: 3-NN interpolation from sparse to dense + shared MLP.

    Args:
        in_channels: C_skip + C_sparse; widths: MLP widths.
    """

    def __init__(self, in_channels: int, widths: Sequence[int]) -> None:
        super().__init__()
        self.mlp = SharedMLP(in_channels, widths)
        self.in_channels = in_channels
        self.out_channels = self.mlp.out_channels

    def forward(
        self,
        xyz_dense: Tensor,
        xyz_sparse: Tensor,
        feat_dense: Tensor | None,
        feat_sparse: Tensor,
        mask_sparse: Tensor | None = None,
        mask_dense: Tensor | None = None,
    ) -> Tensor:
        """xyz_dense [B,n,3], xyz_sparse [B,m,3], feat_dense [B,n,C1] | None, feat_sparse [B,m,C2] -> [B,n,C_out].

        ``mask_dense`` [B,n] (False = padding) keeps padded dense points out of the MLP's batch statistics
        (``SharedMLP.forward``); their rows are then 0 in training.
        """
        skip = 0 if feat_dense is None else feat_dense.shape[-1]
        check_features("FeaturePropagation", "feat_dense", feat_dense, xyz_dense, skip)  # another n: a torch.cat error
        if skip + feat_sparse.shape[-1] != self.in_channels:  # a Linear's "mat1 and mat2 shapes" error
            raise ValueError(
                f"FeaturePropagation: feat_dense and feat_sparse must hold {self.in_channels} channels together, "
                f"got {skip} + {feat_sparse.shape[-1]}"
            )
        interp = three_interpolate(xyz_dense, xyz_sparse, feat_sparse, mask_sparse)
        h = interp if feat_dense is None else torch.cat([feat_dense.to(interp.dtype), interp], dim=-1)
        return self.mlp(h, mask_dense)


class PointNet2Encoder(nn.Module):
    """A stack of set-abstraction levels.

    Args:
        in_channels: per-point feature channels D fed with xyz (0 = xyz only; the classic port then
            feeds xyz as features, see ``xyz_as_feat``).
        npoints: centres per level; radii / nsamples / mlps: per level, per scale.
        group_all_last: append a group-all level with ``group_all_mlp`` (SSG classification style).
        xyz_first: grouped channel order (True for SSG, False for MSG, as the classic port).
        xyz_as_feat: feed xyz as level-0 features (``l0_points = xyz``, NavAff/IAGNet encoders).
    """

    def __init__(
        self,
        in_channels: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        xyz_first: bool = True,
        xyz_as_feat: bool = False,
        group_all_mlp: Sequence[int] | None = None,
    ) -> None:
        super().__init__()
        if not (len(npoints) == len(radii) == len(nsamples) == len(mlps)):
            raise ValueError("npoints, radii, nsamples and mlps need one entry per level")
        # a negative count built a first level narrower than its input, found only at the first batch
        check_integer("in_channels", in_channels, 0, owner="PointNet2Encoder")
        self.xyz_as_feat = xyz_as_feat
        c = in_channels + (3 if xyz_as_feat else 0)
        self.levels = nn.ModuleList()
        for npoint, r, k, m in zip(npoints, radii, nsamples, mlps):
            sa = SetAbstraction(npoint, r, k, c, m, xyz_first=xyz_first)
            self.levels.append(sa)
            c = sa.out_channels
        if group_all_mlp:
            sa = SetAbstraction(1, [], [], c, [group_all_mlp], group_all=True, xyz_first=xyz_first)
            self.levels.append(sa)
            c = sa.out_channels
        self.in_channels = in_channels
        self.out_channels = c
        self.level_channels = [in_channels + (3 if xyz_as_feat else 0)] + [sa.out_channels for sa in self.levels]

    @torch.no_grad()
    def sample(self, xyz: Tensor, mask: Tensor | None) -> list[Tensor | None]:
        """All FPS indices, level by level (level i samples level i-1's centres)."""
        out: list[Tensor | None] = []
        cur, cur_mask = xyz, mask
        for sa in self.levels:
            idx = sa.sample(cur, cur_mask)
            out.append(idx)
            if idx is None:
                break
            cur, cur_mask = index_points(cur, idx), None
        return out

    def forward(
        self,
        xyz: Tensor,
        feat: Tensor | None,
        mask: Tensor | None = None,
        fps: list[Tensor | None] | None = None,
        srcs: list[Tensor | None] | None = None,
    ) -> list[tuple[Tensor, Tensor | None]]:
        """Returns [(xyz_l, feat_l)] for l = 0..L (level 0 is the input).

        ``srcs``: ``sources(fps)`` when the caller needs them too (found here when None)."""
        check_points("PointNet2Encoder: xyz", xyz)
        check_features("PointNet2Encoder", "feat", feat, xyz, self.in_channels)
        for name, given in (("fps", fps), ("srcs", srcs)):  # a shorter list ran only its levels, silently
            if given is not None and len(given) != len(self.levels):
                raise ValueError(
                    f"PointNet2Encoder: {name} needs one entry per level ({len(self.levels)}), got {len(given)}"
                )
        if self.xyz_as_feat:
            feat = xyz if feat is None else torch.cat([xyz, feat], dim=-1)
        if fps is None:
            fps = self.sample(xyz, mask)
        if srcs is None:
            srcs = self.sources(fps)
        levels: list[tuple[Tensor, Tensor | None]] = [(xyz, feat)]
        cur_mask = mask
        for sa, idx, src in zip(self.levels, fps, srcs):
            xyz, feat = sa(xyz, feat, cur_mask, idx, src)
            # centres are valid points; repeated ones (a cloud smaller than npoint) stay out of the next level's
            # groups, where they would only add copies of the first point to the batch statistics
            cur_mask = kept_centres(src)
            levels.append((xyz, feat))
        return levels

    @staticmethod
    def sources(fps: list[Tensor | None]) -> list[Tensor | None]:
        """Per level 1..L of ``sample``'s indices: its ``repeat_sources`` [B, S_l], None where no centre repeats (or
        for a group-all level). One host sync per FPS level: a forward pass finds them once and hands them on."""
        return [None if idx is None else repeat_sources(idx) for idx in fps]

    @staticmethod
    def kept_masks(srcs: list[Tensor | None]) -> list[Tensor | None]:
        """Per level 1..L of ``sources``: [B, S_l] bool, False on repeated centres, or None (none repeat).

        A decoder passes them to ``FeaturePropagation`` (``mask_sparse`` / ``mask_dense``): a repeat shares its
        first occurrence's position, so 3-NN interpolation would otherwise weigh that point two or three times.
        """
        return [kept_centres(src) for src in srcs]


class PointNet2Seg(nn.Module):
    """PointNet++ per-point network: encoder, FP decoder back to the input points, per-point head.

    Level-0 skip features are ``[xyz, feat]``. Output: one logit per point (no sigmoid).

    Args:
        in_channels: D; npoints/radii/nsamples/mlps: encoder (see ``PointNet2Encoder``);
        fp_mlps: decoder widths from the deepest FP to FP1; head: hidden widths before the logit;
        xyz_first: grouped channel order (True = SSG port, False = MSG port).
    """

    def __init__(
        self,
        in_channels: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        fp_mlps: Sequence[Sequence[int]],
        head: Sequence[int] = (),
        xyz_first: bool = True,
    ) -> None:
        super().__init__()
        self.encoder = PointNet2Encoder(in_channels, npoints, radii, nsamples, mlps, xyz_first=xyz_first)
        if len(fp_mlps) != len(npoints):
            raise ValueError(f"fp_mlps needs {len(npoints)} entries (one per level), got {len(fp_mlps)}")
        ch = [3 + in_channels] + self.encoder.level_channels[1:]
        self.fps_layers = nn.ModuleList()
        cur = ch[-1]
        for lvl, widths in zip(range(len(npoints) - 1, -1, -1), fp_mlps):
            fp = FeaturePropagation(ch[lvl] + cur, widths)
            self.fps_layers.append(fp)
            cur = fp.out_channels
        self.head = SharedMLP(cur, list(head)) if head else nn.Identity()
        self.out = nn.Linear(head[-1] if head else cur, 1)

    def forward(
        self, xyz: Tensor, feat: Tensor | None, mask: Tensor | None = None, fps: list[Tensor | None] | None = None
    ) -> Tensor:
        """xyz [B,N,3], feat [B,N,D] | None, mask [B,N] -> logits [B,N]."""
        if fps is None:
            fps = self.encoder.sample(xyz, mask)
        srcs = self.encoder.sources(fps)
        levels = self.encoder(xyz, feat, mask, fps, srcs)
        masks = [mask] + self.encoder.kept_masks(srcs)  # padding, then repeated centres (a cloud under npoint)
        skip0 = xyz if feat is None else torch.cat([xyz, feat], dim=-1)
        skips = [skip0] + [f for _, f in levels[1:]]
        cur = levels[-1][1]
        n = len(levels) - 1
        for j, fp in enumerate(self.fps_layers):
            lvl = n - 1 - j
            cur = fp(levels[lvl][0], levels[lvl + 1][0], skips[lvl], cur, masks[lvl + 1], masks[lvl])
        if isinstance(self.head, SharedMLP):
            cur = self.head(cur, mask)
        return self.out(cur).squeeze(-1)
