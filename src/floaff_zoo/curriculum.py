"""``floaff-zoo curriculum``: run a PFAL curriculum, a list of ordinary ``fit`` stages.

Each stage is one ``floaff-zoo fit`` through the same LightningCLI (``floaff_zoo.cli.run_lightning``),
built from config files plus per-stage overrides. A stage can take the best checkpoint of an earlier
stage as an init argument (``from_stages``), e.g. PFAL stage 2 uses stage 1's best as both
``model.init_args.weights`` (initialisation) and ``model.init_args.teacher`` (distillation), and CFAR
stages take the AxisNet stage's best as ``model.init_args.axisnet``. ``--ckpt_path`` is only used to
resume a stage that was killed (its ``last.ckpt``).

Experiment file (YAML; paths relative to the working directory, ``extends`` relative to the file)::

    extends: pfal_layouts.yaml        # optional: deep-merge onto another experiment (lists replace)
    root: runs/pfal_layouts           # run directory (``--root`` overrides)
    data: [configs/data/x.yaml]       # --config files, in this order: data, model, trainer
    model: [configs/models/cfar.yaml]
    trainer: []
    overrides: {trainer.max_epochs: 30, model.init_args.crop_radius: 1.2}   # every shared stage
    stages:
      - name: axisnet                 # unique; the stage directory is <root>/<name> ...
        root: runs/axisnet_layouts    # ... or this (lets several experiments share a stage)
        shared: false                 # ignore the top-level model files / overrides / --extra-config
        model: [configs/models/axisnet.yaml]
        tasks: [PnPCounterToCab, OpenSingleDoor, CloseDoubleDoor, CloseDrawer]
        overrides: {trainer.max_epochs: 200}
      - name: stage1_pnp
        tasks: [PnPCounterToCab]      # -> --data.init_args.tasks
        from_stages: {model.init_args.axisnet: axisnet}

Order of the fit arguments (later wins): data, model, trainer files, top-level overrides, stage
overrides, ``--extra-config`` files (so an ablation/sweep file beats the experiment's own values),
tasks, ``from_stages``, ``--set``, ``--trainer.default_root_dir``.

Resuming: every finished stage writes ``<stage dir>/stage.json`` and the run writes
``<root>/lineage.json`` (stage, configs, fit arguments, checkpoint, sha256, metrics, teacher/weights).
A rerun skips stages whose record is ``done`` with the same fit arguments, the same ``--config`` file contents
(the stage digest below; any edit, a comment too, means a fresh fit), the same input files (a checkpoint or label
file, ``INPUT_SUFFIXES``, that a fit argument or a value in a ``--config`` file names, such as an earlier stage's
checkpoint or ``data.init_args.train_labels``; sha256 checked), the same data (``data.init_args.root``, or its
``<benchmark>`` folder when the arguments name one: ``floaff_zoo.runs.data_fingerprint``; records written before it
was kept are compared without it) and an intact checkpoint (sha256 checked).
Each run directory a stage's fit writes gets ``curriculum_run.json`` (the digest of the stage's fit arguments and
``--config`` file contents, and its input files' sha256 when the fit started); a stage that was killed resumes from
the newest ``last.ckpt`` of a run with its digest whose input files are unchanged since it started, and that no fit
with other arguments wrote into (``trainer.logger: false`` puts every fit of a stage in one folder), else a fresh
fit, logging into that run's own directory so its ModelCheckpoint keeps the best of the epochs before the kill: the
recorded checkpoint is the best of the whole stage, as ``--ckpt_path best`` finds it. A ``last.ckpt`` that does not
load (a kill while it was written) stops the stage with its path and what to do, instead of failing inside the fit.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import io
import json
import os
import shlex
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import yaml

from floaff_zoo.atomic import atomic_write_json, atomic_write_text, folder_lock
from floaff_zoo.checks import check_flag
from floaff_zoo.runs import RunError, config_value, config_values, data_fingerprint, is_config_file, load_checkpoint

__all__ = ["CurriculumError", "build_stage_args", "load_experiment", "main", "read_lineage", "run_curriculum"]

STAGE_FILE = "stage.json"
LINEAGE_FILE = "lineage.json"
RUN_FILE = "curriculum_run.json"  # in each run directory: the stage digest that wrote it
KEPT_METRICS = "metrics.before_resume.csv"  # a resumed run's earlier metrics.csv rows, during the fit
_STAGE_KEYS = {"name", "root", "shared", "model", "tasks", "overrides", "from_stages", "configs"}
_TOP_KEYS = {"extends", "root", "data", "model", "trainer", "overrides", "stages", "description"}
#: model init args that name a checkpoint, an exported folder or a hub name the model loads (CFAR's teacher and
#: AxisNet, any model's initial weights): one that does not load failed only when its stage's fit started, after
#: the earlier stages trained
WEIGHT_ARGS = ("weights", "teacher", "axisnet")
#: how an earlier stage's checkpoint is named before that stage has run (:func:`build_stage_args`)
_PLACEHOLDER = "<best checkpoint of "


class CurriculumError(ValueError):
    """A user-facing problem with an experiment file or a stage (printed without a traceback)."""


# --------------------------------------------------------------------------- experiment files
def _merge(base: Any, over: Any) -> Any:
    if isinstance(base, dict) and isinstance(over, dict):
        out = dict(base)
        for k, v in over.items():
            out[k] = _merge(base.get(k), v) if k in base else v
        return out
    return over


def load_experiment(path: str | Path) -> dict[str, Any]:
    """Read an experiment YAML (following ``extends``) and check its structure. Without a ``root`` in any file of
    the chain, the runs go to ``runs/<this file's stem>``: an experiment that extends another without naming its
    own root does not write into the other's run folder.

    Raises:
        CurriculumError: naming the file and the problem.
    """
    path = Path(path)
    cfg = _load_chain(path, ())
    cfg.setdefault("root", f"runs/{path.stem}")
    _check(cfg, path)
    return cfg


def _load_chain(path: Path, seen: tuple[Path, ...], by: Path | None = None) -> dict[str, Any]:
    """One experiment file merged over the files it ``extends`` (``by``: the file that extends this one, named
    when this one is missing); each file's own keys are checked here, the merged whole by ``_check``."""
    if not path.is_file():
        if by is not None:
            raise CurriculumError(f"experiment config {by}: 'extends' {path.name}: no such file ({path})")
        raise CurriculumError(f"experiment config {path}: no such file")
    if path.resolve() in seen:
        raise CurriculumError(f"experiment config {path}: 'extends' cycle {[str(p) for p in seen]}")
    try:
        cfg = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        # on one line: YAML's message spans 6-8 lines and calls the file "<unicode string>"
        where = " ".join(str(exc).replace('"<unicode string>"', path.name).split())
        raise CurriculumError(f"experiment config {path}: invalid YAML ({where})") from exc
    if not isinstance(cfg, dict):
        raise CurriculumError(f"experiment config {path}: expected a mapping at the top level")
    unknown = set(cfg) - _TOP_KEYS
    if unknown:
        raise CurriculumError(
            f"experiment config {path}: unknown key(s) {sorted(unknown)}; allowed {sorted(_TOP_KEYS)}"
        )
    if cfg.get("extends") is not None and not isinstance(cfg["extends"], str):
        raise CurriculumError(f"experiment config {path}: 'extends' must be a file name, got {cfg['extends']!r}")
    if cfg.get("extends"):
        parent = _load_chain(path.parent / cfg["extends"], seen + (path.resolve(),), path)
        cfg = _merge(parent, {k: v for k, v in cfg.items() if k != "extends"})
    return cfg


def _as_list(value: Any, where: str) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [value]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise CurriculumError(f"{where}: expected a list of file names, got {value!r}")
    return list(value)


def _check(cfg: dict[str, Any], path: Path) -> None:
    """Check the types of the top-level fields and of every stage (the runner assumes them): errors name the file,
    the stage and the field."""
    where = f"experiment config {path}"
    _check_root(cfg.get("root"), where, optional=False)
    _check_common(cfg, where)
    for key in ("data", "trainer"):
        _as_list(cfg.get(key), f"{where}: '{key}'")
    stages = cfg.get("stages")
    if not isinstance(stages, list) or not stages:
        raise CurriculumError(f"{where}: 'stages' must be a non-empty list")
    names: list[str] = []
    for i, st in enumerate(stages):
        _check_stage(st, f"{where}: stage {i}", names)
        names.append(st["name"])
    _check_folders(cfg, Path(cfg["root"]), where)


def _check_folders(cfg: dict[str, Any], root: Path, where: str) -> None:
    """No two stages share or nest their folders under run folder ``root`` (checked again for the one a run uses:
    ``--root`` or the ``--extra-config`` suffix moves the stages without their own ``root``)."""
    # each stage keeps its record in its folder: two stages in one folder overwrite each other's and always rerun
    stages = cfg["stages"]
    dirs = [(st["name"], stage_dir(cfg, st, root).resolve()) for st in stages]
    for i, (a, da) in enumerate(dirs):
        for b, db in dirs[i + 1 :]:
            if da == db or da.is_relative_to(db) or db.is_relative_to(da):
                raise CurriculumError(
                    f"{where}: stages {a!r} and {b!r} share a folder ({da} and {db}); give each its own"
                )


def _check_root(root: Any, where: str, optional: bool) -> None:
    """``root`` is a directory path (a stage may leave it out: ``<root>/<name>``)."""
    if not isinstance(root, str) and not (optional and root is None):
        raise CurriculumError(f"{where}: 'root' must be a directory path, got {root!r}")


def _check_common(entry: dict[str, Any], where: str) -> None:
    """The fields a stage shares with the top level: ``model`` file names, ``overrides`` a mapping of config
    keys."""
    _as_list(entry.get("model"), f"{where}: 'model'")
    _check_mapping(entry.get("overrides"), f"{where}: 'overrides'", "key -> value")


def _check_mapping(value: Any, where: str, shape: str) -> None:
    """``value`` is absent or a mapping with text keys (config keys such as ``trainer.max_epochs``)."""
    if value is not None and (not isinstance(value, dict) or not all(isinstance(k, str) for k in value)):
        raise CurriculumError(f"{where} must be a mapping {shape}, got {value!r}")


def _check_stage(st: Any, where: str, earlier: list[str]) -> None:
    """One stage: a unique text ``name``, known keys, and fields of the types the runner uses."""
    if not isinstance(st, dict) or not st.get("name"):
        raise CurriculumError(f"{where}: every stage needs a 'name'")
    if not isinstance(st["name"], str):
        raise CurriculumError(f"{where}: 'name' must be a text (the stage directory), got {st['name']!r}")
    where = f"{where} ({st['name']})"
    unknown = set(st) - _STAGE_KEYS
    if unknown:
        raise CurriculumError(f"{where}: unknown key(s) {sorted(unknown)}; allowed {sorted(_STAGE_KEYS)}")
    if st["name"] in earlier:
        raise CurriculumError(f"{where}: duplicate stage name {st['name']!r}")
    _check_root(st.get("root"), where, optional=True)
    _check_common(st, where)
    _as_list(st.get("configs"), f"{where}: 'configs'")
    check_flag("'shared'", st.get("shared", True), owner=where, error=CurriculumError)
    _check_tasks(st.get("tasks"), where)
    _check_mapping(st.get("from_stages"), f"{where}: 'from_stages'", "init-arg key -> earlier stage name")
    for key, ref in (st.get("from_stages") or {}).items():
        if ref not in earlier:
            raise CurriculumError(f"{where}: from_stages {key}: {ref!r} is not an earlier stage (earlier: {earlier})")


def _check_tasks(tasks: Any, where: str) -> None:
    """``tasks`` is absent or a non-empty list of benchmark task names: a typo in a later stage failed only when the
    data module was built, after the earlier stages trained."""
    if tasks is None:
        return
    if not isinstance(tasks, list) or not all(isinstance(t, str) for t in tasks):
        raise CurriculumError(f"{where}: 'tasks' must be a list of task names, got {tasks!r}")
    from floaff_zoo.contract import TASKS
    from floaff_zoo.data.readers import check_names

    try:
        check_names("tasks", tasks, TASKS)  # the data module's own check, before any stage trains
    except ValueError as exc:
        raise CurriculumError(f"{where}: 'tasks': {exc}") from exc


# --------------------------------------------------------------------------- fit arguments
def _value(v: Any) -> str:
    """A CLI value: scalars as text, lists/dicts as JSON (jsonargparse parses both)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return "null"
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    return str(v)


def _flags(overrides: dict[str, Any] | None) -> list[str]:
    out: list[str] = []
    for k, v in (overrides or {}).items():
        out += [f"--{k.lstrip('-')}", _value(v)]
    return out


def parse_sets(items: list[str] | None) -> list[str]:
    """``["trainer.max_epochs=1", ...]`` -> ``["--trainer.max_epochs", "1", ...]``."""
    out: list[str] = []
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CurriculumError(f"--set {item!r}: expected key=value, e.g. trainer.max_epochs=1")
        out += [f"--{key.strip().lstrip('-')}", value]
    return out


def stage_dir(cfg: dict[str, Any], stage: dict[str, Any], root: Path) -> Path:
    return Path(stage["root"]) if stage.get("root") else root / stage["name"]


def build_stage_args(
    cfg: dict[str, Any],
    stage: dict[str, Any],
    root: Path,
    best: dict[str, str],
    extra_configs: list[str] | None = None,
    sets: list[str] | None = None,
) -> list[str]:
    """The ``fit`` argument list of one stage (without ``--ckpt_path``)."""
    shared = stage.get("shared", True)
    files = _as_list(cfg.get("data"), "data")
    files += (
        _as_list(stage.get("model"), f"stage {stage['name']}: model")
        if stage.get("model")
        else (_as_list(cfg.get("model"), "model") if shared else [])
    )
    files += _as_list(cfg.get("trainer"), "trainer") + _as_list(stage.get("configs"), f"stage {stage['name']}: configs")
    args = ["fit"]
    for f in files:
        args += ["--config", f]
    if shared:
        args += _flags(cfg.get("overrides"))
    args += _flags(stage.get("overrides"))
    if shared:  # after the overrides: jsonargparse applies arguments in order, so these files win
        for f in extra_configs or []:
            args += ["--config", f]
    if stage.get("tasks"):
        args += ["--data.init_args.tasks", json.dumps(list(stage["tasks"]))]
    for key, ref in (stage.get("from_stages") or {}).items():
        args += [f"--{key.lstrip('-')}", best.get(ref, f"{_PLACEHOLDER}{ref}>")]
    args += list(sets or [])
    args += ["--trainer.default_root_dir", str(stage_dir(cfg, stage, root))]
    return args


# --------------------------------------------------------------------------- running
def _sha256(path: str | Path) -> str:
    from floaff_zoo.hub.registry import sha256_file

    return sha256_file(Path(path))


#: the kind of each field a stage record (``stage.json``) or a run mark (``curriculum_run.json``) may hold; null is
#: allowed for every field (records of older runners lack some)
_RECORD_FIELDS: dict[str, tuple[type, ...]] = {
    "stage": (str,),
    "status": (str,),
    "args": (list,),
    "digest": (str,),
    "checkpoint": (str,),
    "sha256": (str,),
    "before": (list,),
    "inputs": (dict,),
    "fit_ended": (bool,),
    "shared": (bool,),
    "runs": (list,),
    "started": (float, int),  # a time.time(): compared with checkpoint mtimes (_mark_shared)
}
#: how a kind of ``_RECORD_FIELDS`` is named in an error
_KIND_TEXT = {list: "a list of strings", float: "a number", int: "a number"}


def _read_json(path: Path, fields: dict[str, tuple[type, ...]] | None = None) -> dict[str, Any] | None:
    """A record this runner wrote (None when absent). Records are written atomically, so a file that does
    not parse was damaged by something else: an error naming it, never a silent fresh start. ``fields``: the
    kinds the record's fields must have (a wrong one is named, not met later as a TypeError)."""
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: invalid JSON, or bytes that are no UTF-8
        raise CurriculumError(f"{path}: corrupt curriculum record ({exc}); fix or delete it") from exc
    if not isinstance(record, dict):
        raise CurriculumError(f"{path}: expected a JSON object, got {type(record).__name__}; fix or delete it")
    for key, kinds in (fields or {}).items():
        value = record.get(key)
        bad = value is not None and not isinstance(value, kinds)
        if not bad and isinstance(value, list):
            bad = not all(isinstance(v, str) for v in value)
        if bad:
            want = " or ".join(dict.fromkeys(_KIND_TEXT.get(k, f"a {k.__name__}") for k in kinds))
            raise CurriculumError(f"{path}: field {key!r} is {json.dumps(value)[:40]}, not {want}; fix or delete it")
    return record


def read_lineage(root: str | Path, finished: bool = True) -> dict[str, Any]:
    """``<root>/lineage.json`` of a curriculum run; with ``finished`` (default) only of one whose every stage
    finished (the runner rewrites the file after each stage, so a run killed in a later stage leaves the earlier
    stages alone there, marked ``"complete": false``; files of older runners carry no mark and are accepted).

    Raises:
        CurriculumError: the file is missing, corrupt, has no ``stages`` list, or (``finished``) is the record
        of an unfinished run (names the file).
    """
    path = Path(root) / LINEAGE_FILE
    lineage = _read_json(path)
    if lineage is None:
        raise CurriculumError(f"{path}: no lineage record; run the curriculum first")
    if not isinstance(lineage.get("stages"), list) or not lineage["stages"]:
        raise CurriculumError(f"{path}: 'stages' must be a non-empty list of stage records")
    if finished and lineage.get("complete") is False:
        done = [s.get("stage") for s in lineage["stages"] if isinstance(s, dict)]
        raise CurriculumError(
            f"{path}: the curriculum did not finish (stages done: {', '.join(map(str, done))}); run it again to "
            "finish it"
        )
    return lineage


def _write_json(path: Path, data: dict[str, Any]) -> None:
    """A curriculum record (indent 2, keys in the order written) replaced whole: a kill never leaves half a record,
    and two runners writing one record never share a temp file. Not fsynced, as before: a record a power cut
    empties is named as corrupt by :func:`_read_json`."""
    atomic_write_json(path, data, indent=2, sort_keys=False)


def _finished(record: dict[str, Any] | None, args: list[str], inputs: dict[str, str]) -> tuple[bool, str]:
    """Whether ``record`` is a finished fit of ``args`` whose ``inputs`` (:func:`_input_files`, computed once per
    stage: it hashes the input files) and checkpoint are unchanged; (False, why) otherwise."""
    if not record or record.get("status") != "done":
        return False, "not finished"
    if record.get("args") != args:
        return False, "its fit arguments changed since it finished"
    # records written before digests were kept have none: their arguments alone decide, as they did
    if record.get("digest") and record["digest"] != _digest(args):
        return False, "a --config file it reads changed since it finished"
    # records written before input files were kept have none: their arguments and --config files decide, as they did
    changed = record.get("inputs") is not None and _changed_input(record["inputs"], inputs)
    if changed:
        return False, f"{_input_text(changed)} changed since it finished"
    ckpt = record.get("checkpoint")
    if not ckpt or not Path(ckpt).is_file():
        return False, f"its checkpoint {ckpt} is missing"
    if record.get("sha256") and _sha256(ckpt) != record["sha256"]:
        return False, f"its checkpoint {ckpt} changed (sha256 mismatch)"
    return True, ""


#: arguments naming files of these kinds are inputs whose content a finished stage depends on (an earlier stage's
#: checkpoint as teacher or weights, a label file): a stage re-fit into the same path leaves the arguments unchanged
INPUT_SUFFIXES = (".ckpt", ".safetensors", ".pt", ".pth", ".npz")


def _input_files(args: list[str], fingerprints: dict[str, str] | None = None) -> dict[str, str]:
    """{path: sha256} of every existing file of an ``INPUT_SUFFIXES`` kind that a fit argument names, or that a value
    in one of its ``--config`` files names (e.g. ``data.init_args.train_labels``, an ``.npz`` a script regenerates),
    and {``<data root>/``: fingerprint} of the data folder the fit reads (:func:`floaff_zoo.runs.data_fingerprint`).

    ``fingerprints``: {``<data root>/``: fingerprint} of the folders already walked in this curriculum run, filled
    here: the stages of a curriculum mostly read one folder, which a fit does not change (its sample cache is hidden),
    so each is walked once per run, not once per stage. Not kept across runs: the data may be generated again. Data
    generated again during a run is recorded as the run first saw it: the next run finds the change and fits again."""
    named = list(args) + [v for f in config_values(args) for v in _yaml_strings(f)]
    files = {a: _sha256(a) for a in dict.fromkeys(named) if a.endswith(INPUT_SUFFIXES) and Path(a).is_file()}
    root, bench = _data_value(args, "root"), _data_value(args, "benchmark")
    if root is not None and Path(root).is_dir():
        # the benchmark's folder when the arguments name one there: the other benchmark generated into the same
        # root is not what the stage trains on
        folder = Path(root, bench) if bench and Path(root, bench).is_dir() else Path(root)
        key = folder.as_posix().rstrip("/") + "/"
        seen = {} if fingerprints is None else fingerprints
        if key not in seen:
            seen[key] = data_fingerprint(folder)
        files[key] = seen[key]
    return files


def _changed_input(recorded: dict[str, str] | None, now: dict[str, str]) -> str | None:
    """The first input file whose sha256 differs between ``recorded`` and ``now`` (None: none, or nothing was
    recorded, as by older runners). Records written before data folders were kept (no key ending in ``/``) are
    compared on their files only, as they were."""
    if recorded is None:
        return None
    if not any(k.endswith("/") for k in recorded):
        now = {k: v for k, v in now.items() if not k.endswith("/")}
    changed = sorted(f for f in set(now) | set(recorded) if now.get(f) != recorded.get(f))
    return changed[0] if changed else None


def _input_text(key: str) -> str:
    """How a changed input of :func:`_input_files` is named in a message."""
    return f"its data folder ({key})" if key.endswith("/") else f"a file its arguments name ({key})"


def _data_value(args: list[str], key: str) -> str | None:
    """The ``data.init_args.<key>`` a fit's arguments give (a text value), the last setting winning as in the CLI:
    a ``--config`` file's ``data: {init_args: {<key>: ...}}`` (or ``data: {<key>: ...}``) or a
    ``--data.init_args.<key>`` flag."""
    value = None
    for i, arg in enumerate(args):
        config = config_value(args, i)
        if config is not None and is_config_file(config):
            value = _yaml_data_value(config, key) or value
        for flag in (f"--data.init_args.{key}", f"--data.{key}"):
            if arg == flag and i + 1 < len(args):
                value = args[i + 1]
            elif arg.startswith(flag + "="):
                value = arg.partition("=")[2]
    return value


def _yaml_data_value(path: str, key: str) -> str | None:
    """The data setting ``key`` a ``--config`` file sets (None: it sets none, or it does not parse: the fit reports
    that)."""
    try:
        data = (yaml.safe_load(Path(path).read_text()) or {}).get("data")
    except (OSError, yaml.YAMLError, AttributeError):
        return None
    if not isinstance(data, dict):
        return None
    init = data.get("init_args") if isinstance(data.get("init_args"), dict) else data
    return init.get(key) if isinstance(init.get(key), str) else None


def _yaml_strings(path: str) -> list[str]:
    """Every text value in a YAML file ([] when it is missing or does not parse: the fit reports that). The CLI
    resolves such paths relative to the working directory, as the caller's ``Path(value)`` does."""
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError):
        return []
    out: list[str] = []
    todo = [data]
    while todo:
        item = todo.pop()
        if isinstance(item, str):
            out.append(item)
        elif isinstance(item, dict):
            todo += list(item.values())
        elif isinstance(item, list):
            todo += item
    return out


def _metrics(cli: Any) -> dict[str, float]:
    out = {}
    for k, v in dict(cli.trainer.callback_metrics).items():
        try:
            out[k] = float(v)
        except (TypeError, ValueError):
            continue
    return out


# --------------------------------------------------------------------------- resuming a killed stage
def _digest(args: list[str]) -> str:
    """sha256 of a stage's fit arguments and of its ``--config`` files' contents: a run may be resumed only by a
    stage whose digest is the one recorded for that run."""
    configs = {f: _sha256(f) for f in config_values(args) if is_config_file(f)}
    blob = json.dumps({"args": args, "config_sha256": configs}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _run_dir(ckpt: Path) -> Path:
    """The run directory of a checkpoint: the folder holding its ``checkpoints/``."""
    return ckpt.parent.parent if ckpt.parent.name == "checkpoints" else ckpt.parent


def _run_dirs(sdir: Path) -> set[Path]:
    """The run directories under a stage folder that hold a checkpoint (absolute)."""
    return {_run_dir(p).resolve() for p in sdir.rglob("*.ckpt")} if sdir.is_dir() else set()


def _running_record(name: str, args: list[str], sdir: Path, inputs: dict[str, str]) -> dict[str, Any]:
    """The ``running`` stage record written before a fit: its digest, its input files' sha256 (a killed run is
    resumed only while they are unchanged) and the run directories that existed then (any other one found later was
    written by this fit, see :func:`_claim_runs`)."""
    before = sorted(str(p) for p in _run_dirs(sdir))
    return {
        "stage": name,
        "status": "running",
        "args": args,
        "digest": _digest(args),
        "inputs": inputs,
        "before": before,
    }


def _claim_runs(sdir: Path, record: dict[str, Any] | None) -> None:
    """Write ``RUN_FILE`` (the stage digest, arguments and input files) into every unmarked run directory that the
    fit of a ``running`` record created. A record without ``before`` (an older runner's) claims nothing."""
    if not record or record.get("status") != "running" or "before" not in record or not record.get("digest"):
        return
    mark = {k: record.get(k) for k in ("stage", "digest", "args", "inputs")}
    before = {Path(p) for p in record["before"]}
    runs = _run_dirs(sdir)
    for run in runs - before:
        if not (run / RUN_FILE).is_file():
            _write_json(run / RUN_FILE, mark)
    for run in runs & before:
        _mark_shared(run, mark, record.get("started"))


def _mark_shared(run: Path, mark: dict[str, Any], started: float | None) -> None:
    """Mark a run directory that existed before a fit and that the fit wrote checkpoints into (``trainer.logger:
    false``, or a logger with a fixed version: every fit of the stage writes one folder) as shared when the fit's
    digest or input files are not the ones of the run that made it: its ``last*.ckpt`` may be the other fit's, so
    it is never resumed. ``started``: when the fit started (None, an older runner's record: nothing is marked)."""
    old = _read_json(run / RUN_FILE, _RECORD_FIELDS)
    if started is None or old is None or old.get("shared"):
        return
    # a mark without input files (an older runner's) is judged by its digest, as _resume judges it
    if old.get("digest") == mark["digest"] and not _changed_input(old.get("inputs"), mark["inputs"] or {}):
        return
    if any(p.stat().st_mtime >= started for p in run.rglob("*.ckpt")):
        _write_json(run / RUN_FILE, {**old, "shared": True})


def _run_digest(run: Path) -> str | None:
    """The stage digest recorded in a run directory (None: unknown arguments wrote it, fits with other arguments
    wrote into it too (see :func:`_mark_shared`), or its fit finished: a finished run is never resumed, see
    :func:`_mark_finished`)."""
    mark = _read_json(run / RUN_FILE, _RECORD_FIELDS)
    return mark.get("digest") if mark and not mark.get("fit_ended") and not mark.get("shared") else None


def _shared_run(sdir: Path, digest: str) -> Path | None:
    """An unfinished run directory of this digest that fits with other arguments wrote into too (None: none)."""
    for run in sorted(_run_dirs(sdir)):
        mark = _read_json(run / RUN_FILE, _RECORD_FIELDS) or {}
        if mark.get("shared") and mark.get("digest") == digest and not mark.get("fit_ended"):
            return run
    return None


def _mark_finished(run: Path, record: dict[str, Any]) -> None:
    """Mark a run directory whose fit ended as finished. A stage re-fit because its checkpoint went missing or
    changed, and killed before its first checkpoint, would otherwise resume this run: Lightning trains nothing past
    its last epoch and the stage records whatever file then sits at the old best path."""
    if not run.is_dir():  # deleted since: nothing to resume there
        return
    mark = _read_json(run / RUN_FILE, _RECORD_FIELDS) or {
        "stage": record.get("stage"),
        "digest": record.get("digest"),
        "args": record.get("args"),
    }
    if not mark.get("fit_ended"):
        _write_json(run / RUN_FILE, {**mark, "fit_ended": True})


def _finish_runs(record: dict[str, Any] | None) -> None:
    """Mark the run directories of a ``done`` record finished. They are marked after the record is written (a kill
    in between must not make the next run re-fit a finished fit it cannot see), so every run that reads a ``done``
    record marks them again (nothing to do when they are). Records of older runners name the checkpoint only."""
    if not record or record.get("status") != "done" or not record.get("checkpoint"):
        return
    for run in record.get("runs") or [str(_run_dir(Path(record["checkpoint"])))]:
        _mark_finished(Path(run), record)


def _resume_point(sdir: Path, digest: str) -> Path | None:
    """The newest ``last*.ckpt`` of an unfinished run written with this stage digest (None: nothing to resume)."""
    lasts = [p for p in sdir.rglob("last*.ckpt") if _run_digest(_run_dir(p)) == digest]
    return max(lasts, key=lambda p: p.stat().st_mtime, default=None)


def _same_dir_flags(run: Path) -> list[str] | None:
    """Fit flags that make a resumed fit log and checkpoint into the interrupted run's directory again, so its
    ModelCheckpoint keeps the best of the epochs before the kill (Lightning drops that state when the checkpoint
    directory changes). ``[]``: no logger, the directory does not change; None: the logger cannot be pinned (also
    when the run's ``config.yaml`` is missing or does not read: the resume goes on in a new run directory)."""
    try:
        cfg = yaml.safe_load((run / "config.yaml").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):  # a damaged file: the stage resumes all the same
        return None
    if not isinstance(cfg, dict) or not isinstance(cfg.get("trainer"), dict):
        return None
    logger = cfg["trainer"].get("logger")
    if logger is False:
        return []
    init = logger.get("init_args") if isinstance(logger, dict) and logger.get("class_path") else None
    init = dict(init) if isinstance(init, dict) else {}
    if not init.get("save_dir") or Path(init["save_dir"], str(init.get("name") or ""), run.name).resolve() != run:
        return None
    return ["--trainer.logger", json.dumps({**logger, "init_args": {**init, "version": run.name}})]


def _resume(
    name: str, sdir: Path, record: dict[str, Any] | None, running: dict[str, Any], out: Any
) -> tuple[Path | None, list[str]]:
    """Where a killed stage resumes: (``last.ckpt``, extra fit flags), or (None, []) for a fresh fit. Only a run
    written with the same stage digest (``running``'s) and the same input files is resumed, into its own directory
    when its logger allows."""
    was_running = bool(record) and record.get("status") == "running"
    if was_running:
        _claim_runs(sdir, record)
    # by the runs' own marks: a fit of these arguments killed, then another fit's record put in the folder
    last = _resume_point(sdir, running["digest"])
    if last is None and not was_running:
        return None, []
    shared = _shared_run(sdir, running["digest"]) if last is None else None
    if shared is not None:
        print(
            f"[curriculum] stage {name}: not resuming {shared}: fits with other arguments wrote checkpoints into it "
            "too (trainer.logger false, or a logger with a fixed version), starting a fresh fit",
            file=out,
        )
    elif last is None:
        print(f"[curriculum] stage {name}: no checkpoint of a run with these arguments, starting a fresh fit", file=out)
    if last is None:
        return None, []
    # a teacher/weights checkpoint re-fit into the same path leaves the digest alone: its content decides
    mark = _read_json(_run_dir(last) / RUN_FILE, _RECORD_FIELDS) or {}
    changed = _changed_input(mark.get("inputs"), running["inputs"])
    if changed:
        print(
            f"[curriculum] stage {name}: not resuming {last}: {_input_text(changed)} changed since the killed run "
            "started; starting a fresh fit",
            file=out,
        )
        return None, []
    try:  # a kill while Lightning wrote it can leave it truncated: say how to go on, not only that it does not load
        load_checkpoint(last, keys=("state_dict",))
    except RunError as exc:
        raise CurriculumError(
            f"stage {name}: cannot resume the killed fit: {exc}. Delete that file (its run folder's other files are "
            "kept) and run again: the stage then resumes an earlier killed run of the same arguments if one is left, "
            "else starts afresh; or put a readable copy in its place"
        ) from exc
    flags = _same_dir_flags(_run_dir(last).resolve())
    if flags is None:
        print(
            f"[curriculum] stage {name}: cannot resume into {_run_dir(last)} (its config.yaml names no logger that "
            "can be pinned, or does not read); the stage's best covers the epochs after the resume only",
            file=out,
        )
    return last, flags or []


def _csv_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file ([] when absent)."""
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _write_rows(path: Path, rows: list[dict[str, str]]) -> None:
    """Write rows (duplicates dropped, columns sorted like Lightning's CSVLogger) atomically."""
    unique = list({tuple(sorted(r.items())): r for r in rows}.values())
    keys = sorted({k for r in unique for k in r})
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=keys)
    writer.writeheader()
    writer.writerows(unique)
    atomic_write_text(path, text.getvalue())  # a temp file of its own: two runners never share one


def _keep_metrics(run: Path) -> None:
    """CSVLogger deletes the ``metrics.csv`` of a run directory it logs into again: keep its rows (after those of an
    earlier resume that was killed) in ``KEPT_METRICS`` until the resumed fit ends."""
    rows = _csv_rows(run / KEPT_METRICS) + _csv_rows(run / "metrics.csv")
    if rows:
        _write_rows(run / KEPT_METRICS, rows)


def _restore_metrics(run: Path) -> None:
    """Put the kept rows back in front of the resumed fit's ``metrics.csv``."""
    kept = run / KEPT_METRICS
    if kept.is_file():
        _write_rows(run / "metrics.csv", _csv_rows(kept) + _csv_rows(run / "metrics.csv"))
        kept.unlink()


def _fit_stage(
    name: str,
    stage: dict[str, Any],
    sdir: Path,
    args: list[str],
    inputs: dict[str, str],
    record: dict[str, Any] | None,
    best: dict[str, str],
    runner: Callable[[list[str]], Any],
    out: Any,
) -> tuple[dict[str, Any], Any]:
    """Fit one stage (resuming its killed run when there is one) and write its ``done`` record; returns
    (record, cli)."""
    running = _running_record(name, args, sdir, inputs)
    resume, pin = _resume(name, sdir, record, running, out)
    fit_args = args + pin + (["--ckpt_path", str(resume)] if resume else [])
    print(f"[curriculum] stage {name}: floaff-zoo {shlex.join(fit_args)}", file=out)
    running["started"] = started = time.time()
    _write_json(sdir / STAGE_FILE, running)
    if pin:
        _keep_metrics(_run_dir(resume))
    try:
        cli = runner(fit_args)
    finally:  # a resumed fit killed or failing again keeps every epoch's rows in its metrics.csv too
        if pin:
            _restore_metrics(_run_dir(resume))
    _claim_runs(sdir, running)
    cb = cli.trainer.checkpoint_callback
    ckpt = (cb.best_model_path or cb.last_model_path) if cb is not None else ""
    if not ckpt or not Path(ckpt).is_file():
        why = (
            "it trained no step (trainer.max_epochs / max_steps 0?)"
            if cli.trainer.global_step == 0
            else "enable checkpointing"
        )
        raise CurriculumError(f"stage {name}: the fit wrote no checkpoint ({why})")
    score = getattr(cb, "best_model_score", None)
    record = {
        "stage": name,
        "status": "done",
        "args": args,
        "digest": running["digest"],
        "inputs": running["inputs"],  # as the fit read them: a file rewritten meanwhile is not what it used
        "resumed_from": str(resume) if resume else None,
        "configs": config_values(args),
        "tasks": stage.get("tasks"),
        "from_stages": {k: best.get(ref) for k, ref in (stage.get("from_stages") or {}).items()},
        "checkpoint": str(ckpt),
        "sha256": _sha256(ckpt),
        "runs": sorted({str(_run_dir(Path(p))) for p in (ckpt, cb.last_model_path) if p}),
        "monitor": getattr(cb, "monitor", None),
        "best_score": float(score) if score is not None else None,
        "metrics": _metrics(cli),
        "started": started,
        "finished": time.time(),
    }
    _write_json(sdir / STAGE_FILE, record)
    _write_json(sdir / _digest_file(record["digest"]), record)
    _finish_runs(record)  # after the record: a kill before it leaves a killed run, resumed (trains nothing more)
    return record, cli


def _digest_file(digest: str) -> str:
    """The name of a finished stage's record kept by its digest, beside ``STAGE_FILE`` (see :func:`_reusable`)."""
    return f"stage.{digest[:16]}.json"


def _reusable(
    sdir: Path, args: list[str], record: dict[str, Any] | None, inputs: dict[str, str]
) -> tuple[dict[str, Any] | None, str]:
    """The finished record of a stage with these fit arguments: ``STAGE_FILE``'s, or else one kept by its digest.

    A stage folder shared by experiments (``root:``, e.g. one AxisNet for several curricula) holds one
    ``STAGE_FILE``, the last fit's; a fit made with other arguments (another experiment's ``--set``) replaced it, and
    the earlier fit, still on disk, would be re-fit. Returns (record, "") when one is finished, else (None, why)."""
    done, why = _finished(record, args, inputs)
    if done:
        return record, ""
    kept = _read_json(sdir / _digest_file(_digest(args)), _RECORD_FIELDS)
    if kept is not None and kept != record and _finished(kept, args, inputs)[0]:
        return kept, ""
    return None, why


def _check_config_files(cfg: dict[str, Any], config: str | Path, extra: list[str]) -> None:
    """Every ``--config`` file a stage reads exists, in a dry run too (it printed commands that cannot run, exit 0):
    the ``--extra-config`` and top-level files first, then each stage's own."""
    where = f"(paths are relative to {Path.cwd()})"
    for f in extra + [f for key in ("data", "model", "trainer") for f in _as_list(cfg.get(key), key)]:
        if not is_config_file(f):
            raise CurriculumError(f"{config}: config file {f} does not exist {where}")
    for stage in cfg["stages"]:
        for f in config_values(build_stage_args(cfg, stage, Path(cfg["root"]), {}, extra)):
            if not is_config_file(f):
                raise CurriculumError(f"{config}: stage {stage['name']}: config file {f} does not exist {where}")


def _check_stages(cfg: dict[str, Any], root: Path, extra: list[str], flags: list[str]) -> None:
    """Parse every stage's ``fit`` arguments before the first stage trains, so a typo in a later stage's overrides
    (or an ``--extra-config`` key no model accepts) fails in seconds, not after the earlier stages trained; the
    checkpoints of earlier stages are placeholders here. The other ``WEIGHT_ARGS`` files and hub names are checked
    (:func:`_check_weights_value`)."""
    from floaff_zoo.cli import CLIError, check_trainer_args
    from floaff_zoo.models.cfar import distills

    for stage in cfg["stages"]:
        try:
            parsed = check_trainer_args(build_stage_args(cfg, stage, root, {}, extra, flags))
        except CLIError as exc:
            raise CurriculumError(f"stage {stage['name']}: its fit arguments do not parse: {exc}") from exc
        model = parsed.get("model")
        init = model.get("init_args") if hasattr(model, "get") else None
        for key in WEIGHT_ARGS if hasattr(init, "get") else ():
            value = init.get(key)
            # a teacher is read only while distilling: w/o FD need not name an existing file
            reads = key != "teacher" or distills(value, init.get("use_fd", True), init.get("distill_weight") or 0)
            if isinstance(value, str) and not value.startswith(_PLACEHOLDER) and reads:
                _check_weights_value(f"stage {stage['name']}: model.init_args.{key}", value)


def _check_weights_value(where: str, value: str) -> None:
    """A ``WEIGHT_ARGS`` value names an existing file or folder, or a registered hub name; a torch file is also read
    (memory-mapped, tensors untouched): a truncated or text file is named here, not in the fit's setup."""
    from floaff_zoo.hub.io import looks_like_path
    from floaff_zoo.hub.registry import HubError, get_entry

    path = Path(value).expanduser()
    if path.is_file() and path.suffix in (".ckpt", ".pt", ".pth"):
        try:
            load_checkpoint(path)
        except RunError as exc:
            raise CurriculumError(f"{where}: {exc}") from exc
    elif path.exists():
        return
    elif looks_like_path(value):
        raise CurriculumError(f"{where} {value}: no such file or directory (paths are relative to {Path.cwd()})")
    else:
        try:
            get_entry(value)
        except HubError as exc:
            raise CurriculumError(f"{where}: {exc}") from exc


def run_curriculum(
    config: str | Path,
    root: str | Path | None = None,
    sets: list[str] | None = None,
    extra_configs: list[str] | None = None,
    dry_run: bool = False,
    runner: Callable[[list[str]], Any] | None = None,
    on_stage_end: Callable[[str, Any], None] | None = None,
    out: Any = None,
) -> list[dict[str, Any]]:
    """Run (or print) every stage of an experiment; returns the lineage records.

    Args:
        config: experiment YAML; root: run directory override (default: the file's ``root``, with the
            stems of ``extra_configs`` appended so e.g. each crop-radius sweep point gets its own run);
        sets: ``key=value`` overrides for every stage; extra_configs: extra ``--config`` files for
            every shared stage; dry_run: print the fit commands only (parsed first, as a run parses them);
            runner: the fit function (default ``floaff_zoo.cli.run_lightning``); on_stage_end: ``(stage name,
            cli)`` hook.
    """
    out = out or sys.stdout
    cfg = load_experiment(config)
    extra = list(extra_configs or [])
    _check_config_files(cfg, config, extra)
    if root is None:
        root = cfg["root"] + ("__" + "+".join(Path(f).stem for f in extra) if extra else "")
    root = Path(root)
    if root != Path(cfg["root"]):
        _check_folders(cfg, root, f"experiment config {config} (run folder {root})")
    flags = parse_sets(sets)
    default_runner = runner is None
    if runner is None:
        from floaff_zoo.cli import run_lightning

        runner = run_lightning
    if default_runner:  # a dry run too: the commands it prints must be ones that run
        _check_stages(cfg, root, extra, flags)
    lineage_path = root / LINEAGE_FILE
    if not dry_run:  # a damaged lineage of an earlier run is reported, not silently replaced
        earlier = _read_json(lineage_path)
        try:  # an unwritable --root fails here in one line, not as a traceback in the first stage
            root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CurriculumError(f"--root {root}: cannot create the run folder ({exc})") from exc
        if earlier is not None and earlier.get("complete"):
            # until this run has checked every stage, the earlier lineage may name checkpoints being re-fit
            _write_json(lineage_path, {**earlier, "complete": False})
    lineage = {
        "experiment": str(config),
        "root": str(root),
        "extra_configs": extra,
        "sets": list(sets or []),
        "complete": False,  # true once the last stage is in: a run killed before that leaves false
        "stages": [],
    }
    best: dict[str, str] = {}
    fingerprints: dict[str, str] = {}  # data folder -> fingerprint, walked once per run (see _input_files)
    for stage in cfg["stages"]:
        name = stage["name"]
        sdir = stage_dir(cfg, stage, root)
        args = build_stage_args(cfg, stage, root, best, extra, flags)
        if dry_run:
            print(f"# stage {name}\nfloaff-zoo {shlex.join(args)}", file=out)
            best[name] = f"{_PLACEHOLDER}{name}>"
            continue
        with _stage_lock(name, sdir, out):
            record = _read_json(sdir / STAGE_FILE, _RECORD_FIELDS)
            _finish_runs(record)  # a kill right after writing it left its runs unmarked
            inputs = _input_files(args, fingerprints)  # once per stage: it hashes the input files
            finished, why = _reusable(sdir, args, record, inputs)
            if finished is not None:
                if finished is not record:  # an earlier fit with these arguments: it becomes the folder's record
                    _finish_runs(finished)  # (the runner that replaced its record marked them; an older one did not)
                    _claim_runs(sdir, record)  # a killed fit's running record goes: its runs keep its digest
                    _write_json(sdir / STAGE_FILE, finished)
                record = finished
                print(f"[curriculum] stage {name}: already finished ({record['checkpoint']}), skipping", file=out)
            else:
                if record and record.get("status") == "done":
                    print(f"[curriculum] stage {name}: rerunning, {why}", file=out)
                try:
                    record, cli = _fit_stage(name, stage, sdir, args, inputs, record, best, runner, out)
                except Exception as exc:
                    exc.curriculum_stage = name  # main names the stage in its one-line error
                    raise
                if on_stage_end is not None:
                    on_stage_end(name, cli)
        best[name] = record["checkpoint"]
        lineage["stages"].append(record)
        lineage["complete"] = len(lineage["stages"]) == len(cfg["stages"])
        _write_json(lineage_path, lineage)
    return lineage["stages"]


#: lock file of a stage folder, held while a curriculum reads, fits and records that stage
STAGE_LOCK = ".stage.lock"


@contextlib.contextmanager
def _stage_lock(name: str, sdir: Path, out: Any) -> Iterator[None]:
    """Hold the stage folder's lock: two curricula sharing a stage (the AxisNet folder of every Layouts experiment)
    fitted it twice at once, and each tagged the other's live run as its own. The second waits, then finds the stage
    finished. DDP worker processes (a nonzero LOCAL_RANK / NODE_RANK: Lightning's launcher re-runs the command in
    them) take no lock: rank 0 of the same run holds it."""
    if any(_rank(k) > 0 for k in ("LOCAL_RANK", "NODE_RANK")):
        yield
        return
    message = f"[curriculum] stage {name}: another curriculum is working on {sdir}; waiting for it"
    with folder_lock(sdir / STAGE_LOCK, on_wait=lambda: print(message, file=out)):
        yield


def _rank(variable: str) -> int:
    """The launcher's rank in environment ``variable`` (0 when unset or empty); a non-number is named."""
    value = os.environ.get(variable, "").strip()
    try:
        return int(value or 0)
    except ValueError:
        raise CurriculumError(f"environment variable {variable}={value!r}: not a whole-number rank") from None


def _fit_errors() -> tuple[type[BaseException], ...]:
    """The user errors ``floaff-zoo fit`` prints in one line (``floaff_zoo.cli.main``), imported only when an
    exception reaches :func:`main`."""
    from floaff_zoo.cli import USER_ERRORS

    return USER_ERRORS


def main(argv: list[str] | None = None, *, raise_errors: bool | None = None) -> int:
    """``floaff-zoo curriculum --config <experiment.yaml> [--root DIR] [--set k=v ...] [--extra-config F ...]
    [--dry-run]``.

    A ``CurriculumError``, and a user error of a stage's fit (``floaff-zoo fit``'s one-line kinds: a value a class
    rejects, a diverged loss...; the line names the stage), is printed in one line; then it is raised when
    ``raise_errors`` (default: when ``argv`` is given, i.e. a Python caller), else exit code 2 is returned (the
    console: ``floaff-zoo`` passes False).
    """
    parser = argparse.ArgumentParser(
        prog="floaff-zoo curriculum",
        description="Run a PFAL curriculum: one `floaff-zoo fit` per stage, chained by best checkpoints.",
    )
    parser.add_argument("--config", required=True, help="experiment YAML (e.g. configs/experiments/pfal_layouts.yaml)")
    parser.add_argument(
        "--root",
        default=None,
        help="run directory (default: the experiment's 'root', with '__<stems of the --extra-config files>' appended)",
    )
    parser.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override for every stage, e.g. trainer.max_epochs=1 (repeatable)",
    )
    parser.add_argument(
        "--extra-config",
        dest="extra",
        action="append",
        default=[],
        metavar="FILE",
        help="extra --config file for every shared stage, e.g. an ablation or sweep file (repeatable)",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="check every stage's fit arguments, print the fit commands and exit"
    )
    ns = parser.parse_args(argv)
    try:
        run_curriculum(ns.config, ns.root, ns.sets, ns.extra, ns.dry_run)
    except (CurriculumError, *_fit_errors()) as exc:
        stage = getattr(exc, "curriculum_stage", None)
        where = f"stage {stage}: " if stage and not isinstance(exc, CurriculumError) else ""
        print(f"floaff-zoo curriculum: error: {where}{exc}", file=sys.stderr)
        if raise_errors or (raise_errors is None and argv is not None):
            raise
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
