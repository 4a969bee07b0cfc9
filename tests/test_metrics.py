"""FloAff metrics vs an independent NumPy/SciPy reference (loop over chunks, scipy.stats.pearsonr)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch
from scipy.stats import pearsonr

from floaff_zoo.metrics import (
    FloorCIoU,
    FloorLogMSE,
    FloorMAE,
    FloorPCC,
    FloorRMSE,
    FloorSIM,
    affordance_metrics,
)

KEYS = ("rmse", "logmse", "pcc", "sim", "mae", "ciou")


def reference(preds, target, mask, index, reduction, chunk_size, sim_variant):
    """Plain NumPy/SciPy: build each element's (p, g) by concatenation, then the documented formulas."""
    elem = 1 if reduction == "per_sample" else chunk_size
    groups: dict[int, list[int]] = {}
    for row, idx in enumerate(index):
        groups.setdefault(int(idx) // elem, []).append(row)
    per = {k: [] for k in KEYS}
    for cid in sorted(groups):
        rows = groups[cid]
        p = np.concatenate([preds[r][mask[r]] for r in rows]).astype(np.float64)
        g = np.concatenate([target[r][mask[r]] for r in rows]).astype(np.float64)
        if p.size == 0:
            continue  # element without valid points: excluded
        per["rmse"].append(np.mean((p - g) ** 2))
        per["mae"].append(np.mean(np.abs(p - g)))
        per["logmse"].append(np.mean((np.log1p(g) - np.log1p(p)) ** 2))
        if p.size >= 2 and not np.all(p == p[0]) and not np.all(g == g[0]):
            per["pcc"].append(pearsonr(g, p)[0])
        if sim_variant == "hist":
            per["sim"].append(np.sum(np.minimum(p / (p.sum() + 1e-12), g / (g.sum() + 1e-12))))
        else:
            per["sim"].append(np.dot(p, g) / ((np.linalg.norm(p) + 1e-12) * (np.linalg.norm(g) + 1e-12)))
        union = np.maximum(p, g).sum()
        per["ciou"].append(np.minimum(p, g).sum() / union if union > 0 else 0.0)
    out = {k: (float(np.mean(v)) if v else 0.0) for k, v in per.items()}
    out["rmse"] = math.sqrt(out["rmse"])
    return out


def make_data(seed=0, n=150, m=40):
    rng = np.random.default_rng(seed)
    preds = rng.random((n, m)).astype(np.float32)
    target = (rng.random((n, m)) ** 2).astype(np.float32)
    target[rng.random((n, m)) < 0.3] = 0.0  # many exact zeros, like real labels
    lengths = rng.integers(0, m + 1, size=n)  # includes fully masked samples
    lengths[3] = 0
    mask = np.arange(m)[None, :] < lengths[:, None]
    preds[~mask] = 7.0  # garbage in padding must not matter
    target[7] = 0.25  # constant label map -> PCC undefined for per_sample
    preds[9] = 0.5
    return preds, target, mask


def run_metric(coll, preds, target, mask, splits, index=None):
    start = 0
    for stop in splits + [len(preds)]:
        idx = None if index is None else torch.as_tensor(index[start:stop])
        coll.update(torch.from_numpy(preds[start:stop]), torch.from_numpy(target[start:stop]),
                    torch.from_numpy(mask[start:stop]), idx)  # fmt: skip
        start = stop
    return {k: float(v) for k, v in coll.compute().items()}


@pytest.mark.parametrize("reduction", ["per_sample", "official_batchwise"])
@pytest.mark.parametrize("sim_variant", ["hist", "cosine"])
def test_against_numpy_reference(reduction, sim_variant):
    preds, target, mask = make_data()
    chunk = 16  # 150 samples -> last chunk of 6 (uneven)
    ref = reference(preds, target, mask, np.arange(len(preds)), reduction, chunk, sim_variant)
    for splits in ([], [5, 37, 38, 101], list(range(7, 150, 7))):  # batch split must not matter
        got = run_metric(affordance_metrics(sim_variant, reduction, chunk), preds, target, mask, splits)
        for k in KEYS:
            assert not math.isnan(got[k])
            assert got[k] == pytest.approx(ref[k], rel=1e-5, abs=1e-6), (k, splits)


@pytest.mark.parametrize("sim_variant", ["hist", "cosine"])
def test_shuffled_order_with_index(sim_variant):
    """Out-of-order updates (any loader order) with index give the split-order chunking."""
    preds, target, mask = make_data(seed=1, n=100)
    perm = np.random.default_rng(5).permutation(100)
    ref = reference(preds, target, mask, np.arange(100), "official_batchwise", 64, sim_variant)
    got = run_metric(affordance_metrics(sim_variant, "official_batchwise", 64),
                     preds[perm], target[perm], mask[perm], [10, 30, 31, 77], index=perm)  # fmt: skip
    for k in KEYS:
        assert got[k] == pytest.approx(ref[k], rel=1e-5, abs=1e-6), k


def test_official_and_per_sample_differ_and_chunk_one_matches():
    preds, target, mask = make_data(seed=2, n=70)
    per = run_metric(affordance_metrics("hist", "per_sample"), preds, target, mask, [30])
    one = run_metric(affordance_metrics("hist", "official_batchwise", 1), preds, target, mask, [30])
    off = run_metric(affordance_metrics("hist", "official_batchwise", 64), preds, target, mask, [30])
    for k in KEYS:
        assert one[k] == pytest.approx(per[k], rel=1e-6)
    assert off["pcc"] != pytest.approx(per["pcc"], rel=1e-3)


def test_hand_computed_fixture():
    """Two samples, one chunk of two; numbers worked out by hand."""
    preds = torch.tensor([[0.5, 1.0, 9.0], [0.0, 0.5, 0.5]])
    target = torch.tensor([[1.0, 1.0, 9.0], [0.0, 0.0, 1.0]])
    mask = torch.tensor([[True, True, False], [True, True, True]])
    # sample 0: p=(.5,1) g=(1,1): MSE=.125, MAE=.25, PCC undefined (g constant), cos=1.5/(sqrt1.25*sqrt2),
    #   hist=min(1/3,1/2)+min(2/3,1/2)=5/6, cIoU=1.5/2=.75
    # sample 1: p=(0,.5,.5) g=(0,0,1): MSE=.5/3, MAE=1/3, PCC=0.5, cos=.5/(sqrt.5*1), hist=0+0+.5, cIoU=.5/1.5
    m = affordance_metrics("hist", "per_sample")
    m.update(preds, target, mask)
    out = {k: float(v) for k, v in m.compute().items()}
    assert out["rmse"] == pytest.approx(math.sqrt((0.125 + 0.5 / 3) / 2))
    assert out["mae"] == pytest.approx((0.25 + 1 / 3) / 2)
    assert out["pcc"] == pytest.approx(0.5)
    assert m["pcc"].num_undefined == 1
    assert out["sim"] == pytest.approx((5 / 6 + 0.5) / 2)
    assert out["ciou"] == pytest.approx((0.75 + 1 / 3) / 2)
    log_err0 = (math.log(2) - math.log(1.5)) ** 2 / 2
    log_err1 = ((math.log(1.5)) ** 2 + (math.log(2) - math.log(1.5)) ** 2) / 3
    assert out["logmse"] == pytest.approx((log_err0 + log_err1) / 2)
    cos = FloorSIM("cosine")
    cos.update(preds, target, mask)
    assert float(cos.compute()) == pytest.approx((1.5 / math.sqrt(1.25 * 2) + 0.5 / math.sqrt(0.5)) / 2)
    # One chunk of both samples: p=(.5,1,0,.5,.5), g=(1,1,0,0,1): MSE=.75/5, cIoU=2/3.5
    off = affordance_metrics("hist", "official_batchwise", 64)
    off.update(preds, target, mask)
    res = {k: float(v) for k, v in off.compute().items()}
    assert res["rmse"] == pytest.approx(math.sqrt(0.75 / 5))
    assert res["ciou"] == pytest.approx(2 / 3.5)
    # hist: p/2.5=(.2,.4,0,.2,.2), g/3=(1/3,1/3,0,0,1/3) -> .2+1/3+0+0+.2
    assert res["sim"] == pytest.approx(0.2 + 1 / 3 + 0.2)
    assert res["pcc"] == pytest.approx(pearsonr([1, 1, 0, 0, 1], [0.5, 1, 0, 0.5, 0.5])[0])


def test_degenerate_maps_no_nan():
    """Constant maps, all-zero maps, all-masked samples: documented values, never NaN."""
    z = torch.zeros(3, 4)
    mask = torch.ones(3, 4, dtype=torch.bool)
    for variant in ("hist", "cosine"):
        m = affordance_metrics(variant, "per_sample")
        m.update(z, z, mask)
        out = {k: float(v) for k, v in m.compute().items()}
        assert out == {"rmse": 0.0, "logmse": 0.0, "pcc": 0.0, "sim": 0.0, "mae": 0.0, "ciou": 0.0}
        assert m["pcc"].num_undefined == 3
    # Everything masked: no element at all.
    m = affordance_metrics("hist", "official_batchwise", 2)
    m.update(torch.rand(3, 4), torch.rand(3, 4), torch.zeros(3, 4, dtype=torch.bool))
    out = {k: float(v) for k, v in m.compute().items()}
    assert all(v == 0.0 for v in out.values())
    assert m["rmse"].num_empty == 2 and m["rmse"].num_elements == 0
    # A batch without a single floor point (M = 0) is all-masked too (the reductions over M raised IndexError).
    for reduction in ("per_sample", "official_batchwise"):
        m = affordance_metrics("hist", reduction, 2)
        m.update(torch.zeros(3, 0), torch.zeros(3, 0), torch.zeros(3, 0, dtype=torch.bool))
        assert all(float(v) == 0.0 for v in m.compute().values())
        assert m["rmse"].num_empty == (3 if reduction == "per_sample" else 2) and m["rmse"].num_elements == 0
    # Single valid point: PCC undefined, other metrics fine.
    pcc = FloorPCC()
    pcc.update(torch.tensor([[0.3, 0.0]]), torch.tensor([[0.6, 0.0]]), torch.tensor([[True, False]]))
    assert float(pcc.compute()) == 0.0 and pcc.num_undefined == 1
    # One zero-norm prediction against a non-zero label: cosine 0.
    sim = FloorSIM("cosine")
    sim.update(torch.zeros(1, 3), torch.ones(1, 3))
    assert float(sim.compute()) == 0.0


def test_ddp_style_merge_and_duplicates():
    """Two 'ranks' with DistributedSampler-like interleaving (+ a padded duplicate) merge to the exact result."""
    preds, target, mask = make_data(seed=3, n=101)
    ref = reference(preds, target, mask, np.arange(101), "official_batchwise", 16, "hist")
    ranks = [np.arange(0, 101, 2), np.append(np.arange(1, 101, 2), 0)]  # rank 1 repeats sample 0 (padding)
    metrics = [affordance_metrics("hist", "official_batchwise", 16) for _ in ranks]
    for coll, idx in zip(metrics, ranks):
        for lo in range(0, len(idx), 8):
            sel = idx[lo : lo + 8]
            coll.update(torch.from_numpy(preds[sel]), torch.from_numpy(target[sel]),
                        torch.from_numpy(mask[sel]), torch.from_numpy(sel))  # fmt: skip
    for k in KEYS:
        a = metrics[0][k]
        a.merge_state(metrics[1][k])
        assert float(a.compute()) == pytest.approx(ref[k], rel=1e-5, abs=1e-6), k


def test_in_order_eval_keeps_few_points():
    """Single-process in-order eval reduces complete chunks: the hist point buffer stays ~one chunk."""
    preds, target, mask = make_data(seed=4, n=128)
    sim = FloorSIM("hist", "official_batchwise", 16)
    for lo in range(0, 128, 10):
        sl = slice(lo, lo + 10)
        sim.update(torch.from_numpy(preds[sl]), torch.from_numpy(target[sl]), torch.from_numpy(mask[sl]),
                   torch.arange(lo, min(lo + 10, 128)))  # fmt: skip
        assert sum(t.shape[0] for t in sim.pend_rows) < 16 + 10
    ref = reference(preds, target, mask, np.arange(128), "official_batchwise", 16, "hist")
    assert float(sim.compute()) == pytest.approx(ref["sim"], rel=1e-5)


def test_reset_and_clone():
    preds, target, mask = make_data(seed=5, n=20)
    m = affordance_metrics("hist", "official_batchwise", 4)
    first = run_metric(m, preds, target, mask, [7])
    m.reset()
    assert run_metric(copy.deepcopy(m), preds, target, mask, [3]) == pytest.approx(first)
    # reset forgets: other samples under the same indices give their own values (stale rows would win, first seen)
    other = make_data(seed=6, n=20)
    m.reset()
    assert run_metric(m, *other, [7]) == pytest.approx(
        run_metric(affordance_metrics("hist", "official_batchwise", 4), *other, [7])
    )
    assert run_metric(m, *other, [7]) != pytest.approx(first)


@pytest.mark.parametrize("reduction", ["per_sample", "official_batchwise"])
def test_calling_a_metric_batch_by_batch_accumulates_every_batch(reduction):
    """``metric(preds, target)`` (torchmetrics' forward, as ``self.log(name, metric(...))`` uses it) without
    ``index``: each batch's samples were numbered from 0 again, so every batch after the first counted as repeats."""
    preds, target, mask = make_data(seed=7, n=24)
    called, updated = affordance_metrics("hist", reduction, 4), affordance_metrics("hist", reduction, 4)
    batches = [slice(0, 8), slice(8, 16), slice(16, 24)]
    for sl in batches:
        p, g, v = (torch.from_numpy(a[sl]) for a in (preds, target, mask))
        step = called(p, g, v)  # the batch's own values
        alone = affordance_metrics("hist", reduction, 4)
        alone.update(p, g, v)
        assert {k: float(x) for k, x in step.items()} == pytest.approx(
            {k: float(x) for k, x in alone.compute().items()}
        )
        updated.update(p, g, v)
    assert {k: float(x) for k, x in called.compute().items()} == pytest.approx(
        {k: float(x) for k, x in updated.compute().items()}
    )
    assert called["rmse"].num_elements == updated["rmse"].num_elements > 2


def test_attributes_and_bad_input():
    assert FloorSIM("hist").sim_variant == "hist"
    assert affordance_metrics()["sim"].sim_variant == "cosine"
    for cls in (FloorRMSE, FloorLogMSE, FloorMAE, FloorPCC, FloorCIoU, FloorSIM):
        assert cls.is_differentiable is False and cls.full_state_update is False
    assert FloorRMSE.higher_is_better is False and FloorPCC.higher_is_better is True
    assert FloorRMSE(reduction="official_batchwise").chunk_size == 64
    with pytest.raises(ValueError, match="sim_variant"):
        FloorSIM("dot")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="reduction"):
        FloorMAE(reduction="mean")  # type: ignore[arg-type]
    m = FloorMAE()
    with pytest.raises(ValueError, match="finite"):
        m.update(torch.tensor([[float("nan"), 0.0]]), torch.zeros(1, 2))
    m.update(torch.tensor([[float("nan"), 0.5]]), torch.ones(1, 2), torch.tensor([[False, True]]))  # NaN masked: fine
    assert float(m.compute()) == pytest.approx(0.5)
    with pytest.raises(ValueError, match=r"\[B, M\]"):
        m.update(torch.zeros(2, 3), torch.zeros(2, 4))
    with pytest.raises(ValueError, match="mask"):
        m.update(torch.zeros(2, 3), torch.zeros(2, 3), torch.ones(2, 3))
    with pytest.raises(ValueError, match="index"):
        m.update(torch.zeros(2, 3), torch.zeros(2, 3), None, torch.zeros(3, dtype=torch.long))


def test_bad_values_name_their_argument_and_chunk_size_is_an_integer():
    """The error said "preds/target" whichever held the NaN; a chunk_size of 2.7 was truncated to 2, True taken as 1."""
    m = FloorRMSE()
    with pytest.raises(ValueError, match=r"FloorRMSE: target must be finite and > -1 on valid floor points; 1 bad "):
        m.update(torch.zeros(2, 3), torch.tensor([[0.0, 0.0, 0.0], [0.0, float("inf"), 0.0]]))
    with pytest.raises(ValueError, match=r"FloorRMSE: preds must be finite .* 4 bad values in batch rows \[0, 1\]"):
        m.update(torch.tensor([[float("nan")] * 3, [0.0, -1.0, 0.0]]), torch.zeros(2, 3))
    for bad in (2.7, True, 0, None):
        with pytest.raises(ValueError, match="FloorPCC: chunk_size must be an integer >= 1"):
            FloorPCC(reduction="official_batchwise", chunk_size=bad)  # type: ignore[arg-type]
    assert FloorPCC(reduction="official_batchwise", chunk_size=np.int64(8)).chunk_size == 8
    z = torch.zeros(2, 3)
    for arg, args in (
        ("index", (z, z, None, [0, 1])),  # an AttributeError on ``.shape`` before
        ("mask", (z, z, [[True] * 3] * 2)),
        ("target", (z, np.zeros((2, 3)))),
    ):
        with pytest.raises(TypeError, match=f"FloorRMSE: {arg} must be a torch.Tensor, got "):
            m.update(*args)


def test_defaults_are_the_documented_conventions():
    """FloorSIM() is the FloAff paper's cosine SIM and the official chunk is 64 samples (docs/background.md §2);
    every other test named both, so neither default was pinned."""
    sim = FloorSIM()
    sim.update(torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([[1.0, 1.0, 0.0]]))
    assert float(sim.compute()) == pytest.approx(1 / math.sqrt(2))  # hist: min(1, .5) = 0.5
    # 65 one-point samples, the last one off by 1: chunk MSEs 0 and 1 -> sqrt(1/2) (chunks of 32: sqrt(1/3))
    preds, target = torch.zeros(65, 1), torch.zeros(65, 1)
    preds[64] = 1.0
    coll = affordance_metrics(reduction="official_batchwise")
    coll.update(preds, target)
    assert float(coll.compute()["rmse"]) == pytest.approx(math.sqrt(0.5))
    for cls in (FloorRMSE, FloorLogMSE, FloorMAE, FloorPCC, FloorCIoU, FloorSIM):
        m = cls(reduction="official_batchwise")
        m.update(preds, target)
        m.compute()
        assert m.num_elements == 2, cls.__name__


def test_official_hist_sim_of_an_all_zero_chunk_is_zero():
    """Histogram SIM of an all-zero p or g is 0 (the official 1e-12); only the per-sample path was pinned, the
    chunk path (raw points) could divide 0 by 0."""
    g = torch.tensor([[0.2, 0.6], [0.0, 0.4], [0.5, 0.5], [0.1, 0.3]])
    p = g.clone()
    p[:2] = 0.0  # chunk 0 predicts nothing; chunk 1 is exact (SIM 1)
    for preds, target in ((p, g), (g, p)):
        m = FloorSIM("hist", "official_batchwise", 2)
        m.update(preds, target)
        assert float(m.compute()) == pytest.approx(0.5)


def test_pcc_of_a_constant_map_is_undefined_whatever_the_rounding_and_padding():
    """Three one-point samples of 0.1 (float64) in one chunk: the merged mean is 0.1 plus an ulp, so the centred
    second moment is ~6e-34, not 0, yet Pearson is undefined (scipy: constant input). Padding (7 above, 0 below the
    constant) must not make the map look varied."""
    varied = torch.tensor([[0.2, 0.0], [0.5, 0.0], [0.9, 0.0]], dtype=torch.float64)
    mask = torch.tensor([[True, False]] * 3)
    for pad in (7.0, 0.0):
        const = torch.tensor([[0.1, pad]] * 3, dtype=torch.float64)
        for preds, target in ((const, varied), (varied, const)):
            m = FloorPCC("official_batchwise")
            m.update(preds, target, mask)
            assert float(m.compute()) == 0.0 and m.num_undefined == 1, (pad, preds is const)


@pytest.mark.parametrize("sim_variant", ["hist", "cosine"])
@pytest.mark.parametrize("reduction", ["per_sample", "official_batchwise"])
def test_a_repeated_index_counts_its_first_sample_only(sim_variant, reduction):
    """Samples with the same index count once, the first one seen: a repeat inside one batch and a later batch
    with other maps under the same indices change nothing (histogram SIM reduces complete chunks early, on its own
    path)."""
    rng = np.random.default_rng(11)
    preds, target = rng.random((4, 6)).astype(np.float32), rng.random((4, 6)).astype(np.float32)
    mask = np.ones((4, 6), bool)
    want = reference(preds, target, mask, np.arange(4), reduction, 2, sim_variant)
    m = affordance_metrics(sim_variant, reduction, 2)
    for rows in ([0, 1, 0], [2, 3]):
        m.update(torch.from_numpy(preds[rows]), torch.from_numpy(target[rows]), None, torch.tensor(rows))
    other = torch.from_numpy(rng.random((4, 6)).astype(np.float32))  # other maps under the same indices
    m.update(other, torch.from_numpy(target), None, torch.arange(4))
    got = {k: float(v) for k, v in m.compute().items()}
    assert got == pytest.approx(want, rel=1e-5, abs=1e-6)


def test_a_negative_index_is_refused():
    with pytest.raises(ValueError, match="FloorRMSE: index must be >= 0"):
        FloorRMSE().update(torch.zeros(2, 3), torch.zeros(2, 3), None, torch.tensor([0, -1]))
