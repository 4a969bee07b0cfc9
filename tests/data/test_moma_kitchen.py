"""MoMaKitchenDataModule on a fixture in the exact official layout (tests/data/moma_kitchen/data.py)."""

import math

import numpy as np
import pytest
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.data.moma_kitchen import (
    FLAG_RADIUS,
    LABEL_TXT,
    MoMaKitchenDataModule,
    estimate_target_yaw,
    read_ply,
    target_flags,
)
from floaff_zoo.data.readers import DataError
from floaff_zoo.data.transforms import OfficialNormalize


def _dm(root, **kw):
    args = dict(root=str(root), val_fraction=0.34, batch_size=2, num_points=256, cache=False)
    args.update(kw)
    return MoMaKitchenDataModule(**args)


def test_skips_counted_and_summarised(moma_root, capsys):
    root, exp = moma_root
    dm = _dm(root)
    dm.setup("fit")
    dm.setup("test")
    got = dict(dm.skips["train"].counts)
    assert got == exp["skips"]
    out = capsys.readouterr().out
    assert "skipped 7 sample(s)" in out and "elephant" in out and "144 points" in out
    kept = sorted(r.key for s in ("train", "val") for r in dm.datasets[s].records)
    assert kept == sorted(exp["kept"]["train"])


def test_split_order_index_and_scene_level_val(moma_root):
    root, exp = moma_root
    dm = _dm(root)
    dm.setup("fit")
    dm.setup("test")
    test = dm.datasets["test"]
    assert [r.key for r in test.records] == exp["kept"]["test"]  # split-file order, not sorted
    metas = [test[i]["meta"] for i in range(len(test))]
    assert [m["index"] for m in metas] == [0, 1, 2]
    assert [m["split_line"] for m in metas] == [0, 1, 2]
    tr = {r.meta["scene_id"] for r in dm.datasets["train"].records}
    va = {r.meta["scene_id"] for r in dm.datasets["val"].records}
    assert tr and va and not tr & va
    again = _dm(root)
    again.setup("fit")
    assert [r.key for r in again.datasets["val"].records] == [r.key for r in dm.datasets["val"].records]
    loader = dm.test_dataloader()
    assert [m["sample_id"] for b in loader for m in b["meta"]] == exp["kept"]["test"]


def test_sample_fields_flags_and_labels(moma_root):
    root, exp = moma_root
    dm = _dm(root)
    dm.setup("fit")
    ds = next(
        dm.datasets[x] for x in ("train", "val") if exp["barrier_sample"] in [r.key for r in dm.datasets[x].records]
    )
    i = [r.key for r in ds.records].index(exp["barrier_sample"])
    s = ds[i]
    n = s["scene_xyz"].shape[0]
    assert s["scene_feat"].shape == (n, 1) and s["floor_xyz"].shape == (exp["floor_points"], 3)
    assert s["robot"].tolist() == pytest.approx([0.7, 0.33])  # xarm
    flag = s["scene_feat"][:, 0]
    assert set(flag.unique().tolist()) == {-1.0, 0.0, 1.0}
    d = root / "rgbd" / exp["barrier_sample"]
    target = read_ply(d / "point_cloud_transformed" / "target_pcd_transformed.ply")
    assert torch.allclose(s["target_xyz"], torch.tensor(target.mean(0), dtype=torch.float32), atol=1e-5)
    assert (flag == 1).sum() >= len(target) - 2  # target points are in the global cloud
    # labels: CSV column 3, one row per floor point, in order
    csv = np.loadtxt(d / LABEL_TXT, delimiter=",")
    assert np.allclose(s["floor_label"].numpy(), csv[:, 3], atol=1e-6)
    assert np.allclose(s["floor_xyz"].numpy(), csv[:, :3], atol=1e-5)
    # yaw estimate: from the target toward the robot origin
    t = s["target_xyz"]
    assert float(s["target_yaw"]) == pytest.approx(math.atan2(-t[1], -t[0]), abs=1e-5)


def test_flag_radius_and_barrier_override():
    scene = np.array([[0, 0, 0], [0.03, 0, 0], [0.05, 0, 0], [1, 0, 0], [1.02, 0, 0.0]])
    target = np.array([[0, 0, 0], [1.0, 0, 0]])
    barrier = np.array([[1.0, 0.0, 0.0]])
    f = target_flags(scene, target, [], FLAG_RADIUS)
    assert f.tolist() == [1, 1, 0, 1, 1]
    f = target_flags(scene, target, [barrier], FLAG_RADIUS)
    assert f.tolist() == [1, 1, 0, -1, -1]


def test_yaw_estimators():
    tc = np.array([2.0, 0.0, 1.0])
    floor = np.array([[1.0, 1.0, 0], [1.0, -1.0, 0], [3.0, 0.0, 0]])
    assert abs(estimate_target_yaw("toward_origin", tc, floor, np.ones(3), None)) == pytest.approx(math.pi)
    assert estimate_target_yaw("toward_view", tc, floor, np.ones(3), (2.0, 5.0)) == pytest.approx(math.pi / 2)
    assert estimate_target_yaw("label_centroid", tc, floor, np.array([1.0, 0, 0]), None) == pytest.approx(
        math.atan2(1, -1)
    )
    with pytest.raises(ValueError, match="toward_origin"):
        estimate_target_yaw("nope", tc, floor, np.ones(3), None)


def test_strict_names_file_and_problem(moma_root):
    root, _ = moma_root
    with pytest.raises(DataError, match="world_pcd_transformed.ply: file missing"):
        _dm(root, strict=True).setup("fit")


@pytest.mark.parametrize("ascii_ply", [False, True])
def test_a_truncated_ply_is_refused_naming_it(tmp_path, ascii_ply):
    """open3d reads a PLY cut short with its header's point count, the rest from uninitialised memory: strict mode
    let such a sample through, and a skip depended on what that memory held."""
    from tests.data.moma_kitchen.data import _write_ascii_ply, _write_ply

    whole = tmp_path / "whole.ply"
    xyz = np.random.default_rng(0).uniform(-1, 1, (144, 3))
    (_write_ascii_ply if ascii_ply else _write_ply)(whole, xyz)
    assert np.allclose(read_ply(whole), xyz)
    raw = whole.read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(raw[: raw.index(b"end_header") + 11 + (10 * 24 if not ascii_ply else 400)])
    with pytest.raises(DataError, match=rf"{cut}: truncated PLY \(its header declares 144 vertices") as info:
        read_ply(cut)
    assert info.value.kind == "corrupt_ply"


@pytest.mark.parametrize(
    "body, match",
    [
        ("1 2 3\n4 5 6\n7 8\n", r"vertex row 2 holds 2\)"),  # cut inside its last row
        ("1 2 3\n4 5 x\n7 8 9\n", "vertex row 1 holds a word that is no number"),
    ],
)
def test_an_ascii_ply_row_cut_short_or_not_numeric_is_refused(tmp_path, body, match):
    """Counting non-empty lines let a row cut inside itself through: open3d filled the missing value from
    uninitialised memory (it printed 'Unexpected end of file' and raised nothing)."""
    ply = tmp_path / "bad.ply"
    header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    ply.write_text(header + "end_header\n" + body)
    with pytest.raises(DataError, match=match) as info:
        read_ply(ply)
    assert info.value.kind == "corrupt_ply" and str(ply) in str(info.value)
    ply.write_text(header + "end_header\n1 2 3\n4 5 6\n7 8 9\n")
    assert np.allclose(read_ply(ply), [[1, 2, 3], [4, 5, 6], [7, 8, 9]])


def test_extra_robot_keeps_sample(moma_root):
    root, exp = moma_root
    dm = _dm(root, extra_robots={"elephant": [0.6, 0.5]})
    dm.setup("fit")
    assert "unknown_robot" not in dm.skips["train"].counts
    robots = {r.meta["robot_name"] for s in ("train", "val") for r in dm.datasets[s].records}
    assert "elephant" in robots


def test_robot_table_entries_are_checked_by_name():
    for bad, match in (
        ({"elephant": 0.9}, "robot 'elephant' needs a list of finite numbers, got 0.9"),
        ({"elephant": [0.6]}, "must all have the same length"),
        # a NaN made every sample of the robot a skip that named the sample folders, not the table
        ({"elephant": [0.6, float("nan")]}, r"robots / extra_robots: robot 'elephant' needs a list of finite"),
        # every sample of the robot came with robot [0], and an int name failed in the reader's .lower()
        ({"ur5e": [], "xarm": [], "flexiv": [], "panda": []}, r"robot 'ur5e' has an empty descriptor"),
        ({7: [0.6, 1.0]}, r"robots / extra_robots: robot names must be texts, got 7"),
    ):
        with pytest.raises(ValueError, match=match):
            _dm("unused", extra_robots=bad)


@pytest.mark.parametrize("field, value", [("seed", -1), ("max_samples", 0), ("max_samples", -2)])
def test_a_negative_seed_or_a_non_positive_max_samples_is_named(field, value):
    """A negative seed failed at setup as numpy's bare 'expected non-negative integer' (or, with pre-transforms,
    skipped every sample); max_samples 0 kept every record and a negative one dropped the last ones."""
    with pytest.raises(ValueError, match=f"data.{field} must be an integer >= "):
        _dm("unused", **{field: value})


@pytest.mark.parametrize("radius", [0.0, -0.031, float("nan"), float("inf"), True, "0.031"])
def test_a_flag_radius_that_flags_nothing_is_named(radius):
    """0, a negative or a NaN flag radius flagged no point as target or obstacle, silently, in every sample."""
    with pytest.raises(ValueError, match=r"data.flag_radius must be a finite number > 0 \(a distance in metres\)"):
        _dm("unused", flag_radius=radius)


def test_a_scene_is_held_out_by_its_own_draw_whatever_other_scenes_exist(moma_root, tmp_path):
    """The val scenes were a seeded permutation of the scenes that survived indexing: one missing folder (or
    max_samples) moved other scenes between train and val, so a scene trained in one run and validated in another."""
    import shutil

    root, _ = moma_root

    def split(r, **kw):
        dm = _dm(r, val_fraction=0.5, **kw)
        dm.setup("fit")
        return {s: {x.meta["scene_id"] for x in dm.datasets[s].records} for s in ("train", "val")}

    full = split(root)
    scenes = sorted(full["train"] | full["val"])
    assert len(scenes) >= 3 and full["val"] and full["train"]
    for gone in scenes:
        part = tmp_path / gone
        shutil.copytree(root, part, ignore=shutil.ignore_patterns(".cache"))
        for folder in part.rglob(f"*{gone}*"):
            if folder.is_dir() and folder.exists():
                shutil.rmtree(folder)
        got = split(part)
        assert gone not in got["train"] | got["val"]
        left = set(scenes) - {gone}
        for s, other in (("train", "val"), ("val", "train")):
            if full[other] & left:  # else the rule 'one scene on each side' must move one
                assert full[s] & left <= got[s], (gone, s, full, got)


def test_a_view_folder_name_that_does_not_parse_does_not_abort_setup(moma_root):
    """position_3.1.5_...: the folder's position is unknown (only yaw_estimator toward_view needs it)."""
    import re

    root, exp = moma_root
    split = root / "data_split" / "kitchen_train.txt"
    lines = split.read_text().splitlines()
    rel = next(x.strip() for x in lines if x.strip() and (root / "rgbd" / x.strip()).is_dir())
    parent, name = rel.split("/")
    bad = re.sub(r"^position_[^_]+_", "position_3.1.5_", name)
    assert bad != name
    (root / "rgbd" / parent / name).rename(root / "rgbd" / parent / bad)
    split.write_text(split.read_text().replace(name, bad))
    dm = _dm(root)
    dm.setup("fit")
    kept = {r.key for s in ("train", "val") for r in dm.datasets[s].records}
    assert f"{parent}/{bad}" in kept and dict(dm.skips["train"].counts) == exp["skips"]


def test_faithful_pad_mode_and_official_normalize(moma_root):
    root, _ = moma_root
    dm = _dm(
        root, collate_mode="pad", num_points=300, num_floor=200, val_fraction=0.0, pre_transforms=[OfficialNormalize()]
    )
    dm.setup("fit")
    assert dm.datasets["val"] is dm.datasets["test"]  # official: evaluate test every epoch
    b = next(iter(dm.val_dataloader()))
    assert b["scene_xyz"].shape == (2, 300, 3) and b["floor_xyz"].shape == (2, 200, 3)
    assert b["scene_mask"].all()  # clouds longer than 300 are truncated
    assert b["floor_mask"].sum(1).tolist() == [144, 144] and not b["floor_mask"][:, 144:].any()
    assert (b["floor_label"][:, 144:] == 0).all()
    r = b["scene_xyz"].norm(dim=-1)
    assert r.max() <= 1.0 + 1e-5  # normalised global cloud (truncation keeps a subset)


def test_bad_roots_and_empty_split(moma_root, tmp_path):
    root, _ = moma_root
    with pytest.raises(MisconfigurationException, match="does not exist"):
        _dm(tmp_path / "nowhere").setup("fit")
    (root / "data_split" / "kitchen_test.txt").write_text("\n")
    with pytest.raises(MisconfigurationException, match="kitchen_test.txt is empty"):
        _dm(root).setup("test")
    with pytest.raises(ValueError, match="yaw_estimator"):
        _dm(root, yaw_estimator="sideways")


def test_cache_hit_and_invalidation(moma_root, monkeypatch):
    root, exp = moma_root
    dm = _dm(root, cache=True)
    dm.setup("test")
    first = dm.datasets["test"][0]
    entries = list((root / ".cache").rglob("*.pt"))
    assert len(entries) == 3 and list((root / ".cache").rglob("config.json"))
    # second setup: everything from the cache, the PLY reader is never called
    calls = []
    import floaff_zoo.data.moma_kitchen as mk

    real = mk.read_ply
    monkeypatch.setattr(mk, "read_ply", lambda *a, **k: calls.append(a) or real(*a, **k))
    dm2 = _dm(root, cache=True)
    dm2.setup("test")
    assert torch.equal(dm2.datasets["test"][0]["scene_xyz"], first["scene_xyz"]) and not calls
    # editing a source file (new size/mtime) misses the cache for that sample only
    rel = exp["kept"]["test"][0]
    csv = root / "rgbd" / rel / LABEL_TXT
    rows = np.loadtxt(csv, delimiter=",")
    rows[:, 3] = 0.5
    np.savetxt(csv, rows, delimiter=",", fmt="%.7f")
    dm3 = _dm(root, cache=True)
    dm3.setup("test")
    assert len(calls) == 3  # global, floor, target of one sample
    assert torch.allclose(dm3.datasets["test"][0]["floor_label"], torch.full((144,), 0.5))
    # a different reader setting uses a different cache directory
    _dm(root, cache=True, flag_radius=0.05).setup("test")
    assert len({p.parent for p in (root / ".cache").rglob("*.pt")}) == 2


def test_robust_getitem_after_file_loss(moma_root, capsys):
    root, exp = moma_root
    dm = _dm(root)
    dm.setup("test")
    (root / "rgbd" / exp["kept"]["test"][0] / "point_cloud_transformed" / "world_pcd_transformed.ply").unlink()
    s = dm.datasets["test"][0]  # replaced by the next sample, not a crash mid-epoch
    assert s["meta"]["sample_id"] == exp["kept"]["test"][1]
    assert s["meta"]["replaces"] == dm.datasets["test"].records[0].key  # counted downstream by this mark
    assert "failed at load time" in capsys.readouterr().out


def test_label_centroid_warns_when_the_test_split_is_set_up(moma_root):
    """The estimate reads the labels: the test split's target_yaw then carries the test labels, without a word."""
    root, _ = moma_root
    with pytest.warns(UserWarning, match="label_centroid estimates the test samples' target_yaw from their labels"):
        _dm(root, yaw_estimator="label_centroid").setup("test")


def test_a_split_file_that_is_no_utf8_text_or_repeats_a_line(moma_root):
    """A latin-1 byte died as a bare UnicodeDecodeError naming no file; a repeated line loaded its sample twice
    (counted twice by the metrics) without a word."""
    root, exp = moma_root
    split = root / "data_split" / "kitchen_test.txt"
    text = split.read_text()
    first = text.split()[0]
    split.write_text(text.rstrip("\n") + f"\n{first}\n")
    dm = _dm(root)
    dm.setup("test")
    assert [r.key for r in dm.datasets["test"].records] == exp["kept"]["test"]
    assert dm.skips["test"].counts["duplicate_line"] == 1 and str(split) in dm.skips["test"].summary()
    split.write_bytes(text.encode() + b"caf\xe9\n")
    with pytest.raises(MisconfigurationException, match=r"kitchen_test\.txt is unreadable \(UnicodeDecodeError"):
        _dm(root).setup("test")
    split.unlink()
    split.mkdir()
    with pytest.raises(MisconfigurationException, match=r"kitchen_test\.txt is not a file"):
        _dm(root).setup("test")


def test_a_target_away_from_the_scene_cloud_is_skipped_and_counted(moma_root):
    """A target no scene point lies within flag_radius of flagged no point +1, silently: the model trained on that
    sample without its target. It is now a counted ``target_not_in_scene`` skip naming the file (strict raises)."""
    from tests.data.moma_kitchen.data import _write_ply

    root, exp = moma_root
    far = exp["kept"]["test"][0]
    target = root / "rgbd" / far / "point_cloud_transformed" / "target_pcd_transformed.ply"
    _write_ply(target, np.array([[50.0, 50.0, 1.0], [50.1, 50.0, 1.0]]))
    dm = _dm(root)
    dm.setup("test")
    assert [r.key for r in dm.datasets["test"].records] == exp["kept"]["test"][1:]
    assert dict(dm.skips["test"].counts) == {"target_not_in_scene": 1}
    assert str(target) in dm.skips["test"].summary()
    with pytest.raises(DataError, match="target_pcd_transformed.ply: no point of world_pcd_transformed.ply"):
        _dm(root, strict=True).setup("test")


def test_train_and_test_split_files_that_share_a_scene_are_refused(moma_root):
    """The test split is unseen scenes: a test line from a training scene (a split file edited or mixed up) tested
    the model on a kitchen it trained on, without a word."""
    root, _ = moma_root
    train = (root / "data_split" / "kitchen_train.txt").read_text().split()
    test = root / "data_split" / "kitchen_test.txt"
    test.write_text(test.read_text() + train[0] + "\n")
    for stage in ("fit", "test"):
        with pytest.raises(
            MisconfigurationException, match=r"kitchen_train\.txt and .*kitchen_test\.txt share 1 scene"
        ):
            _dm(root).setup(stage)


@pytest.mark.parametrize("stage", [None, "fit", "test"])
def test_a_setup_reads_each_split_file_once(moma_root, monkeypatch, stage):
    """The unseen-scene check read both split files, then indexing read them again: each setup read a file twice."""
    import floaff_zoo.data.moma_kitchen as mk

    root, _ = moma_root
    reads = []
    real = mk.read_split_file
    monkeypatch.setattr(mk, "read_split_file", lambda p: reads.append(p.name) or real(p))
    _dm(root).setup(stage)
    assert sorted(reads) == ["kitchen_test.txt", "kitchen_train.txt"]


def test_a_pre_transform_that_is_no_transform_is_named_at_construction():
    """A text in pre_transforms failed at setup, inside the cache key (no config()) or the first parse."""
    with pytest.raises(
        ValueError, match=r"data\.pre_transforms\[1\] must be a SampleTransform .*got 'OfficialNormalize'"
    ):
        _dm("unused", pre_transforms=[OfficialNormalize(), "OfficialNormalize"])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("strict", "false", r"data\.strict must be true or false, got 'false'"),  # a true text: strict mode
        ("validate", 0, r"data\.validate must be true or false, got 0"),
        ("cache", "no", r"data\.cache must be true or false, got 'no'"),
        ("cache_hash", "sha", r"data\.cache_hash must be one of 'stat', 'content', got 'sha'"),
        ("val_fraction", "0.05", r"data\.val_fraction must be in \[0, 1\), got '0\.05'"),  # a bare TypeError
        ("val_fraction", False, r"data\.val_fraction must be in \[0, 1\), got False"),  # 0: validate on test
        ("val_fraction", 1.0, r"data\.val_fraction must be in \[0, 1\), got 1\.0"),
    ],
)
def test_a_flag_a_choice_or_a_fraction_of_the_wrong_kind_is_named(field, value, message):
    """A text where a flag is asked for was true ("false" set strict mode), a cache_hash typo passed unseen while the
    cache was off, and a text fraction failed in a bare comparison naming nothing."""
    from floaff_zoo.data.base import DataConfigError

    with pytest.raises(DataConfigError, match=message):
        _dm("unused", **{field: value})
