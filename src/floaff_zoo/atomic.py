"""Whole-file writes: a temp file in the destination's folder, renamed over it once complete.

Every file the package writes for others to read (generated scenes and views, cache entries, hub indexes and
weights, rollout caches) goes through here, so a killed writer never leaves half a file, and the file gets the mode
a plain ``open`` would have given it (``mkstemp`` makes owner-only files, which nobody else sharing a data or hub
folder could read).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def publish(tmp: str | os.PathLike[str], dest: str | os.PathLike[str]) -> None:
    """Rename the finished temp file ``tmp`` onto ``dest``, with the mode the umask gives a new file."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    os.replace(tmp, dest)


def atomic_write(path: str | os.PathLike[str], write: Callable[[BinaryIO], None], durable: bool = False) -> None:
    """Write ``path`` whole or not at all: ``write(f)`` fills a temp file beside it, which then replaces it.

    ``durable`` also flushes the data to disk before the rename (after a power loss the file is the old or the new
    one, never empty)."""
    path = Path(path)
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
