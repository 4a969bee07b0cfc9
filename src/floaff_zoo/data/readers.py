"""Readers: how a dataset on disk becomes an index of sample records and contract samples.

A *reader* turns a dataset root into a list of :class:`SampleRecord` (cheap, at setup: file
existence and metadata only) and loads one record into a contract sample (expensive: parsing).
:class:`SkipLog` collects the records that cannot be used (counted skips) and prints one summary;
in strict mode the first problem raises :class:`DataError` naming the file and the problem.

FloAff-Kitchen readers implement :class:`FloAffReader` and are registered by name::

    from floaff_zoo.data.readers import FloAffReader, register_reader

    @register_reader("floaff_release")
    class ReleaseReader(FloAffReader):
        def scenes(self, benchmark): ...      # -> list[SceneEntry]
        def load_view(self, scene, view): ... # -> contract sample dict

Then ``FloAffKitchenDataModule(reader="floaff_release")`` (a registered name) or
``reader="my_pkg.my_module:ReleaseReader"`` (an import path, no registration needed) uses it.
The built-in ``generated`` reader reads the format of ``floaff-zoo generate``
(``floaff_zoo.sim.fileformat``, docs/data_format.md).
"""

from __future__ import annotations

import abc
import hashlib
import importlib
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from floaff_zoo.contract import TASKS, VIEWS, Sample, SampleError
from floaff_zoo.floor import check_pose


class DataError(SampleError):
    """A dataset file is missing, corrupt or inconsistent; the message names the file and the problem.

    ``kind`` (optional) is the skip-summary category (e.g. ``corrupt_view``).
    """

    def __init__(self, message: str, kind: str | None = None) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass
class SampleRecord:
    """One indexed sample: enough to load it later and to key its cache entry.

    Attributes:
        key: stable, unique id within the dataset (e.g. the relative sample directory).
        sources: files the sample is built from (their size/mtime or bytes key the cache), its own file first (the
            view file, the scene cloud): the one :attr:`file` names.
        meta: contract ``meta`` (JSON-able), complete except what only loading reveals.
        payload: reader-specific loading instructions (JSON-able).
    """

    key: str
    sources: list[str]
    meta: dict[str, Any]
    payload: dict[str, Any] = field(default_factory=dict)

    @property
    def file(self) -> str:
        """The sample's own file, which its error messages name (the key names no file): the first source, the key
        when there is none."""
        return self.sources[0] if self.sources else self.key


class SkipLog:
    """Counts unusable records by kind and prints one summary; ``strict`` raises on the first one.

    Args:
        name: dataset name used in the summary.
        strict: raise :class:`DataError` instead of skipping.
        keep: how many example paths to keep per kind.
    """

    def __init__(self, name: str, strict: bool = False, keep: int = 3) -> None:
        self.name, self.strict, self.keep = name, strict, keep
        self.counts: Counter[str] = Counter()
        self.examples: dict[str, list[str]] = {}

    def add(self, kind: str, path: str | Path, problem: str) -> None:
        """Record one skip of ``kind`` (e.g. ``missing_global``) at ``path``; raise when strict."""
        msg = f"{path}: {problem}" if str(path) else problem
        if self.strict:
            raise DataError(f"{self.name}: {msg} (strict=True; set strict: false to skip and count such samples)")
        self.counts[kind] += 1
        ex = self.examples.setdefault(kind, [])
        if len(ex) < self.keep:
            ex.append(msg)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def record(self) -> dict[str, Any]:
        """The log as JSON-able data: ``{"log": name, "total", "counts": {kind: n}, "examples": {kind: [path:
        problem]}}`` (test reports carry it)."""
        return {
            "log": self.name,
            "total": self.total,
            "counts": dict(sorted(self.counts.items())),
            "examples": {k: list(v) for k, v in sorted(self.examples.items())},
        }

    def summary(self) -> str:
        """One multi-line summary: total, per kind count and the first few paths."""
        if not self.total:
            return f"{self.name}: no sample skipped"
        lines = [f"{self.name}: skipped {self.total} sample(s):"]
        for kind, n in sorted(self.counts.items()):
            lines.append(f"  {kind}: {n}")
            lines.extend(f"    e.g. {m}" for m in self.examples.get(kind, []))
        return "\n".join(lines)


def source_signature(paths: list[str], mode: str = "stat") -> str:
    """Hash identifying the current content of ``paths``.

    ``stat`` hashes (path, size, mtime_ns) (cheap, the default); ``content`` hashes the bytes.
    Missing files hash as ``missing``.
    """
    h = hashlib.sha256()
    for p in paths:
        h.update(p.encode())
        try:
            if mode == "content":
                with open(p, "rb") as f:
                    for chunk in iter(lambda: f.read(1 << 20), b""):
                        h.update(chunk)
            else:
                st = os.stat(p)
                h.update(f"{st.st_size}:{st.st_mtime_ns}".encode())
        except OSError:
            h.update(b"missing")
    return h.hexdigest()


def check_finite_arrays(sample: Sample, path: str) -> None:
    """Raise DataError naming ``path`` and the field when a float array holds NaN/Inf."""
    for k in ("scene_xyz", "scene_feat", "floor_xyz", "floor_label", "robot", "target_xyz", "target_yaw"):
        a = np.asarray(sample[k])
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise DataError(f"{path}: field {k} contains {int((~np.isfinite(a)).sum())} NaN/Inf value(s)")


# --------------------------------------------------------------------------------------- FloAff readers
@dataclass
class ViewEntry:
    """One view of a scene: ``view`` is ``front`` or ``side``; ``file`` is the view's data file."""

    view_id: str
    view: str
    file: str
    base_pose_world: list[float]


@dataclass
class SceneEntry:
    """One scene of a FloAff benchmark (what the DataModule needs for splitting and ``meta``)."""

    scene_id: str
    benchmark: str
    split: str  # train | test
    task: str
    layout_id: Any
    style_id: Any
    seed: Any
    dir: str
    views: list[ViewEntry]
    sources: list[str] = field(default_factory=list)  # scene-level files (e.g. scene.json)
    format_version: int | None = None  # generated data's on-disk format (1 or 2, docs/data_format.md); else None
    labels_digest: str | None = None  # short hash of the scene's labels (``fileformat.labels_digest``); else None
    target_world: list[float] | None = None  # the target centre's world (x, y) the annotation faced; else None


class FloAffReader(abc.ABC):
    """Interface of a FloAff-Kitchen reader (subclass it and :func:`register_reader` it).

    Args:
        root: dataset root.
        skips: where to count unusable scenes/views (strict mode raises).
    """

    name = "base"

    def __init__(self, root: str | Path, skips: SkipLog) -> None:
        self.root = Path(root)
        self.skips = skips

    @abc.abstractmethod
    def scenes(self, benchmark: str) -> list[SceneEntry]:
        """All usable scenes of ``benchmark`` (``styles`` | ``layouts``), sorted by scene_id."""

    @abc.abstractmethod
    def load_view(self, scene: SceneEntry, view: ViewEntry) -> Sample:
        """The contract sample of one view (numpy arrays or tensors; meta may be empty)."""

    def config(self) -> dict[str, Any]:
        """JSON-able settings that change what load_view returns (part of the cache key)."""
        return {"reader": type(self).__module__ + "." + type(self).__qualname__}


READERS: dict[str, type[FloAffReader]] = {}


def register_reader(name: str):
    """Class decorator: make a :class:`FloAffReader` subclass selectable as ``reader: <name>``."""

    def deco(cls: type[FloAffReader]) -> type[FloAffReader]:
        if not (isinstance(cls, type) and issubclass(cls, FloAffReader)):
            raise TypeError(f"register_reader({name!r}): {cls!r} is not a FloAffReader subclass")
        cls.name = name
        READERS[name] = cls
        return cls

    return deco


def get_reader(name: str) -> type[FloAffReader]:
    """A registered reader name, or an import path ``pkg.module:Class`` / ``pkg.module.Class``."""
    if not isinstance(name, str):  # a number failed as "argument of type 'int' is not iterable"
        raise ValueError(f"reader must be a registered name {sorted(READERS)} or 'pkg.module:Class', got {name!r}")
    if name in READERS:
        return READERS[name]
    if ":" in name or "." in name:
        mod, _, attr = name.partition(":") if ":" in name else name.rpartition(".")
        try:
            cls = getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"reader {name!r}: cannot import it ({exc})") from exc
        if not (isinstance(cls, type) and issubclass(cls, FloAffReader)):
            raise ValueError(f"reader {name!r} is not a FloAffReader subclass")
        return cls
    raise ValueError(f"unknown reader {name!r}; registered: {sorted(READERS)} (or give 'pkg.module:Class')")


@register_reader("generated")
class GeneratedReader(FloAffReader):
    """Reads the format written by ``floaff-zoo generate`` through ``floaff_zoo.sim.fileformat``.

    Both format versions (docs/data_format.md): 1 (every view holds the scene's filtered candidate cells) and 2
    (every view holds the label-grid cells it observes as ground). Samples carry the extra key ``floor_known``
    [M] bool (all true in version 1); a scene of an unknown version is skipped as ``corrupt_scene_json``, one whose
    scene.json lists no view, or only view files that are missing, as ``scene_without_views``.
    """

    def scenes(self, benchmark: str) -> list[SceneEntry]:
        from floaff_zoo.sim import fileformat as ff

        bdir = self.root / benchmark
        if not bdir.is_dir():
            return []
        out: list[SceneEntry] = []
        for d in sorted(p for p in bdir.iterdir() if p.is_dir() and not p.name.startswith(".")):
            sj = d / ff.SCENE_JSON
            if not sj.is_file():
                self.skips.add("missing_scene_json", sj, "no scene.json (scene not committed)")
                continue
            try:
                rec = ff.read_scene(d)
            except ff.FormatError as exc:
                self.skips.add("corrupt_scene_json", sj, str(exc).split(": ", 1)[-1])
                continue
            if rec.get("status") != "ok":
                self.skips.add("scene_not_ok", sj, f"status {rec.get('status')!r}")
                continue
            if isinstance(rec["views"], list) and not rec["views"]:
                # kept, it holds no sample yet takes a place in the validation draw (a split shrinks unseen)
                why = f"scene {rec.get('scene_id', d.name)} lists no view (generators up to 2.2.0 committed some)"
                self.skips.add("scene_without_views", sj, why)
                continue
            try:
                entry = self._entry(rec, d, benchmark)
            except DataError:  # strict: a missing view file, already named and counted as one
                raise
            except (KeyError, TypeError, ValueError, AttributeError) as exc:  # a field of the wrong kind or missing
                why = f"missing field {exc}" if isinstance(exc, KeyError) else str(exc)
                self.skips.add("corrupt_scene_json", sj, why)
                continue
            if not entry.views:  # every view file it lists is missing (each counted): no sample, like a scene with none
                why = f"scene {entry.scene_id}: none of the {len(rec['views'])} view file(s) it lists is there"
                self.skips.add("scene_without_views", sj, why)
                continue
            first = next((e for e in out if e.scene_id == entry.scene_id), None)
            if first is not None:  # a copied folder (X.bak) would count its views twice under one sample id
                self.skips.add("duplicate_scene", sj, f"scene {entry.scene_id} is already read from {first.dir}")
                continue
            out.append(entry)
        return out

    def _entry(self, rec: dict[str, Any], d: Path, benchmark: str) -> SceneEntry:
        """The scene record of a read ``scene.json`` (its views whose file is missing are skipped and counted).

        ``ff.read_scene`` has checked split, task and benchmark.

        Raises:
            KeyError / TypeError / ValueError: a field is missing or of the wrong kind, or a view's kind is unknown.
        """
        from floaff_zoo.sim import fileformat as ff

        views: list[ViewEntry] = []
        seen: dict[Any, ViewEntry] = {}  # ("id", view_id) and ("file", path) of the views kept so far
        for v in rec["views"]:
            if v["view"] not in VIEWS:  # else filtered out later by the data module's `views`, without a count
                raise ValueError(f"view {v['view_id']!r}: kind {v['view']!r} is not one of {list(VIEWS)}")
            vf = d / v["file"]
            again = seen.get(("id", v["view_id"])) or seen.get(("file", vf))
            if again is not None:  # one view twice: twice in the metrics, and one more under max_views_per_scene
                why = f"view {v['view_id']!r} ({v['file']}) repeats view {again.view_id!r} ({Path(again.file).name})"
                self.skips.add("duplicate_view", d / ff.SCENE_JSON, why)
                continue
            if not vf.is_file():
                self.skips.add("missing_view", vf, "view file listed in scene.json is missing")
                continue
            # the SR rollout parks the robot from it
            pose = list(check_pose(v["base_pose_world"], f"view {v['view_id']!r}", "base_pose_world"))
            views.append(ViewEntry(v["view_id"], v["view"], str(vf), pose))
            seen[("id", v["view_id"])] = seen[("file", vf)] = views[-1]
        spec = rec["spec"]
        return SceneEntry(
            scene_id=str(rec.get("scene_id", d.name)),
            benchmark=benchmark,
            split=rec["split"],
            task=rec["task"],
            layout_id=spec.get("layout_id"),
            style_id=spec.get("style_id"),
            seed=spec.get("seed"),
            dir=str(d),
            views=views,
            sources=[str(d / ff.SCENE_JSON)],
            format_version=int(rec["format_version"]),
            labels_digest=ff.labels_digest(rec),
            target_world=ff.target_world(rec),
        )

    def load_view(self, scene: SceneEntry, view: ViewEntry) -> Sample:
        from floaff_zoo.sim import fileformat as ff

        rec = {
            "dir": scene.dir,
            "spec": {"layout_id": scene.layout_id, "style_id": scene.style_id, "seed": scene.seed},
            "task": scene.task,
            "benchmark": scene.benchmark,
            "scene_id": scene.scene_id,
            "split": scene.split,
            "format_version": scene.format_version or 1,
        }
        try:
            s = ff.read_sample(
                rec,
                {
                    "file": os.path.relpath(view.file, scene.dir),
                    "view": view.view,
                    "view_id": view.view_id,
                    "base_pose_world": view.base_pose_world,  # checked against the npz's (the rollout parks from it)
                },
                root=self.root,
            )
        except ff.FormatError as exc:  # by its class: the message holds the path, which may say 'corrupt' or 'NaN'
            kind = (
                "corrupt_view"
                if isinstance(exc, ff.CorruptFileError)
                else "nan_values"
                if isinstance(exc, ff.NonFiniteFieldError)
                else "bad_view"
            )
            raise DataError(str(exc), kind) from exc
        return s


def check_names(kind: str, given: list[str] | tuple[str, ...], valid: tuple[str, ...] | list[str]) -> list[str]:
    """Return ``given`` as a list or raise a ValueError listing the valid names."""
    if not isinstance(given, (list, tuple)):  # a text was read letter by letter: "unknown tasks ['C', 'l', ...]"
        raise ValueError(f"{kind} must be a list of names (valid {kind}: {list(valid)}), got {given!r}")
    bad = [g for g in given if g not in valid]
    if bad:
        raise ValueError(f"unknown {kind} {bad}; valid {kind}: {list(valid)}")
    if not given:
        raise ValueError(f"empty {kind} list; choose from {list(valid)}")
    return list(dict.fromkeys(given))


__all__ = [
    "READERS",
    "TASKS",
    "VIEWS",
    "DataError",
    "FloAffReader",
    "GeneratedReader",
    "SampleRecord",
    "SceneEntry",
    "SkipLog",
    "ViewEntry",
    "check_finite_arrays",
    "check_names",
    "get_reader",
    "register_reader",
    "source_signature",
]
