"""FloAff map metrics as DDP-correct torchmetrics ``Metric`` subclasses.

Every metric takes ``update(preds [B, M], target [B, M], mask [B, M] bool | None, index [B] long | None)``.
Masked (padding) floor points never count. Definitions follow MoMa-Kitchen's official evaluation
(``MoMaKitchen/MoMaKitchen:utils/cal_metric.py@64ca7a4``, ``utils/cal_metric_new.py@64ca7a4``; see
docs/background.md §2). An **element** is the unit a metric is computed on before averaging:

* ``reduction="per_sample"``: one element per sample (its valid floor points).
* ``reduction="official_batchwise"``: one element per *chunk* of ``chunk_size`` (64) consecutive samples in
  split order, i.e. chunk = ``index // chunk_size``; the valid floor points of all the chunk's samples are
  concatenated into one (p, g) pair, exactly like the official eval loader (batch 64, no shuffle, no drop_last).
  The result does not depend on how the caller batches ``update()`` calls.

Per element (p = prediction, g = label, over its valid points):

=========  ====================================================  ================================
metric     per element                                           reported
=========  ====================================================  ================================
rmse       MSE = mean (p - g)^2                                  sqrt(mean over elements of MSE)
mae        mean |p - g|                                          mean over elements
logmse     mean (log1p(g) - log1p(p))^2 (natural log, no sqrt)   mean over elements
pcc        Pearson r (``scipy.stats.pearsonr`` semantics)         mean over *defined* elements
sim        ``hist``: sum min(p/(sum p+1e-12), g/(sum g+1e-12))   mean over elements
           ``cosine``: sum pg / ((|p|+1e-12)(|g|+1e-12))
ciou       sum min(p, g) / sum max(p, g) (0 when sum max <= 0)    mean over elements
=========  ====================================================  ================================

Documented conventions:

* ``per_sample`` RMSE is sqrt(mean over samples of the per-sample MSE): the official formula with a chunk
  size of 1 (not the mean of per-sample RMSEs).
* An element with no valid point (all-masked sample, or a chunk of such samples) is excluded from every
  average; ``metric.num_empty`` counts them after ``compute()``.
* PCC is undefined for an element with < 2 points or a constant p or g (scipy returns NaN / raises there).
  Such elements are excluded from the PCC average and counted in ``FloorPCC.num_undefined``; if no element
  is defined, PCC is 0.0 (never NaN). The official code instead adds 0 for < 2 points and lets NaN leak
  for constant maps.
* Zero maps follow the official epsilons: cosine SIM of a zero-norm p or g is 0 (``1e-12`` added to each
  norm), histogram SIM of an all-zero p or g is 0, cIoU with an empty union (both all-zero) is 0. cIoU is meant for
  non-negative maps (scores and labels in [0, 1]); where sum max(p, g) <= 0 it is 0 as well.
* Values must be finite and > -1 on valid points (log1p); anything else raises ``ValueError``.
* Samples with the same ``index`` count once (first one seen): ``DistributedSampler`` pads the last
  rank-batches by repeating samples. Under DDP always pass ``index``; without it samples are numbered in
  local ``update()`` order, which is only meaningful on a single process.

State design (why it is DDP-correct): every update appends one float64 row of sufficient statistics per
sample (``cat`` state ``rows``: index, n, sums, centred second moments, min/max, ...). ``compute()`` groups
rows by element id and merges them exactly (Chan et al.'s pairwise moment update), so an element may be
split across updates and ranks. Histogram SIM in ``official_batchwise`` mode needs each chunk's totals
before it can normalise, so the (p, g) values of valid points are kept (``cat`` states ``pend_rows``,
``pend_pts``) until the chunk's ``chunk_size`` distinct indices have all been seen on this process; then
the chunk is reduced to one (chunk id, SIM) row (``cat`` state ``hist_done``) and its points are dropped.
With in-order single-process evaluation at most about one chunk of points is held; under DDP (a
``DistributedSampler`` spreads every chunk over the ranks) the points of all chunks are held until
``compute()`` gathers them: exact, at the cost of memory (2 float32 per valid point).
"""

from __future__ import annotations

from typing import Any, Literal

import torch
from torch import Tensor
from torchmetrics import Metric, MetricCollection
from torchmetrics.utilities.data import dim_zero_cat
from torchmetrics.utilities.distributed import gather_all_tensors

from floaff_zoo.checks import check_integer

__all__ = [
    "FloorCIoU",
    "FloorLogMSE",
    "FloorMAE",
    "FloorPCC",
    "FloorRMSE",
    "FloorSIM",
    "affordance_metrics",
]

Reduction = Literal["per_sample", "official_batchwise"]
SimVariant = Literal["hist", "cosine"]

_EPS = 1e-12  # official epsilon for SIM normalisation (hist) and norms (cosine)
# Columns of one per-sample statistics row.
_COLS = (
    "index", "n", "sp", "sg", "m2p", "m2g", "cpg", "spp", "sgg", "spg",
    "sse", "sae", "sle", "smin", "smax", "pmin", "pmax", "gmin", "gmax", "simh",
)  # fmt: skip
_C = {name: i for i, name in enumerate(_COLS)}


def _check_inputs(
    name: str, preds: Tensor, target: Tensor, mask: Tensor | None, index: Tensor | None
) -> tuple[Tensor, Tensor, Tensor]:
    """Validate shapes/dtypes; return (p, g) float64 [B, M] and mask bool [B, M]."""
    for arg, value in (("preds", preds), ("target", target), ("mask", mask), ("index", index)):
        if value is not None and not isinstance(value, Tensor):  # a list failed on ``.shape`` naming nothing
            raise TypeError(f"{name}: {arg} must be a torch.Tensor, got {type(value).__name__}")
    if preds.ndim != 2 or preds.shape != target.shape:
        raise ValueError(
            f"{name}: preds and target must both be [B, M]; got {tuple(preds.shape)} and {tuple(target.shape)}"
        )
    if mask is None:
        mask = torch.ones_like(preds, dtype=torch.bool)
    if mask.dtype != torch.bool or mask.shape != preds.shape:
        raise ValueError(f"{name}: mask must be bool {tuple(preds.shape)}; got {mask.dtype} {tuple(mask.shape)}")
    if index is not None:
        if index.shape != preds.shape[:1] or index.is_floating_point() or index.dtype == torch.bool:
            raise ValueError(
                f"{name}: index must be an integer tensor [B={preds.shape[0]}]; got {index.dtype} {tuple(index.shape)}"
            )
        if (index < 0).any():
            raise ValueError(f"{name}: index must be >= 0 (position of the sample in its split)")
    p, g = preds.detach().double(), target.detach().double()
    bad = {arg: mask & ~(torch.isfinite(v) & (v > -1)) for arg, v in (("preds", p), ("target", g))}
    # one sync for both; the message names the argument that holds them
    for (arg, b), has_bad in zip(bad.items(), torch.stack([b.any() for b in bad.values()]).tolist()):
        if has_bad:
            rows = torch.nonzero(b.any(1)).flatten()[:8].tolist()
            raise ValueError(
                f"{name}: {arg} must be finite and > -1 on valid floor points; "
                f"{int(b.sum())} bad values in batch rows {rows}"
            )
    return p, g, mask


def _sample_stats(p: Tensor, g: Tensor, mask: Tensor, index: Tensor) -> Tensor:
    """Sufficient statistics of each sample. p, g float64 [B, M], mask bool [B, M], index [B] -> [B, len(_COLS)]."""
    pz, gz = torch.where(mask, p, 0.0), torch.where(mask, g, 0.0)
    n = mask.sum(1).double()
    sp, sg = pz.sum(1), gz.sum(1)
    # Centred moments within the sample (stable; merged exactly across samples in compute()).
    dp = torch.where(mask, p - (sp / n.clamp_min(1))[:, None], 0.0)
    dg = torch.where(mask, g - (sg / n.clamp_min(1))[:, None], 0.0)
    inf = torch.tensor(float("inf"), dtype=p.dtype, device=p.device)
    simh = torch.minimum(pz / (sp[:, None] + _EPS), gz / (sg[:, None] + _EPS)).sum(1)
    cols = [
        index.double(), n, sp, sg, (dp * dp).sum(1), (dg * dg).sum(1), (dp * dg).sum(1),
        (pz * pz).sum(1), (gz * gz).sum(1), (pz * gz).sum(1),
        ((pz - gz) ** 2).sum(1), (pz - gz).abs().sum(1), ((torch.log1p(gz) - torch.log1p(pz)) ** 2).sum(1),
        torch.minimum(pz, gz).sum(1), torch.maximum(pz, gz).sum(1),
        torch.where(mask, p, inf).amin(1), torch.where(mask, p, -inf).amax(1),
        torch.where(mask, g, inf).amin(1), torch.where(mask, g, -inf).amax(1),
        simh,
    ]  # fmt: skip
    return torch.stack(cols, 1)


def _first_occurrence(keys: Tensor) -> Tensor:
    """Bool [S]: True at the first occurrence of each value of ``keys`` [S]."""
    keep = torch.zeros(keys.numel(), dtype=torch.bool, device=keys.device)
    if keys.numel() == 0:
        return keep
    uniq, inv = torch.unique(keys, return_inverse=True)
    pos = torch.arange(keys.numel(), device=keys.device)
    first = torch.full((uniq.numel(),), keys.numel(), dtype=torch.long, device=keys.device)
    first = first.scatter_reduce(0, inv, pos, reduce="amin", include_self=True)
    keep[first] = True
    return keep


def _group_sum(values: Tensor, inv: Tensor, size: int) -> Tensor:
    """Sum ``values`` [S, ...] into ``size`` groups by ``inv`` [S]."""
    out = torch.zeros((size, *values.shape[1:]), dtype=values.dtype, device=values.device)
    return out.index_add_(0, inv, values)


def _group_reduce(values: Tensor, inv: Tensor, size: int, how: Literal["amin", "amax"]) -> Tensor:
    """Min/max of ``values`` [S] per group (``inv`` [S]) -> [size]."""
    out = torch.zeros(size, dtype=values.dtype, device=values.device)
    return out.scatter_reduce(0, inv, values, reduce=how, include_self=False)


def _element_table(rows: Tensor, chunk_size: int) -> dict[str, Tensor]:
    """Merge per-sample rows [S, K] (already deduplicated) into per-element statistics.

    Returns a dict of [E] float64 tensors, one entry per element (chunk id ascending), including
    ``id`` (element id), ``n``, ``mse``, ``mae``, ``logmse``, ``pcc``, ``pcc_defined`` (bool), ``cos``,
    ``ciou`` and ``simh_sample`` (per-sample hist SIM, only meaningful when an element is one sample).
    """
    cid = torch.div(rows[:, _C["index"]], chunk_size, rounding_mode="floor")
    ids, inv = torch.unique(cid, return_inverse=True)
    e = ids.numel()
    s = {
        k: _group_sum(rows[:, _C[k]], inv, e)
        for k in ("n", "sp", "sg", "spp", "sgg", "spg", "sse", "sae", "sle", "smin", "smax", "simh")
    }
    n_i = rows[:, _C["n"]]
    mp_i, mg_i = rows[:, _C["sp"]] / n_i.clamp_min(1), rows[:, _C["sg"]] / n_i.clamp_min(1)
    n = s["n"]
    mp, mg = s["sp"] / n.clamp_min(1), s["sg"] / n.clamp_min(1)
    # Exact merge of centred moments: M2 = sum_i [M2_i + n_i (mean_i - mean)^2], same for the co-moment.
    ddp, ddg = mp_i - mp[inv], mg_i - mg[inv]
    m2p = _group_sum(rows[:, _C["m2p"]] + n_i * ddp * ddp, inv, e)
    m2g = _group_sum(rows[:, _C["m2g"]] + n_i * ddg * ddg, inv, e)
    cpg = _group_sum(rows[:, _C["cpg"]] + n_i * ddp * ddg, inv, e)
    pmin, pmax = _group_reduce(rows[:, _C["pmin"]], inv, e, "amin"), _group_reduce(rows[:, _C["pmax"]], inv, e, "amax")
    gmin, gmax = _group_reduce(rows[:, _C["gmin"]], inv, e, "amin"), _group_reduce(rows[:, _C["gmax"]], inv, e, "amax")
    nn = n.clamp_min(1)
    # Pearson is undefined (scipy: NaN / error) for < 2 points or a constant input; detect constancy exactly.
    defined = (n >= 2) & (pmax > pmin) & (gmax > gmin) & (m2p > 0) & (m2g > 0)
    pcc = torch.where(defined, cpg / torch.sqrt(m2p * m2g).clamp_min(1e-300), 0.0).clamp(-1.0, 1.0)
    cos = s["spg"] / ((torch.sqrt(s["spp"]) + _EPS) * (torch.sqrt(s["sgg"]) + _EPS))
    ciou = torch.where(s["smax"] > 0, s["smin"] / s["smax"].clamp_min(1e-300), 0.0)
    return {
        "id": ids, "n": n, "mse": s["sse"] / nn, "mae": s["sae"] / nn, "logmse": s["sle"] / nn,
        "pcc": pcc, "pcc_defined": defined, "cos": cos, "ciou": ciou, "simh_sample": s["simh"],
    }  # fmt: skip


def _hist_sim_from_points(rows: Tensor, pts: Tensor, chunk_size: int) -> tuple[Tensor, Tensor]:
    """Histogram SIM per chunk from raw points.

    rows [S, 2] = (sample index, n points), pts [sum n, 2] = (p, g) in row order.
    Returns (chunk ids [E] float64, SIM [E] float64).
    """
    cid = torch.div(rows[:, 0], chunk_size, rounding_mode="floor")
    ids, inv = torch.unique(cid, return_inverse=True)
    pinv = torch.repeat_interleave(inv, rows[:, 1].long())
    p, g = pts[:, 0].double(), pts[:, 1].double()
    sp, sg = _group_sum(p, pinv, ids.numel()), _group_sum(g, pinv, ids.numel())
    inter = torch.minimum(p / (sp[pinv] + _EPS), g / (sg[pinv] + _EPS))
    return ids, _group_sum(inter, pinv, ids.numel())


def _cat_or_empty(state: list[Tensor] | Tensor, width: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """A ``cat`` state (list before sync, tensor after) as one [S, width] tensor."""
    if isinstance(state, Tensor):
        return state.reshape(-1, width)
    if len(state) == 0:
        return torch.zeros((0, width), dtype=dtype, device=device)
    return dim_zero_cat(state).reshape(-1, width)


#: row width and dtype of each ``cat`` state of the map metrics (``rows`` always; the others for histogram SIM over
#: multi-sample chunks)
_CAT_STATES: dict[str, tuple[int, torch.dtype]] = {
    "rows": (len(_COLS), torch.float64),
    "pend_rows": (2, torch.float64),
    "pend_pts": (2, torch.float32),
    "hist_done": (2, torch.float64),
}


def fill_empty_cat_states(metric: Metric, states: dict[str, tuple[int, torch.dtype]]) -> None:
    """Before a DDP sync, give each empty list state ``name`` of ``metric`` one [0, width] tensor (``states``: name ->
    (width, dtype)). A process that saw no batch holds empty lists, for which torchmetrics gathers a 1-D stand-in
    whose size does not match the other processes' [S, width] rows, and the collective aborts."""
    for name, (width, dtype) in states.items():
        state = getattr(metric, name, None)
        if isinstance(state, list) and not state:
            state.append(torch.zeros((0, width), dtype=dtype, device=metric.device))


class _FloorMetric(Metric):
    """Shared state and element bookkeeping of the FloAff map metrics (see the module docstring)."""

    is_differentiable = False
    full_state_update = False
    #: added to ``seen`` when update() numbers samples without ``index`` (see forward)
    _forward_offset = 0
    higher_is_better: bool

    def __init__(self, reduction: Reduction = "per_sample", chunk_size: int = 64, keep_points: bool = False) -> None:
        super().__init__()
        if reduction not in ("per_sample", "official_batchwise"):
            raise ValueError(
                f"{type(self).__name__}: reduction must be 'per_sample' or 'official_batchwise', got {reduction!r}"
            )
        # a float was truncated (2.7 -> 2), True counted as 1
        check_integer("chunk_size", chunk_size, minimum=1, owner=type(self).__name__)
        self.reduction = reduction
        self.chunk_size = int(chunk_size)
        # Element size in samples: 1 for per_sample, chunk_size for the official convention.
        self._elem = 1 if reduction == "per_sample" else self.chunk_size
        # Raw points only needed for histogram SIM over multi-sample chunks.
        self._keep_points = keep_points and reduction == "official_batchwise"
        self.num_empty = 0
        self.num_elements = 0
        self.add_state("rows", default=[], dist_reduce_fx="cat")
        self.add_state("seen", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        if self._keep_points:
            self.add_state("pend_rows", default=[], dist_reduce_fx="cat")
            self.add_state("pend_pts", default=[], dist_reduce_fx="cat")
            self.add_state("hist_done", default=[], dist_reduce_fx="cat")

    def _cat(self, name: str) -> Tensor:
        """The ``cat`` state ``name`` as one [S, width] tensor."""
        width, dtype = _CAT_STATES[name]
        return _cat_or_empty(getattr(self, name), width, dtype, self.device)

    def _sync_dist(self, dist_sync_fn: Any = gather_all_tensors, process_group: Any = None) -> None:
        fill_empty_cat_states(self, _CAT_STATES)
        super()._sync_dist(dist_sync_fn, process_group)

    def update(self, preds: Tensor, target: Tensor, mask: Tensor | None = None, index: Tensor | None = None) -> None:
        """Accumulate a batch: preds/target [B, M], mask bool [B, M] (None = all valid), index [B] split positions."""
        p, g, mask = _check_inputs(type(self).__name__, preds, target, mask, index)
        b = p.shape[0]
        if p.shape[1] == 0:  # no floor point in the batch: one padded column keeps the per-sample reductions defined
            p, g, mask = p.new_zeros((b, 1)), g.new_zeros((b, 1)), mask.new_zeros((b, 1))
        if index is None:
            index = torch.arange(b, device=p.device) + self.seen + self._forward_offset
        index = index.to(p.device).long()
        self.seen += b
        self.rows.append(_sample_stats(p, g, mask, index))
        if self._keep_points:
            self._update_points(p, g, mask, index)

    def forward(self, *args: Any, **kwargs: Any) -> Any:
        """torchmetrics' forward updates a fresh state with the batch alone (``seen`` 0), then merges it into the one
        held: without ``index`` its samples took the numbers of the first batch's and counted once with them."""
        self._forward_offset = int(self.seen)
        try:
            return super().forward(*args, **kwargs)
        finally:
            self._forward_offset = 0

    def _update_points(self, p: Tensor, g: Tensor, mask: Tensor, index: Tensor) -> None:
        """Buffer valid (p, g) points; reduce chunks whose chunk_size samples are all here to one SIM row."""
        # Always append (possibly empty) tensors so no rank syncs an empty list (mismatched gathers).
        self.pend_rows.append(torch.stack([index.double(), mask.sum(1).double()], 1))
        self.pend_pts.append(torch.stack([p[mask], g[mask]], 1).float())
        self.hist_done.append(torch.zeros((0, 2), dtype=torch.float64, device=p.device))
        rows = dim_zero_cat(self.pend_rows)
        touched = torch.unique(torch.div(index, self.chunk_size, rounding_mode="floor")).double()
        cid = torch.div(rows[:, 0], self.chunk_size, rounding_mode="floor")
        uniq_idx = torch.unique(rows[torch.isin(cid, touched), 0])
        chunks, counts = torch.unique(torch.div(uniq_idx, self.chunk_size, rounding_mode="floor"), return_counts=True)
        complete = chunks[counts == self.chunk_size]
        if complete.numel() == 0:
            return
        pts = dim_zero_cat(self.pend_pts)
        keep_rows = _first_occurrence(rows[:, 0])
        done_rows = torch.isin(cid, complete)
        pt_done = torch.repeat_interleave(done_rows, rows[:, 1].long())
        pt_keep = torch.repeat_interleave(keep_rows, rows[:, 1].long())
        sel = done_rows & keep_rows
        ids, sim = _hist_sim_from_points(rows[sel], pts[pt_done & pt_keep], self.chunk_size)
        # Mutate lists in place: MetricCollection compute groups may share these list objects.
        self.hist_done.append(torch.stack([ids, sim], 1))
        self.pend_rows[:] = [rows[~done_rows]]
        self.pend_pts[:] = [pts[~pt_done]]

    def _elements(self) -> dict[str, Tensor]:
        """Per-element statistics of everything seen (deduplicated by sample index); sets num_empty/num_elements."""
        rows = self._cat("rows")
        rows = rows[_first_occurrence(rows[:, _C["index"]])]
        table = _element_table(rows, self._elem)
        table["valid"] = table["n"] > 0
        self.num_elements = int(table["valid"].sum())
        self.num_empty = int((~table["valid"]).sum())
        return table

    def _hist_sim(self, table: dict[str, Tensor]) -> Tensor:
        """Histogram SIM per element [E], aligned with ``table['id']``."""
        if not self._keep_points:
            return table["simh_sample"]  # per_sample: one sample per element
        done = self._cat("hist_done")
        done = done[_first_occurrence(done[:, 0])]
        rows = self._cat("pend_rows")
        pts = self._cat("pend_pts")
        cid = torch.div(rows[:, 0], self.chunk_size, rounding_mode="floor")
        keep = _first_occurrence(rows[:, 0]) & ~torch.isin(cid, done[:, 0])
        pt_keep = torch.repeat_interleave(keep, rows[:, 1].long())
        ids, sim = _hist_sim_from_points(rows[keep], pts[pt_keep], self.chunk_size)
        all_ids, all_sim = torch.cat([done[:, 0], ids]), torch.cat([done[:, 1], sim])
        out = torch.zeros_like(table["n"])
        pos = torch.searchsorted(table["id"], all_ids)
        out[pos] = all_sim
        return out

    @staticmethod
    def _mean(values: Tensor, valid: Tensor) -> Tensor:
        """Mean of ``values`` [E] over ``valid`` [E]; 0.0 when nothing is valid (never NaN)."""
        if not bool(valid.any()):
            return torch.zeros((), dtype=torch.float64, device=values.device)
        return values[valid].mean()

    def _finish(self, value: Tensor) -> Tensor:
        return value.float()


class FloorRMSE(_FloorMetric):
    """sqrt(mean over elements of the element MSE) (official: sqrt of mean chunk MSE)."""

    higher_is_better = False

    def __init__(self, reduction: Reduction = "per_sample", chunk_size: int = 64) -> None:
        super().__init__(reduction=reduction, chunk_size=chunk_size)

    def compute(self) -> Tensor:
        t = self._elements()
        return self._finish(torch.sqrt(self._mean(t["mse"], t["valid"])))


class FloorMAE(_FloorMetric):
    """Mean over elements of mean |p - g|."""

    higher_is_better = False

    def __init__(self, reduction: Reduction = "per_sample", chunk_size: int = 64) -> None:
        super().__init__(reduction=reduction, chunk_size=chunk_size)

    def compute(self) -> Tensor:
        t = self._elements()
        return self._finish(self._mean(t["mae"], t["valid"]))


class FloorLogMSE(_FloorMetric):
    """Mean over elements of mean (log1p(g) - log1p(p))^2 (natural log, no sqrt)."""

    higher_is_better = False

    def __init__(self, reduction: Reduction = "per_sample", chunk_size: int = 64) -> None:
        super().__init__(reduction=reduction, chunk_size=chunk_size)

    def compute(self) -> Tensor:
        t = self._elements()
        return self._finish(self._mean(t["logmse"], t["valid"]))


class FloorPCC(_FloorMetric):
    """Mean Pearson r over elements where it is defined; ``num_undefined`` counts the others (0.0 if none)."""

    higher_is_better = True

    def __init__(self, reduction: Reduction = "per_sample", chunk_size: int = 64) -> None:
        super().__init__(reduction=reduction, chunk_size=chunk_size)
        self.num_undefined = 0

    def compute(self) -> Tensor:
        t = self._elements()
        defined = t["valid"] & t["pcc_defined"]
        self.num_undefined = int((t["valid"] & ~t["pcc_defined"]).sum())
        return self._finish(self._mean(t["pcc"], defined))


class FloorSIM(_FloorMetric):
    """Mean SIM over elements; ``sim_variant`` = ``hist`` (MoMa-Kitchen code) or ``cosine`` (FloAff paper)."""

    higher_is_better = True

    def __init__(
        self, sim_variant: SimVariant = "cosine", reduction: Reduction = "per_sample", chunk_size: int = 64
    ) -> None:
        if sim_variant not in ("hist", "cosine"):
            raise ValueError(f"FloorSIM: sim_variant must be 'hist' or 'cosine', got {sim_variant!r}")
        super().__init__(reduction=reduction, chunk_size=chunk_size, keep_points=sim_variant == "hist")
        self.sim_variant = sim_variant

    def compute(self) -> Tensor:
        t = self._elements()
        values = self._hist_sim(t) if self.sim_variant == "hist" else t["cos"]
        return self._finish(self._mean(values, t["valid"]))


class FloorCIoU(_FloorMetric):
    """Mean over elements of the continuous IoU sum min(p, g) / sum max(p, g) (0 for an empty union)."""

    higher_is_better = True

    def __init__(self, reduction: Reduction = "per_sample", chunk_size: int = 64) -> None:
        super().__init__(reduction=reduction, chunk_size=chunk_size)

    def compute(self) -> Tensor:
        t = self._elements()
        return self._finish(self._mean(t["ciou"], t["valid"]))


def affordance_metrics(
    sim_variant: SimVariant = "cosine", reduction: Reduction = "per_sample", chunk_size: int = 64
) -> MetricCollection:
    """All six FloAff metrics keyed ``rmse, logmse, pcc, sim, mae, ciou`` (update with preds, target, mask, index)."""
    return MetricCollection(
        {
            "rmse": FloorRMSE(reduction=reduction, chunk_size=chunk_size),
            "logmse": FloorLogMSE(reduction=reduction, chunk_size=chunk_size),
            "pcc": FloorPCC(reduction=reduction, chunk_size=chunk_size),
            "sim": FloorSIM(sim_variant=sim_variant, reduction=reduction, chunk_size=chunk_size),
            "mae": FloorMAE(reduction=reduction, chunk_size=chunk_size),
            "ciou": FloorCIoU(reduction=reduction, chunk_size=chunk_size),
        }
    )
