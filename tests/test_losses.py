"""Masked FloAff losses vs hand NumPy."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from floaff_zoo.losses import (
    affordance_loss,
    build_loss,
    listwise_rank_loss,
    masked_mse,
    navaff_weighted_mse,
    soft_dice_loss,
)


def data(seed=0, b=4, m=30):
    rng = np.random.default_rng(seed)
    pred = rng.random((b, m))
    target = rng.random((b, m)) * (rng.random((b, m)) > 0.4)
    mask = rng.random((b, m)) > 0.3
    mask[2] = False  # an all-masked sample
    return pred, target, mask


def np_mse(p, g, m):
    return np.mean((p[m] - g[m]) ** 2)


def np_sdl(p, g, m, eps):
    vals = [1 - (2 * np.sum(p[i][m[i]] * g[i][m[i]]) + eps) / (np.sum(p[i][m[i]] ** 2) + np.sum(g[i][m[i]] ** 2) + eps)
            for i in range(len(p)) if m[i].any()]  # fmt: skip
    return np.mean(vals)


def np_rank(p, g, m, temp):
    """Per sample with a positive label: KL(g / sum g || softmax(logit(p) / T)) over the valid points; mean."""
    vals = []
    for i in range(len(p)):
        gi, pi = np.clip(g[i][m[i]], 0, None), np.clip(p[i][m[i]], 1e-6, 1 - 1e-6)
        if gi.sum() <= 0:
            continue
        q = gi / gi.sum()
        z = np.log(pi / (1 - pi)) / temp
        log_soft = z - z.max() - np.log(np.exp(z - z.max()).sum())
        vals.append(np.sum(q[q > 0] * (np.log(q[q > 0]) - log_soft[q > 0])))
    return np.mean(vals)


def t(x):
    return torch.from_numpy(np.asarray(x))


@pytest.mark.parametrize("eps", [1.0, 1e-6])
def test_values_match_numpy(eps):
    p, g, m = data()
    assert float(masked_mse(t(p), t(g), t(m))) == pytest.approx(np_mse(p, g, m))
    assert float(soft_dice_loss(t(p), t(g), t(m), eps=eps)) == pytest.approx(np_sdl(p, g, m, eps))
    want = np_mse(p, g, m) + 0.3 * np_sdl(p, g, m, 1.0)
    assert float(affordance_loss(t(p), t(g), t(m), beta=0.3)) == pytest.approx(want)
    assert float(build_loss("aff", beta=0.3)(t(p), t(g), t(m))) == pytest.approx(want)
    assert float(build_loss("mse")(t(p), t(g), t(m))) == pytest.approx(np_mse(p, g, m))


@pytest.mark.parametrize("temp", [1.0, 0.5])
def test_rank_values_match_numpy(temp):
    p, g, m = data(seed=2)
    p = 0.05 + 0.9 * p  # away from the clamp
    assert float(listwise_rank_loss(t(p), t(g), t(m), temp)) == pytest.approx(np_rank(p, g, m, temp))
    fn = build_loss("aff", beta=0.3, rank_weight=0.2, rank_temperature=temp)
    want = np_mse(p, g, m) + 0.3 * np_sdl(p, g, m, 1.0) + 0.2 * np_rank(p, g, m, temp)
    assert float(fn(t(p), t(g), t(m))) == pytest.approx(want)


def test_rank_rewards_mass_on_the_successful_cells():
    """Same scores, permuted: the map that ranks the labelled cells first costs less; 0 when softmax == q."""
    g = torch.tensor([[1.0, 1.0, 0.0, 0.0, 0.0]])
    m = torch.ones_like(g, dtype=torch.bool)
    good = torch.tensor([[0.9, 0.8, 0.2, 0.1, 0.1]])
    bad = torch.tensor([[0.1, 0.2, 0.9, 0.8, 0.1]])
    assert float(listwise_rank_loss(good, g, m)) < float(listwise_rank_loss(bad, g, m))
    # log-odds equal to log q (plus a constant) on the positives and the clamp's floor elsewhere: KL ~ 0
    q_exact = torch.tensor([[0.5, 0.5, 1e-9, 1e-9, 1e-9]])
    assert float(listwise_rank_loss(q_exact, g, m)) == pytest.approx(0.0, abs=1e-4)


def test_rank_skips_samples_without_a_positive_label():
    p = torch.rand(3, 6, requires_grad=True)
    g = torch.zeros(3, 6)
    g[1, 2] = 1.0
    m = torch.ones(3, 6, dtype=torch.bool)
    alone = listwise_rank_loss(p[1:2], g[1:2], m[1:2])
    assert float(listwise_rank_loss(p, g, m)) == pytest.approx(float(alone))
    nothing = listwise_rank_loss(p, torch.zeros(3, 6), m)
    assert float(nothing) == 0.0
    nothing.backward()
    assert torch.isfinite(p.grad).all()


@pytest.mark.parametrize("name,rank", [("mse", 0.0), ("aff", 0.0), ("navaff", 0.0), ("aff", 0.5)])
def test_masked_points_do_not_matter_and_grads_finite(name, rank):
    p, g, m = data(seed=1)
    fn = build_loss(name, rank_weight=rank)
    p2, g2 = p.copy(), g.copy()
    p2[~m] = np.nan  # garbage (even NaN) in padding
    g2[~m] = 123.0
    torch.manual_seed(0)
    a = fn(t(p), t(g), t(m))
    torch.manual_seed(0)
    x = t(p2).requires_grad_(True)
    b = fn(x, t(g2), t(m))
    assert float(a.detach()) == pytest.approx(float(b.detach()))
    b.backward()
    assert torch.isfinite(x.grad).all()
    assert (x.grad[~t(m)] == 0).all()


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
@pytest.mark.parametrize("name,rank", [("mse", 0.0), ("aff", 0.0), ("aff", 0.5)])
def test_half_precision_scores_are_computed_in_float32(dtype, name, rank):
    """Under bf16/16-mixed autocast a model hands half-precision scores to the loss: a score that rounded to 1.0 gave
    the ranking term infinite log-odds (NaN loss, training stopped), and the labels were rounded to half precision."""
    p, g, m = data(seed=2)
    p[0, :3] = 1.0  # a confident cell: a half-precision sigmoid reaches 1.0 at logit ~5.5 (bf16) / ~8.3 (fp16)
    fn = build_loss(name, rank_weight=rank)
    x = t(p).to(dtype).requires_grad_(True)
    loss = fn(x, t(g).float(), t(m))
    loss.backward()
    assert loss.dtype == torch.float32 and torch.isfinite(loss) and torch.isfinite(x.grad).all()
    # the same scores in float32 give the same value: only the scores' own rounding is left
    assert float(loss) == pytest.approx(float(fn(t(p).to(dtype).float(), t(g).float(), t(m))), rel=1e-6)


@pytest.mark.parametrize("padding", [0.5, float("nan"), float("inf")])
def test_empty_batch_is_zero_not_nan(padding):
    """NaN or inf in the padding of a batch without valid points made the fallback 0 * sum(pred) a NaN."""
    p = torch.rand(2, 5)
    p[0, 1] = padding
    p.requires_grad_(True)
    m = torch.zeros(2, 5, dtype=torch.bool)
    for name, rank in (("mse", 0.0), ("aff", 0.0), ("navaff", 0.0), ("aff", 0.5)):
        loss = build_loss(name, rank_weight=rank)(p, torch.rand(2, 5), m)
        assert float(loss) == 0.0, (name, rank)
        loss.backward()
        assert torch.isfinite(p.grad).all()
    # the ranking term's own fallback (valid points, but no positive label to rank first)
    valid = torch.ones(2, 5, dtype=torch.bool)
    valid[0, 1] = False
    assert float(listwise_rank_loss(p, torch.zeros(2, 5), valid)) == 0.0


@pytest.mark.parametrize("temperature", [1.0, 1e-3, 1e-4, 1e-6])
def test_padding_never_takes_the_ranking_mass(temperature):
    """Below T ~1e-3 the valid log-odds (>= logit(1e-6) / T) fell under the fixed padding value, so padded points
    took the softmax mass: the same view scored differently with padding."""
    p = torch.tensor([[0.01, 0.05, 0.02]])  # all below 0.5: log-odds < 0, far below at small T
    g = torch.tensor([[0.0, 1.0, 0.5]])
    padded_p, padded_g = torch.cat([p, torch.full((1, 5), 0.5)], 1), torch.cat([g, torch.zeros(1, 5)], 1)
    mask = torch.cat([torch.ones(1, 3, dtype=torch.bool), torch.zeros(1, 5, dtype=torch.bool)], 1)
    alone = listwise_rank_loss(p, g, None, temperature)
    assert float(listwise_rank_loss(padded_p, padded_g, mask, temperature)) == pytest.approx(float(alone), rel=1e-5)


def test_sdl_zero_for_perfect_prediction():
    g = torch.tensor([[0.0, 0.3, 1.0, 0.7], [1.0, 0.0, 0.0, 0.2]])
    m = torch.tensor([[True, True, True, False], [True, True, True, True]])
    for eps in (1.0, 1e-8):
        assert float(soft_dice_loss(g, g, m, eps=eps)) == pytest.approx(0.0, abs=1e-7)
    assert float(soft_dice_loss(torch.zeros_like(g), g, m)) > 0.5
    with pytest.raises(ValueError, match="eps"):
        soft_dice_loss(g, g, m, eps=0.0)


def test_navaff_expected_weight():
    """Zero-label points get weight 0.7 half the time -> mean weight 0.85; non-zero labels weight 1."""
    gen = torch.Generator().manual_seed(1234)
    pred = torch.ones(8, 5000)
    zeros = torch.zeros(8, 5000)
    mask = torch.ones(8, 5000, dtype=torch.bool)
    loss = float(navaff_weighted_mse(pred, zeros, mask, generator=gen))
    assert loss == pytest.approx(0.85, abs=0.005)  # std of the mean ~0.0007
    half = torch.full((8, 5000), 0.5)
    assert float(navaff_weighted_mse(pred, half, mask, generator=gen)) == pytest.approx(0.25)
    # Fresh draws: two calls differ; same seed reproduces.
    a = navaff_weighted_mse(pred, zeros, mask, generator=torch.Generator().manual_seed(7))
    b = navaff_weighted_mse(pred, zeros, mask, generator=torch.Generator().manual_seed(7))
    c = navaff_weighted_mse(pred, zeros, mask, generator=torch.Generator().manual_seed(8))
    assert float(a) == float(b) and float(a) != float(c)


def test_bad_input():
    with pytest.raises(ValueError, match="unknown loss"):
        build_loss("l1")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="rank_weight"):
        build_loss("aff", rank_weight=-0.1)
    with pytest.raises(ValueError, match="rank_temperature"):
        build_loss("aff", rank_weight=0.1, rank_temperature=0.0)
    with pytest.raises(ValueError, match="temperature"):
        listwise_rank_loss(torch.zeros(2, 3), torch.zeros(2, 3), None, temperature=float("nan"))
    # a text or None failed a comparison naming nothing
    with pytest.raises(ValueError, match="build_loss: rank_weight must be a finite number >= 0, got '0.1'"):
        build_loss("aff", rank_weight="0.1")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="build_loss: beta must be a finite number >= 0, got nan"):
        build_loss("aff", beta=float("nan"))
    with pytest.raises(ValueError, match="build_loss: rank_temperature must be a finite number > 0, got None"):
        build_loss("aff", rank_weight=0.1, rank_temperature=None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="listwise_rank_loss: temperature must be a finite number > 0, got '1'"):
        listwise_rank_loss(torch.zeros(2, 3), torch.zeros(2, 3), None, temperature="1")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\[B, M\]"):
        masked_mse(torch.zeros(2, 3), torch.zeros(3, 2), None)
    with pytest.raises(ValueError, match="mask"):
        masked_mse(torch.zeros(2, 3), torch.zeros(2, 3), torch.ones(2, 3))
    assert float(masked_mse(torch.ones(2, 3), torch.zeros(2, 3), None)) == 1.0


def test_integer_scores_are_promoted():
    """Integer scores took the labels to their integer type: 0.6 became 0, so every loss saw another label map."""
    pred, target = torch.tensor([[1, 0, 0]]), torch.tensor([[0.6, 0.3, 0.0]])
    for fn in (masked_mse, soft_dice_loss, listwise_rank_loss):
        assert float(fn(pred, target, None)) == pytest.approx(float(fn(pred.float(), target, None))), fn.__name__


def test_dice_eps_and_beta_must_be_finite_numbers():
    """A NaN or infinite eps or beta gave a NaN loss; a text eps failed a comparison naming nothing."""
    p, g = torch.rand(2, 3), torch.rand(2, 3)
    for eps in (float("nan"), float("inf"), 0.0, "1"):
        with pytest.raises(ValueError, match=r"soft_dice_loss: eps must be a finite number > 0"):
            soft_dice_loss(p, g, None, eps=eps)  # type: ignore[arg-type]
    for beta in (float("nan"), -1.0):
        with pytest.raises(ValueError, match=r"affordance_loss: beta must be a finite number >= 0"):
            affordance_loss(p, g, None, beta=beta)


def test_affordance_loss_passes_its_eps_to_the_dice_term():
    """pred (1, 0), label (0, 1): MSE 1, Dice 1 - eps / (2 + eps) (2/3 at the default eps 1, ~1 at 1e-6)."""
    p, g = torch.tensor([[1.0, 0.0]]), torch.tensor([[0.0, 1.0]])
    assert float(affordance_loss(p, g, None)) == pytest.approx(1 + 2 / 3)
    assert float(affordance_loss(p, g, None, eps=1e-6)) == pytest.approx(2 - 1e-6 / (2 + 1e-6))


def test_navaff_deterministic_loss_is_the_expected_weight():
    """Validation and test use NavAff's weights at their expectation (0.85 on a zero label, no draw): pred (1, 1),
    label (0, 0.5) -> (0.85 * 1 + 0.25) / 2 = 0.55; one random draw gives 0.475 or 0.625."""
    p, g = torch.tensor([[1.0, 1.0]]), torch.tensor([[0.0, 0.5]])
    assert float(navaff_weighted_mse(p, g, None, expected=True)) == pytest.approx(0.55)
    fn = build_loss("navaff", deterministic=True)
    assert [float(fn(p, g, None)) for _ in range(8)] == pytest.approx([0.55] * 8)
    draws = {round(float(build_loss("navaff")(p, g, None)), 6) for _ in range(64)}
    assert draws == {0.475, 0.625}
