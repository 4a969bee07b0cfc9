"""runtime.keep_freed_memory: glibc keeps freed memory for reuse (checked on the process's resident size)."""

from __future__ import annotations

import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from floaff_zoo import cli, runtime

glibc_only = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's (Linux)"
)

_PROBE = """
import os, sys, torch
from floaff_zoo import runtime
applied = runtime.keep_freed_memory()
page = os.sysconf("SC_PAGE_SIZE")
rss = lambda: int(open("/proc/self/statm").read().split()[1]) * page
before = rss()
x = torch.ones(64 * 1024 * 1024 // 4)  # 64 MB, touched
del x
print(applied, (rss() - before) / 2**20)
"""


def _probe(mode: str) -> tuple[bool, float]:
    env = {**__import__("os").environ, runtime.MALLOC_ENV: mode}
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True).stdout
    applied, kept_mb = out.split()
    return applied == "True", float(kept_mb)


@glibc_only
def test_freed_memory_is_kept_only_when_asked():
    applied, kept = _probe("keep")
    assert applied and kept > 48  # the freed 64 MB block stays with the process, ready for reuse
    applied, kept = _probe("system")
    assert not applied and kept < 16  # glibc's default: a large block is unmapped on free


def test_bad_setting_is_named(monkeypatch, capsys):
    monkeypatch.setenv(runtime.MALLOC_ENV, "jemalloc")
    with pytest.raises(ValueError, match="FLOAFF_ZOO_MALLOC"):
        runtime.malloc_requested()
    monkeypatch.setattr(sys, "argv", ["floaff-zoo", "--version"])
    assert cli.main() == 2
    assert "FLOAFF_ZOO_MALLOC='jemalloc'" in capsys.readouterr().err


_DRIVER = """
import multiprocessing as mp, os, sys, threading, time


def job_fn(job, out, preset, images):
    time.sleep(120)


if __name__ == "__main__":
    if sys.argv[1] == "generate":  # generate's own pool, as _run_local starts it
        from floaff_zoo.sim.generate import _in_shared_pool

        jobs = _in_shared_pool([1, 2], 2, job_fn, "out", {}, False)
        threading.Thread(target=lambda: next(jobs, None), daemon=True).start()
    else:  # the rollout service's pool
        from floaff_zoo.sim.rollout import RolloutService

        pool = RolloutService(workers=2)._new_pool()
        for _ in range(2):
            pool.submit(time.sleep, 120)
    while len(mp.active_children()) < 2:
        time.sleep(0.001)
    with open("pids.txt", "w") as f:  # the log takes the workers' own output as well
        f.write(" ".join(str(p.pid) for p in mp.active_children()))
    os._exit(0)  # killed at once: its workers are still importing the initializer's module
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("pool", ["generate", "rollout"])
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_pool_workers_end_with_a_driver_killed_before_their_initializer_ran(tmp_path, pool):
    """`generate` killed in its first seconds left its workers running: a spawned worker runs its initializer only
    after importing the initializer's module, and the initializer took its parent from os.getppid(), by then init.
    They went on committing scenes into --out beside a rerun, then waited for ever. The rollout service's workers
    had no watch at all."""
    script = tmp_path / "driver.py"
    script.write_text(_DRIVER)
    log = tmp_path / "driver.log"  # not a pipe: orphans would hold it open, and run() would wait for them
    with open(log, "w") as out:
        done = subprocess.run([sys.executable, str(script), pool], stdout=out, stderr=subprocess.STDOUT, cwd=tmp_path)
    pids = tmp_path / "pids.txt"
    workers = [int(p) for p in pids.read_text().split()] if pids.is_file() else []
    assert done.returncode == 0 and len(workers) == 2, log.read_text()
    deadline = time.monotonic() + 90  # a worker still imports torch and MuJoCo, on a busy 2-core machine
    try:
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.5)
        left = [p for p in workers if _alive(p)]
        assert not left, f"worker(s) {left} outlived their driver"
    finally:
        for p in workers:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
