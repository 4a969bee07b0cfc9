"""Resolve a name or path to weights, offline first; fetch registry files with sha256 checks.

Resolution order of ``resolve_state_dict`` / ``load_model``:

1. an existing file (``.ckpt``, ``.pth``, ``.pt``, ``.safetensors``);
2. an exported directory (``config.json`` + the weights file it names, default ``model.safetensors``);
3. a registry name: ``<hub dir>/<filename>``, ``<hub dir>/<name>/<filename>``, the entry's local
   source, ``torch.hub.get_dir()/checkpoints/<filename>``; the sha256 is checked before loading;
4. a download, only when ``allow_download`` and ``$FLOAFF_ZOO_OFFLINE`` is unset/0: a pinned URL
   (urllib, streamed and hashed) or a Hugging Face repo at a pinned revision (``huggingface_hub``,
   optional); the file lands in ``<hub dir>/<filename>`` only if its hash matches.

Loading never executes code from a file: safetensors, or ``torch.load(weights_only=True)``; the
model class is imported only from ``floaff_zoo`` or from modules the caller has already imported.

Layering: this module and :mod:`floaff_zoo.hub.registry` sit below the models (``from_pretrained``,
teachers and AxisNets of ``floaff_zoo.models`` read weights through them) and import no model and no CLI;
a checkpoint's class is found by the dotted name it records, like a config's ``class_path``.
``hub.export`` and ``hub.cli`` (``floaff-zoo hub push``) sit above the models.
"""

from __future__ import annotations

import copy
import importlib
import json
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path
from typing import IO, Any

import torch

from floaff_zoo.atomic import atomic_write, publish
from floaff_zoo.hub.registry import (
    NON_PORTABLE_ARGS,
    WEIGHT_EXTS,
    ChecksumError,
    HubEntry,
    HubError,
    UnknownWeightsError,
    WeightsNotFoundError,
    get_entry,
    hub_dir,
    is_offline,
    sha256_file,
)
from floaff_zoo.runs import load_failure_reason

CONFIG_NAME = "config.json"
DEFAULT_WEIGHTS_NAME = "model.safetensors"
#: safetensors header metadata key holding {"name", "class_path", "init_args"} as JSON
SAFETENSORS_META_KEY = "floaff_zoo"
#: state-dict prefixes dropped on load and export (a PFAL student must not carry its teacher)
TEACHER_PREFIX = "teacher."
URL_TIMEOUT_S = 60.0
#: where bare class names live, and the class every loadable model derives from
MODELS_PACKAGE = "floaff_zoo.models"
MODEL_BASE_CLASS = "floaff_zoo.models.base.ZooModule"

Info = dict[str, Any]


# --------------------------------------------------------------------------- reading files
def _strip_teacher(state: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in state.items() if not k.startswith(TEACHER_PREFIX)}


def _read_torch(path: Path) -> tuple[dict[str, Any], Info]:
    """State dict and (class_path, init_args) of a Lightning ``.ckpt`` or a plain state-dict file."""
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupt file or a pickle with code in it
        raise ValueError(f"{path}: not a readable weights-only checkpoint ({load_failure_reason(exc)})") from exc
    if not isinstance(obj, dict):
        raise ValueError(f"{path}: expected a checkpoint dict or a state dict, got {type(obj).__name__}")
    if "state_dict" in obj:
        state = obj["state_dict"]
        hp = obj.get("hyper_parameters") or {}
        if not isinstance(state, dict) or not isinstance(hp, dict):
            raise ValueError(f"{path}: 'state_dict' and 'hyper_parameters' must be dicts")
        hp = dict(hp)
    elif obj and all(isinstance(v, torch.Tensor) for v in obj.values()):
        state, hp = obj, {}
    else:
        raise ValueError(f"{path}: no 'state_dict' in the checkpoint and not a plain state dict of tensors")
    class_path = hp.pop("_class_path", None)
    if class_path is not None and not isinstance(class_path, str):  # import_model_class's TypeError named no file
        raise ValueError(f"{path}: its hyper_parameters' '_class_path' is a {type(class_path).__name__}, not a str")
    hp.pop("_instantiator", None)
    return state, {"class_path": class_path, "init_args": hp}


def _read_safetensors(path: Path) -> tuple[dict[str, Any], Info]:
    """Tensors of a ``.safetensors`` file and the config stored in its header (if any)."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file, safe_open

    try:
        with safe_open(str(path), framework="pt") as f:
            header = f.metadata() or {}
        state = load_file(str(path), device="cpu")
    except (SafetensorError, OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable safetensors file ({exc})") from exc
    info: Info = {"class_path": None, "init_args": {}}
    if SAFETENSORS_META_KEY in header:
        try:
            cfg = json.loads(header[SAFETENSORS_META_KEY])
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: malformed '{SAFETENSORS_META_KEY}' metadata in the header ({exc})") from exc
        init_args = cfg.get("init_args") or {} if isinstance(cfg, dict) else None
        if not isinstance(init_args, dict) or not isinstance(cfg.get("class_path") or "", str):
            raise ValueError(
                f"{path}: malformed '{SAFETENSORS_META_KEY}' metadata in the header (expected an object with a "
                "string 'class_path' and an object 'init_args')"
            )
        info = {"class_path": cfg.get("class_path"), "init_args": dict(init_args)}
    return state, info


def read_weights(path: str | os.PathLike[str]) -> tuple[dict[str, Any], Info]:
    """State dict (teacher keys dropped) + ``{"class_path", "init_args"}`` of one weights file."""
    p = Path(path)
    if p.suffix not in WEIGHT_EXTS:
        raise ValueError(f"{p}: unsupported weights format {p.suffix!r}; use one of {WEIGHT_EXTS}")
    state, info = _read_safetensors(p) if p.suffix == ".safetensors" else _read_torch(p)
    return _strip_teacher(state), info


def read_config(directory: Path) -> dict[str, Any]:
    """``config.json`` of an exported directory (validated: class_path, init_args, weights)."""
    cfg_path = directory / CONFIG_NAME
    if not cfg_path.is_file():
        raise FileNotFoundError(f"{directory}: not an exported model directory (no {CONFIG_NAME})")
    try:
        cfg = json.loads(cfg_path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # bad JSON, bytes that are not UTF-8, nesting too deep
        raise ValueError(f"{cfg_path}: unreadable JSON ({exc})") from exc
    if (
        not isinstance(cfg, dict)
        or not isinstance(cfg.get("init_args", {}), dict)
        or not isinstance(cfg.get("class_path") or "", str)
    ):
        raise ValueError(f"{cfg_path}: expected an object with a string 'class_path' and an object 'init_args'")
    weights = cfg.get("weights", DEFAULT_WEIGHTS_NAME)
    if not isinstance(weights, str) or "/" in weights or "\\" in weights:
        raise ValueError(f"{cfg_path}: 'weights' must be a file name inside the directory, got {weights!r}")
    sha = cfg.get("sha256")
    if sha is not None and not (isinstance(sha, str) and re.fullmatch(r"[0-9a-fA-F]{64}", sha)):
        raise ValueError(f"{cfg_path}: 'sha256' must be 64 hex digits, got {sha!r}")
    if not isinstance(cfg.get("meta") or {}, dict):  # the loader hands it on as a dict (test metrics, SR, ...)
        raise ValueError(f"{cfg_path}: 'meta' must be an object, got {cfg['meta']!r}")
    if not isinstance(cfg.get("name") or "", str):
        raise ValueError(f"{cfg_path}: 'name' must be a string, got {cfg['name']!r}")
    return cfg


def _verify(path: Path, sha256: str, what: str) -> None:
    """Raise ChecksumError naming ``path`` unless its sha256 equals ``sha256``."""
    got = sha256_file(path)
    if got != sha256.lower():
        raise ChecksumError(
            f"{path}: sha256 mismatch for {what}: expected {sha256}, file has {got}; the file is corrupt "
            "or was changed — delete it (and re-download) instead of loading it"
        )


# --------------------------------------------------------------------------- registry files
def local_candidates(entry: HubEntry, directory: str | os.PathLike[str] | None = None) -> list[Path]:
    """Where a registry file may already be, in search order."""
    root = hub_dir(directory)
    out = [root / entry.filename, root / entry.name / entry.filename]
    if entry.source.get("kind") == "local" and entry.source.get("path"):
        p = Path(entry.source["path"]).expanduser()
        if not p.is_absolute():
            base = entry.index_path.parent if entry.index_path is not None else root
            p = base / p
        out.append(p)
    out.append(Path(torch.hub.get_dir()) / "checkpoints" / entry.filename)
    seen: list[Path] = []
    for p in out:
        if p not in seen:
            seen.append(p)
    return seen


def find_local(entry: HubEntry, directory: str | os.PathLike[str] | None = None) -> Path | None:
    """First existing local copy of ``entry``'s file (not yet verified), or None."""
    return next((p for p in local_candidates(entry, directory) if p.is_file()), None)


def _open_url(url: str, timeout: float = URL_TIMEOUT_S) -> IO[bytes]:
    """The transport (tests replace it): a readable binary stream of ``url``."""
    import urllib.request

    from floaff_zoo._version import __version__

    req = urllib.request.Request(url, headers={"User-Agent": f"floaff-zoo/{__version__}"})
    return urllib.request.urlopen(req, timeout=timeout)  # noqa: S310 - scheme checked by the registry


def _download_url(url: str, dest: Path, sha256: str) -> Path:
    """Stream ``url`` to a temp file next to ``dest``, hashing; keep it only if the hash matches."""
    import hashlib

    def stream_checked(out: IO[bytes]) -> None:
        h = hashlib.sha256()
        with _open_url(url) as stream:
            while block := stream.read(1 << 20):
                h.update(block)
                out.write(block)
        if h.hexdigest() != sha256:  # raised inside the write: atomic_write discards the temp file
            raise ChecksumError(
                f"download of {url} for {dest.name}: sha256 {h.hexdigest()} != registered {sha256}; "
                "the file was discarded"
            )

    atomic_write(dest, stream_checked)
    return dest


def _hf_hub_download(repo: str, path_in_repo: str, revision: str, local_dir: Path) -> str:
    """``huggingface_hub.hf_hub_download`` into ``local_dir`` (imported lazily: it is optional)."""
    try:
        from huggingface_hub import hf_hub_download
    except ImportError as exc:
        raise HubError(
            f"downloading from the Hugging Face repo {repo} needs the optional package huggingface_hub: "
            "`pip install huggingface_hub` (or `pip install floaff-zoo[hf]`), or put the file in place by hand"
        ) from exc
    return hf_hub_download(repo_id=repo, filename=path_in_repo, revision=revision, local_dir=str(local_dir))


def _download_hf(source: dict[str, Any], dest: Path, sha256: str, default_path: str) -> Path:
    """Fetch from the pinned HF revision into a private temp dir; move into place if the hash matches."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    try:
        in_repo = source.get("path_in_repo", default_path)
        got = Path(_hf_hub_download(source["repo"], in_repo, source["revision"], tmpdir))
        digest = sha256_file(got)
        if digest != sha256:
            raise ChecksumError(
                f"download of {source['repo']}@{source['revision']}/{got.name} for {dest.name}: sha256 "
                f"{digest} != registered {sha256}; the file was discarded"
            )
        publish(got, dest)  # the mode a plain open would give, as every other file the hub writes
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return dest


def fetch(
    name_or_entry: str | HubEntry,
    directory: str | os.PathLike[str] | None = None,
    allow_download: bool = True,
) -> Path:
    """Local, sha256-verified path of a registry entry's file, downloading it when allowed.

    Raises:
        UnknownWeightsError: unknown name (lists close matches).
        ChecksumError: a local copy or a download does not match the registered sha256.
        WeightsNotFoundError: not available locally and downloading is off (names file and folder).
    """
    entry = name_or_entry if isinstance(name_or_entry, HubEntry) else get_entry(name_or_entry, directory)
    local = find_local(entry, directory)
    if local is not None:
        _verify(local, entry.sha256, f"hub entry {entry.name!r}")
        return local
    root = hub_dir(directory)
    kind = entry.source.get("kind")
    hf_offline = kind == "hf" and os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in ("1", "true", "yes", "on")
    offline = is_offline() or hf_offline
    if allow_download and not offline and kind in ("url", "hf"):
        dest = root / entry.filename
        try:
            if kind == "url":
                return _download_url(entry.source["url"], dest, entry.sha256)
            return _download_hf(entry.source, dest, entry.sha256, default_path=entry.filename)
        except HubError:
            raise
        except OSError as exc:  # urllib's URLError/HTTPError, timeouts, requests' errors: no network, 404, ...
            raise WeightsNotFoundError(
                f"weights {entry.name!r} are not available locally and their download failed ({exc}): put the file "
                f"{entry.filename} (sha256 {entry.sha256}) into the folder {root}, or set FLOAFF_ZOO_OFFLINE=1"
            ) from exc
    if kind == "local":
        why = "its source is a local file that is not present"
    elif offline:
        why = "HF_HUB_OFFLINE is set" if hf_offline and not is_offline() else "FLOAFF_ZOO_OFFLINE is set"
    else:
        why = "downloading was not allowed (allow_download=False)"
    tried = ", ".join(str(p.parent) for p in local_candidates(entry, directory))
    raise WeightsNotFoundError(
        f"weights {entry.name!r} are not available locally and {why}: put the file {entry.filename} "
        f"(sha256 {entry.sha256}) into the folder {root} (searched: {tried})"
        + ("" if kind == "local" else f", or run `floaff-zoo hub pull {entry.name}` with network access")
    )


# --------------------------------------------------------------------------- resolution
def looks_like_path(s: str) -> bool:
    """True for strings that name a file rather than a hub entry (a separator, ``~``/``.``, a weights suffix)."""
    return any(sep in s for sep in ("/", "\\", os.sep)) or s.startswith(("~", ".")) or Path(s).suffix in WEIGHT_EXTS


def resolve_state_dict(
    name_or_path: str | os.PathLike[str],
    hub_dir: str | os.PathLike[str] | None = None,
    allow_download: bool = True,
) -> tuple[dict[str, torch.Tensor], Info]:
    """State dict (``teacher.*`` keys dropped) and info of a file, an exported directory or a hub name.

    Returns:
        (state_dict, info) with info = ``{"class_path": str | None, "init_args": dict, "source": str
        (the file read), "kind": "file" | "dir" | "hub", "name": str | None, "sha256": str | None,
        "meta": dict}``; ``init_args`` never contains ``weights``/``teacher``.
    """
    target = os.fspath(name_or_path) if isinstance(name_or_path, (str, os.PathLike)) else None
    if not isinstance(target, str):  # str(None) was looked up as the hub name 'None'
        raise TypeError(f"weights must be a hub name or a path (a str or os.PathLike), got {name_or_path!r}")
    if not target.strip():  # Path('') is '.': the working folder was read as an exported directory
        raise UnknownWeightsError(f"weights {target!r}: an empty name is no file, exported directory nor hub name")
    path = Path(target).expanduser()
    name, sha, meta = None, None, {}
    # a registered name is the hub's entry even when the working folder holds a file or folder of that name, unless
    # that folder is an export (it shadowed the entry with "not an exported model directory")
    hub_name = not looks_like_path(target) and not (path / CONFIG_NAME).is_file() and _is_registered(target, hub_dir)
    if not hub_name and path.is_file():
        kind, weights_path = "file", path
        # the weights file of an exported folder, named directly: its config's hash is checked as for the folder
        # (exports write safetensors: a checkpoint beside some other config.json does not read it)
        exported_kind = path.suffix == ".safetensors" and (path.parent / CONFIG_NAME).is_file()
        cfg = read_config(path.parent) if exported_kind else {}
        exported = bool(cfg) and cfg.get("weights", DEFAULT_WEIGHTS_NAME) == path.name
        if exported and cfg.get("sha256"):
            sha = cfg["sha256"]
            _verify(path, sha, f"{path.parent / CONFIG_NAME}")
        state, info = read_weights(path)
        if exported and info["class_path"] is None:
            info = {"class_path": cfg.get("class_path"), "init_args": dict(cfg.get("init_args") or {})}
    elif not hub_name and path.is_dir():
        kind = "dir"
        cfg = read_config(path)
        weights_path = path / cfg.get("weights", DEFAULT_WEIGHTS_NAME)
        if not weights_path.is_file():
            raise FileNotFoundError(f"{path / CONFIG_NAME} names weights {weights_path.name}, which is missing")
        sha, name, meta = cfg.get("sha256"), cfg.get("name"), dict(cfg.get("meta") or {})
        if sha:  # the directory records its hash: check it before deserialising
            _verify(weights_path, sha, f"{path / CONFIG_NAME}")
        state, _file_info = read_weights(weights_path)
        info = {"class_path": cfg.get("class_path"), "init_args": dict(cfg.get("init_args") or {})}
    elif looks_like_path(target) and not _is_registered(target, hub_dir):
        raise FileNotFoundError(f"weights {target!r}: no such file or directory")
    else:
        kind = "hub"
        entry = get_entry(target, hub_dir)
        weights_path = fetch(entry, hub_dir, allow_download=allow_download)  # verified before reading
        state, _file_info = read_weights(weights_path)
        info = {"class_path": entry.class_path, "init_args": dict(entry.init_args)}
        name, sha, meta = entry.name, entry.sha256, dict(entry.meta)
    init_args = {k: v for k, v in info["init_args"].items() if k not in NON_PORTABLE_ARGS}
    return state, {
        "class_path": info["class_path"],
        "init_args": init_args,
        "source": str(weights_path),
        "kind": kind,
        "name": name,
        "sha256": sha,
        "meta": meta,
    }


def _is_registered(name: str, directory: str | os.PathLike[str] | None) -> bool:
    from floaff_zoo.hub.registry import load_registry

    return name in load_registry(directory)


def import_model_class(class_path: str, where: str) -> type:
    """The model class ``class_path`` names, importing only trusted modules.

    ``floaff_zoo.*`` modules are imported on demand; other modules must already be imported by the
    caller (a weights file must never make us import arbitrary code). A bare name means
    ``floaff_zoo.models.<name>``. The class is found by its dotted name, like a config's
    ``class_path``: this module sits below ``floaff_zoo.models`` and imports none of them itself.
    """
    if "." not in class_path:
        class_path = f"{MODELS_PACKAGE}.{class_path}"
    mod_name, cls_name = class_path.rsplit(".", 1)
    if mod_name.split(".")[0] != "floaff_zoo" and mod_name not in sys.modules:
        raise HubError(
            f"{where}: model class {class_path!r} lives outside floaff_zoo; import {mod_name} "
            "yourself before loading (the hub never imports a module because a file names it)"
        )
    try:
        obj = getattr(importlib.import_module(mod_name), cls_name, None)
    except ImportError as exc:
        raise HubError(f"{where}: cannot import model module {mod_name!r} ({exc})") from exc
    if not (isinstance(obj, type) and _is_model_class(obj)):
        raise HubError(f"{where}: class_path {class_path!r} is not a model of the zoo (a ZooModule subclass)")
    return obj


def _is_model_class(cls: type) -> bool:
    """True for subclasses of ``floaff_zoo.models.base.ZooModule`` (compared by qualified name)."""
    return any(f"{c.__module__}.{c.__qualname__}" == MODEL_BASE_CLASS for c in cls.__mro__)


def _naming(exc: Exception, where: str) -> Exception:
    """A copy of ``exc`` whose message starts with ``where``, of the same class (a ChecksumError a model's own
    weights file raised stays one for the callers that catch it)."""
    try:
        named = copy.copy(exc)
        named.args = (f"{where}: {exc}",)
    except Exception:  # noqa: BLE001 - a class copy cannot rebuild (its own __init__): the message matters more
        return ValueError(f"{where}: {exc}")
    return named if str(named).startswith(where) else ValueError(f"{where}: {exc}")  # str() not from args


def load_model(
    name_or_path: str | os.PathLike[str],
    map_location: str | torch.device = "cpu",
    hub_dir: str | os.PathLike[str] | None = None,
    allow_download: bool = True,
    expected: type | None = None,
) -> torch.nn.Module:
    """Rebuild the model a checkpoint / export / hub entry describes and load its weights strictly.

    Args:
        expected: if given, the class the caller wants; a checkpoint of another class raises
            ``TypeError`` before anything is built, and checkpoints that do not record their class
            (e.g. a bare state dict) are built as ``expected``.
    Returns:
        the model in eval mode on ``map_location``.
    """
    state, info = resolve_state_dict(name_or_path, hub_dir=hub_dir, allow_download=allow_download)
    where = info["source"]
    if info["class_path"]:
        cls = import_model_class(info["class_path"], where)
    elif expected is not None:
        cls = expected
    else:
        raise ValueError(
            f"{where}: the checkpoint does not record its model class; call <ModelClass>.from_pretrained "
            "or export it with `floaff-zoo hub push ... --class-path`"
        )
    if expected is not None and not issubclass(cls, expected):
        raise TypeError(f"{name_or_path!r} holds a {cls.__name__} checkpoint, not a {expected.__name__}")
    # configs and checkpoints written before the `train` group hold the training args flat
    init_args = cls.upgrade_init_args(info["init_args"])
    try:
        model = cls(**init_args)
    except TypeError as exc:
        raise TypeError(f"{where}: its init_args do not fit {cls.__name__} ({exc})") from exc
    except Exception as exc:  # a value the class refuses (a train field of a newer version...): name the file too
        from lightning.fabric.utilities.exceptions import MisconfigurationException

        if isinstance(exc, (ValueError, MisconfigurationException)):
            raise _naming(exc, where) from exc
        raise
    own = model.state_dict()
    resized = [
        f"{k} {tuple(v.shape)} (model {tuple(own[k].shape)})"
        for k, v in state.items()
        if k in own and isinstance(v, torch.Tensor) and v.shape != own[k].shape
    ]
    if resized:  # load_state_dict would raise a RuntimeError that names no file
        raise ValueError(
            f"{where}: weights do not match {cls.__name__}({init_args}): {len(resized)} of another shape, {resized[:3]}"
        )
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise ValueError(
            f"{where}: weights do not match {cls.__name__}({init_args}): missing {list(missing)[:5]} "
            f"({len(missing)}), unexpected {list(unexpected)[:5]} ({len(unexpected)})"
        )
    return model.to(map_location).eval()
