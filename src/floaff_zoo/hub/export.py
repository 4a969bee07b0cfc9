"""Export a training run's checkpoint as a hub entry (safetensors + config.json + model card).

Layout written by :func:`export_checkpoint` (also a valid Hugging Face model repo)::

    <hub dir>/<name>/
        <name>-<sha256[:8]>.safetensors   weights (teacher.* dropped), config in the header too
        config.json                       class_path, init_args, weights, sha256, metrics, meta
        README.md                         model card
    <hub dir>/index.json                  user index, entry registered with source {"kind": "local"}

:func:`save_model_dir` (``model.save_pretrained(directory)``) writes the same format for a model in
memory, unregistered: ``config.json`` + ``model.safetensors``.
"""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from floaff_zoo.atomic import atomic_write_text, publish
from floaff_zoo.hub.io import (
    CONFIG_NAME,
    DEFAULT_WEIGHTS_NAME,
    SAFETENSORS_META_KEY,
    TEACHER_PREFIX,
    import_model_class,
    load_model,
    looks_like_path,
)
from floaff_zoo.hub.registry import (
    NON_PORTABLE_ARGS,
    SHIPPED_INDEX,
    HubEntry,
    HubError,
    RegistryFormatError,
    check_name,
    hub_dir,
    is_offline,
    read_index,
    read_retired,
    register,
    sha256_file,
    unique_filename,
    user_index_path,
)
from floaff_zoo.runs import RunError, load_failure_reason, resolve_ckpt_alias


def find_run_checkpoint(run: str | os.PathLike[str]) -> Path:
    """A ``.ckpt``/``.pth`` file as given; for a run directory its best checkpoint, like the CLI's ``best``.

    ``best`` = the ModelCheckpoint ``best_model_path`` recorded in the newest ``last.ckpt``, else that
    ``last.ckpt``.
    """
    p = Path(run).expanduser()
    if p.is_file():
        if p.suffix not in (".ckpt", ".pth", ".pt"):
            raise HubError(f"{p}: push takes a run directory or a .ckpt file, not {p.suffix or 'this file'}")
        return p
    if not p.is_dir():
        raise FileNotFoundError(f"{p}: no such run directory or checkpoint file")
    try:
        return Path(resolve_ckpt_alias("best", p))
    except RunError as exc:
        # the lookup is the CLI's ``best``: its message says whether last.ckpt is missing or unreadable, and names it
        raise HubError(f"{p}: no checkpoint to push ({exc}); pass a .ckpt file instead") from exc


#: suffixes of the files whose sha256 a report's ``checkpoint`` can be compared with (weights files, exported
#: folders and hub names hash other bytes than the .ckpt being pushed)
CKPT_SUFFIXES = (".ckpt", ".pth", ".pt")


def _report_metrics(
    ckpt_path: Path, run: Path | None, report: Path | None = None, cls: type | None = None
) -> dict[str, float]:
    """Numbers from a ``report.json`` (its ``metrics`` object, else its top-level numbers): ``report`` when
    given, else the first one in the run, checkpoint or run-version directory.

    A report must be of the pushed checkpoint (``_report_mismatch``): a given one that is not is refused, a found
    one is left out with a warning (the next candidate, else the best validation score, is used instead).
    """
    if report is not None and not report.is_file():
        raise HubError(f"{report}: no such report file")
    dirs = [d for d in (run, ckpt_path.parent, ckpt_path.parent.parent) if d is not None and d.is_dir()]
    candidates = [report] if report is not None else [d / "report.json" for d in dirs]
    ckpt_sha = functools.cache(lambda: sha256_file(ckpt_path))  # hashed once, and only if a report records one
    for path in candidates:
        if path.is_file():
            try:
                raw = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:  # ValueError: invalid JSON, or bytes that are no UTF-8
                raise HubError(f"{path}: unreadable report ({exc})") from exc
            problem = _report_mismatch(raw, ckpt_path, cls, ckpt_sha)
            if problem and report is not None:
                raise HubError(
                    f"{path}: its metrics cannot be recorded for {ckpt_path}: {problem}; pass the report.json of "
                    f"`floaff-zoo test ... --ckpt_path {ckpt_path}`, or push without --report"
                )
            if problem:
                warnings.warn(f"{path}: left out of the metrics pushed for {ckpt_path}: {problem}", stacklevel=3)
                continue
            src = raw.get("metrics", raw) if isinstance(raw, dict) else {}
            if not isinstance(src, dict):
                src = {}
            return {
                k: float(v)
                for k, v in src.items()
                if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))
            }
    return {}


def _report_mismatch(
    raw: Any, ckpt_path: Path, cls: type | None, ckpt_sha: Callable[[], str] | None = None
) -> str | None:
    """Why a parsed report is not of the checkpoint ``ckpt_path`` of class ``cls``; None when nothing says so.
    ``ckpt_sha``: the checkpoint's sha256 (a memoised call, so several candidate reports hash the file once).

    Only a positive mismatch counts: a report without a checkpoint (weights tested as trained), or one of weights
    given by a hub name, an exported folder or a weights file (their sha256 is not the .ckpt's), is not refused.
    """
    if not isinstance(raw, dict):
        return f"it is a JSON {type(raw).__name__}, not a report object"
    checkpoint, model = raw.get("checkpoint"), raw.get("model")
    for field, value in (("checkpoint", checkpoint), ("model", model)):
        if value is not None and not isinstance(value, dict):
            return f"its {field!r} field is a {type(value).__name__}, not an object or null"
    checkpoint, model = checkpoint or {}, model or {}
    recorded, where = checkpoint.get("sha256"), checkpoint.get("path")
    for field, value in (
        ("checkpoint.sha256", recorded),
        ("checkpoint.path", where),
        ("model.class_path", model.get("class_path")),
    ):
        if value is not None and not isinstance(value, str):
            return f"its {field!r} field is a {type(value).__name__}, not a string or null"
    problems = []
    if recorded and (where is None or Path(where).suffix in CKPT_SUFFIXES):
        actual = ckpt_sha() if ckpt_sha is not None else sha256_file(ckpt_path)
        if recorded.lower() != actual:
            problems.append(f"it tested checkpoint {where or '?'} with sha256 {recorded}, the pushed one has {actual}")
    class_path = model.get("class_path")
    if class_path and cls is not None and not _same_class(class_path, cls):
        problems.append(f"it tested a {class_path}, the pushed checkpoint holds a {cls.__module__}.{cls.__qualname__}")
    return "; ".join(problems) or None


def _same_class(class_path: str, cls: type) -> bool:
    """Whether ``class_path`` names ``cls`` (a re-export counts; a path that no longer imports is compared by
    the class name, as the report may predate a move of the module)."""
    if class_path == f"{cls.__module__}.{cls.__qualname__}":
        return True
    try:
        return import_model_class(class_path, "report") is cls
    except HubError:
        return class_path.rsplit(".", 1)[-1] == cls.__name__


def _best_score(ckpt_path: Path, ckpt: dict[str, Any], run: Path | None) -> dict[str, float]:
    """``{monitor: best_model_score}`` that a ModelCheckpoint recorded for this very file.

    Looked up in the exported checkpoint itself, then in the run's newest ``last.ckpt`` (which
    knows the final best); a score is used only if its ``best_model_path`` is this file.
    """
    states: list[Any] = [ckpt]
    if run is not None:
        lasts = sorted(run.rglob("last*.ckpt"), key=lambda p: p.stat().st_mtime)
        if lasts and lasts[-1] != ckpt_path:
            try:
                states.append(torch.load(lasts[-1], map_location="cpu", weights_only=True))
            except Exception as exc:  # the score is metadata: the export goes on, the skip is said
                problem = f"not a readable checkpoint ({load_failure_reason(exc)})"
                warnings.warn(f"{lasts[-1]}: {problem}; its best validation score is not recorded", stacklevel=3)
    for state in states:
        callbacks = state.get("callbacks") if isinstance(state, dict) else None
        # a list of callbacks died in .items(), naming no file
        for key, cb in (callbacks if isinstance(callbacks, dict) else {}).items():
            if not (str(key).startswith("ModelCheckpoint") and isinstance(cb, dict)):
                continue
            score, monitor, best = cb.get("best_model_score"), cb.get("monitor"), cb.get("best_model_path")
            if not (monitor and isinstance(best, (str, os.PathLike)) and Path(best).name == ckpt_path.name):
                continue
            value = _finite_score(score)
            if value is not None:
                return {str(monitor): value}
    return {}


def _finite_score(score: Any) -> float | None:
    """A recorded best score as a float: a number or a one-element tensor that is finite, else None (a text or a
    tensor of several values failed in float()/.item(), naming no file)."""
    if isinstance(score, torch.Tensor):
        score = score.item() if score.numel() == 1 else None
    if isinstance(score, bool) or not isinstance(score, (int, float)):
        return None
    return float(score) if math.isfinite(score) else None


def _portable_state(state: dict[str, Any], where: Path, allow_empty: bool = False) -> dict[str, torch.Tensor]:
    """Tensors only, teacher dropped, contiguous private copies (safetensors refuses shared storage).

    ``allow_empty``: a model without weights (training-free, e.g. C2F-Exp) may be saved as its config.
    """
    out = {}
    for k, v in state.items():
        if k.startswith(TEACHER_PREFIX):
            continue
        if not isinstance(v, torch.Tensor):
            raise HubError(f"{where}: state entry {k!r} is a {type(v).__name__}, not a tensor; cannot export")
        out[k] = v.detach().to("cpu").contiguous().clone()
    broken = [k for k, v in out.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if broken:  # a diverged run: refused, not shipped under a name with a hash that vouches for it
        raise HubError(f"{where}: {len(broken)} weight tensor(s) hold NaN or inf, e.g. {broken[:3]}; not exported")
    if not out and not allow_empty:
        raise HubError(f"{where}: the checkpoint holds no (student) weights")
    return out


def _portable_init_args(cls: type, hparams: dict[str, Any], where: Path) -> dict[str, Any]:
    """The init args an export records: today's form (``cls.upgrade_init_args``: old checkpoints hold the
    training args flat), without Lightning's private keys and the args that name other files."""
    args = {k: v for k, v in hparams.items() if not k.startswith("_") and k not in NON_PORTABLE_ARGS}
    args = cls.upgrade_init_args(args)
    try:
        json.dumps(args)
    except TypeError as exc:
        raise HubError(f"{where}: hyper_parameters are not JSON primitives ({exc})") from exc
    return _without_local_paths(args)


def _without_local_paths(value: Any) -> Any:
    """``value`` with every string that names a local file (``runs/.../x.ckpt``, ``/abs/path``) set to None.

    An entry travels to other machines: a path of the exporting machine means nothing there, and a CFAR's
    AxisNet is rebuilt from the recorded ``axisnet_arch`` (its sha256 stays as the lineage), not from a file.
    Hub names (``axisnet.floaff-layouts.v1``) are portable and kept.
    """
    if isinstance(value, dict):
        return {k: _without_local_paths(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_without_local_paths(v) for v in value]
    if isinstance(value, str) and looks_like_path(value):
        return None
    return value


def _write_weights(
    out: Path, state: dict[str, torch.Tensor], header: dict[str, Any], filename: str | Callable[[str], str]
) -> tuple[str, str]:
    """Write ``state`` as safetensors into ``out`` atomically, ``header`` (JSON) in its metadata.

    Args:
        filename: a fixed name, or a function of the file's sha256 (the hub's ``<name>-<sha[:8]>``).
    Returns:
        (file name, sha256).
    """
    from safetensors.torch import save_file

    out.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=".export-", suffix=".safetensors", dir=out)
    os.close(fd)  # safetensors writes by path
    tmp = Path(name)
    try:
        save_file(state, str(tmp), metadata={SAFETENSORS_META_KEY: json.dumps(header)})
        sha = sha256_file(tmp)
        name = filename(sha) if callable(filename) else filename
        publish(tmp, out / name)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return name, sha


def save_model_dir(model: torch.nn.Module, directory: str | os.PathLike[str]) -> Path:
    """``model`` as an exported directory, ``config.json`` + ``model.safetensors`` (``save_pretrained``).

    ``from_pretrained``/``load_model`` read it back (strictly); no checkpoint, run or CLI is needed.
    Returns the directory.
    """
    out = Path(directory).expanduser()
    cls = type(model)
    class_path = f"{cls.__module__}.{cls.__qualname__}"
    init_args = _portable_init_args(cls, dict(getattr(model, "hparams", {})), out)
    state = _portable_state(model.state_dict(), out, allow_empty=True)
    filename, sha = _write_weights(out, state, {"class_path": class_path, "init_args": init_args}, DEFAULT_WEIGHTS_NAME)
    config = {"class_path": class_path, "init_args": init_args, "weights": filename, "sha256": sha}
    # whole or not at all: a save over an earlier one that was killed here left a half config.json
    atomic_write_text(out / CONFIG_NAME, json.dumps(config, indent=2) + "\n")
    return out


def _model_card(entry: HubEntry, metrics: dict[str, float], source_ckpt: str) -> str:
    meta = entry.meta
    lines = [
        "---",
        f"license: {str(meta.get('license', 'other')).lower()}",
        "library_name: floaff-zoo",
        "tags:",
        "- floor-affordance",
        "- point-cloud",
        "- mobile-manipulation",
        "---",
        "",
        f"# {entry.name}",
        "",
        f"`{entry.class_path}` weights for floor-affordance prediction "
        "(where a mobile manipulator should stand to do a task).",
        "",
    ]
    for key in ("dataset", "benchmark", "description"):
        if meta.get(key):
            lines.append(f"- **{key}**: {meta[key]}")
    lines += [
        f"- **weights**: `{entry.filename}` (sha256 `{entry.sha256}`)",
        f"- **exported from**: `{source_ckpt}`",
        "",
        "## Metrics",
        "",
    ]
    if metrics:
        lines += ["| metric | value |", "|---|---|"] + [f"| {k} | {v:.4g} |" for k, v in sorted(metrics.items())]
    else:
        lines.append("No metrics were recorded for this checkpoint.")
    lines += [
        "",
        "## Usage",
        "",
        "```python",
        f"from {entry.class_path.rsplit('.', 1)[0]} import {entry.class_path.rsplit('.', 1)[1]}",
        "",
        f'model = {entry.class_path.rsplit(".", 1)[1]}.from_pretrained("{entry.name}")',
        "```",
        "",
        "or in a config: `model.init_args.weights: " + entry.name + "`.",
        "",
        "## Config",
        "",
        "```json",
        json.dumps({"class_path": entry.class_path, "init_args": entry.init_args}, indent=2),
        "```",
        "",
    ]
    return "\n".join(lines)


def export_checkpoint(
    run_or_ckpt: str | os.PathLike[str],
    name: str,
    directory: str | os.PathLike[str] | None = None,
    class_path: str | None = None,
    meta: dict[str, Any] | None = None,
    report: str | os.PathLike[str] | None = None,
    replace: bool = False,
) -> tuple[HubEntry, Path]:
    """Export a run's best checkpoint into ``<hub dir>/<name>/`` and register it in the user index.

    Args:
        run_or_ckpt: a run directory (best checkpoint found like ``--ckpt_path best``) or a ``.ckpt``.
        name: the hub name, ``model.dataset.vN``.
        directory: hub directory (default ``$FLOAFF_ZOO_HUB``).
        class_path: model class when the checkpoint does not record ``_class_path``.
        meta: extra metadata (dataset, benchmark, license, description); ``metrics`` is filled in.
        report: a ``report.json`` of ``floaff-zoo test`` on this checkpoint whose metrics (map metrics and
            success rates) are recorded; default: one found in the run directory, else the best
            validation score. A report that records another checkpoint (sha256) or model class is
            refused (a found one is left out with a warning).
        replace: push over a name that is taken (see ``check_name_free``).
    Returns:
        (the registered entry, the export directory).
    """
    check_name(name, "push")  # it becomes a folder and file name: checked before anything is written
    read_index(user_index_path(directory))  # a malformed user index fails here too
    if not replace:
        check_name_free(name, directory)
    ckpt_path = find_run_checkpoint(run_or_ckpt)
    run_or_ckpt = Path(run_or_ckpt).expanduser()
    report = Path(report).expanduser() if report is not None else None
    run = run_or_ckpt if run_or_ckpt.is_dir() else None
    ckpt = _read_lightning_checkpoint(ckpt_path)
    hp = dict(ckpt.get("hyper_parameters") or {})
    recorded = hp.pop("_class_path", None)
    if recorded and class_path and class_path != recorded:  # it was ignored without a word
        raise HubError(
            f"{ckpt_path}: --class-path {class_path} differs from the class the checkpoint records ({recorded})"
        )
    cls_path = recorded or class_path
    hp.pop("_instantiator", None)
    if not cls_path:
        raise HubError(f"{ckpt_path}: the checkpoint does not record its model class; pass --class-path")
    cls = import_model_class(cls_path, str(ckpt_path))
    init_args = _portable_init_args(cls, hp, ckpt_path)
    state = _portable_state(ckpt["state_dict"], ckpt_path)
    metrics = _report_metrics(ckpt_path, run, report, cls)
    metrics = metrics or _best_score(ckpt_path, ckpt, run)
    meta = {**(meta or {}), "metrics": metrics}

    root = hub_dir(directory)
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".push-", dir=root))  # beside the entry: renames stay atomic
    try:
        entry = _stage_export(staging, name, cls_path, init_args, state, meta, ckpt_path)
        out = root / name
        _install_export(staging, out, entry, directory, overwrite=replace)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return entry, out


def _read_lightning_checkpoint(ckpt_path: Path) -> dict[str, Any]:
    """The dict of a Lightning checkpoint, read weights-only; HubError naming the file for anything else (a
    ``state_dict`` or ``hyper_parameters`` of another type, a ``_class_path`` that is no string: each ended in a
    TypeError or AttributeError that named nothing)."""
    try:
        ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupt file or a pickle with code in it: torch's reason, not its page of advice
        raise HubError(f"{ckpt_path}: not a readable weights-only checkpoint ({load_failure_reason(exc)})") from exc
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise HubError(f"{ckpt_path}: not a Lightning checkpoint (no 'state_dict')")
    for key, kind in (("state_dict", dict), ("hyper_parameters", (dict, type(None)))):
        if not isinstance(ckpt.get(key), kind):
            raise HubError(f"{ckpt_path}: its {key!r} is a {type(ckpt.get(key)).__name__}, not a dict")
    recorded = (ckpt.get("hyper_parameters") or {}).get("_class_path")
    if recorded is not None and not isinstance(recorded, str):
        raise HubError(f"{ckpt_path}: its hyper_parameters' '_class_path' is a {type(recorded).__name__}, not a str")
    return ckpt


def check_name_free(name: str, directory: str | os.PathLike[str] | None = None) -> None:
    """Refuse a push under a name that is taken: one registered in the user index (its weights would be deleted),
    or a checkpoint shipped with the package, current or retired (every load by that name would get the pushed
    weights instead). ``--replace`` pushes anyway."""
    index = user_index_path(directory)
    if any(e.name == name for e in read_index(index)):
        raise HubError(
            f"{name!r} is registered already ({index}): a push would replace it and delete its weights; push a new "
            "version (vN+1) or pass --replace"
        )
    shipped = {e.name for e in read_index(SHIPPED_INDEX)} | set(read_retired())
    if name in shipped:
        raise HubError(
            f"{name!r} names a checkpoint shipped with the package ({SHIPPED_INDEX.parent}): a push would hide it from "
            "every load by that name; push another name or pass --replace"
        )


def _stage_export(
    staging: Path,
    name: str,
    cls_path: str,
    init_args: dict[str, Any],
    state: dict[str, torch.Tensor],
    meta: dict[str, Any],
    source_ckpt: Path,
) -> HubEntry:
    """Write a complete export (weights, ``config.json``, model card) into ``staging`` and check it: a valid
    entry that rebuilds and loads strictly. Nothing outside ``staging`` is touched, so a refusal leaves an
    entry already registered under ``name`` as it was."""
    header = {"name": name, "class_path": cls_path, "init_args": init_args}
    filename, sha = _write_weights(staging, state, header, lambda sha: unique_filename(name, sha, ".safetensors"))
    entry = HubEntry(
        name=name,
        class_path=cls_path,
        filename=filename,
        sha256=sha,
        init_args=init_args,
        source={"kind": "local", "path": f"{name}/{filename}"},
        meta=meta,
    )
    try:
        HubEntry.from_json(entry.to_json(), "push")  # the name etc., as the index will read them
    except RegistryFormatError as exc:
        raise HubError(str(exc)) from exc
    metrics = meta.get("metrics", {})
    config = {
        "name": name,
        "class_path": cls_path,
        "init_args": init_args,
        "weights": filename,
        "sha256": sha,
        "metrics": metrics,
        "meta": meta,
    }
    (staging / CONFIG_NAME).write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
    (staging / "README.md").write_text(_model_card(entry, metrics, source_ckpt.name), encoding="utf-8")
    try:
        load_model(staging)  # refuse to register an export that does not rebuild and load strictly
    except (HubError, ValueError, TypeError) as exc:
        why = str(exc).replace(f"{staging}{os.sep}", "")  # the staging folder is gone when this is read
        raise HubError(f"{source_ckpt}: not pushed as {name!r}, its export does not load back: {why}") from exc
    return entry


def _install_export(
    staging: Path, out: Path, entry: HubEntry, directory: str | os.PathLike[str] | None, overwrite: bool
) -> None:
    """Move a checked export from ``staging`` into ``out`` and register it, each step by an atomic rename.

    ``overwrite`` False: the index, under its lock, refuses a name registered meanwhile (``check_name_free`` ran
    seconds earlier without the lock: two pushes of one new name both passed it, and the second deleted the first's
    weights).

    The new weights file (its name carries its hash) lands beside the old one; the index is switched to it;
    then ``config.json`` and the model card are replaced and the earlier weights of the name are deleted. At
    every point the index and ``out/config.json`` name a weights file that exists.
    """
    out.mkdir(parents=True, exist_ok=True)
    weights = out / entry.filename
    existed = weights.is_file()  # same name = same hash: the same content, pushed again
    os.replace(staging / entry.filename, weights)
    try:
        register(entry, directory, overwrite=overwrite)
    except BaseException:
        if not existed:
            weights.unlink(missing_ok=True)
        raise
    for extra in (CONFIG_NAME, "README.md"):
        os.replace(staging / extra, out / extra)
    for old in out.glob(f"{entry.name}-*.safetensors"):  # an earlier export of the same name
        if old.name != entry.filename:
            old.unlink()


def upload_export(
    entry: HubEntry, export_dir: Path, repo: str, directory: str | os.PathLike[str] | None = None, private: bool = False
) -> HubEntry:
    """Upload an export folder to the Hugging Face repo ``repo`` and re-register it pinned to the new commit."""
    if is_offline():
        raise HubError("refusing to upload: FLOAFF_ZOO_OFFLINE is set")
    try:
        from huggingface_hub import HfApi
    except ImportError as exc:
        raise HubError("--upload needs the optional package huggingface_hub: `pip install huggingface_hub`") from exc
    api = HfApi()
    api.create_repo(repo_id=repo, repo_type="model", exist_ok=True, private=private)
    info = api.upload_folder(
        folder_path=str(export_dir), repo_id=repo, repo_type="model", commit_message=f"floaff-zoo: {entry.name}"
    )
    revision = getattr(info, "oid", None)
    if not isinstance(revision, str) or len(revision) != 40:
        raise HubError(f"upload to {repo} returned no commit id to pin (got {revision!r})")
    entry.source = {"kind": "hf", "repo": repo, "revision": revision, "path_in_repo": entry.filename}
    register(entry, directory)
    return entry
