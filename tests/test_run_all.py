"""benchmarks/run_all.py: refreshing some sections keeps the rest and adds new ones before the hand-written reading."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

_SPEC = importlib.util.spec_from_file_location("run_all", Path(__file__).parents[1] / "benchmarks" / "run_all.py")
run_all = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(run_all)


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
