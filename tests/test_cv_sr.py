"""scripts/cv_sr.py: leave-one-layout-out folds of scene_sr.py pooled into one validation table."""

import json

import pytest

from tests._scripts import load_script

cv = load_script("cv_sr")


def fold(layout, name, srs, split="val", bench="layouts"):
    """A scene_sr.py JSON of one fold and one model: srs = {scene id: (task, views, SR)}."""
    scenes = {sid: {"task": t, "views": v, "sr": {name: sr}} for sid, (t, v, sr) in srs.items()}
    return {"benchmark": bench, "split": split, "val_layout": layout, "scenes": scenes}


F0 = {"L0_pnp": ("PnPCounterToCab", 4, 1.0), "L0_cd": ("CloseDrawer", 2, 0.5)}
F1 = {"L1_pnp": ("PnPCounterToCab", 2, 0.0), "L1_cd": ("CloseDrawer", 2, 1.0)}


def _docs():
    return [
        ("a0", fold(0, "occ", F0)),
        ("b0", fold(0, "prior", {k: (t, v, sr / 2) for k, (t, v, sr) in F0.items()})),
        ("a1", fold(1, "occ", F1)),
        ("b1", fold(1, "prior", F1)),
    ]


def test_folds_merge_by_scene_and_weigh_views():
    scenes, per_fold, bench = cv.merge_folds(_docs())
    assert bench == "layouts" and sorted(scenes) == ["L0_cd", "L0_pnp", "L1_cd", "L1_pnp"]
    assert scenes["L0_pnp"] == {"task": "PnPCounterToCab", "views": 4, "fold": 0, "sr": {"occ": 1.0, "prior": 0.5}}
    assert per_fold["0"] == pytest.approx({"occ": (4 * 1.0 + 2 * 0.5) / 6, "prior": (4 * 0.5 + 2 * 0.25) / 6})
    assert per_fold["1"] == pytest.approx({"occ": 0.5, "prior": 0.5})


@pytest.mark.parametrize(
    ("docs", "match"),
    [
        (lambda d: d[:3], r"L1_\w+ \(fold 1\) is not scored for \['prior'\]"),
        (lambda d: d + [("c1", fold(1, "occ", F1))], "occ scored twice on L1_"),
        (lambda d: d + [("t", fold(1, "x", F1, split="test"))], "t is not a fold"),
        (lambda d: d + [("s", fold(1, "x", F1, bench="styles"))], "mix benchmarks"),
        (lambda d: d + [("v", fold(1, "x", {"L1_cd": ("CloseDrawer", 3, 1.0)}))], "L1_cd has other views"),
        (lambda d: d + [("n", {"split": "val", "val_layout": 1, "benchmark": "layouts"})], r"n is not a .*no scenes"),
        (lambda d: d + [("l", [1, 2])], "l is not a fold"),  # a top-level list: an AttributeError before
        # no file names its benchmark: pooled as benchmark None, exit 0
        (lambda d: [("nb", {k: v for k, v in fold(1, "x", F1).items() if k != "benchmark"})], "nb is not a fold"),
        (lambda d: d + [("k", fold(1, "x", {"L1_zz": ("CloseDrawer", 0, 1.0)}))], r"scene L1_zz needs .*views >= 1"),
    ],
)
def test_bad_folds_exit_naming_what_is_wrong(docs, match):
    with pytest.raises(SystemExit, match=match):
        cv.merge_folds(docs(_docs()))


def test_main_pools_every_fold_and_writes_json(tmp_path, capsys):
    folder = tmp_path / "cv"
    folder.mkdir()
    for name, doc in _docs():
        (folder / f"{name}.json").write_text(json.dumps(doc))
    out = tmp_path / "new" / "pooled.json"  # a missing folder is made
    assert cv.main([str(folder), "--draws", "50", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    # occ: (4 + 1 + 0 + 2) / 10 views; prior: (2 + 0.5 + 0 + 2) / 10
    assert res["models"]["occ"]["sr_all"] == pytest.approx(0.7)
    assert res["models"]["prior"]["sr_all"] == pytest.approx(0.45)
    assert res["differences"]["occ - prior"]["diff"] == pytest.approx(0.25)
    assert "2 folds, 4 validation scenes, 4 files" in capsys.readouterr().out


def test_missing_or_empty_inputs_exit(tmp_path):
    with pytest.raises(SystemExit, match="no such file or folder"):
        cv.fold_files([str(tmp_path / "nope")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no fold JSON"):
        cv.fold_files([str(tmp_path / "empty")])
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "cv0_occ.json").write_text("{}")
    # one empty input among others: the comparison it was named for silently lacked its models
    with pytest.raises(SystemExit, match=r"no fold JSON in .*empty"):
        cv.fold_files([f"{tmp_path / 'full'}@old", f"{tmp_path / 'empty'}@new"])


def test_an_empty_tag_exits(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "cv0_occ.json").write_text("{}")
    # `full@` used to be read untagged, its names pooled with the other input's own
    with pytest.raises(SystemExit, match=r"full@: the tag after @ is empty"):
        cv.fold_files([str(tmp_path / "full"), f"{tmp_path / 'full'}@"])


def test_tagged_inputs_compare_one_model_from_two_runs(tmp_path):
    before, after = tmp_path / "before", tmp_path / "run@2" / "after"  # an @ inside the path, the tag after the last
    for folder, scale in ((before, 0.5), (after, 1.0)):
        folder.mkdir(parents=True)
        for f, srs in ((0, F0), (1, F1)):
            doc = fold(f, "succ", {k: (t, v, sr * scale) for k, (t, v, sr) in srs.items()})
            (folder / f"cv{f}_succ.json").write_text(json.dumps(doc))
    out = tmp_path / "pooled.json"
    assert cv.main([f"{after}@new", f"{before}@old", "--draws", "20", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["models"]["succ@new"]["sr_all"] == pytest.approx(0.7)
    assert res["models"]["succ@old"]["sr_all"] == pytest.approx(0.35)
    assert res["differences"]["succ@new - succ@old"]["diff"] == pytest.approx(0.35)
    assert res["files"][0].endswith("cv0_succ.json@new")
    with pytest.raises(SystemExit, match="succ scored twice"):  # untagged, the two runs collide
        cv.main([str(after), str(before), "--draws", "20"])


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ([1, 2], r"l\.json is not a scene_sr\.py --json output"),  # a list: an AttributeError in tagged
        ({"scenes": {"L0_a": [1]}}, r"l\.json: scene L0_a needs"),  # a scene that is a list: a TypeError
        ({"scenes": {"L0_a": {"task": "A", "views": 2, "sr": [0.5]}}}, r"l\.json: scene L0_a needs"),
    ],
)
def test_a_malformed_tagged_file_is_named(tmp_path, content, match):
    (tmp_path / "l.json").write_text(json.dumps(content))
    with pytest.raises(SystemExit, match=match):
        cv.main([f"{tmp_path / 'l.json'}@t", "--draws", "5"])


@pytest.mark.parametrize("layout", [[0], "x", True])
def test_a_fold_that_is_not_a_layout_number_is_named(layout):
    """A list was unhashable, a string beside numbers unsortable: TypeErrors after every file had been read."""
    docs = _docs() + [("w", fold(layout, "occ", {"L2_a": ("CloseDrawer", 2, 1.0)}))]
    with pytest.raises(SystemExit, match="w is not a fold"):
        cv.merge_folds(docs)


def test_a_negative_seed_is_a_usage_error(tmp_path, capsys):
    (tmp_path / "f.json").write_text(json.dumps(fold(0, "occ", F0)))
    with pytest.raises(SystemExit) as done:
        cv.main([str(tmp_path / "f.json"), "--seed", "-1", "--draws", "5"])
    assert done.value.code == 2 and "--seed must be >= 0" in capsys.readouterr().err
