"""scripts/protocol_change.py: SR changes between two scene_sr outputs, with paired scene-bootstrap intervals."""

import json

import pytest

from tests._scripts import ROOT, load_script

pc = load_script("protocol_change")


def _scenes(sr: dict[str, list[float]]) -> dict:
    """Four scenes (two tasks, 100 / 300 views) with the given SR per name and scene."""
    tasks, views = ["A", "A", "B", "B"], [100, 300, 100, 300]
    return {f"s{i}": {"task": tasks[i], "views": views[i], "sr": {n: v[i] for n, v in sr.items()}} for i in range(4)}


def test_changes_are_view_weighted_and_paired(tmp_path, capsys):
    a = _scenes({"set": [1.0, 0.5, 0.5, 0.0], "point": [0.5, 0.5, 0.5, 0.5]})
    b = _scenes({"set": [0.5, 0.5, 0.5, 0.0], "point": [0.4, 0.4, 0.4, 0.4]})
    res = pc.changes(a, b, draws=200, seed=0)
    assert res["models"]["set"]["change"] == pytest.approx(-0.5 * 100 / 800)
    point = res["models"]["point"]
    assert point["change"] == pytest.approx(-0.1) and point["p05"] == pytest.approx(point["p95"])  # a constant shift
    assert res["differences"]["set - point"]["diff"] == pytest.approx(-0.0625 + 0.1)
    for name, data in (("a.json", a), ("b.json", b)):
        (tmp_path / name).write_text(json.dumps({"scenes": data}))
    assert pc.main([str(tmp_path / "a.json"), str(tmp_path / "b.json"), "--draws", "50"]) == 0
    assert "| point | 0.500 | 0.400 | -0.100 |" in capsys.readouterr().out


def test_files_of_other_scenes_or_no_shared_name_are_refused(tmp_path):
    a = _scenes({"m": [1.0, 1.0, 1.0, 1.0]})
    with pytest.raises(SystemExit, match="different scenes"):
        pc.changes(a, {k: v for k, v in a.items() if k != "s0"}, 10, 0)
    with pytest.raises(SystemExit, match="share no model"):
        pc.changes(a, _scenes({"other": [1.0, 1.0, 1.0, 1.0]}), 10, 0)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(SystemExit, match="bad.json is not a scene_sr.py --json output"):
        pc.load(str(tmp_path / "bad.json"))


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"scenes": {}}, "no scenes"),  # a StopIteration traceback before
        ({"scenes": {"s0": {"task": "A", "views": 0, "sr": {"m": 1.0}}}}, r"s0 needs .*views >= 1"),  # printed nan
        ({"scenes": {"s0": {"task": "A", "views": 3, "sr": {"m": "0.5"}}}}, r"SR values in \[0, 1\]"),
    ],
)
def test_a_malformed_scene_table_is_named(tmp_path, doc, match):
    (tmp_path / "x.json").write_text(json.dumps(doc))
    with pytest.raises(SystemExit, match=match):
        pc.load(str(tmp_path / "x.json"))


def test_a_json_write_that_fails_leaves_the_old_file_whole(tmp_path):
    """--json was rewritten in place: a write that failed part way (here a file-size limit, as a full disk would)
    left the first bytes of the new table and nothing of the old one; it is written whole or not at all."""
    import subprocess
    import sys

    a = _scenes({"m": [1.0, 0.5, 0.5, 0.0]})
    for name in ("a.json", "b.json"):
        (tmp_path / name).write_text(json.dumps({"scenes": a}))
    out = tmp_path / "out.json"
    out.write_text('{"old": true}\n')
    driver = f"""
import resource, signal
from tests._scripts import load_script
pc = load_script("protocol_change")
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead of killing
resource.setrlimit(resource.RLIMIT_FSIZE, (256, 256))
try:
    pc.main([{str(tmp_path / "a.json")!r}, {str(tmp_path / "b.json")!r}, "--draws", "5", "--json", {str(out)!r}])
except OSError as exc:
    print("write failed", exc.errno)
"""
    proc = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True, cwd=ROOT)
    assert "write failed" in proc.stdout, proc.stderr[-2000:]
    assert out.read_text() == '{"old": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json", "out.json"]  # no temp file left


def test_a_negative_seed_is_a_usage_error(tmp_path, capsys):
    """--seed -1 reached numpy's generator and ended the script with a ValueError traceback."""
    (tmp_path / "a.json").write_text(json.dumps({"scenes": _scenes({"m": [1.0, 0.5, 0.5, 0.0]})}))
    with pytest.raises(SystemExit) as done:
        pc.main([str(tmp_path / "a.json"), str(tmp_path / "a.json"), "--seed", "-1"])
    assert done.value.code == 2 and "--seed must be >= 0, got -1" in capsys.readouterr().err


def test_a_name_not_in_both_files_is_said_to_be_left_out(tmp_path, capsys):
    """A NAME scored in one file only (or on some scenes) vanished from the table without a word."""
    a = _scenes({"m": [1.0, 1.0, 1.0, 1.0], "old": [0.0, 0.0, 0.0, 0.0]})
    b = _scenes({"m": [1.0, 1.0, 1.0, 1.0], "new": [1.0, 1.0, 1.0, 1.0]})
    for name, doc in (("a.json", a), ("b.json", b)):
        (tmp_path / name).write_text(json.dumps({"scenes": doc}))
    assert pc.main([str(tmp_path / "a.json"), str(tmp_path / "b.json"), "--draws", "5"]) == 0
    assert "left out (not scored on every scene of both files): new, old" in capsys.readouterr().out
    assert pc.changes(a, b, 5, 0)["left_out"] == ["new", "old"]
