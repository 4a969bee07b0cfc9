"""TestReport: write ``report.json``, ``report.md`` and qualitative figures at the end of ``test``.

The run directory is ``out_dir`` when given, else ``trainer.log_dir`` (the logger's version dir,
where LightningCLI saves ``config.yaml``), else ``trainer.default_root_dir``.

``report.json`` (schema ``floaff-zoo/report`` version 1) holds: every ``test_*`` metric (with ``map_elements``:
how many maps, or 64-sample chunks under ``official_batchwise``, they averaged, how many were empty and how many
PCC left out as constant), the SR
table from a ``RolloutSuccessRate`` callback in the same trainer (or ``available: false`` with the
reason: "SR n/a"), the resolved CLI config (``<log_dir>/config.yaml``), the model class and its
hparams, the seed, the checkpoint path and sha256, dataset/benchmark/tasks/views, sim_variant and
metric_reduction, package versions, an optional ``label`` (row name for ablation tables) and the
figure paths. ``test_pcc`` is null ("n/a") when no map has a Pearson r (all constant or empty): the metric's 0.0
there is no value. ``floaff-zoo table`` reads only these files.

Each file is written whole (a temp file renamed over it), every text rendered before the first is written, and the
folder is locked (``.report.lock``) while one test writes its figures and report: a table or montage reading meanwhile
never meets half a file, and two tests into one folder leave one test's files, not a mix.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import warnings
from functools import partial
from importlib import metadata
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.atomic import atomic_write_text, existing_ancestor, folder_lock
from floaff_zoo.data.base import FloAffDataModule
from floaff_zoo.report.figures import FigureSample, write_figures

SCHEMA = "floaff-zoo/report"
SCHEMA_VERSION = 1
#: held in the run directory while a test writes its figures and report files there
REPORT_LOCK = ".report.lock"
PACKAGES = ("floaff-zoo", "torch", "lightning", "torchmetrics", "numpy", "scipy", "mujoco", "robosuite", "jsonargparse")
#: metric display names and decimals (paper: RMSE/PCC/SIM 3, logMSE 4, SR 2)
MAP_METRICS = (
    ("rmse", "RMSE", 3),
    ("logmse", "logMSE", 4),
    ("pcc", "PCC", 3),
    ("sim", "SIM", 3),
    ("mae", "MAE", 3),
    ("ciou", "cIoU", 3),
)


#: what rolled out a view's pose, by RolloutSuccessRate's ``pose_source`` (reports before it existed: the map)
_POSE_FROM = {"map": "the map's best cell", "model": "the model's placement procedure"}


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def package_versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def checkpoint_record(trainer: L.Trainer, pl_module: L.LightningModule) -> dict[str, Any] | None:
    """{path, sha256} of what a test evaluates: the ``ckpt_path`` file, else the model's ``weights`` (their sha256
    as the model loaded them, which also covers a hub name or an exported folder); None for neither."""
    ckpt = trainer.ckpt_path
    if ckpt and Path(ckpt).is_file():
        return {"path": str(Path(ckpt).resolve()), "sha256": sha256_file(ckpt)}
    hp = dict(pl_module.hparams) if hasattr(pl_module, "hparams") else {}
    if not hp.get("weights"):
        return None
    w = str(hp["weights"])
    digest = getattr(pl_module, "weights_sha256", None) or (sha256_file(w) if Path(w).is_file() else None)
    return {"path": w, "sha256": digest}


def jsonable(x: Any) -> Any:
    """Convert tensors/numpy/paths inside ``x`` to JSON types (NaN/Inf -> None)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if torch.is_tensor(x):
        x = x.detach().cpu()
        return jsonable(x.item() if x.numel() == 1 else x.tolist())
    if isinstance(x, np.generic):
        return jsonable(x.item())
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, (str, int, bool)) or x is None:
        return x
    return str(x)


def read_config(run_dir: Path) -> dict[str, Any] | None:
    """The resolved CLI config LightningCLI saved in the run directory (None when absent/unreadable)."""
    path = run_dir / "config.yaml"
    if not path.is_file():
        return None
    import yaml

    try:
        cfg = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        warnings.warn(f"TestReport: {path} is not valid YAML ({exc}); config left out of the report", stacklevel=2)
        return None
    return jsonable(cfg) if isinstance(cfg, dict) else None


class TestReport(L.Callback):
    """Write the test report of a run (see module docstring).

    Args:
        out_dir: where to write; default the run's log dir (``trainer.log_dir``) or ``default_root_dir``.
        label: row name in ``floaff-zoo table`` (e.g. ``w/o SDL``); default the logger's name or the
            model class name.
        figures: write qualitative PNG figures.
        figures_per_group: samples drawn per (task, view).
        write_episodes: also write ``sr_episodes.json`` (one record per rolled-out sample).
    """

    __test__ = False  # not a pytest test class despite its name

    def __init__(
        self,
        out_dir: str | None = None,
        label: str | None = None,
        figures: bool = True,
        figures_per_group: int = 2,
        write_episodes: bool = True,
    ) -> None:
        super().__init__()
        if figures_per_group < 0:
            raise ValueError(f"TestReport: figures_per_group must be >= 0, got {figures_per_group}")
        self.out_dir = out_dir
        self.label = label
        self.figures = figures
        self.figures_per_group = figures_per_group
        self.write_episodes = write_episodes
        #: the figures' samples, chosen when the test ends (every rank's candidates pooled)
        self._samples: list[FigureSample] = []
        #: (task, view) -> [(split position, sample)]: this rank's first ``figures_per_group`` in split order
        self._candidates: dict[tuple[str, str], list[tuple[tuple, FigureSample]]] = {}
        self._seen: dict[str, set[str]] = {}
        self._keys: set[tuple[int, int]] = set()  # (dataloader, meta['index']) of every sample seen
        self._unkeyed = 0  # samples seen without meta['index']
        self._replaced: set[str] = set()  # samples that failed at load time and were replaced (meta['replaces'])
        #: paths written by the last test run
        self.written: dict[str, Any] = {}
        #: what was tested, taken when the test starts (``checkpoint_record``): the file may change or go by the end
        self._checkpoint: dict[str, Any] | None = None
        self._weights_known = False  # _checkpoint was taken for this run
        #: the run's saved config, read when the test starts (a later run in the folder may rewrite config.yaml)
        self._config: dict[str, Any] | None = None
        self._config_known = False

    # ------------------------------------------------------------------------------ collection
    def on_test_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Take the tested checkpoint's path and sha256 and the run's config.yaml now, right after Lightning loaded
        the checkpoint and LightningCLI saved the config: a fit still running rewrites ``last.ckpt`` and deletes an
        older best, and a later run in the folder rewrites config.yaml, so what the test's end finds can be another
        run's. (``trainer.log_dir`` is a broadcast under DDP: every rank calls it here.)"""
        self._checkpoint, self._weights_known = checkpoint_record(trainer, pl_module), True
        log_dir = trainer.log_dir
        self._check_report_dir(Path(self.out_dir or log_dir or trainer.default_root_dir), _rollout(trainer) is not None)
        self._config = read_config(Path(log_dir)) if log_dir else None
        if self._config is None and self.out_dir:
            self._config = read_config(Path(self.out_dir))
        self._config_known = True

    def _check_report_dir(self, run_dir: Path, rollout: bool) -> None:
        """Refuse, before the test and its rollouts run (minutes), a folder whose report files could not be written:
        something other than a folder on its path, a folder in place of one of the files it writes (the episodes'
        only when a ``rollout`` callback gives them), or a file in place of its ``figures`` folder failed at the
        end, and the test's results were lost."""
        if not (found := existing_ancestor(run_dir)).is_dir():
            raise MisconfigurationException(
                f"TestReport: cannot write the report into {run_dir}: {found} is not a folder"
            )
        names = ("report.json", "report.md") + (("sr_episodes.json",) if rollout and self.write_episodes else ())
        for name in names:
            if (run_dir / name).is_dir():
                raise MisconfigurationException(f"TestReport: {run_dir / name} is a folder; the report writes a file")
        figures = run_dir / "figures"
        if self.figures and (figures.exists() or figures.is_symlink()) and not figures.is_dir():
            raise MisconfigurationException(f"TestReport: {figures} is not a folder; the figures go into one there")

    def on_test_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._samples, self._candidates = [], {}
        self._seen = {"dataset": set(), "task": set(), "view": set()}
        self._keys, self._unkeyed, self._replaced = set(), 0, set()

    def on_test_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0) -> None:
        metas = batch["meta"]
        for m in metas:
            if m.get("index") is None:
                self._unkeyed += 1
            else:
                self._keys.add((dataloader_idx, int(m["index"])))
            if m.get("replaces"):
                self._replaced.add(str(m["replaces"]))
            for key in self._seen:
                if m.get(key):
                    self._seen[key].add(str(m[key]))
        if not self.figures or self.figures_per_group == 0:
            return
        scores = outputs.get("scores") if isinstance(outputs, dict) else None
        if scores is None:
            return  # not a floor-map model (AxisNet's test_step gives a yaw): nothing to draw
        for i, m in enumerate(metas):
            group = (str(m.get("task", "")), str(m.get("view", "")))
            order = split_position(m, dataloader_idx, (trainer.global_rank, batch_idx, i))
            kept = self._candidates.setdefault(group, [])
            if len(kept) >= self.figures_per_group and order >= kept[-1][0]:
                continue
            valid = batch["floor_mask"][i].detach().cpu().numpy().astype(bool)
            sample = FigureSample(
                floor_xyz=batch["floor_xyz"][i].detach().cpu().numpy()[valid],
                label=batch["floor_label"][i].detach().cpu().numpy()[valid],
                scores=scores[i].detach().float().cpu().numpy()[valid],
                target_xyz=batch["target_xyz"][i].detach().cpu().numpy(),
                target_yaw=float(batch["target_yaw"][i]),
                meta=dict(m),
            )
            kept[:] = first_in_split_order([*kept, (order, sample)], self.figures_per_group)

    # ------------------------------------------------------------------------------ writing
    def _pool_ranks(self, trainer: L.Trainer) -> None:
        """Under DDP, pool what every rank saw (a collective: every rank calls it): the datasets, tasks and views,
        the sample count without the repeats ``DistributedSampler`` pads the last batches with (samples with
        one ``meta['index']`` count once, as in the metrics) and the figure candidates, so that the figures are those
        one process would draw (each rank sees every world_size-th sample)."""
        dist = torch.distributed
        if trainer.world_size <= 1 or not dist.is_available() or not dist.is_initialized():
            return
        parts: list[Any] = [None] * trainer.world_size
        dist.all_gather_object(parts, (self._seen, self._keys, self._unkeyed, self._replaced, self._candidates))
        self._seen = {k: set().union(*(seen[k] for seen, *_ in parts)) for k in self._seen}
        self._keys = set().union(*(keys for _, keys, *_ in parts))
        self._unkeyed = sum(n for _, _, n, *_ in parts)
        self._replaced = set().union(*(r for *_, r, _ in parts))
        groups = {g for *_, cands in parts for g in cands}
        self._candidates = {
            g: first_in_split_order([c for *_, cands in parts for c in cands.get(g, [])], self.figures_per_group)
            for g in groups
        }

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Write the report on rank 0; every rank first takes part in the collectives (``trainer.log_dir`` is a
        broadcast under DDP, ``_pool_ranks`` a gather), or DDP would hang or crash."""
        log_dir = trainer.log_dir
        run_dir = Path(self.out_dir or log_dir or trainer.default_root_dir)  # where the report goes
        self._pool_ranks(trainer)
        if not trainer.is_global_zero:
            return
        self._samples = [s for _, s in sorted((c for cands in self._candidates.values() for c in cands), key=_first)]
        run_dir.mkdir(parents=True, exist_ok=True)
        rollout = _rollout(trainer)
        report = self.build_report(trainer, pl_module, run_dir, rollout, log_dir)
        episodes = rollout.episodes.get("test", []) if rollout is not None else []
        # a report that cannot be rendered fails here, before the earlier report's figures are replaced
        render_markdown(jsonable(report))
        waiting = partial(
            print, f"floaff-zoo test: another test is writing its report into {run_dir}; waiting", flush=True
        )
        # another test into this folder writes before or after, not between
        with folder_lock(run_dir / REPORT_LOCK, on_wait=waiting):
            earlier = remove_earlier_figures(run_dir)
            if self.figures and self._samples:
                by_id = {e["sample_id"]: e for e in episodes}
                for s in self._samples:
                    ep = by_id.get(str(s.meta.get("sample_id", "")))
                    if ep is not None:  # draw the pose that was actually rolled out (top-k may differ from argmax)
                        s.chosen, s.success = tuple(ep["pose"]), ep.get("success")
                        s.oracle = tuple(ep["oracle_pose"]) if "oracle_pose" in ep else None
                        s.oracle_success = ep.get("oracle_success")
                paths = write_figures(self._samples, run_dir / "figures")
                report["figures"] = [p.relative_to(run_dir).as_posix() for p in paths]
            report = jsonable(report)
            write_report_files(run_dir, report, episodes if self.write_episodes else [])
        if earlier is not None:
            print(
                f"floaff-zoo test: replaced the earlier report in {run_dir} ({earlier} figure(s) removed)", flush=True
            )
        self.written = {
            "run_dir": str(run_dir),
            "report_json": str(run_dir / "report.json"),
            "report_md": str(run_dir / "report.md"),
            "figures": report.get("figures", []),
        }

    def teardown(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if stage == "test":  # the next run takes its own
            self._checkpoint, self._weights_known = None, False
            self._config, self._config_known = None, False

    def build_report(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        run_dir: Path,
        rollout: Any | None,
        log_dir: str | None = None,
    ) -> dict[str, Any]:
        """The report dict of a finished test (see the module docstring); ``log_dir`` is ``trainer.log_dir`` (where
        LightningCLI saved ``config.yaml``), resolved by the caller on every rank."""
        hp = dict(pl_module.hparams) if hasattr(pl_module, "hparams") else {}
        metrics = {k: v for k, v in sorted(trainer.callback_metrics.items()) if k.startswith("test_")}
        test_metrics = getattr(pl_module, "test_metrics", None)
        configured = sorted(test_metrics.keys()) if test_metrics is not None else []
        missing = [k for k in configured if k not in metrics]
        if missing:
            warnings.warn(f"TestReport: configured metric(s) {missing} were not logged", stacklevel=2)
        if self._config_known:
            config = self._config
        else:  # called outside a test run (tests build reports directly)
            config = read_config(Path(log_dir)) if log_dir else None
            if config is None and self.out_dir:
                config = read_config(run_dir)
        seed = (config or {}).get("seed_everything")
        if seed is None and os.environ.get("PL_GLOBAL_SEED") is not None:
            seed = int(os.environ["PL_GLOBAL_SEED"])
        checkpoint = self._checkpoint if self._weights_known else checkpoint_record(trainer, pl_module)
        dm = trainer.datamodule
        datasets = sorted(self._seen.get("dataset", ()))
        benchmark = getattr(dm, "benchmark", None) or (datasets[0] if len(datasets) == 1 else "+".join(datasets))
        logger_name = getattr(trainer.logger, "name", None) if trainer.logger is not None else None
        sr = (rollout.summaries.get("test") if rollout is not None else None) or {
            "available": False,
            "reason": "no RolloutSuccessRate callback in this run"
            if rollout is None
            else "RolloutSuccessRate did not run on test",
        }
        elements = map_elements(pl_module)
        if "test_pcc" in metrics and elements is not None and pcc_defined(elements) == 0:
            metrics["test_pcc"] = None  # the metric's 0.0 where no map has a Pearson r is no value to rank
        return {
            "schema": SCHEMA,
            "version": SCHEMA_VERSION,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "run_dir": str(run_dir.resolve()),
            "label": self.label or logger_name or type(pl_module).__name__,
            "model": {
                "class_path": f"{type(pl_module).__module__}.{type(pl_module).__qualname__}",
                "name": type(pl_module).__name__,
                "hparams": hp,
            },
            "seed": seed,
            "checkpoint": checkpoint,
            "data": {
                "datamodule": f"{type(dm).__module__}.{type(dm).__qualname__}" if dm is not None else None,
                "dataset": datasets[0] if len(datasets) == 1 else datasets,
                "benchmark": benchmark,
                "tasks": sorted(self._seen.get("task", ())),
                "views": sorted(self._seen.get("view", ())),
                # distinct samples (one index counts once: DDP's padding repeats, a replacement of a broken file)
                "num_samples": len(self._keys) + self._unkeyed,
                "samples_replaced": sorted(self._replaced),
                # records setup skipped (a corrupt or missing file): not in num_samples, named here, not on a console
                "skipped_at_setup": _skipped_at_setup(dm),
                # scene id -> labels hash: copies generated on different CPUs differ (floaff-zoo table checks it)
                "labels_sha256": getattr(dm, "labels_digests", None) or None,
            },
            "sim_variant": (hp.get("train") or {}).get("sim_variant"),
            "metric_reduction": (hp.get("train") or {}).get("metric_reduction"),
            "configured_metrics": configured,
            "metrics": metrics,
            "map_elements": elements,
            "sr": sr,
            "config": config,
            "versions": package_versions(),
            "figures": [],
        }


def _rollout(trainer: L.Trainer) -> L.Callback | None:
    """The trainer's ``RolloutSuccessRate`` (by name: this module does not import the rollout callback), or None."""
    return next((c for c in trainer.callbacks if type(c).__name__ == "RolloutSuccessRate"), None)


def write_report_files(run_dir: Path, report: dict[str, Any], episodes: list[dict[str, Any]]) -> None:
    """Write ``sr_episodes.json`` (or remove an earlier run's: it would sit beside this report), ``report.md`` and
    ``report.json`` into ``run_dir``, each whole: every text is rendered before the first file is written (a failure
    leaves the earlier report) and each lands by a rename (a reader holding the earlier file keeps reading it whole).
    ``report.json``, the file ``floaff-zoo table`` reads, comes last."""
    texts = {"report.md": render_markdown(report), "report.json": json.dumps(report, indent=2, sort_keys=False)}
    if episodes:
        texts = {"sr_episodes.json": json.dumps(jsonable(episodes), indent=1), **texts}
    elif (run_dir / "sr_episodes.json").is_file():
        (run_dir / "sr_episodes.json").unlink()
    for name, text in texts.items():
        atomic_write_text(run_dir / name, text)


def remove_earlier_figures(run_dir: Path) -> int | None:
    """Remove the figures an earlier report in ``run_dir`` listed: a new test draws other (task, view) groups or
    fewer per group, and their old PNGs would sit beside the new report. Only files of ``run_dir/figures`` go.

    Returns:
        None without an earlier ``report.json``, else how many figures were removed.
    """
    path = run_dir / "report.json"
    if not path.is_file():
        return None
    try:
        listed = json.loads(path.read_text(encoding="utf-8")).get("figures")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):  # unreadable or not an object: nothing listed
        return 0
    folder, removed = (run_dir / "figures").resolve(), 0
    for name in listed if isinstance(listed, list) else []:
        figure = (run_dir / str(name)).resolve()
        if figure.parent == folder and figure.suffix == ".png" and figure.is_file():
            figure.unlink()
            removed += 1
    return removed


def split_position(meta: dict[str, Any], dataloader_idx: int, seen: tuple[int, int, int]) -> tuple:
    """Where a sample stands in the test split: (dataloader, ``meta['index']``); a sample without an index comes
    after the indexed ones, where it was ``seen`` (rank, batch, row)."""
    if meta.get("index") is not None:
        return (dataloader_idx, int(meta["index"]))
    return (dataloader_idx, 1 << 62, *seen)


def _first(candidate: tuple[tuple, FigureSample]) -> tuple:
    return candidate[0]


def first_in_split_order(candidates: list[tuple[tuple, FigureSample]], k: int) -> list[tuple[tuple, FigureSample]]:
    """The first ``k`` (split position, sample) pairs of one (task, view) in split order, a position once (the
    repeats ``DistributedSampler`` pads with): the k-th figure of a group shows the same sample in every run."""
    out: dict[tuple, tuple[tuple, FigureSample]] = {}
    for c in sorted(candidates, key=_first):
        out.setdefault(c[0], c)
    return list(out.values())[:k]


# ------------------------------------------------------------------------------------------ markdown
def _fmt(v: Any, decimals: int) -> str:
    return "n/a" if v is None else f"{float(v):.{decimals}f}"


def _sr_cell(cell: dict | None) -> str:
    return "n/a" if not cell else f"{cell['mean']:.2f} ± {cell['std']:.2f} (n={cell['n']})"


def map_elements(pl_module: L.LightningModule) -> dict[str, int] | None:
    """How many elements the test's map metrics averaged, read from the metrics' last compute: ``maps`` (one per
    sample), or under ``official_batchwise`` ``chunks`` of ``chunk_size`` consecutive samples (the official eval
    batches: one element each, not one per map); ``empty`` (no valid floor point) and ``pcc_undefined`` (a constant
    map or label, left out of PCC's mean) count elements of the same kind. None for a module without them."""
    metrics = getattr(pl_module, "test_metrics", None)
    pcc = metrics["pcc"] if metrics is not None and "pcc" in metrics.keys(keep_base=True) else None
    if pcc is None or not hasattr(pcc, "num_undefined"):
        return None
    total = int(pcc.num_elements) + int(pcc.num_empty)  # num_elements: the elements with a valid floor point
    counts = {"empty": int(pcc.num_empty), "pcc_undefined": int(pcc.num_undefined)}
    if getattr(pcc, "reduction", "per_sample") == "per_sample":
        return {"maps": total, **counts}
    return {"chunks": total, "chunk_size": int(pcc.chunk_size), **counts}


def _elements_counted(counts: dict[str, int]) -> tuple[int, str]:
    """(how many, what) of a report's ``map_elements``: maps, or chunks of N samples (``official_batchwise``)."""
    if "chunks" in counts:
        return counts["chunks"], f"chunks of {counts.get('chunk_size')} samples"
    return counts["maps"], "maps"


def pcc_defined(counts: dict[str, int]) -> int:
    """How many elements of a report's ``map_elements`` PCC averaged (not empty, not constant)."""
    return _elements_counted(counts)[0] - counts["empty"] - counts["pcc_undefined"]


def _skipped_at_setup(dm: Any) -> dict[str, Any] | None:
    """The data module's record of what its setup skipped for the test split (``skip_log``; None without one)."""
    log = dm.skip_log("test") if isinstance(dm, FloAffDataModule) else None  # a plain LightningDataModule has none
    return log.record() if log is not None else None


def render_markdown(report: dict[str, Any]) -> str:
    """Readable summary of a report dict: run facts, map metrics, SR table, figures."""
    m = report.get("metrics", {})
    ck = report.get("checkpoint") or {}
    data = report.get("data", {})
    lines = [
        f"# Test report: {report.get('label')}",
        "",
        f"- model: `{report['model']['class_path']}`",
        f"- checkpoint: `{ck.get('path', 'none')}` (sha256 `{(ck.get('sha256') or 'n/a')[:16]}…`)",
        f"- seed: {report.get('seed')}",
        f"- data: {data.get('dataset')} | benchmark {data.get('benchmark')} | "
        f"tasks {', '.join(data.get('tasks', [])) or '-'}"
        f" | views {', '.join(data.get('views', [])) or '-'} | {data.get('num_samples')} samples",
        f"- sim_variant: {report.get('sim_variant')}, metric_reduction: {report.get('metric_reduction')}",
    ]
    replaced = data.get("samples_replaced") or []
    if replaced:  # files that broke after setup: the next sample stood in, so these were not evaluated
        lines.append(
            f"- **{len(replaced)} sample(s) failed at load time** and were not evaluated: {', '.join(replaced[:5])}"
        )
    skipped = data.get("skipped_at_setup") or {}
    if skipped.get("total"):  # never evaluated: a report over fewer samples than its split file or scenes list
        kinds = "; ".join(f"{k} {n}" for k, n in skipped.get("counts", {}).items())
        first = next((e[0] for e in skipped.get("examples", {}).values() if e), "")
        lines.append(
            f"- **{skipped['total']} record(s) skipped at setup** ({skipped.get('log')}): {kinds}"
            + (f"; e.g. {first}" if first else "")
        )
    lines += [
        "",
        "## Floor-affordance map metrics",
        "",
    ]
    shown = [(k, name, d) for k, name, d in MAP_METRICS if f"test_{k}" in m]
    lines += ["| " + " | ".join(n for _, n, _ in shown) + " |", "|" + "---|" * len(shown)]
    lines.append("| " + " | ".join(_fmt(m.get(f"test_{k}"), d) for k, _, d in shown) + " |")
    counts = report.get("map_elements") or {}
    if counts.get("pcc_undefined") or counts.get("empty"):  # PCC is a mean over fewer elements than the others
        total, unit = _elements_counted(counts)
        lines += [
            "",
            f"PCC over {pcc_defined(counts)} of {total} {unit}: "
            f"{counts['pcc_undefined']} constant (Pearson r undefined), {counts['empty']} without a floor point.",
        ]
    others = {k: v for k, v in m.items() if not any(k == f"test_{x}" for x, _, _ in shown) and "_sr_" not in k}
    if others:
        lines += ["", "Other logged values: " + ", ".join(f"`{k}` = {_fmt(v, 4)}" for k, v in others.items())]
    lines += ["", "## Success rate (rollouts in the simulator)", ""]
    sr = report.get("sr") or {}
    if not sr.get("available"):
        lines.append(f"SR: n/a ({sr.get('reason', 'not evaluated')})")
    else:
        model, oracle = sr.get("model") or {}, sr.get("oracle") or {}
        lines += ["| | SR_front | SR_side | SR_all |", "|---|---|---|---|"]
        for name, t in (("model", model), ("Oracle", oracle)):
            if t:
                lines.append(
                    f"| {name} | {_sr_cell(t.get('front'))} | {_sr_cell(t.get('side'))} | {_sr_cell(t.get('all'))} |"
                )
        tasks = sorted(set(model.get("tasks", {})) | set(oracle.get("tasks", {})))
        if tasks:
            lines += ["", "| | " + " | ".join(tasks) + " |", "|---|" + "---|" * len(tasks)]
            for name, t in (("model", model), ("Oracle", oracle)):
                if t:
                    lines.append(f"| {name} | " + " | ".join(_sr_cell(t.get("tasks", {}).get(x)) for x in tasks) + " |")
        lines += [
            "",
            f"± = {sr.get('std_method')}; {sr.get('n_evaluated')} evaluated, {sr.get('n_skipped')} skipped"
            f" (no sim metadata); pose from {_POSE_FROM.get(sr.get('pose_source'), _POSE_FROM['map'])};"
            f" top_k = {sr.get('top_k')} (free space: {sr.get('free_space', 'sim')});"
            f" rollouts took {sr.get('seconds', 0):.1f} s.",
        ]
    if report.get("figures"):
        lines += ["", "## Figures (ground truth | prediction; x = chosen base pose)", ""]
        lines += [f"![{Path(f).stem}]({f})" for f in report["figures"]]
    return "\n".join(lines) + "\n"
