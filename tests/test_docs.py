"""The repository documents itself: nothing points at documents outside it, and the figures of the README and the
config headers are the measured ones of docs/performance.md."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

from floaff_zoo.hub.registry import read_retired

ROOT = Path(__file__).resolve().parents[1]
#: names of the notes the project was started from, which do not ship with it, and paths outside the repository
OUTSIDE = re.compile(
    r"\b(?:REFERENCE|SIMULATOR|PERFORMANCE|CONVENTIONS|COMMON)(?:\.md|\s+§)|\.\./shared\b|shared/(?:docs|paper)/"
)
#: files allowed to keep a stale pointer while being fixed (the test says so once one is fixed)
PENDING: set[str] = set()
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".json", ".sh", ".txt", ".cfg", ".ini", ""}


def _repo_files() -> list[str]:
    try:
        out = subprocess.run(
            ["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the file list comes from git ls-files")
    return [f for f in out.splitlines() if Path(f).suffix in TEXT_SUFFIXES and (ROOT / f).is_file()]


def _pointers() -> dict[str, list[str]]:
    hits: dict[str, list[str]] = {}
    for f in _repo_files():
        if f == "tests/test_docs.py":
            continue
        for no, line in enumerate((ROOT / f).read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if OUTSIDE.search(line):
                hits.setdefault(f, []).append(f"{f}:{no}: {line.strip()[:120]}")
    return hits


def test_nothing_points_outside_the_repository():
    hits = _pointers()
    bad = [line for f, lines in sorted(hits.items()) if f not in PENDING for line in lines]
    assert not bad, "pointers to documents that are not in the repository (use docs/background.md):\n" + "\n".join(bad)
    fixed = sorted(PENDING - set(hits))
    assert not fixed, f"no stale pointer left in {fixed}: remove them from PENDING in tests/test_docs.py"


def _absolute_paths(value: object) -> list[str]:
    """The string values of a JSON document that are absolute paths (a folder of the machine that wrote it)."""
    if isinstance(value, str):
        return [value] if re.match(r"/[^/\s]+/", value) else []
    items = value.values() if isinstance(value, dict) else value if isinstance(value, list) else []
    return [p for v in items for p in _absolute_paths(v)]


#: a machine's folder in text: an absolute path under a usual root
MACHINE_FOLDER = re.compile(r"(?<![\w.~])/(?:work|home|root|tmp|mnt|Users|opt|data)/[\w.-]+")


def test_committed_reports_name_no_folder_of_a_machine():
    """Reports and tables are committed: a path in them is relative to the checkout (reports copied from a run in a
    git worktree once kept the main checkout's absolute paths)."""
    bad = []
    for f in _repo_files():
        if f.startswith("docs/") and f.endswith(".json"):
            found = _absolute_paths(json.loads((ROOT / f).read_text(encoding="utf-8")))
            bad += [f"{f}: {p[:80]}" for p in found[:1]]
        elif f.startswith("docs/results/") and f.endswith("report.md"):  # the copied report's rendering
            found = MACHINE_FOLDER.findall((ROOT / f).read_text(encoding="utf-8"))
            bad += [f"{f}: {p}" for p in found[:1]]
    assert not bad, "absolute paths in committed reports:\n" + "\n".join(bad[:20])


def test_background_sections_that_code_cites_exist():
    text = (ROOT / "docs/background.md").read_text(encoding="utf-8")
    sections = set(re.findall(r"^#+ (§\d+(?:\.\d+)?)", text, flags=re.M))
    cited = set()
    for f in _repo_files():
        if f.startswith("tests/test_docs.py"):
            continue
        body = (ROOT / f).read_text(encoding="utf-8", errors="replace")
        cited |= set(re.findall(r"background\.md\)?,? (§\d+(?:\.\d+)?)", body))
    assert cited, "nothing cites docs/background.md"
    assert cited <= sections, f"cited sections missing from docs/background.md: {sorted(cited - sections)}"


#: benchmark rows that are a variant of a shipped config (benchmarks/bench_models.py WITH_AXISNET)
PSEUDO_MODELS = {"cfar_axisnet": "cfar"}


def _performance_models() -> dict[str, tuple[str, str, str | None]]:
    """model config name -> (params M, predict ms, train samples/s or None) from docs/performance.md."""
    text = (ROOT / "docs/performance.md").read_text(encoding="utf-8")
    block = text.split("== models, mode eager", 1)[1].split("==", 1)[0]
    out = {}
    for line in block.splitlines():
        m = re.match(
            r"(\w+)\s+([\d.]+) M params\s+(?:train\s+([\d.]+) samples/s.*?|training-free); predict\s+([\d.]+) ms",
            line.strip(),
        )
        if m:
            out[m.group(1)] = (m.group(2), m.group(4), m.group(3))
    return out


def test_model_config_headers_quote_docs_performance():
    measured = _performance_models()
    assert {"pointnet2_ssg", "cfar", "navaff"} <= set(measured)
    for name, (params, predict, train) in measured.items():
        config = PSEUDO_MODELS.get(name, name)  # a benchmark variant is quoted in its base config's header
        header = "\n".join(
            ln for ln in (ROOT / f"configs/models/{config}.yaml").read_text().splitlines() if ln.startswith("#")
        )
        assert "docs/performance.md" in header, name
        assert f"predict {predict} ms" in header, (name, predict)
        if train is not None:
            assert f"{params} M params" in header and f"train {train} samples/s" in header, (name, params, train)


def test_readme_hub_names_exist():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    shipped = {e["name"] for e in json.loads((ROOT / "src/floaff_zoo/hub/index.json").read_text())["entries"]}
    retired = set(read_retired())  # loading one says where it is: named only where the README lists what was retired
    start = readme.index("Earlier versions were retired from the package")
    end = readme.index("\n\n", start)
    names = re.compile(r"\b[a-z0-9][a-z0-9-]*\.floaff-[a-z0-9-]+\.v\d+\b")
    elsewhere = set(names.findall(readme[:start] + readme[end:]))
    in_retired = set(names.findall(readme[start:end]))
    assert elsewhere, "the README names no hub entry"
    assert elsewhere <= shipped, f"README uses hub entries that do not ship: {sorted(elsewhere - shipped)}"
    assert in_retired <= shipped | retired, (
        f"README lists unknown hub entries: {sorted(in_retired - shipped - retired)}"
    )
