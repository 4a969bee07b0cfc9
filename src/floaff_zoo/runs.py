"""Run directories written by ``floaff-zoo fit``: which checkpoint to use, and whether the fit finished.

A run directory is ``<default_root_dir>/<model>/version_<n>/`` with ``config.yaml`` and
``checkpoints/`` (``last.ckpt`` and the best by the model's monitor). A ``last.ckpt`` alone does not
say that the fit ended: the fit's checkpoint callback (``callbacks.checkpoint.LatestCheckpoint``) rewrites it at every
validation, so a killed fit leaves one too. Whoever
needs a finished run (the demo) writes ``finished.json`` after ``fit`` returns and checks it later.

This module reads files only (torch for ``weights_only`` checkpoint loading): the CLI and the hub's
``push`` both use it, and it imports neither.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import stat
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from floaff_zoo.atomic import atomic_write_text

FINISHED_FILE = "finished.json"
#: keys of every checkpoint a Lightning ``Trainer`` writes (``--ckpt_path`` fails without them)
CHECKPOINT_KEYS = ("state_dict", "pytorch-lightning_version")


class RunError(RuntimeError):
    """A run directory lacks what a command needs (user-facing: the CLI prints it without a traceback)."""


def resolve_ckpt_alias(alias: str, root: str | Path, model_class: str | None = None) -> str:
    """Turn ``best``/``last`` into a checkpoint file found under a run directory.

    ``last`` is the newest ``last.ckpt``; ``best`` is the ``best_model_path`` its ModelCheckpoint state recorded
    (``last`` when none was monitored; an error when the recorded file is gone). With ``model_class`` (a class name
    such as ``PointNet2Module``) only checkpoints whose hyper-parameters record that class count: a root that holds
    the runs of several models (``trainer.default_root_dir``) must not hand one model another model's weights.
    """
    lasts, skipped = _newest_files(Path(root).rglob("last*.ckpt"))
    if not lasts:
        why = f" ({len(skipped)} not a file, e.g. {skipped[0]})" if skipped else ""
        raise RunError(f"--ckpt_path {alias}: no last.ckpt under {root}{why}; pass a checkpoint file instead")
    last, state = lasts[0], None
    if model_class is not None:
        last, others, unreadable = None, [], None
        for path in lasts:  # newest first; each file is memory-mapped, so a look at its hyper-parameters costs little
            try:
                ckpt = load_checkpoint(path, f"--ckpt_path {alias}: ")
            except RunError as exc:  # another run's file cut off or still being written: it must not stop this one
                unreadable = unreadable or exc
                continue
            found = checkpoint_class(ckpt)
            if found == model_class:
                last, state = path, ckpt
                break
            others.append(f"{path} ({found or 'no class recorded'})")
        if last is None and unreadable is not None:  # perhaps this model's own: its file and why, as before
            raise unreadable
        if last is None:
            raise RunError(
                f"--ckpt_path {alias}: no last.ckpt of {model_class} under {root} (only {len(others)} of other "
                f"models, newest {others[0]}); pass a checkpoint file or the run's own --config <run>/config.yaml"
            )
    if alias == "last":
        return str(last)
    if state is None:
        state = load_checkpoint(last, f"--ckpt_path {alias}: ")
    recorded = [Path(p) for p in _recorded_best_paths(state, f"--ckpt_path {alias}: {last}: ")]
    for best in recorded:
        # the run's own folder first: a moved run's old absolute path may hold another run's file by now
        for candidate in (last.parent / best.name, best):
            if candidate.is_file():
                return str(candidate)
    if recorded:  # last.ckpt holds other weights than the best: never hand them out under the name "best"
        raise RunError(
            f"--ckpt_path {alias}: {last} records the best checkpoint {recorded[0]}, which is gone (nor is it next "
            f"to {last.name}); pass a checkpoint file instead (e.g. {last} for the last epoch's weights)"
        )
    return str(last)


def _recorded_best_paths(state: dict[str, Any], context: str) -> list[str]:
    """The ``best_model_path`` each ModelCheckpoint state of a checkpoint records (those that recorded one).

    Raises:
        RunError: ``{context}...`` when the callbacks' states are not the mappings Lightning writes (a damaged or
            hand-made file): read as "none recorded", ``best`` would hand out the last weights.
    """
    callbacks = state.get("callbacks") or {}
    if not isinstance(callbacks, dict):
        raise RunError(f"{context}its 'callbacks' is a {type(callbacks).__name__}, not a mapping")
    out = []
    for key, cb in callbacks.items():
        if not str(key).startswith("ModelCheckpoint"):
            continue
        best = cb.get("best_model_path") if isinstance(cb, dict) else cb
        if not isinstance(cb, dict) or not isinstance(best, (str, type(None))):
            raise RunError(f"{context}callback state {key}: expected a best_model_path text, got {best!r:.60}")
        if best:
            out.append(best)
    return out


def _newest_files(paths: Iterable[Path]) -> tuple[list[Path], list[Path]]:
    """(the regular files among ``paths``, newest first; the others): a link to nothing, a folder, or a file
    removed since it was listed (another run's, rotated) has no time to sort by."""
    files: list[tuple[float, Path]] = []
    others: list[Path] = []
    for path in paths:
        try:
            st = path.stat()
        except OSError:
            st = None
        if st is not None and stat.S_ISREG(st.st_mode):
            files.append((st.st_mtime, path))
        else:
            others.append(path)
    files.sort(key=lambda item: item[0], reverse=True)
    return [p for _, p in files], others


def checkpoint_class(ckpt: dict[str, Any]) -> str | None:
    """The class name a Lightning checkpoint's hyper-parameters record (``_class_path``, written when the CLI built
    the model), or None."""
    hparams = ckpt.get("hyper_parameters")
    path = hparams.get("_class_path") if isinstance(hparams, dict) else None
    return str(path).rsplit(".", 1)[-1] if path else None


def load_failure_reason(exc: Exception) -> str:
    """Why ``torch.load`` failed, in one line (checkpoints here, ``weights`` files in ``hub.io``): a weights-only
    refusal's own reason, not the page of advice around it."""
    text = str(exc)
    if "WeightsUnpickler error:" in text:
        text = text.split("WeightsUnpickler error:", 1)[1].strip().split("\n\n", 1)[0]
    return f"{type(exc).__name__}: {' '.join(text.split())}"


def load_checkpoint(path: str | Path, context: str = "", keys: tuple[str, ...] = ()) -> dict[str, Any]:
    """The dict of a checkpoint file, read weights-only (no code runs) and memory-mapped when torch allows (its zip
    format): the tensors stay on disk until used, so checking a large file costs little.

    Raises:
        RunError: ``{context}{path}: ...`` when the file does not load, is not a dict or lacks one of ``keys``.
    """
    import torch

    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True, mmap=zipfile.is_zipfile(path))
    except Exception as exc:  # truncated, not a torch file, or a pickle with code in it
        raise RunError(f"{context}{path}: not a readable checkpoint ({load_failure_reason(exc)})") from exc
    if not isinstance(ckpt, dict):
        raise RunError(f"{context}{path}: expected a checkpoint (a dict), got a {type(ckpt).__name__}")
    missing = [k for k in keys if k not in ckpt]
    if missing:
        raise RunError(f"{context}{path}: not a Lightning checkpoint (no {', '.join(map(repr, missing))})")
    return ckpt


def mark_finished(run_dir: str | Path, checkpoint: str | Path, extra: dict[str, Any] | None = None) -> Path:
    """Write ``<run_dir>/finished.json`` = {finished (UTC ISO time), checkpoint, *extra}, atomically."""
    path = Path(run_dir) / FINISHED_FILE
    record = {
        "finished": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "checkpoint": str(checkpoint),
        **(extra or {}),
    }
    atomic_write_text(path, json.dumps(record, indent=2) + "\n")  # a kill never leaves half a marker
    return path


def read_finished(run_dir: str | Path) -> dict[str, Any] | None:
    """The ``finished.json`` record of a run, or None when the run never finished.

    Raises:
        RunError: the marker exists but is not a JSON object with a ``checkpoint`` (names the file).
    """
    path = Path(run_dir) / FINISHED_FILE
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: bad JSON, or bytes that are not UTF-8
        raise RunError(f"{path}: unreadable finished-run marker ({exc}); delete it to fit the run again") from exc
    if not isinstance(record, dict) or not isinstance(record.get("checkpoint"), str):
        raise RunError(f"{path}: expected an object with a 'checkpoint' path; delete it to fit the run again")
    return record


def finished_runs(root: str | Path) -> list[tuple[Path, dict[str, Any]]]:
    """(run dir, record) of every finished run under ``root`` whose checkpoint still exists, oldest first."""
    out = []
    for marker in Path(root).rglob(FINISHED_FILE):
        record = read_finished(marker.parent)
        if record is not None and Path(record["checkpoint"]).is_file():
            out.append((marker.parent, record))
    return sorted(out, key=lambda item: item[0].joinpath(FINISHED_FILE).stat().st_mtime)


#: files under a data folder whose content the fingerprint reads: the small metadata a generator or a public format
#: writes per scene and per dataset (scene.json, split lists); larger ones (MoMa-Kitchen's per-sample label tables)
#: and other files count by path and size
_DATA_TEXT_SUFFIXES = (".json", ".txt", ".yaml", ".yml", ".csv")
_DATA_TEXT_MAX_BYTES = 1 << 20
#: files that the fingerprint leaves out: the generator's log of its runs (wall times, workers, package versions),
#: rewritten by every `floaff-zoo generate` resume, the demo's included, that makes nothing; the scene records it lists
#: say what was generated
_DATA_RUN_LOGS = ("manifest.json",)


def data_fingerprint(root: str | Path) -> str:
    """sha256 over every file of a data folder but hidden ones (the sample cache ``.cache``, lock files, which fits
    write there) and ``_DATA_RUN_LOGS``: each file's relative path and size, and the content of its small metadata
    files; symbolic links to folders are followed (each real folder once). The curriculum reuses a finished stage,
    and the demo a finished baseline, only while it is unchanged: data generated again (new scene records), another
    copy in the same folder, or scenes added or removed (test scenes too) give another fingerprint; a generator run
    that made nothing does not."""
    root = Path(root)
    h = hashlib.sha256()
    seen: set[str] = set()
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen:  # a link cycle, or a second link to one folder: walked once
            dirnames[:] = []
            continue
        seen.add(real)
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for name in sorted(f for f in filenames if not f.startswith(".") and f not in _DATA_RUN_LOGS):
            path = Path(dirpath, name)
            try:
                size = path.stat().st_size
                small = name.endswith(_DATA_TEXT_SUFFIXES) and size <= _DATA_TEXT_MAX_BYTES
                text = hashlib.sha256(path.read_bytes()).hexdigest() if small else ""
            except OSError:  # removed meanwhile (a generator running beside us): counted as missing
                size, text = -1, ""
            h.update(f"{path.relative_to(root).as_posix()}\0{size}\0{text}\n".encode())
    return h.hexdigest()


def config_value(args: list[str], i: int) -> str | None:
    """The value ``args[i]`` gives ``--config`` (``--config X`` or ``--config=X``); None when it gives none."""
    if args[i] == "--config":
        return args[i + 1] if i + 1 < len(args) else None
    return args[i].partition("=")[2] if args[i].startswith("--config=") else None


def is_config_file(value: str) -> bool:
    """True when a ``--config`` value names a file; else it is YAML text (jsonargparse takes both) or a missing
    file. A YAML text too long for a path is no file (``is_file`` raised ENAMETOOLONG)."""
    try:
        return Path(value).is_file()
    except (OSError, ValueError):
        return False


def config_values(args: list[str]) -> list[str]:
    """The ``--config`` values of ``args`` (``--config X`` or ``--config=X``), in order: the CLI's and the
    curriculum's (which reads lineages without loading the CLI's Lightning and models)."""
    return [v for v in (config_value(args, i) for i in range(len(args))) if v is not None]
