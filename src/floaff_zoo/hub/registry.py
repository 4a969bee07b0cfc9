"""The checkpoint registry: named entries from the shipped index merged with the user's index.

An index file is JSON ``{"version": 1, "entries": [ENTRY, ...]}``. One entry::

    {
      "name": "tiny-pointnet.synthetic.v1",          # model.dataset.vN
      "class_path": "floaff_zoo.models.tiny.TinyPointNetModule",
      "init_args": {"width": 32, ...},               # exact hparams (no weights/teacher)
      "filename": "tiny-pointnet.synthetic.v1-1a2b3c4d.safetensors",   # name-<sha256[:8]>.<ext>
      "sha256": "<64 hex>",                          # of the file, checked before loading
      "source": {"kind": "local", "path": "tiny-pointnet.synthetic.v1/<filename>"}
             | {"kind": "url", "url": "https://.../<pinned revision>/..."}
             | {"kind": "hf", "repo": "org/repo", "revision": "<40-hex commit>", "path_in_repo": "..."},
      "meta": {"dataset": ..., "benchmark": ..., "metrics": {...}, "license": ..., ...}
    }

Entries superseded by a newer version leave the package (its size is kept to the current tables' checkpoints);
``floaff_zoo/hub/retired.json`` lists them in batches, one per retirement: each batch names the commit whose tree
still holds its entries' exported directories and maps each retired name to its successor, so asking for a retired
name says where to find it.

The shipped index (``floaff_zoo/hub/index.json``) is read first; ``<hub dir>/index.json`` (the user
index, written by ``floaff-zoo hub push``) is merged over it by name. The hub directory is
``$FLOAFF_ZOO_HUB`` (default ``~/.cache/floaff_zoo/hub``).
"""

from __future__ import annotations

import difflib
import hashlib
import json
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from floaff_zoo.atomic import atomic_write_text, folder_lock

INDEX_VERSION = 1
SHIPPED_INDEX = Path(__file__).with_name("index.json")
RETIRED_INDEX = Path(__file__).with_name("retired.json")
USER_INDEX_NAME = "index.json"
DEFAULT_HUB_DIR = Path("~/.cache/floaff_zoo/hub")
#: weight file formats the hub reads (all without executing code: safetensors / weights-only torch.load)
WEIGHT_EXTS = (".safetensors", ".ckpt", ".pth", ".pt")
#: endings of the files a hub folder holds beside its entries' folders (index.json, retired.json, the package's code)
HUB_FILE_EXTS = (".json", ".py", ".lock")
#: init args that must never travel with a checkpoint (they point at other files)
NON_PORTABLE_ARGS = ("weights", "teacher")

_NAME_RE = re.compile(r"^[a-z0-9][a-z0-9_\-]*(\.[a-z0-9_\-]+)*$")
_SHA_RE = re.compile(r"^[0-9a-f]{64}$")
_COMMIT_RE = re.compile(r"^[0-9a-f]{40}$")
_HF_RESOLVE_RE = re.compile(r"huggingface\.co/.+/resolve/([^/]+)/")
_VERSION_RE = re.compile(r"(.*)\.v(\d+)")
SOURCE_KINDS = ("local", "url", "hf")


class HubError(RuntimeError):
    """Base class of user-facing hub errors (the CLI prints them without a traceback)."""


class RegistryFormatError(HubError, ValueError):
    """An index file or entry is malformed (names the file and the field)."""


class UnknownWeightsError(HubError, LookupError):
    """A name that is neither a file, an exported directory nor a registry entry."""


class RetiredEntryError(UnknownWeightsError):
    """A name that the package shipped once and retired (the message names its successor and where it is kept)."""


class ChecksumError(HubError, ValueError):
    """A file's sha256 differs from the one the registry / config records."""


class WeightsNotFoundError(HubError, FileNotFoundError):
    """A registry entry whose file is not available locally and may not be downloaded."""


# --------------------------------------------------------------------------- environment
def hub_dir(override: str | os.PathLike[str] | None = None) -> Path:
    """The hub directory: ``override``, else ``$FLOAFF_ZOO_HUB``, else ``~/.cache/floaff_zoo/hub``."""
    if override is not None:
        return Path(override).expanduser()
    env = os.environ.get("FLOAFF_ZOO_HUB")
    return Path(env).expanduser() if env else DEFAULT_HUB_DIR.expanduser()


def is_offline() -> bool:
    """True when ``$FLOAFF_ZOO_OFFLINE`` is set to anything but ``''``/``0``/``false``/``no``."""
    return os.environ.get("FLOAFF_ZOO_OFFLINE", "").strip().lower() not in ("", "0", "false", "no", "off")


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file, streamed."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def unique_filename(name: str, sha256: str, ext: str) -> str:
    """``name-<sha256[:8]><ext>``: unique per content, so caches keyed by basename never collide."""
    return f"{name}-{sha256[:8]}{ext if ext.startswith('.') else '.' + ext}"


# --------------------------------------------------------------------------- entries
def check_name(name: Any, where: str) -> str:
    """``name`` if it is a valid entry name (lower-case ``model.dataset.vN``), else RegistryFormatError naming
    ``where`` (the index file, or the command)."""
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise RegistryFormatError(
            f"{where}: entry name {name!r} must be lower-case 'model.dataset.vN' (letters, digits, '-', '_', '.')"
        )
    if name.endswith(WEIGHT_EXTS):  # read as a file path by every command that takes a name or a path
        raise RegistryFormatError(f"{where}: entry name {name!r} ends like a weights file ({', '.join(WEIGHT_EXTS)})")
    if name.endswith(HUB_FILE_EXTS):  # an entry is a folder <hub dir>/<name>: 'index.json' took the index's path
        raise RegistryFormatError(
            f"{where}: entry name {name!r} ends like one of the hub's own files ({', '.join(HUB_FILE_EXTS)})"
        )
    return name


@dataclass
class HubEntry:
    """One named checkpoint (see the module docstring for the JSON form)."""

    name: str
    class_path: str
    filename: str
    sha256: str
    init_args: dict[str, Any] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=lambda: {"kind": "local"})
    meta: dict[str, Any] = field(default_factory=dict)
    #: the index file the entry came from (not serialised); relative local paths are relative to its folder
    index_path: Path | None = field(default=None, compare=False, repr=False)

    @property
    def ext(self) -> str:
        return Path(self.filename).suffix

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("index_path")
        return d

    @classmethod
    def from_json(cls, raw: Any, where: str) -> "HubEntry":
        """Validate and build an entry; ``where`` names the index file for error messages."""
        if not isinstance(raw, dict):
            raise RegistryFormatError(f"{where}: every entry must be an object, got {type(raw).__name__}")
        name = check_name(raw.get("name"), where)
        at = f"{where}: entry {name!r}"
        unknown = set(raw) - {"name", "class_path", "init_args", "filename", "sha256", "source", "meta"}
        if unknown:
            raise RegistryFormatError(f"{at}: unknown field(s) {sorted(unknown)}")
        for key in ("class_path", "filename", "sha256"):
            if not isinstance(raw.get(key), str) or not raw[key]:
                raise RegistryFormatError(f"{at}: field {key!r} is required (a non-empty string)")
        sha = raw["sha256"].lower()
        if not _SHA_RE.match(sha):
            raise RegistryFormatError(f"{at}: sha256 must be the full 64-hex-digit hash, got {raw['sha256']!r}")
        filename = raw["filename"]
        if "/" in filename or "\\" in filename or Path(filename).suffix not in WEIGHT_EXTS:
            raise RegistryFormatError(
                f"{at}: filename {filename!r} must be a bare file name ending in one of {WEIGHT_EXTS}"
            )
        if f"-{sha[:8]}." not in filename:
            raise RegistryFormatError(
                f"{at}: filename {filename!r} must carry the hash prefix: "
                f"{unique_filename(name, sha, Path(filename).suffix)!r}"
            )
        for key in ("init_args", "meta"):
            if not isinstance(raw.get(key, {}), dict):
                raise RegistryFormatError(f"{at}: field {key!r} must be an object")
        if not isinstance(raw.get("meta", {}).get("metrics", {}), dict):  # `hub list` reads its scores by name
            raise RegistryFormatError(f"{at}: field 'meta.metrics' must be an object of metric name -> value")
        bad_args = [a for a in NON_PORTABLE_ARGS if a in raw.get("init_args", {})]
        if bad_args:
            raise RegistryFormatError(f"{at}: init_args must not contain {bad_args} (they point at other files)")
        source = raw.get("source", {"kind": "local"})
        _check_source(source, at)
        return cls(
            name=name,
            class_path=raw["class_path"],
            filename=filename,
            sha256=sha,
            init_args=dict(raw.get("init_args", {})),
            source=dict(source),
            meta=dict(raw.get("meta", {})),
        )


def _check_source(source: Any, at: str) -> None:
    """Sources must be pinned: HF by a 40-hex commit, huggingface.co URLs by a commit in the path."""
    if not isinstance(source, dict) or source.get("kind") not in SOURCE_KINDS:
        raise RegistryFormatError(f"{at}: source must be an object with kind in {SOURCE_KINDS}, got {source!r}")
    kind = source["kind"]
    if kind == "local":
        if "path" in source and not isinstance(source["path"], str):
            raise RegistryFormatError(f"{at}: source.path must be a string")
    elif kind == "url":
        url = source.get("url")
        if not isinstance(url, str) or not url.startswith(("https://", "http://", "file://")):
            raise RegistryFormatError(f"{at}: source.url must be an http(s):// or file:// URL, got {url!r}")
        m = _HF_RESOLVE_RE.search(url)
        if m and not _COMMIT_RE.match(m.group(1)):
            raise RegistryFormatError(
                f"{at}: Hugging Face URL must pin a 40-hex commit (…/resolve/<commit>/…), not {m.group(1)!r}"
            )
    else:
        if not isinstance(source.get("repo"), str) or "/" not in source["repo"]:
            raise RegistryFormatError(f"{at}: source.repo must be 'org/name', got {source.get('repo')!r}")
        if not isinstance(source.get("revision"), str) or not _COMMIT_RE.match(source["revision"]):
            raise RegistryFormatError(
                f"{at}: source.revision must be a pinned 40-hex commit, got {source.get('revision')!r} "
                "(branch names like 'main' move and are refused)"
            )
        if "path_in_repo" in source and not isinstance(source["path_in_repo"], str):
            raise RegistryFormatError(f"{at}: source.path_in_repo must be a string")


# --------------------------------------------------------------------------- index files
def read_index(path: Path) -> list[HubEntry]:
    """Entries of one index file (a missing user index is empty; a malformed one is an error)."""
    if not path.is_file():
        if path.exists():  # a folder in its place read as an empty index: every user entry vanished without a word
            raise RegistryFormatError(f"{path}: not a file (a hub index must be a JSON file; move the folder away)")
        return []
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # bad JSON, bytes that are not UTF-8, nesting too deep
        raise RegistryFormatError(f"{path}: not a readable JSON index ({exc})") from exc
    if not isinstance(raw, dict) or raw.get("version") != INDEX_VERSION or not isinstance(raw.get("entries"), list):
        raise RegistryFormatError(f"{path}: expected {{'version': {INDEX_VERSION}, 'entries': [...]}}")
    entries, seen = [], set()
    for item in raw["entries"]:
        e = HubEntry.from_json(item, str(path))
        if e.name in seen:
            raise RegistryFormatError(f"{path}: entry {e.name!r} appears twice")
        seen.add(e.name)
        e.index_path = path
        entries.append(e)
    return entries


def write_index(path: Path, entries: list[HubEntry]) -> None:
    """Write an index atomically (temp file + rename) so a crash never leaves half a JSON file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"version": INDEX_VERSION, "entries": [e.to_json() for e in sorted(entries, key=lambda e: e.name)]}
    text = json.dumps(payload, indent=2, sort_keys=False) + "\n"
    atomic_write_text(path, text, durable=True)  # after a power loss: old or new, never empty


def user_index_path(directory: str | os.PathLike[str] | None = None) -> Path:
    return hub_dir(directory) / USER_INDEX_NAME


def load_registry(directory: str | os.PathLike[str] | None = None) -> dict[str, HubEntry]:
    """Shipped entries with the user index (``<hub dir>/index.json``) merged over them by name."""
    merged = {e.name: e for e in read_index(SHIPPED_INDEX)}
    merged.update({e.name: e for e in read_index(user_index_path(directory))})
    return merged


@dataclass(frozen=True)
class RetiredEntry:
    """A checkpoint that left the package: the entry that supersedes it and the commit whose tree still holds it."""

    successor: str
    commit: str


def read_retired(path: Path = RETIRED_INDEX) -> dict[str, RetiredEntry]:
    """Retired name -> its successor and commit, over every batch of ``retired.json`` (empty without the file)."""
    if not path.is_file():
        return {}
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # bad JSON, bytes that are not UTF-8, nesting too deep
        raise RegistryFormatError(f"{path}: not a readable JSON file ({exc})") from exc
    form = "{'batches': [{'commit': '<40 hex>', 'entries': {name: successor}}, ...]}"
    batches = raw.get("batches") if isinstance(raw, dict) else None
    if not isinstance(batches, list) or not batches:
        raise RegistryFormatError(f"{path}: expected {form}")
    out: dict[str, RetiredEntry] = {}
    for k, batch in enumerate(batches):
        commit = batch.get("commit") if isinstance(batch, dict) else None
        entries = batch.get("entries") if isinstance(batch, dict) else None
        if not isinstance(commit, str) or not _COMMIT_RE.match(commit) or not isinstance(entries, dict):
            raise RegistryFormatError(f"{path}: batches[{k}]: expected {{'commit': '<40 hex>', 'entries': {{...}}}}")
        for name, successor in entries.items():
            if not isinstance(successor, str):
                raise RegistryFormatError(f"{path}: batches[{k}].entries[{name!r}]: the successor must be a name")
            if name in out:  # two commits for one name: which tree holds it would be a guess
                raise RegistryFormatError(f"{path}: batches[{k}]: {name!r} is retired in an earlier batch already")
            out[name] = RetiredEntry(successor, commit)
    return out


def _version_of(name: str) -> tuple[str, int]:
    """(``model.dataset``, N) of a ``model.dataset.vN`` name; (name, -1) for a name without a version."""
    m = _VERSION_RE.fullmatch(name)
    return (m[1], int(m[2])) if m else (name, -1)


def close_names(name: str, names: list[str], n: int = 5) -> list[str]:
    """The registered ``names`` a mistyped or partial ``name`` may mean, at most ``n``: the newest version of each
    entry that ``name`` begins (a model alone, ``votenet``, or a name without its version; difflib finds none for a
    short prefix of a long name, and ranks v9 above v12), then every version of an entry named with a version it
    does not have, newest first, then difflib's close matches. Case is ignored: names are
    lower-case."""
    key = name.strip().lower()
    newest: dict[str, str] = {}
    for candidate in names:
        if candidate.startswith(key):
            base, version = _version_of(candidate)
            if base not in newest or version > _version_of(newest[base])[1]:
                newest[base] = candidate
    # the entries of the model (or model.dataset) typed before those of a longer name it begins (cfar before cfar-x)
    begun = sorted(newest.values(), key=lambda c: (c[len(key) : len(key) + 1] not in ("", "."), c))
    # a version that does not exist: the entry's versions, newest first (difflib put v9 before v12 for v99)
    base, version = _version_of(key)
    versions = sorted(
        (c for c in names if version >= 0 and _version_of(c)[0] == base), key=lambda c: -_version_of(c)[1]
    )
    close = difflib.get_close_matches(key, names, n=n, cutoff=0.5)
    return list(dict.fromkeys([*begun, *versions, *close]))[:n]


def get_entry(name: str, directory: str | os.PathLike[str] | None = None) -> HubEntry:
    """The entry called ``name``; a retired name says where it went, an unknown one lists close matches."""
    if not isinstance(name, str):  # close_names died in `.strip()` with an AttributeError
        raise TypeError(f"a hub name must be a str, got {name!r}")
    reg = load_registry(directory)
    if name in reg:
        return reg[name]
    retired = read_retired().get(name)
    if retired is not None:
        folder = f"src/floaff_zoo/hub/{name}"
        raise RetiredEntryError(
            f"{name!r} is no longer shipped: it was superseded by {retired.successor!r}. Its exported directory is in "
            f"the floaff-zoo git history; from a clone: `git archive {retired.commit} {folder} | tar -x -C <dir>`, "
            f"then load <dir>/{folder} (a directory loads like a name)"
        )
    close = close_names(name, list(reg))
    if close:
        hint = f"; did you mean {close}?"
    else:
        hint = f"; known: {sorted(reg)[:10]}" if reg else "; the registry is empty"
    raise UnknownWeightsError(
        f"{name!r} is not a checkpoint file, an exported directory, nor a registered hub name{hint} "
        f"(registries read: {SHIPPED_INDEX}, {user_index_path(directory)})"
    )


def register(entry: HubEntry, directory: str | os.PathLike[str] | None = None, overwrite: bool = True) -> Path:
    """Add/replace ``entry`` in the user index of ``directory``; returns the index path."""
    HubEntry.from_json(entry.to_json(), "new entry")  # same validation as on read
    path = user_index_path(directory)
    # pushes at once each read the index, add their entry and write it back: without the lock the last writer
    # dropped the others' entries
    with folder_lock(path.parent / ".index.lock"):
        entries = {e.name: e for e in read_index(path)}
        if entry.name in entries and not overwrite:
            raise HubError(f"{path}: an entry named {entry.name!r} exists already")
        entries[entry.name] = entry
        write_index(path, list(entries.values()))
    entry.index_path = path
    return path
