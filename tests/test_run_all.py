"""benchmarks/run_all.py: refreshing some sections keeps the rest and adds new ones before the hand-written reading."""

from __future__ import annotations

import importlib.util
from pathlib import Path

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
