"""Process settings the command line applies before it trains or evaluates (standard library only).

:func:`keep_freed_memory` makes glibc's ``malloc`` keep freed memory for reuse. By default glibc serves
every allocation above its mmap threshold (at most 32 MB) with a fresh ``mmap`` and unmaps it on ``free``,
so each large activation of a training step (a [B, S, K, C] grouped tensor is ~130 MB at B=8) costs the
kernel's zero-filling of every page on first touch: on a 2-core CPU machine allocating and filling such a
tensor took 62 ms that way and 6 ms from reused memory. Measured on a whole training step (benchmarks/
bench_vs_port.py, docs/performance.md): PointNet++ SSG and H3DNet train ~1.4x faster, at ~25 % more peak
resident memory (freed memory stays with the process instead of going back to the system).

``floaff-zoo`` calls it at start; Python users call it themselves before training. Set
``FLOAFF_ZOO_MALLOC=system`` to keep the system's default behaviour.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import threading
import time
from collections.abc import Iterator

MALLOC_ENV = "FLOAFF_ZOO_MALLOC"
#: glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4

_state: dict[str, bool] = {}


def malloc_requested() -> str:
    """``FLOAFF_ZOO_MALLOC``: ``keep`` (default: keep freed memory) or ``system`` (leave malloc alone)."""
    value = os.environ.get(MALLOC_ENV, "keep").strip().lower() or "keep"
    if value not in ("keep", "system"):
        raise ValueError(f"{MALLOC_ENV}={value!r}: choose keep or system")
    return value


def keep_freed_memory() -> bool:
    """Ask glibc malloc to serve large blocks from its heap and never trim it (no mmap, no unmapping).

    Idempotent; affects allocations made after the call. Returns True when applied, False when
    ``FLOAFF_ZOO_MALLOC=system`` or the C library is not glibc (macOS, musl: nothing to do).
    """
    if malloc_requested() == "system":
        return False
    if "applied" in _state:
        return _state["applied"]
    ok = False
    try:
        libc = ctypes.CDLL(None)  # the symbols already loaded into this process (no library search at start-up)
        mallopt = getattr(libc, "mallopt", None)
        gnu = getattr(libc, "gnu_get_libc_version", None)
        if mallopt is not None and gnu is not None:
            mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            # no mmap for large blocks (they come from the heap) and no trimming of the heap's top
            ok = bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
    except OSError:
        ok = False
    _state["applied"] = ok
    return ok


#: the variables that cap the BLAS / OpenMP threads of a process (read when the library loads)
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def one_thread_children() -> Iterator[None]:
    """Worker processes started inside get one BLAS / OpenMP thread each (docs/background.md §5: a pool of
    workers oversubscribes the cores otherwise). A pool's initializer sets them too late: a spawned worker loads
    numpy while it unpickles the initializer's module. This process keeps its own threads, whose libraries are
    loaded already."""
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update(dict.fromkeys(THREAD_ENV, "1"))
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def exit_with_parent(parent: int, every_s: float = 0.5) -> None:
    """Start a daemon thread that ends this process once ``parent`` (a pid the parent passed down) is no longer its
    parent: a pool worker otherwise outlives a killed driver, finishing its queued jobs (and writing their files)
    and then waiting forever. The pid must come from the parent, not ``os.getppid()`` here: a spawned worker runs
    its initializer only after importing the job's modules (seconds), and a driver killed meanwhile left it
    watching init, its new parent, for ever. For workers the driver starts itself (the ``spawn`` context); under a
    forkserver their parent is the server, and they would exit at once."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(every_s)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()
