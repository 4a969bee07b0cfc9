"""Preprocessed sample cache and the record-backed Dataset every file DataModule uses.

Loading a sample from its source files (PLY parsing, KD-tree flags, CSV labels, npz
decompression) happens once: the validated tensors, after the deterministic ``pre_transforms``,
are written to ``<cache_dir>/<dataset>-<config hash>/<sample hash>.pt``.

* ``<config hash>`` = SHA-256 of the reader's settings (e.g. flag radius, robot table, yaw
  estimator), the ``pre_transforms`` config (with the seed they draw from, when there are any) and the source code
  of the modules that turn files into tensors (``PARSER_MODULES``, and the files defining a reader or pre-transform
  class from outside them: ``code_digest``): changing any of them uses a fresh directory, so a parsing fix reaches
  samples (and ``.skip`` markers) cached before it. Without pre-transforms every training seed
  shares one directory.
* ``<sample hash>`` = SHA-256 of the record key and its source files' signature: (path, size,
  mtime_ns) by default (``hash_mode="stat"``, checked at every access), or the file bytes (``hash_mode="content"``,
  slower: reads every source file once, at setup, or at a record's first access with ``validate`` false). An edited
  source file therefore misses the cache.
* A sample that failed to load leaves a small ``.skip`` marker with the reason, so the next setup
  counts it again without re-reading it.
* The cache is only a speed-up: when it cannot be written (its folder under a file, read-only, a full disk) one
  warning names the folder and the error, and the dataset stops writing to it and reads its samples from their
  sources (a good sample is never skipped for it).

Stale entries are never read again but stay on disk; delete the directory to reclaim space.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import inspect
import json
import sys
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from floaff_zoo.atomic import atomic_write
from floaff_zoo.contract import FULL_CLOUD_KEY, TENSOR_KEYS, Sample, SampleError, validate_sample
from floaff_zoo.data.readers import DataError, SampleRecord, SkipLog, source_signature
from floaff_zoo.data.transforms import SampleTransform, apply_transforms

CACHE_VERSION = 1
#: the modules whose code turns source files into cached tensors or skip markers (read, validate, pre-transform);
#: any edit to one of them, a comment included, re-parses every cached sample once (correct over fast)
PARSER_MODULES = (
    "floaff_zoo.contract",
    "floaff_zoo.data.cache",
    "floaff_zoo.data.readers",
    "floaff_zoo.data.transforms",
    "floaff_zoo.data.floaff_kitchen",
    "floaff_zoo.data.moma_kitchen",
    "floaff_zoo.sim.fileformat",
    # what those and the package's pre-transforms call on a sample: the readers' pose check (which samples are
    # skipped, and marked so) and SceneLabels' frame change (the labels cached)
    "floaff_zoo.floor",
    "floaff_zoo.frames",
)


@functools.cache
def parser_digest() -> str:
    """SHA-256 (16 hex digits) of the source files of ``PARSER_MODULES`` as installed: part of every cache key."""
    h = hashlib.sha256()
    for name in PARSER_MODULES:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            raise ImportError(f"sample cache: cannot find the module {name}")
        h.update(name.encode() + b"\0" + Path(spec.origin).read_bytes())
    return h.hexdigest()[:16]


def code_digest(objects: Sequence[object]) -> str | None:
    """SHA-256 (16 hex digits) of the code of the classes of ``objects`` (a reader, the pre-transforms) and their
    bases that lie outside ``PARSER_MODULES`` and the standard library: a user's reader (``reader:
    my_pkg.my_module:MyReader``) or pre-transform, whose edits must reach cached samples as the package's do. None
    when every class is the package's parsing code (those caches keep their key)."""
    h, found = hashlib.sha256(), False
    for obj in objects:
        for cls in type(obj).__mro__:
            module = cls.__module__
            if module in PARSER_MODULES or module.split(".")[0] in sys.stdlib_module_names:
                continue
            found = True
            h.update(f"{module}:{cls.__qualname__}".encode() + b"\0")
            try:
                path = inspect.getsourcefile(cls)
            except TypeError:  # a class without a source file (a C extension's)
                path = None
            if path is not None and Path(path).is_file():
                h.update(Path(path).read_bytes())
    return h.hexdigest()[:16] if found else None


def _sha(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


class SampleCache:
    """Directory of per-sample tensor files keyed by config and source hashes (module docstring).

    Args:
        directory: cache root (``<root>/.cache`` by default in the DataModules).
        name: dataset name (directory prefix).
        config: JSON-able reader + pre-transform settings.
        hash_mode: ``stat`` or ``content`` (see module docstring).
    """

    def __init__(self, directory: str | Path, name: str, config: dict[str, Any], hash_mode: str = "stat") -> None:
        if hash_mode not in ("stat", "content"):
            raise ValueError(f"cache hash_mode must be 'stat' or 'content', got {hash_mode!r}")
        self.config = {"version": CACHE_VERSION, "parser": parser_digest(), **config}
        if config.get("pre_transforms"):  # entries made before kept no meta change of the pre-transforms
            self.config["pre_transform_meta"] = True
        else:  # the seed reaches the cached tensors through the pre-transforms only: every seed shares the parse
            self.config.pop("seed", None)
        self.dir = Path(directory) / f"{name}-{_sha(self.config)[:12]}"
        self.hash_mode = hash_mode
        self.writable = True  # False after a failed write: the samples are then served from their sources
        self._entries: dict[tuple[str, ...], Path] = {}  # content mode: entry of each record whose bytes were read

    def entry(self, record: SampleRecord, fresh: bool = False) -> Path:
        """Cache file of ``record`` (its name changes when a source file changes).

        ``content`` mode reads the source files at the record's first call or with ``fresh`` (the setup check),
        then reuses that name: reading them at every access would cost more than the parse the cache saves.
        """
        memo = (record.key, *record.sources)
        if self.hash_mode == "content" and not fresh and memo in self._entries:
            return self._entries[memo]
        h = hashlib.sha256(record.key.encode() + source_signature(record.sources, self.hash_mode).encode())
        path = self.dir / f"{h.hexdigest()[:32]}.pt"
        self.remember(record, path)
        return path

    def remember(self, record: SampleRecord, path: Path) -> None:
        """Keep ``record``'s entry in content mode (one a setup worker process computed)."""
        if self.hash_mode == "content":
            self._entries[(record.key, *record.sources)] = path

    def get(self, path: Path) -> dict[str, torch.Tensor] | None:
        """Cached tensors, or None on a miss or an unreadable entry."""
        if not path.is_file():
            return None
        try:
            return torch.load(path, map_location="cpu", weights_only=True)
        except Exception:  # noqa: BLE001 - a torn/corrupt cache file is just a miss
            return None

    def put(self, path: Path, tensors: dict[str, torch.Tensor]) -> None:
        """Atomically write one entry (temp file + os.replace)."""
        self._atomic(path, lambda f: torch.save(tensors, f))

    def skipped(self, path: Path) -> tuple[str, str] | None:
        """(kind, problem) of a sample that failed before, or None."""
        marker = path.with_suffix(".skip")
        if not marker.is_file():
            return None
        try:
            d = json.loads(marker.read_text())
            return str(d["kind"]), str(d["problem"])
        except (OSError, ValueError, KeyError):
            return None

    def mark_skipped(self, path: Path, kind: str, problem: str) -> None:
        self._atomic(
            path.with_suffix(".skip"), lambda f: f.write(json.dumps({"kind": kind, "problem": problem}).encode())
        )

    def prepare(self) -> bool:
        """Make the cache folder and its ``config.json`` (warning and disabling the cache when it cannot be
        written); whether the cache is writable."""
        if self.writable and not (self.dir / "config.json").is_file():
            cfg = json.dumps(self.config, indent=1, sort_keys=True, default=str).encode()
            self._write(self.dir / "config.json", lambda f: f.write(cfg))
        return self.writable

    def _atomic(self, path: Path, write: Callable[[Any], None]) -> None:
        if self.prepare():
            self._write(path, write)

    def _write(self, path: Path, write: Callable[[Any], None]) -> None:
        """``atomic_write``; an OSError disables the cache with one warning instead of failing the sample."""
        try:
            atomic_write(path, write)
        except OSError as exc:
            self.writable = False
            warnings.warn(
                f"sample cache {self.dir} cannot be written ({exc}); reading the samples from their sources",
                stacklevel=2,
            )


#: cache-entry key of the meta a pre-transform changed (JSON: {"set": {key: value}, "drop": [key, ...]})
_META_DELTA = "meta_delta"


def _meta_delta(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """What the pre-transforms changed in a sample's meta ({} when nothing)."""
    changed = {k: v for k, v in after.items() if k not in before or not _same(before[k], v)}
    dropped = [k for k in before if k not in after]
    return {"set": changed, "drop": dropped} if changed or dropped else {}


def _same(a: Any, b: Any) -> bool:
    """Equal meta values (arrays compared as data, not by identity)."""
    try:
        return bool(a == b)
    except (ValueError, RuntimeError):  # arrays with several elements
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))


def _json_default(value: Any) -> Any:
    """numpy / torch values inside meta as JSON numbers and lists."""
    if isinstance(value, (np.ndarray, np.generic, torch.Tensor)):
        return value.tolist()
    raise TypeError(f"meta value {value!r} ({type(value).__name__}) is not JSON-able")


def classify_error(exc: Exception) -> str:
    """Skip kind of a load error: the ``kind`` attribute when the reader set one, else its class."""
    return getattr(exc, "kind", None) or type(exc).__name__


def _record_seed(seed: int, key: str) -> np.random.Generator:
    return np.random.default_rng([seed, int(hashlib.sha256(key.encode()).hexdigest()[:15], 16)])


#: errors of a bad or vanished sample: skipped by the setup check, replaced by the next sample at run time (one set,
#: so a file that breaks after setup cannot crash an epoch with an error the setup would have counted)
_LOAD_ERRORS = (SampleError, ValueError, OSError, RuntimeError, KeyError, IndexError, TypeError)


def _transient(exc: BaseException) -> bool:
    """Whether a load error may pass: an I/O error of the disk or file system (not a missing file), raised or
    wrapped by a reader. Its record is skipped this time but not marked in the cache, so the next setup reads it
    again (a marker stands until the source file changes)."""
    seen: BaseException | None = exc
    while seen is not None:  # readers wrap errors (FormatError from OSError, then a reader's own error)
        if isinstance(seen, OSError) and not isinstance(seen, FileNotFoundError):
            return True
        seen = seen.__cause__
    return False


class RecordDataset(Dataset):
    """Samples from reader records, through the cache; ``build`` validates them all at setup.

    Args:
        records: the indexed samples.
        loader: record -> contract sample (raises on a bad file; an exception ``kind`` attribute
            names the skip kind).
        cache: a :class:`SampleCache` or None (no cache: every access parses the sources).
        pre_transforms: deterministic transforms applied once before caching (seeded per record).
        seed: seed of the pre-transforms.
        name: dataset name for messages.
        strict: a sample that fails to load after setup raises (naming its record) instead of being replaced by
            the next one, as the DataModule's ``strict`` promises for every missing or corrupt file.
    """

    def __init__(
        self,
        records: Sequence[SampleRecord],
        loader: Callable[[SampleRecord], Sample],
        cache: SampleCache | None = None,
        pre_transforms: Sequence[SampleTransform] | None = None,
        seed: int = 0,
        name: str = "dataset",
        strict: bool = False,
    ) -> None:
        self.records = list(records)
        self.strict = strict
        self.loader = loader
        self.cache = cache
        self.pre_transforms = list(pre_transforms or [])
        self.seed = seed
        self.name = name
        self.runtime_failures = 0

    # ---------------------------------------------------------------- loading one record
    def _parse(self, rec: SampleRecord) -> dict[str, torch.Tensor]:
        """Read, validate and pre-transform one record (no cache). Raises on bad data."""
        raw = self.loader(rec)
        # the contract check and the pre-transforms name meta's path in their messages: the file, not the id again
        raw["meta"] = {**rec.meta, **(raw.get("meta") or {}), "path": rec.file}
        mask = raw.get("scene_mask")
        if mask is not None and not np.asarray(mask).any():  # its own skip kind, before the contract's SampleError
            raise DataError(
                f"{rec.file}: sample {rec.key} has no valid scene point (scene_mask all false)", "empty_cloud"
            )
        s = validate_sample(raw)
        before = dict(s.get("meta") or {})
        s = apply_transforms(s, self.pre_transforms, _record_seed(self.seed, rec.key))
        out: dict[str, Any] = {k: s[k].contiguous() for k in (*TENSOR_KEYS, FULL_CLOUD_KEY) if k in s}
        delta = _meta_delta(before, s.get("meta") or {})
        if delta:  # a pre-transform changed the meta (a turned base pose, a mirror flag): kept with the tensors
            out[_META_DELTA] = json.dumps(delta, sort_keys=True, default=_json_default)
        return out

    def _tensors(self, rec: SampleRecord) -> dict[str, torch.Tensor]:
        if self.cache is None:
            return self._parse(rec)
        path = self.cache.entry(rec)
        hit = self.cache.get(path)
        if hit is not None:
            return hit
        t = self._parse(rec)
        self.cache.put(path, t)
        return t

    def check(self, i: int) -> tuple[str, str] | None:
        """Load record ``i`` (filling the cache); None if fine, else (kind, problem)."""
        return self._check(i)[0]

    def _check(self, i: int) -> tuple[tuple[str, str] | None, Path | None]:
        """``check``'s result and the record's cache entry (a setup worker process hands it back to the dataset)."""
        rec = self.records[i]
        path = self.cache.entry(rec, fresh=True) if self.cache is not None else None
        if path is not None:
            if path.is_file():
                return None, path
            prev = self.cache.skipped(path)
            if prev is not None:
                return prev, path
        try:
            self._tensors(rec)
            return None, path
        except _LOAD_ERRORS as exc:
            kind, problem = classify_error(exc), str(exc)
            if path is not None and not _transient(exc):
                self.cache.mark_skipped(path, kind, problem)
            return (kind, problem), path

    def build(self, skips: SkipLog, workers: int = 0) -> "RecordDataset":
        """Validate every record now (setup time); drop the bad ones into ``skips`` (strict raises).

        With ``workers > 0`` records are parsed in that many processes (cache misses only).
        """
        if self.cache is not None:  # an unwritable cache warns here once, not in every worker
            self.cache.prepare()
        n = len(self.records)
        if workers > 0 and n > 1:
            with ProcessPoolExecutor(workers) as pool:
                checked = list(pool.map(self._check, range(n), chunksize=max(1, n // (8 * workers))))
        else:
            checked = [self._check(i) for i in range(n)]
        keep = []
        for rec, (res, path) in zip(self.records, checked):
            if self.cache is not None and path is not None:  # content mode: no access reads the sources again
                self.cache.remember(rec, path)
            if res is None:
                keep.append(rec)
            else:
                # loaders name the file in the problem, the contract check and pre-transforms the key and file
                skips.add(res[0], "" if rec.key in res[1] or "/" in res[1] else rec.key, res[1])
        self.records = keep
        return self

    # ---------------------------------------------------------------- Dataset API
    def __len__(self) -> int:
        return len(self.records)

    def get(self, i: int) -> Sample:
        """Sample ``i`` (tensors + meta with ``index`` = position in this split). Raises on bad data."""
        rec = self.records[i]
        s: Sample = dict(self._tensors(rec))
        meta = dict(rec.meta)
        if _META_DELTA in s:
            delta = json.loads(s.pop(_META_DELTA))
            meta = {k: v for k, v in meta.items() if k not in delta["drop"]} | delta["set"]
        s["meta"] = {**meta, "index": i}
        return s

    def __getitem__(self, i: int) -> Sample:
        if not 0 <= i < len(self.records):
            raise IndexError(i)
        # Robust mid-epoch: a sample that broke after setup (file deleted/changed) is replaced by the next one. The
        # replacement's meta names the broken record (``replaces``), so the DataModule and the test report count it
        # in the main process (a worker's own counter never reaches it); metrics count samples once by ``index``.
        for k in range(len(self.records)):
            j = (i + k) % len(self.records)
            try:
                s = self.get(j)
                if k:
                    s["meta"]["replaces"] = self.records[i].key
                return s
            except _LOAD_ERRORS as exc:
                if self.strict:
                    raise DataError(
                        f"{self.name}: sample {self.records[j].key} failed at load time ({exc}) (strict=True; set "
                        "strict: false to replace such samples by the next one and count them)"
                    ) from exc
                self.runtime_failures += 1
                if self.runtime_failures <= 3:
                    print(f"{self.name}: sample {self.records[j].key} failed at load time ({exc}); using the next one")
        raise SampleError(f"{self.name}: no sample of the split could be loaded")


__all__ = ["CACHE_VERSION", "RecordDataset", "SampleCache", "classify_error"]
