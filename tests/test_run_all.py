"""benchmarks/run_all.py: refreshing some sections keeps the rest and adds new ones before the hand-written reading."""

from __future__ import annotations

import pytest

from tests._scripts import ROOT, load_benchmark

run_all = load_benchmark("run_all")


def test_merge_replaces_same_titles_and_inserts_new_sections_before_the_reading():
    old = "# Performance\n\nold head\n\n## A\n\nold a\n\n## B\n\nold b\n\n## Reading (by hand)\n\nmine\n"
    new = ["# Performance\n", "new head", "## B\n\nnew b\n", "## C\n\nnew c\n"]
    text = "\n".join(run_all._merge_sections(old, new))
    assert "new head" in text and "old head" not in text
    assert "old a" in text and "new b" in text and "old b" not in text and "mine" in text
    assert text.index("## A") < text.index("## B") < text.index("## C") < text.index("## Reading")


def test_an_unknown_only_name_is_refused_before_anything_runs_or_is_written(tmp_path, capsys):
    """A typo (or a name without .py) ran nothing, rewrote the report's header and exited 0; --only with no name
    ran the whole suite."""
    out = tmp_path / "perf.md"
    out.write_text("# Performance\n\nold head\n")
    for only in (["bench_predcit"], []):
        with pytest.raises(SystemExit) as exc:
            run_all.main(["--only", *only, "--out", str(out)])
        assert exc.value.code == 2
    assert "unknown script(s) ['bench_predcit.py']" in capsys.readouterr().err
    assert out.read_text() == "# Performance\n\nold head\n"


def test_a_report_write_that_fails_leaves_the_old_report_whole(tmp_path):
    """The report was rewritten in place: a write that failed part way (here a file-size limit, as a full disk
    would) left the first bytes of the new one and nothing of the old one's hand-written reading."""
    import subprocess
    import sys

    out = tmp_path / "perf.md"
    old = "# Performance\n\nold head\n\n## Reading (by hand)\n\nmine\n"
    out.write_text(old)
    driver = f"""
import resource, signal, subprocess
from tests._scripts import load_benchmark
run_all = load_benchmark("run_all")
run_all.subprocess.run = lambda cmd, **kw: subprocess.CompletedProcess(cmd, 0, stdout="x" * 100000, stderr="")
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead of killing
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
try:
    run_all.main(["--only", "bench_predict", "--out", {str(out)!r}])
except OSError as exc:
    print("write failed", exc.errno)
"""
    proc = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True, cwd=ROOT)
    assert "write failed" in proc.stdout, proc.stderr[-2000:]
    assert out.read_text() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["perf.md"]  # no temp file left either


def test_an_out_path_that_cannot_be_written_is_refused_before_the_suite_runs(tmp_path, monkeypatch, capsys):
    """An --out that is a folder, lies under a file or holds a report that is not text failed only at the write,
    after the whole suite (10-20 minutes) had run: its output was lost."""
    import subprocess

    ran = []
    monkeypatch.setattr(
        run_all.subprocess, "run", lambda cmd, **kw: ran.append(cmd) or subprocess.CompletedProcess(cmd, 0, "x", "")
    )
    (tmp_path / "file").write_text("x")
    (tmp_path / "binary.md").write_bytes(b"\xff\xfe\x00bad")
    (tmp_path / "dangling").symlink_to(tmp_path / "gone")
    (tmp_path / "link.md").symlink_to(tmp_path / "file" / "perf.md")  # written through: mkdir failed at the end
    for out, said in (
        (tmp_path / "dangling" / "perf.md", "cannot write under"),  # mkdir would fail only at the end
        (tmp_path, "is a folder"),
        (tmp_path / "file" / "sub" / "perf.md", "cannot write under"),
        (tmp_path / "link.md", "cannot write under"),
        (tmp_path / "binary.md", "cannot read the existing report"),
    ):
        with pytest.raises(SystemExit) as exc:
            run_all.main(["--only", "bench_predict", "--out", str(out)])
        assert exc.value.code == 2 and f"--out {out}: {said}" in capsys.readouterr().err
    assert ran == []
    assert (tmp_path / "binary.md").read_bytes() == b"\xff\xfe\x00bad"
    # a report in folders that do not exist yet is still written (the write creates them)
    assert run_all.main(["--only", "bench_predict", "--out", str(tmp_path / "new" / "perf.md")]) == 0
    assert (tmp_path / "new" / "perf.md").read_text().startswith("# Performance")
