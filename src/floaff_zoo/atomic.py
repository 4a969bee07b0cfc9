"""Files shared between processes: whole-file writes and folder locks.

Every file the package writes for others to read (generated scenes and views, cache entries, hub indexes and
weights, rollout caches) is written to a temp file in the destination's folder and renamed over it once complete,
so a killed writer never leaves half a file, and the file gets the mode a plain ``open`` would have given it
(``mkstemp`` makes owner-only files, which nobody else sharing a data or hub folder could read). A folder that
several processes update (a hub index, a generated benchmark) is locked while one of them does.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

try:  # POSIX advisory locks (elsewhere the lock is a no-op: writers must not overlap)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]


class LockedError(RuntimeError):
    """Another process holds the lock (``folder_lock(..., wait=False)``)."""


@contextlib.contextmanager
def folder_lock(
    lock_file: str | os.PathLike[str], wait: bool = True, on_wait: Callable[[], None] | None = None
) -> Iterator[None]:
    """Hold an exclusive lock on ``lock_file`` (created if missing; released when the process dies).

    ``wait``: block until the lock is free, else raise ``LockedError`` at once; ``on_wait`` is called once before
    blocking, when another process holds the lock (to say why nothing happens)."""
    path = Path(lock_file)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        if fcntl is not None:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError as exc:
                if not wait:
                    raise LockedError(f"{path} is locked by another process") from exc
                if on_wait is not None:
                    on_wait()
                fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            if fcntl is not None:
                fcntl.flock(f, fcntl.LOCK_UN)


def _umask() -> int:
    """The process's umask, read without changing it where Linux shows it (``os.umask`` sets it to 0 for a moment,
    which a file another thread creates meanwhile would get)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    umask = os.umask(0)
    os.umask(umask)
    return umask


def existing_ancestor(path: str | os.PathLike[str]) -> Path:
    """The first of ``path`` and its parents that exists (a dangling link counts): where a write that creates the
    missing folders would start. Callers check it is a folder before minutes of work whose output it is to hold."""
    path = Path(path).absolute()
    return next(p for p in (path, *path.parents) if p.exists() or p.is_symlink())


def publish(tmp: str | os.PathLike[str], dest: str | os.PathLike[str]) -> None:
    """Rename the finished temp file ``tmp`` onto ``dest``, with the mode the umask gives a new file."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, dest)


def atomic_write(path: str | os.PathLike[str], write: Callable[[BinaryIO], None], durable: bool = False) -> None:
    """Write ``path`` whole or not at all: ``write(f)`` fills a temp file beside it, which then replaces it.

    ``durable`` also flushes the data to disk before the rename (after a power loss the file is the old or the new
    one, never empty). A symlink is written through, as ``open`` does (the rename would replace the link itself and
    leave its target as it was): a link into another folder has that file replaced there, and a link to a folder
    fails as ``open`` would."""
    path = Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        publish(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | os.PathLike[str], text: str, durable: bool = False) -> None:
    """``text`` (UTF-8) written whole or not at all, as :func:`atomic_write`."""
    data = text.encode("utf-8")
    atomic_write(path, lambda f: f.write(data), durable=durable)


def atomic_write_json(
    path: str | os.PathLike[str],
    obj: Any,
    indent: int | None = 1,
    sort_keys: bool = True,
    default: Callable[[Any], Any] | None = None,
    durable: bool = False,
) -> None:
    """``obj`` as JSON (``json.dumps`` with ``indent``, ``sort_keys`` and ``default``; ASCII, no final newline),
    written whole or not at all, as :func:`atomic_write`. Each kind of file keeps its own layout: readers that hash
    a file's bytes (``runs.data_fingerprint`` over scene records) see the bytes they saw before."""
    data = json.dumps(obj, indent=indent, sort_keys=sort_keys, default=default).encode()
    atomic_write(path, lambda f: f.write(data), durable=durable)
