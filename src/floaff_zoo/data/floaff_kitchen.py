"""FloAff-Kitchen (Styles / Layouts): scene-level splits over a FloAff reader (generated data by default).

Splits follow the paper: per task, the benchmark's *train* scenes (5 in the paper) and one unseen
*test* scene. Validation is carved from the train scenes at scene level: ``val_scenes`` scenes
per task (seeded by ``seed``); a task with a single train scene instead gives a seeded
``val_view_fraction`` of that scene's views to val (views of one scene share its label map, so
this val split measures fit, not generalisation: documented, unavoidable with one scene).

Every sample's ``meta`` carries ``dataset, task, view, scene_id, layout_id, style_id, sample_id,
index`` and ``sim = {layout_id, style_id, seed, task, base_pose_world: [x, y, yaw], scene_dir,
root}`` so a rollout callback can rebuild the scene and map base-frame poses to the world.

Readers: ``reader`` is a name registered with :func:`floaff_zoo.data.readers.register_reader`
(built in: ``generated``, the format of ``floaff-zoo generate``) or an import path
``pkg.module:Class`` of a :class:`~floaff_zoo.data.readers.FloAffReader` subclass, e.g. one for the
published FloAff-Kitchen release once its format is known.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any, Literal

import numpy as np
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.contract import FULL_CLOUD_KEY, TASKS, VIEWS, Sample, SampleError
from floaff_zoo.data.base import (
    DataConfigError,
    FloAffDataModule,
    check_choice,
    check_flag,
    check_fraction,
    check_size,
    check_transforms,
)
from floaff_zoo.data.cache import RecordDataset, SampleCache, code_digest
from floaff_zoo.data.readers import (
    FloAffReader,
    SampleRecord,
    SceneEntry,
    SkipLog,
    ViewEntry,
    check_names,
    get_reader,
)
from floaff_zoo.data.scene_labels import SceneLabels
from floaff_zoo.data.transforms import SampleTransform, transforms_config
from floaff_zoo.names import BENCHMARKS as BENCHMARKS  # defined once there; re-exported


def view_sample_id(benchmark: str, scene_id: str, view_id: str) -> str:
    """A view's sample id (and record key): ``<benchmark>/<scene_id>/<view_id>``."""
    return f"{benchmark}/{scene_id}/{view_id}"


class _ViewLoader:
    """Picklable record -> sample function (worker processes rebuild the reader from its class and root).

    ``full_cloud``: keep every valid stored point as ``full_xyz`` before any pre-transform crops or resamples it.
    """

    def __init__(self, reader: FloAffReader, full_cloud: bool = False) -> None:
        self.reader = reader
        self.full_cloud = full_cloud

    def __call__(self, rec: SampleRecord) -> Sample:
        scene = SceneEntry(**{k: v for k, v in rec.payload["scene"].items() if k != "views"}, views=[])
        s = self.reader.load_view(scene, ViewEntry(**rec.payload["view"]))
        s["meta"] = {}
        if self.full_cloud:
            xyz = np.asarray(s["scene_xyz"], dtype=np.float32)
            mask = s.get("scene_mask")
            s[FULL_CLOUD_KEY] = xyz if mask is None else xyz[np.asarray(mask, dtype=bool).reshape(-1)]
        return s


class FloAffKitchenDataModule(FloAffDataModule):
    """FloAff-Kitchen benchmark data (module docstring).

    Args:
        root: dataset root (``floaff-zoo generate --out``).
        benchmark: ``styles`` | ``layouts``.
        tasks: any subset of PnPCounterToCab, OpenSingleDoor, CloseDrawer, CloseDoubleDoor (None = all;
            one task = single-task run).
        views: any subset of front, side (None = both).
        reader: registered reader name or ``pkg.module:Class``.
        val_scenes: train scenes per task held out as val (seeded; at least one scene stays in train). 0 (with
            neither ``val_scene_ids`` nor ``val_layout``): no validation, every train scene and view trains, ``fit``
            runs without a validation loop and its checkpoint is the last one (refitting on the whole training
            pool once the choices are made on the ``val_layout`` folds).
        val_scene_ids: hold out exactly these train scenes as val instead (the seeded draw is skipped;
            e.g. to keep one validation set while training scenes are added); unknown ids raise.
        val_layout: hold out every train scene of this layout id (all tasks) as val instead: leave-one-layout-out
            validation, the fold of a cross-validation over the training layouts (the seeded draw is skipped; not
            together with ``val_scene_ids``; a layout without train scenes raises).
        val_view_fraction: share of the views of a single-train-scene task that go to val.
        train_labels: a scene-label file (:mod:`floaff_zoo.data.scene_labels`, e.g. fresh-episode success rates
            from ``scripts/fresh_labels.py``) whose labels replace the generated ones in the train split only;
            every train scene must be in it (checked when the train loader is first made, before training).
            Validation and test keep the generated labels.
        max_views_per_scene: keep the first N views (per kept view kind order) of each scene (smoke runs).
        strict: raise on the first missing/corrupt file instead of skipping and counting.
        validate: load every sample at setup (fills the cache; bad ones are skipped and counted).
        cache / cache_dir / cache_hash / pre_transforms: see :class:`~floaff_zoo.data.cache.SampleCache`.
        full_cloud: also give every val, test and predict sample ``full_xyz``, every point its view file stores
            (before ``pre_transforms``, ``eval_transforms`` and the loader's resampling), and their batches
            ``full_xyz`` / ``full_mask``: what the rollout callback's ``free_space: full_cloud`` checks a base
            footprint against (``configs/trainer/eval_sr_top10_full.yaml`` sets both). Models do not read it; the
            train split never carries it and shares the cache of ``full_cloud: false``.
        (the rest: see :class:`FloAffDataModule`)
    """

    def __init__(
        self,
        root: str = "data/floaff_sim",
        benchmark: Literal["styles", "layouts"] = "styles",
        tasks: list[str] | None = None,
        views: list[str] | None = None,
        reader: str = "generated",
        val_scenes: int = 1,
        val_scene_ids: list[str] | None = None,
        val_layout: int | None = None,
        val_view_fraction: float = 0.2,
        train_labels: str | None = None,
        max_views_per_scene: int | None = None,
        strict: bool = False,
        validate: bool = True,
        cache: bool = True,
        cache_dir: str | None = None,
        cache_hash: Literal["stat", "content"] = "stat",
        pre_transforms: list[SampleTransform] | None = None,
        full_cloud: bool = False,
        batch_size: int = 8,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        num_points: int | None = 4096,
        num_floor: int | None = None,
        collate_mode: Literal["pad", "resample"] = "resample",
        seed: int = 0,
        train_transforms: list[SampleTransform] | None = None,
        eval_transforms: list[SampleTransform] | None = None,
        persistent_train_workers: bool = False,
    ) -> None:
        super().__init__(
            batch_size,
            eval_batch_size,
            num_workers,
            num_points,
            num_floor,
            collate_mode,
            seed,
            train_transforms,
            eval_transforms,
            persistent_train_workers,
        )
        self.benchmark = check_names("benchmark", [benchmark], BENCHMARKS)[0]
        self.tasks = check_names("tasks", list(TASKS) if tasks is None else tasks, TASKS)
        self.views = check_names("views", list(VIEWS) if views is None else views, VIEWS)
        self.reader_cls = get_reader(reader)
        check_size("val_scenes", val_scenes, 0)  # 1.5 reached the scene split as a slice index (a TypeError)
        check_size("max_views_per_scene", max_views_per_scene, 1, "every view")  # 0 or less emptied every split
        check_fraction("val_view_fraction", val_view_fraction)  # False was 0, a text a bare TypeError
        for name, flag in (("strict", strict), ("validate", validate), ("cache", cache), ("full_cloud", full_cloud)):
            check_flag(name, flag)  # "false" from a hand-written config is a true text
        check_choice("cache_hash", cache_hash, ("stat", "content"))
        self.root = Path(root)
        self.val_scenes = val_scenes
        if val_scene_ids is not None and (isinstance(val_scene_ids, str) or len(val_scene_ids) == 0):
            # [] held out nothing, yet a fit asked for a validation split: "the 'val' split is empty" at setup; a text
            # was taken letter by letter
            raise DataConfigError(
                f"FloAffKitchenDataModule: data.val_scene_ids must be a non-empty list of train scene ids (null: the "
                f"seeded draw of val_scenes), got {val_scene_ids!r}"
            )
        self.val_scene_ids = None if val_scene_ids is None else list(val_scene_ids)
        if val_layout is not None and val_scene_ids is not None:
            raise DataConfigError("FloAffKitchenDataModule: give data.val_scene_ids or data.val_layout, not both")
        # True or 1.5 matched no layout id and was refused only at setup, after the other checks had passed
        check_size("val_layout", val_layout, 0, "no layout held out")
        self.val_layout = None if val_layout is None else int(val_layout)
        # val_scenes 0 alone means no validation at all (module docstring)
        self.validates = not (val_scenes == 0 and val_scene_ids is None and val_layout is None)
        self.val_view_fraction = val_view_fraction
        self.train_labels = None if train_labels is None else SceneLabels(train_labels)
        self._train_labels_checked = False
        self.max_views_per_scene = max_views_per_scene
        self.strict = strict
        self.validate = validate
        self.use_cache = cache
        self.cache_dir = Path(cache_dir) if cache_dir else self.root / ".cache"
        self.cache_hash = cache_hash
        self.pre_transforms = check_transforms("pre_transforms", pre_transforms)
        self.full_cloud = full_cloud
        self.skips: SkipLog | None = None
        self.split_scenes: dict[str, list[str]] = {}
        #: the tasks the data has scenes of, and the splits a missing task was warned about (``_warn_missing_tasks``)
        self._scene_tasks: set[str] = set()
        self._warned_splits: set[str] = set()
        #: scene id -> short hash of its labels, for every scene of this run's tasks (after setup; reports record it)
        self.labels_digests: dict[str, str] = {}

    # ------------------------------------------------------------------ indexing
    def _records(self, scene: SceneEntry, views: list[ViewEntry]) -> list[SampleRecord]:
        out = []
        for v in views:
            sim = {
                "layout_id": scene.layout_id,
                "style_id": scene.style_id,
                "seed": scene.seed,
                "task": scene.task,
                "base_pose_world": list(v.base_pose_world),
                "scene_dir": scene.dir,
                "root": str(self.root),
                "benchmark": scene.benchmark,
            }
            if scene.target_world is not None:  # the rollout faces it as the annotation did (frames.facing_pose)
                sim["target_world"] = list(scene.target_world)
            sample_id = view_sample_id(scene.benchmark, scene.scene_id, v.view_id)
            meta = {
                "dataset": f"floaff_kitchen_{scene.benchmark}",
                "task": scene.task,
                "view": v.view,
                "scene_id": scene.scene_id,
                "layout_id": scene.layout_id,
                "style_id": scene.style_id,
                "sample_id": sample_id,
                "sim": sim,
            }
            payload = {"scene": {k: val for k, val in asdict(scene).items() if k != "views"}, "view": asdict(v)}
            out.append(SampleRecord(sample_id, [v.file, *scene.sources], meta, payload))
        return out

    def _views(self, scene: SceneEntry) -> list[ViewEntry]:
        vs = [v for v in scene.views if v.view in self.views]
        if self.max_views_per_scene is not None:
            per: dict[str, int] = {}
            keep = []
            for v in vs:
                per[v.view] = per.get(v.view, 0) + 1
                if per[v.view] <= self.max_views_per_scene:
                    keep.append(v)
            vs = keep
        return vs

    def split_records(self, scenes: list[SceneEntry]) -> dict[str, list[SampleRecord]]:
        """Scene-level train/val/test records (module docstring), ordered by task, scene, view.

        The seeded validation draw runs over every task of the benchmark in the canonical order (``TASKS``),
        whichever tasks this run loads and in whatever order: a task holds out the same scenes in a run of all
        four tasks and in a PFAL stage that loads only some, so no stage trains on another model's validation
        scenes. The view-level draw of a task with a single train scene has a stream of its own, so the views a run
        loads (``views``, ``max_views_per_scene``) never move another task's held-out scenes.
        """
        rng = np.random.default_rng(self.seed)
        fixed = self._fixed_val_ids(scenes)
        held: dict[str, tuple[set[str] | None, set[int]]] = {}
        for t, task in enumerate(TASKS):  # every task draws, loaded or not: the stream does not depend on self.tasks
            train = [s for s in scenes if s.task == task and s.split == "train"]
            val_ids, val_idx = fixed, set()
            n_val = min(self.val_scenes, len(train) - 1)
            if val_ids is None and len(train) >= 2 and n_val > 0:
                val_ids = set(rng.permutation([s.scene_id for s in train])[:n_val].tolist())
            elif val_ids is None and len(train) == 1 and self.validates:
                n = len(self._views(train[0]))
                k = int(round(self.val_view_fraction * n))
                k = min(max(k, 1 if self.val_view_fraction > 0 and n > 1 else 0), max(n - 1, 0))
                val_idx = set(np.random.default_rng([self.seed, t]).permutation(n)[:k].tolist())
            held[task] = (val_ids, val_idx)
        out: dict[str, list[SampleRecord]] = {"train": [], "val": [], "test": []}
        self.split_scenes = {"train": [], "val": [], "test": []}
        for task in self.tasks:
            mine = [s for s in scenes if s.task == task]
            train = [s for s in mine if s.split == "train"]
            for s in (s for s in mine if s.split == "test"):
                out["test"] += self._records(s, self._views(s))
                self.split_scenes["test"].append(s.scene_id)
            val_ids, val_idx = held[task]
            if val_ids is not None:
                for s in train:
                    split = "val" if s.scene_id in val_ids else "train"
                    out[split] += self._records(s, self._views(s))
                    self.split_scenes[split].append(s.scene_id)
                if train and all(s.scene_id in val_ids for s in train):
                    # the seeded draw keeps one scene per task in train; a pinned hold-out can take them all
                    by = "val_scene_ids" if self.val_layout is None else f"val_layout {self.val_layout}"
                    warnings.warn(
                        f"FloAffKitchenDataModule: every train scene of {task} is held out for validation ({by}): "
                        "a fit trains no sample of that task",
                        stacklevel=2,
                    )
            elif len(train) == 1:
                s = train[0]
                vs = self._views(s)
                out["val"] += self._records(s, [v for i, v in enumerate(vs) if i in val_idx])
                out["train"] += self._records(s, [v for i, v in enumerate(vs) if i not in val_idx])
                self.split_scenes["train"].append(s.scene_id)
                if val_idx:
                    self.split_scenes["val"].append(s.scene_id + " (views)")
            else:
                for s in train:
                    out["train"] += self._records(s, self._views(s))
                    self.split_scenes["train"].append(s.scene_id)
        return out

    def _fixed_val_ids(self, scenes: list[SceneEntry]) -> set[str] | None:
        """``val_scene_ids`` checked against the benchmark's train scenes, any task, or the train scenes of
        ``val_layout`` (None when neither is set)."""
        if self.val_layout is not None:
            layouts = {str(s.layout_id) for s in scenes if s.split == "train"}
            ids = {s.scene_id for s in scenes if s.split == "train" and str(s.layout_id) == str(self.val_layout)}
            if not ids:
                raise DataConfigError(
                    f"FloAffKitchenDataModule: data.val_layout {self.val_layout} has no train scene under "
                    f"{self.root}/{self.benchmark} (train layouts: {sorted(layouts)})"
                )
            return ids
        if self.val_scene_ids is None:
            return None
        known = {s.scene_id for s in scenes if s.split == "train"}
        unknown = sorted(set(self.val_scene_ids) - known)
        if unknown:
            raise DataConfigError(
                f"FloAffKitchenDataModule: data.val_scene_ids {unknown} are not train scenes "
                f"under {self.root}/{self.benchmark} (train scenes: {sorted(known)})"
            )
        return set(self.val_scene_ids)

    def _smallest_preset(self) -> str:
        """The first generator preset (tiny, demo, small, ...) with this benchmark and every task asked for."""
        from floaff_zoo.sim.presets import PRESETS

        fits = [n for n, p in PRESETS.items() if self.benchmark in p.benchmarks and set(self.tasks) <= set(p.tasks)]
        return fits[0] if fits else "small"

    # ------------------------------------------------------------------ setup
    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            self._warn_missing_tasks(stage)
            return
        if self.root.exists() and not self.root.is_dir():  # "does not exist, generate into it" misled
            raise MisconfigurationException(f"FloAffKitchenDataModule: root {self.root} is a file, not a data folder")
        if not self.root.is_dir():
            raise MisconfigurationException(
                f"FloAffKitchenDataModule: root {self.root} does not exist (generate data with "
                f"`floaff-zoo generate --preset {self._smallest_preset()} --out {self.root}` or set "
                "data.init_args.root)"
            )
        skips = SkipLog(f"floaff_kitchen {self.benchmark}", self.strict)
        reader = self.reader_cls(self.root, skips)
        scenes = reader.scenes(self.benchmark)
        if not scenes:
            raise MisconfigurationException(
                f"FloAffKitchenDataModule: no usable '{self.benchmark}' scene under {self.root} "
                f"(reader {self.reader_cls.name!r})\n{skips.summary()}"
            )
        records = self.split_records(scenes)
        self.labels_digests = {s.scene_id: s.labels_digest for s in scenes if s.task in self.tasks and s.labels_digest}
        for split, recs in records.items():
            # the stored cloud serves the rollout check of evaluated poses only: the train split never carries it, so
            # it shares the cache of full_cloud false and its batches stay small
            full = self.full_cloud and split != "train"
            cache = self._cache(reader, full) if self.use_cache else None
            loader = _ViewLoader(reader, full)
            ds = RecordDataset(
                recs, loader, cache, self.pre_transforms, self.seed, f"floaff_{self.benchmark}/{split}", self.strict
            )
            if self.validate:
                ds.build(skips, self.num_workers)
            self.datasets[split] = ds
        self.datasets["predict"] = self.datasets["test"]
        self.skips = skips
        empty = [t for t in self.tasks if not any(s.task == t for s in scenes)]
        self._scene_tasks = {s.task for s in scenes}
        if empty:
            print(f"FloAffKitchenDataModule: no '{self.benchmark}' scene for task(s) {empty} under {self.root}")
        old = sum(s.format_version == 1 for s in scenes)
        if old:  # docs/data_format.md "Versions"
            print(
                f"FloAffKitchenDataModule: {old} of {len(scenes)} scene(s) under {self.root} are format 1: their floor "
                "points are the filtered candidate set, not the observed floor predict() asks about; regenerate "
                "with `floaff-zoo generate` (format 2) to train models for deployment"
            )
        sizes = ", ".join(f"{s} {len(self.datasets[s])}" for s in ("train", "val", "test"))
        print(
            f"FloAffKitchenDataModule[{self.benchmark}, tasks={self.tasks}, views={self.views}]: {sizes} samples. "
            f"{skips.summary()}"
        )
        fit = ["train", "val"] if self.validates else ["train"]
        need = {"fit": fit, "validate": ["val"], "test": ["test"], "predict": ["test"]}.get(stage or "", [])
        for split in need:
            if len(self.datasets[split]) == 0:
                why = " (val_scenes 0: no validation split)" if split == "val" and not self.validates else ""
                raise MisconfigurationException(
                    f"FloAffKitchenDataModule: the '{split}' split is empty{why} for tasks {self.tasks}, views "
                    f"{self.views} under {self.root}/{self.benchmark} (scenes per split: {self.split_scenes})"
                )
        self._warn_missing_tasks(stage)

    def _warn_missing_tasks(self, stage: str | None) -> None:
        """Warn, once per split, when a split ``stage`` uses holds no sample of a task this run loads although the
        data has scenes of it (a task without any scene is printed at setup): e.g. every train scene of the task
        failed or was skipped, so a fit trained the other tasks only and its test scored one it never trained, or
        the seeded validation draw left it out (a single train scene of one view, views skipped at setup), so no
        checkpoint choice saw it. A pinned hold-out (``val_scene_ids``, ``val_layout``) leaves tasks out of
        validation by design and is not checked here."""
        pinned = self.val_scene_ids is not None or self.val_layout is not None
        fit = ["train"] + (["val"] if self.validates and not pinned else [])
        splits = {"fit": fit, "test": ["test"], "predict": ["test"]}.get(stage or "", [])
        tasks = {split: {r.meta.get("task") for r in getattr(ds, "records", [])} for split, ds in self.datasets.items()}
        for split in splits:
            if split not in tasks or split in self._warned_splits:
                continue
            # a task without a train sample is said once, for train: its validation is empty too; one a pinned
            # hold-out took whole is said at the split ("every train scene of ... is held out")
            known = tasks.get("train", set()) if split == "val" else self._scene_tasks
            held = tasks.get("val", set()) if split == "train" and pinned else set()
            missing = [t for t in self.tasks if t in known and t not in tasks[split] and t not in held]
            if missing:
                self._warned_splits.add(split)
                what = {
                    "train": "a fit trains the other tasks only",
                    "val": "the validation that chooses the checkpoint sees the other tasks only",
                    "test": "the test scores the other tasks only",
                }[split]
                warnings.warn(
                    f"FloAffKitchenDataModule: the '{split}' split holds no sample of task(s) {missing} under "
                    f"{self.root}/{self.benchmark} (views {self.views}; scenes per split: {self.split_scenes}; "
                    f"{self.skips.total if self.skips is not None else 0} skipped at setup): {what}",
                    stacklevel=2,
                )

    def skip_log(self, split: str) -> SkipLog | None:
        """What setup skipped, for a report on ``split``: one log over every split (scenes are read, and a corrupt
        scene.json skipped, before they are split); None before setup."""
        return self.skips

    def _cache(self, reader: FloAffReader, full_cloud: bool) -> SampleCache:
        """The sample cache of this reader and these pre-transforms, with or without the stored cloud."""
        cfg = {**reader.config(), "pre_transforms": transforms_config(self.pre_transforms), "seed": self.seed}
        if full_cloud:  # only then: caches made without it keep their key
            cfg["full_cloud"] = True
        code = code_digest([reader, *self.pre_transforms])
        if code is not None:  # a user's reader or pre-transform: its edits re-parse, as the package's do
            cfg["code"] = code
        return SampleCache(self.cache_dir, f"floaff_{self.benchmark}", cfg, self.cache_hash)

    def transforms_for(self, split: str) -> list[SampleTransform]:
        """The configured transforms; the train split's labels are replaced first when ``train_labels`` is set."""
        extra = [self.train_labels] if split == "train" and self.train_labels is not None else []
        return [*extra, *super().transforms_for(split)]

    def train_dataloader(self) -> Any:
        if self.train_labels is not None and not self._train_labels_checked:
            self._check_train_labels()  # once, and only when the train split is used (not for test / predict)
            self._train_labels_checked = True
        return super().train_dataloader()

    def val_dataloader(self) -> Any:
        # no loaders: Lightning then runs no validation loop (val_scenes 0, module docstring)
        return super().val_dataloader() if self.validates else []

    def _check_train_labels(self) -> None:
        """Every train sample must find its scene and cells in ``train_labels``: fail before training, not mid-epoch."""
        assert self.train_labels is not None
        try:
            table = self.train_labels.table()
        except (OSError, ValueError) as exc:
            raise MisconfigurationException(f"FloAffKitchenDataModule: train_labels: {exc}") from exc
        missing = sorted(set(self.split_scenes.get("train", [])) - set(table))
        if missing:
            raise MisconfigurationException(
                f"FloAffKitchenDataModule: train_labels {self.train_labels.path} has no labels for the train "
                f"scene(s) {missing}"
            )
        self._check_made_from(self.split_scenes.get("train", []))
        ds = self.datasets["train"]
        rng = np.random.default_rng(0)
        for i in range(len(ds)):
            try:
                self.train_labels(ds[i], rng)
            except SampleError as exc:
                raise MisconfigurationException(f"FloAffKitchenDataModule: train_labels: {exc}") from exc

    def _check_made_from(self, train: list[str]) -> None:
        """The train scenes' labels in ``train_labels`` must be made from this data copy's generated labels: a file
        made from another copy (a few cells differ across CPUs) was trained on without a word. Files written before
        the digest was kept are used unchecked, with a warning."""
        assert self.train_labels is not None
        made = self.train_labels.made_from()
        if made is None:
            warnings.warn(
                f"FloAffKitchenDataModule: train_labels {self.train_labels.path} does not record which generated "
                f"labels it was made from (written before that was kept), so it is not checked against {self.root}; "
                "make it again with scripts/fresh_labels.py to have it checked",
                stacklevel=2,
            )
            return
        other = [s for s in train if made.get(s) != self.labels_digests.get(s)]
        if other:
            shown = ", ".join(other[:5]) + (f" and {len(other) - 5} more" if len(other) > 5 else "")
            raise MisconfigurationException(
                f"FloAffKitchenDataModule: train_labels {self.train_labels.path} was made from other generated "
                f"labels than {self.root} holds for the train scene(s) {shown} (another copy of the data, or data "
                "generated again): make it again from this copy with scripts/fresh_labels.py"
            )

    def describe(self) -> dict[str, Any]:
        """Scene ids per split (after setup): for logs and reports."""
        return {k: list(v) for k, v in self.split_scenes.items()}


__all__ = ["BENCHMARKS", "FloAffKitchenDataModule"]
