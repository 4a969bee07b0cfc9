"""runtime.keep_freed_memory: glibc keeps freed memory for reuse (checked on the process's resident size)."""

from __future__ import annotations

import platform
import subprocess
import sys

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
