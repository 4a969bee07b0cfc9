"""scripts/episodes_sr.py: per-scene SR from `floaff-zoo test` episode files, in scene_sr's scene table."""

import json

import pytest

from tests._scripts import load_script

es = load_script("episodes_sr")


def _episodes(wins: dict[str, list[bool]]) -> list[dict]:
    """Episodes of scenes s0 (task A) and s1 (task B), one per listed outcome."""
    return [
        {"sample_id": f"{sid}/v{i}", "scene_id": sid, "task": "A" if sid == "s0" else "B", "success": w}
        for sid, outcomes in wins.items()
        for i, w in enumerate(outcomes)
    ]


def test_scene_table_counts_each_views_success(tmp_path, capsys):
    a = tmp_path / "a.json"
    b = tmp_path / "b.json"
    a.write_text(json.dumps(_episodes({"s0": [True, False, True, True], "s1": [False, False]})))
    b.write_text(json.dumps(_episodes({"s0": [False, False, True, True], "s1": [True, False]})))
    out = tmp_path / "t.json"
    assert es.main([f"map={a}", f"own={b}", "--json", str(out)]) == 0
    scenes = json.loads(out.read_text())["scenes"]
    assert scenes["s0"] == {"task": "A", "views": 4, "sr": {"map": 0.75, "own": 0.5}}
    assert scenes["s1"] == {"task": "B", "views": 2, "sr": {"map": 0.0, "own": 0.5}}
    printed = capsys.readouterr().out
    assert "map: SR_all 0.500 over 6 views of 2 scenes" in printed and "own: SR_all 0.500" in printed
    # the table is what protocol_change.py reads (one name per file there)
    pc = load_script("protocol_change")
    for name, src in (("x.json", a), ("y.json", b)):
        assert es.main([f"m={src}", "--json", str(tmp_path / name)]) == 0
    res = pc.changes(pc.load(str(tmp_path / "x.json")), pc.load(str(tmp_path / "y.json")), draws=20, seed=0)
    assert res["models"]["m"]["change"] == pytest.approx(0.0)


def test_bad_files_are_named(tmp_path, capsys):
    good = tmp_path / "good.json"
    good.write_text(json.dumps(_episodes({"s0": [True], "s1": [False]})))
    other = tmp_path / "other.json"
    other.write_text(json.dumps(_episodes({"s0": [True, True], "s1": [False]})))
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps([{"sample_id": "x", "scene_id": "s0", "task": "A", "success": 1}]))
    out = str(tmp_path / "t.json")
    with pytest.raises(SystemExit, match="other holds other views than good"):
        es.main([f"good={good}", f"other={other}", "--json", out])
    with pytest.raises(SystemExit, match="broken.json: episode 0 lacks one of"):
        es.main([f"b={broken}", "--json", out])
    with pytest.raises(SystemExit, match="missing.json is not a readable sr_episodes.json"):
        es.main([f"m={tmp_path / 'missing.json'}", "--json", out])
    for bad, why in (
        (["no-equals-sign"], "'no-equals-sign' is not NAME=PATH"),
        ([f"a={good}", f"a={other}"], "given twice"),
    ):
        with pytest.raises(SystemExit) as done:
            es.main([*bad, "--json", out])
        assert done.value.code == 2 and why in capsys.readouterr().err


@pytest.mark.parametrize(
    ("episodes", "match"),
    [
        ([{"sample_id": ["a"], "scene_id": "s0", "task": "A", "success": True}], "episode 0 lacks"),  # a TypeError
        ([{"sample_id": "a", "scene_id": ["s0"], "task": "A", "success": True}], "episode 0 lacks"),  # a TypeError
        ([{"sample_id": "a", "scene_id": "s0", "task": 3, "success": True}], "episode 0 lacks"),  # written as is
        (
            _episodes({"s0": [True]}) + [{"sample_id": "b", "scene_id": "s0", "task": "B", "success": False}],
            "two tasks",
        ),
    ],
)
def test_malformed_episodes_are_named(tmp_path, episodes, match):
    (tmp_path / "e.json").write_text(json.dumps(episodes))
    with pytest.raises(SystemExit, match=match):
        es.main([f"e={tmp_path / 'e.json'}", "--json", str(tmp_path / "t.json")])


def test_a_view_in_another_scene_than_the_first_runs_is_named(tmp_path):
    """The same views under other scenes were counted there: a silently wrong SR for both scenes."""
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(_episodes({"s0": [True, False]})))
    moved = _episodes({"s0": [True, True]})
    moved[0] |= {"scene_id": "s1", "task": "B"}
    b.write_text(json.dumps(moved))
    with pytest.raises(SystemExit, match="b puts view s0/v0 in another scene or task than a"):
        es.main([f"a={a}", f"b={b}", "--json", str(tmp_path / "t.json")])
