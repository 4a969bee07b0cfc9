"""Masked FloAff training losses on per-point maps ``pred``/``target`` [B, M] with a validity ``mask`` [B, M].

Masked (padding) points never change a loss or its gradient; a batch or sample without valid points
gives 0 (with a graph attached), never NaN. Nothing here checks the maps' values: ``contract.check_batch``, which
every model's step calls, refuses a non-finite label on a valid point in the host sync it already makes, and a
non-finite prediction gives a non-finite loss, which the step refuses naming the samples (``NonFiniteError``).

* ``masked_mse``: the paper's eq. (mse), but the mean over all valid points of the batch (docs/method.md, "The loss").
* ``soft_dice_loss``: the paper's eq. (sdl) per sample, averaged over samples that have valid points.
  The paper only calls epsilon "a small constant"; the default ``eps = 1.0`` is the usual Dice smoothing
  term (Milletari et al. / common V-Net implementations). It keeps the loss bounded and ~0 for a sample
  whose label map is all zero and whose prediction is near zero, instead of pushing such samples at full
  strength (with a tiny eps an all-zero label gives a loss of ~1 for any non-zero prediction).
* ``affordance_loss``: the paper's L_aff = L_mse + beta * L_sdl.
* ``listwise_rank_loss``: a departure, off by default (``rank_weight = 0``): per sample, the KL divergence from the
  label map normalised over the valid points to the softmax of the predicted log-odds. The success rate scores
  only the map's argmax; MSE and Dice weigh every cell alike, this term pays for probability mass on the cells that
  fail, wherever they are, so it concentrates training on the top of the ranking.
* ``navaff_weighted_mse``: NavAff's training loss (``MoMaKitchen/MoMaKitchen:train.py@64ca7a4``,
  docs/background.md §3): weight 0.7 where the label is 0 *and* a fresh Bernoulli(0.5) draw fires, else 1;
  mean(w (p - g)^2) over valid points (expected weight 0.85 on zero-label points).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import torch
from torch import Tensor

from floaff_zoo.checks import check_number, check_numbers

__all__ = [
    "affordance_loss",
    "build_loss",
    "listwise_rank_loss",
    "masked_mse",
    "navaff_weighted_mse",
    "soft_dice_loss",
]

LossFn = Callable[[Tensor, Tensor, Tensor], Tensor]

#: scores are clamped to [eps, 1 - eps] before their log-odds (a sigmoid output never reaches 0 or 1 in float32 use)
LOGIT_EPS = 1e-6
#: log-odds given to padded points, below the lowest a valid point can have (logit(LOGIT_EPS) / T): exp(-1e4) is 0
#: in any float type, and unlike -inf it keeps gradients finite
MASKED_LOGIT = -1e4


def _prepare(name: str, pred: Tensor, target: Tensor, mask: Tensor | None) -> tuple[Tensor, Tensor, Tensor]:
    """Check shapes; return (pred, target) with padded entries zeroed and the bool mask, all [B, M] (half-precision
    scores promoted to float32)."""
    if pred.ndim != 2 or pred.shape != target.shape:
        raise ValueError(
            f"{name}: pred and target must both be [B, M]; got {tuple(pred.shape)} and {tuple(target.shape)}"
        )
    if mask is None:
        mask = torch.ones_like(pred, dtype=torch.bool)
    if mask.dtype != torch.bool or mask.shape != pred.shape:
        raise ValueError(f"{name}: mask must be bool {tuple(pred.shape)}; got {mask.dtype} {tuple(mask.shape)}")
    if pred.dtype in (torch.float16, torch.bfloat16) or not pred.is_floating_point():
        # autocast hands over half-precision scores: a score that rounds to 1.0 has infinite log-odds (the clamp's
        # 1 - 1e-6 is 1.0 there), and half-precision labels lose their third digit; integer scores took the labels to
        # their integer type (0.6 became 0)
        pred = pred.float()
    target = target.to(pred.dtype)
    # where() (not multiplication) so NaN/garbage in padded entries cannot reach the value or the gradient.
    return torch.where(mask, pred, 0.0), torch.where(mask, target, 0.0), mask


def _masked_mean(values: Tensor, mask: Tensor, ref: Tensor) -> Tensor:
    """Mean of ``values`` [B, M] over ``mask``; ``0 * ref.sum()`` when nothing is valid (keeps the graph; ``ref`` is
    the masked prediction, so NaN in padded entries cannot make that 0 a NaN)."""
    n = mask.sum()
    if int(n) == 0:
        return ref.sum() * 0.0
    return torch.where(mask, values, 0.0).sum() / n


def masked_mse(pred: Tensor, target: Tensor, mask: Tensor | None) -> Tensor:
    """Mean (pred - target)^2 over all valid points of the batch (pooled: a map with more valid points weighs more;
    the paper averages per map, then over maps: docs/method.md, "The loss"). [B, M] x3 -> scalar."""
    p, g, m = _prepare("masked_mse", pred, target, mask)
    return _masked_mean((p - g) ** 2, m, p)


def soft_dice_loss(pred: Tensor, target: Tensor, mask: Tensor | None, eps: float = 1.0) -> Tensor:
    """Per-sample 1 - (2 sum pg + eps) / (sum p^2 + sum g^2 + eps), mean over samples with valid points.

    pred, target [B, M], mask bool [B, M] -> scalar. 0 for a perfect prediction; samples without a valid
    point are left out of the mean (0 if the whole batch is empty).
    """
    check_number("eps", eps, strict=True, owner="soft_dice_loss")  # a NaN or inf eps made every term NaN
    p, g, m = _prepare("soft_dice_loss", pred, target, mask)
    inter = (p * g).sum(1)
    denom = (p * p).sum(1) + (g * g).sum(1)
    per_sample = 1.0 - (2.0 * inter + eps) / (denom + eps)  # [B]
    has_points = m.any(1)
    if not bool(has_points.any()):
        return p.sum() * 0.0  # the masked prediction: a NaN in padding would make 0 * NaN
    return per_sample[has_points].mean()


def affordance_loss(pred: Tensor, target: Tensor, mask: Tensor | None, beta: float = 1.0, eps: float = 1.0) -> Tensor:
    """The paper's L_aff = masked MSE + beta * soft Dice (eps see ``soft_dice_loss``). [B, M] x3 -> scalar."""
    # a NaN beta made the loss NaN; build_loss checks it once for training, this covers a direct call (a few Python
    # comparisons, no host sync)
    check_number("beta", beta, owner="affordance_loss")
    return masked_mse(pred, target, mask) + beta * soft_dice_loss(pred, target, mask, eps=eps)


def navaff_weighted_mse(
    pred: Tensor, target: Tensor, mask: Tensor | None, generator: torch.Generator | None = None, expected: bool = False
) -> Tensor:
    """NavAff's randomised weighted MSE: mean(w (p - g)^2) over valid points. [B, M] x3 -> scalar.

    w = 0.7 where target == 0 and a fresh Bernoulli(0.5) fires (redrawn every call), else 1.
    ``generator`` (on pred's device) makes the draw reproducible; ``expected`` uses the draw's expectation
    (0.85 where target == 0) and draws nothing (the evaluation loss).
    """
    p, g, m = _prepare("navaff_weighted_mse", pred, target, mask)
    if expected:  # the draw's expectation: 0.85 on zero-label points, no RNG
        w = torch.where(g == 0, 0.85, 1.0).to(p.dtype)
    else:
        fire = torch.rand(p.shape, generator=generator, device=p.device) < 0.5
        w = torch.where((g == 0) & fire, 0.7, 1.0).to(p.dtype)
    return _masked_mean(w * (p - g) ** 2, m, p)


def listwise_rank_loss(pred: Tensor, target: Tensor, mask: Tensor | None, temperature: float = 1.0) -> Tensor:
    """KL(q || softmax(logit(pred) / T)) per sample over its valid points, mean over samples with a positive label.

    pred (scores in [0, 1]), target (labels >= 0), mask bool, all [B, M] -> scalar; q = target / sum(target) over the
    sample's valid points. 0 when the softmax equals q; samples whose labels are all 0 (nothing to rank first) are
    left out of the mean (0 with a graph if none is left).
    """
    check_number("temperature", temperature, strict=True, owner="listwise_rank_loss")
    p, g, m = _prepare("listwise_rank_loss", pred, target, mask)
    z = torch.logit(p.clamp(LOGIT_EPS, 1.0 - LOGIT_EPS)) / temperature
    # padding sits 1e4 below the lowest valid log-odds at any temperature (a fixed -1e4 outranked them below T ~1e-3)
    floor = math.log(LOGIT_EPS / (1.0 - LOGIT_EPS)) / temperature + MASKED_LOGIT
    log_soft = torch.log_softmax(torch.where(m, z, floor), dim=1)  # [B, M]
    w = torch.where(m, g.clamp_min(0.0), 0.0)
    total = w.sum(1)  # [B]
    keep = total > 0
    if not bool(keep.any()):
        return p.sum() * 0.0  # the masked prediction: a NaN in padding would make 0 * NaN
    q = w / total.clamp_min(1e-12).unsqueeze(1)
    # q log q is 0 where q is 0; where() keeps log(0) out of the value
    kl = torch.where(q > 0, q * (torch.log(q.clamp_min(1e-30)) - log_soft), 0.0).sum(1)  # [B]
    return kl[keep].mean()


def build_loss(
    name: Literal["mse", "aff", "navaff"],
    beta: float = 1.0,
    rank_weight: float = 0.0,
    rank_temperature: float = 1.0,
    deterministic: bool = False,
) -> LossFn:
    """Loss callable ``(pred [B, M], target [B, M], mask [B, M]) -> scalar`` by name.

    ``mse`` = masked MSE, ``aff`` = MSE + beta * soft Dice (paper), ``navaff`` = NavAff's weighted MSE; with
    ``rank_weight > 0`` plus ``rank_weight * listwise_rank_loss(..., rank_temperature)``. ``deterministic``:
    no random draw (NavAff's weights at their expectation), for validation and test.
    """
    # a text or None failed a comparison unnamed; a NaN beta made every Dice term NaN
    check_numbers({"beta": beta, "rank_weight": rank_weight}, owner="build_loss")
    if name == "mse":
        base: LossFn = masked_mse
    elif name == "aff":

        def base(pred: Tensor, target: Tensor, mask: Tensor) -> Tensor:
            return affordance_loss(pred, target, mask, beta=beta)

    elif name == "navaff":

        def base(pred: Tensor, target: Tensor, mask: Tensor) -> Tensor:
            return navaff_weighted_mse(pred, target, mask, expected=deterministic)

    else:
        raise ValueError(f"build_loss: unknown loss {name!r}; expected one of 'mse', 'aff', 'navaff'")
    if rank_weight == 0:
        return base
    check_number("rank_temperature", rank_temperature, strict=True, owner="build_loss")

    def ranked(pred: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        return base(pred, target, mask) + rank_weight * listwise_rank_loss(pred, target, mask, rank_temperature)

    return ranked
