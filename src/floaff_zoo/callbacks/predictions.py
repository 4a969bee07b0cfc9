"""What ``floaff-zoo predict`` computes, written into the run's folder.

``predictions.npz`` holds one array per tensor the model's ``predict_step`` returns, the batches concatenated
in the loader's order: ``[N, ...]`` (N samples; a bfloat16 tensor, as ``bf16-mixed`` autocast gives, as float32:
numpy has no bfloat16); a per-point array ``[N, M, ...]`` is padded to the largest view
(NaN for floats, False for masks, 0 for integers, so ``floor_mask`` says which entries are real; a floor-map
model's ``scores`` and ``floor_xyz`` are NaN on every padded point, its batch's padding included; a NaN/Inf score on
a real floor point is refused with the samples named, as ``predict()`` refuses it). A floor-map
model writes ``scores``, ``floor_xyz``, ``floor_mask``, ``target_xyz`` and ``best_pose`` ([N, 3] x, y, yaw: the
top-scored floor point facing the target, where the success-rate callback stands at top-1) in the robot base frame;
CFAR also the yaw, crop radius and canonical-to-robot transform it used, N2M and C2F-Exp their own proposed
``poses`` [N, 3], AxisNet its ``yaw``. ``predictions.json`` holds the samples'
``meta`` (scene, view, task, ...) in the same order and each array's shape. Read it back with
``np.load(path)`` (no pickle).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import BasePredictionWriter
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.atomic import atomic_write, atomic_write_text, existing_ancestor
from floaff_zoo.callbacks.report import jsonable
from floaff_zoo.contract import NonFiniteError


def _pad_value(dtype: np.dtype) -> Any:
    if np.issubdtype(dtype, np.floating):
        return np.nan
    return False if dtype == np.bool_ else 0


def stack_batches(parts: list[np.ndarray], key: str) -> np.ndarray:
    """Concatenate batch arrays [B_i, M_i, ...] along the batch, padding every later axis to its largest size.

    Raises:
        ValueError: the batches disagree in rank or dtype (naming ``key``).
    """
    if len({p.ndim for p in parts}) > 1 or len({p.dtype for p in parts}) > 1:
        seen = [(p.shape, str(p.dtype)) for p in parts]
        raise ValueError(f"predict: {key!r} changes rank or dtype between batches: {seen}")
    shape = np.max([p.shape for p in parts], axis=0)
    out = []
    for p in parts:
        pad = [(0, 0)] + [(0, int(n) - s) for n, s in zip(shape[1:], p.shape[1:])]
        out.append(np.pad(p, pad, constant_values=_pad_value(p.dtype)) if any(b for _, b in pad) else p)
    return np.concatenate(out, axis=0)


def _to_numpy(t: torch.Tensor) -> np.ndarray:
    """A record's tensor as numpy; bfloat16 (an output computed under ``bf16-mixed`` autocast, e.g. AxisNet's yaw),
    which numpy has no type for, as float32."""
    t = t.detach().cpu()
    return (t.float() if t.dtype == torch.bfloat16 else t).numpy()


def check_record(i: int, record: dict[str, Any], keys: list[str]) -> None:
    """Refuse batch ``i``'s ``predict_step`` record unless it holds a tensor ``[B, ...]`` under each of ``keys``
    (batch 0's tensors), no other tensor, and ``meta`` (when given) of ``B`` samples: written, an array of another
    length, or a ``meta`` list of another length, sat in the files out of step with the samples, and a key that
    batch 0 lacked vanished without a word.

    Raises:
        ValueError: naming the batch and the key.
    """
    missing = [k for k in keys if not torch.is_tensor(record.get(k))]
    if missing:
        raise ValueError(f"predict: batch {i} has no tensor {missing[0]!r} (batch 0 has)")
    extra = [k for k, v in record.items() if torch.is_tensor(v) and k not in keys]
    if extra:
        raise ValueError(f"predict: batch {i} has tensor(s) {extra} that batch 0 has not")
    sizes = {k: len(record[k]) if record[k].dim() else None for k in keys}
    if record.get("meta"):  # none (or an empty list) stands for one empty meta per sample
        sizes["meta"] = len(record["meta"])
    if len(set(sizes.values())) > 1 or None in sizes.values():
        got = ", ".join(f"{k}: {'a scalar' if n is None else n}" for k, n in sizes.items())
        raise ValueError(f"predict: batch {i}: every output must hold one entry per sample [B, ...]; got {got}")


def gather_predictions(records: list[dict[str, Any]]) -> tuple[dict[str, np.ndarray], list[dict[str, Any]]]:
    """Batch records of ``predict_step`` -> (arrays {key: [N, ...]}, meta [N]); a record that does not hold the same
    per-sample tensors as batch 0 is an error (``check_record``)."""
    for i, r in enumerate(records):
        if not isinstance(r, dict):
            raise ValueError(f"predict: batch {i}: predict_step returned a {type(r).__name__}, not a dict of tensors")
    keys = [k for k, v in records[0].items() if torch.is_tensor(v)]
    dropped = [k for k in records[0] if k != "meta" and k not in keys]
    if dropped:  # a model's extra output that is no tensor (a list of poses) would vanish without a word
        warnings.warn(f"predict: {dropped} are not tensors and are not written to the predictions file", stacklevel=2)
    for i, r in enumerate(records):
        check_record(i, r, keys)
    arrays = {k: stack_batches([_to_numpy(r[k]) for r in records], k) for k in keys}
    meta: list[dict[str, Any]] = []
    for r in records:
        meta.extend(r.get("meta") or [{}] * (len(r[keys[0]]) if keys else 0))
    return arrays, meta


def check_finite_scores(arrays: dict[str, np.ndarray], meta: list[dict[str, Any]], model: str) -> None:
    """Refuse ``scores`` [N, M] that are NaN/Inf on a real floor point (``floor_mask`` [N, M]), as ``predict()``
    does: written, they would be NaN maps and poses that nothing counts.

    Raises:
        NonFiniteError: one line naming the samples (``meta['sample_id']``, else their position).
    """
    if "scores" not in arrays or "floor_mask" not in arrays:
        return  # not a floor-map model (AxisNet writes a yaw)
    scores, mask = arrays["scores"], arrays["floor_mask"].astype(bool)
    bad = np.flatnonzero((~np.isfinite(scores) & mask).reshape(len(scores), -1).any(axis=1))
    if len(bad):
        ids = [str((meta[i] if i < len(meta) else {}).get("sample_id", i)) for i in bad]
        more = f" and {len(ids) - 5} more" if len(ids) > 5 else ""
        raise NonFiniteError(
            f"predict: {model} returned NaN/Inf scores on floor points of {len(ids)} of {len(scores)} sample(s): "
            f"{', '.join(ids[:5])}{more}; no predictions written"
        )


def remove_stale_predictions(run_dir: Path, world_size: int) -> bool:
    """Remove the prediction files of an earlier run in ``run_dir`` that this run (``world_size`` processes) does
    not rewrite: ``predictions.*`` under DDP, ``predictions_rank<r>.*`` of other world sizes. Returns whether any
    went. (Rank 0 alone calls it: no file it removes is one a rank of this run writes.)"""
    ours = {"predictions"} if world_size == 1 else {f"predictions_rank{r}" for r in range(world_size)}
    stale = [
        f
        for f in [*run_dir.glob("predictions.*"), *run_dir.glob("predictions_rank*.*")]
        if f.suffix in (".npz", ".json") and f.stem not in ours
    ]
    for f in stale:
        f.unlink()
    return bool(stale)


def _stem(trainer: L.Trainer) -> str:
    """This process's prediction file name without suffix: ``predictions``, ``predictions_rank<r>`` under DDP."""
    return "predictions" if trainer.world_size == 1 else f"predictions_rank{trainer.global_rank}"


class PredictionWriter(BasePredictionWriter):
    """Write ``<run>/predictions.npz`` and ``predictions.json`` at the end of ``floaff-zoo predict`` (module
    docstring); under several processes each rank writes its own pair, ``predictions_rank<r>``.

    Args:
        out_dir: where to write; default the run's log dir (``trainer.log_dir``) or ``default_root_dir``.
    """

    def __init__(self, out_dir: str | None = None) -> None:
        super().__init__(write_interval="epoch")
        self.out_dir = out_dir
        self.written: dict[str, str] = {}

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        """Refuse an ``out_dir`` that is a file, lies under one or is a dangling link, and a folder where a
        prediction file goes, before predicting: its ``mkdir`` or the write failed after the whole run."""
        super().setup(trainer, pl_module, stage)
        if not self.out_dir:  # the run's log dir, made by its logger
            return
        out = Path(self.out_dir)
        found = existing_ancestor(out)  # the first of out_dir and its parents there (a dangling link counts)
        if found == out.absolute() and not found.is_dir():
            what = "a dangling link" if found.is_symlink() and not found.exists() else "a file"
            raise MisconfigurationException(f"PredictionWriter: out_dir {self.out_dir} is {what}, not a folder")
        if not found.is_dir():
            raise MisconfigurationException(f"PredictionWriter: out_dir {self.out_dir}: {found} is not a folder")
        stem = _stem(trainer)
        taken = [f for f in (out / f"{stem}.npz", out / f"{stem}.json") if f.is_dir()]
        if taken:
            raise MisconfigurationException(f"PredictionWriter: {taken[0]} is a folder, where the predictions go")

    def write_on_epoch_end(
        self, trainer: L.Trainer, pl_module: L.LightningModule, predictions: Any, batch_indices: Any
    ) -> None:
        # one list per dataloader when there are several
        several = bool(predictions) and isinstance(predictions[0], list)
        batches = [r for p in predictions for r in p] if several else predictions
        if not batches:
            return
        arrays, meta = gather_predictions(list(batches))
        check_finite_scores(arrays, meta, type(pl_module).__name__)
        run_dir = Path(self.out_dir or trainer.log_dir or trainer.default_root_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        stem = _stem(trainer)
        npz, js = run_dir / f"{stem}.npz", run_dir / f"{stem}.json"
        replaced = npz.is_file() or js.is_file()
        if trainer.is_global_zero:
            replaced = remove_stale_predictions(run_dir, trainer.world_size) or replaced
        shapes = {k: list(v.shape) for k, v in arrays.items()}
        text = json.dumps({"n": len(meta), "arrays": shapes, "meta": jsonable(meta)}, indent=1)
        # each file whole (a temp file renamed over it): a reader of the earlier pair never meets half a file, and a
        # killed run leaves the earlier file, not a truncated one
        atomic_write(npz, lambda f: np.savez_compressed(f, **arrays))
        atomic_write_text(js, text)
        self.written = {"npz": str(npz), "json": str(js)}
        print(f"floaff-zoo predict: {len(meta)} samples -> {npz} (+ {js.name})", flush=True)
        if replaced:
            print(f"floaff-zoo predict: replaced the earlier predictions in {run_dir}", flush=True)
