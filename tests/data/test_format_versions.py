"""The generated-data readers take format 1 (generator 1.x) and format 2 (observed floor cells) files."""

import json

import numpy as np
import pytest

from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
from floaff_zoo.data.readers import DataError, GeneratedReader, SkipLog
from floaff_zoo.sim import fileformat as ff
from tests.data.floaff_fixture import make_floaff_dataset


@pytest.fixture(scope="module", params=[1, 2])
def versioned_root(request, tmp_path_factory):
    root = tmp_path_factory.mktemp(f"floaff_v{request.param}")
    make_floaff_dataset(root, problems=False, version=request.param)
    return root, request.param


def test_reader_reads_both_versions(versioned_root):
    root, version = versioned_root
    reader = GeneratedReader(root, SkipLog("test", strict=True))
    scenes = reader.scenes("styles")
    assert scenes and {s.format_version for s in scenes} == {version}
    s = reader.load_view(scenes[0], scenes[0].views[0])
    m = len(s["floor_xyz"])
    assert s["floor_known"].dtype == bool and s["floor_known"].shape == (m,)
    if version == 1:
        assert s["floor_known"].all()  # v1 labels are taken as given
    else:
        assert s["floor_known"][:-1].all() and not s["floor_known"][-1]
    rec = next(ff.iter_scenes(root, benchmark="styles"))
    sample = ff.read_sample(rec, rec["views"][0])
    assert sample["meta"]["format_version"] == version and rec["format_version"] == version
    dm = FloAffKitchenDataModule(root=str(root), tasks=["CloseDrawer"], cache=False, strict=True)
    dm.setup("fit")
    assert len(dm.datasets["train"]) and dm.skips.total == 0


def test_version_2_view_without_its_fields_is_named(tmp_path):
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    path = tmp_path / "styles" / rec["scene_id"] / rec["views"][0]["file"]
    arr = dict(np.load(path))
    del arr["floor_known"]
    ff.atomic_save_npz(path, arr)
    with pytest.raises(ff.FormatError, match=r"front_0000.npz: missing field 'floor_known'"):
        ff.read_sample(rec, rec["views"][0])
    reader = GeneratedReader(tmp_path, SkipLog("test"))
    scene = next(s for s in reader.scenes("styles") if s.scene_id == rec["scene_id"])
    with pytest.raises(DataError, match="floor_known") as err:
        reader.load_view(scene, scene.views[0])
    assert err.value.kind == "bad_view"
    ff.validate_view(arr, path, format_version=1)  # the same arrays are a valid format-1 view
    with pytest.raises(ff.FormatError, match="floor_known.*M="):
        ff.validate_view(dict(arr, floor_known=np.ones(2, bool)), path)  # given, it must match the floor size


def test_unknown_format_version_is_skipped_and_named(tmp_path):
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    sj = tmp_path / "styles" / rec["scene_id"] / ff.SCENE_JSON
    data = json.loads(sj.read_text())
    data["format_version"] = 99
    sj.write_text(json.dumps(data))
    with pytest.raises(ff.FormatError, match=r"scene.json: format_version 99 is not supported"):
        ff.read_scene(sj)
    skips = SkipLog("test")
    scenes = GeneratedReader(tmp_path, skips).scenes("styles")
    assert rec["scene_id"] not in {s.scene_id for s in scenes}
    assert skips.counts["corrupt_scene_json"] == 1 and "format_version 99" in skips.summary()


def test_floor_index_beyond_the_candidate_grid_is_named(tmp_path):
    """floor_index was checked for negative entries only: an entry past the scene's candidate grid reached the
    scripts that index the grid with it (scripts/fixed_cell_ceiling.py, prior_cells.py) as a bare IndexError."""
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    path = tmp_path / "styles" / rec["scene_id"] / rec["views"][0]["file"]
    arr = dict(np.load(path))
    n = len(rec["candidates"]["xy"])
    ff.read_view(path, 2, n)  # the fixture's own view indexes the grid
    arr["floor_index"] = arr["floor_index"].copy()
    arr["floor_index"][-1] = n
    ff.atomic_save_npz(path, arr)
    with pytest.raises(ff.FormatError, match=rf"front_0000.npz: field .floor_index. reaches cell {n}, .* {n} cells"):
        ff.read_sample(rec, rec["views"][0])
    ff.read_view(path, 2)  # without the grid's size nothing to check it against


def test_floor_points_off_the_floor_are_named(tmp_path):
    """The format puts a view's floor points (candidate base positions) at z = 0; a file with z = 5 was read as is."""
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    path = tmp_path / "styles" / rec["scene_id"] / rec["views"][0]["file"]
    arr = dict(np.load(path))
    ff.validate_view(arr, path)  # the fixture's own floor is at 0
    arr["floor_xyz"] = arr["floor_xyz"].copy()
    arr["floor_xyz"][0, 2] = 5.0
    ff.atomic_save_npz(path, arr)
    with pytest.raises(ff.FormatError, match=r"front_0000.npz: field 'floor_xyz' has z up to 5 m"):
        ff.read_sample(rec, rec["views"][0])


def test_malformed_records_are_named(tmp_path):
    """A repeated floor cell, a view record without its file name, a boolean format version and a scene.json
    that is a directory passed the reader or ended in a bare KeyError / IsADirectoryError."""
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    path = tmp_path / "styles" / rec["scene_id"] / rec["views"][0]["file"]
    arr = dict(np.load(path))
    arr["floor_index"] = np.zeros_like(arr["floor_index"])
    ff.atomic_save_npz(path, arr)
    with pytest.raises(ff.FormatError, match="floor_index' is not strictly increasing"):
        ff.read_sample(rec, rec["views"][0])
    with pytest.raises(ff.FormatError, match="a view record needs a 'file' name"):
        ff.read_sample(rec, {"view": "front", "view_id": "front_0000"})
    with pytest.raises(ff.FormatError, match="format_version True is not supported"):
        ff.check_format_version(True, "scene.json")
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / ff.SCENE_JSON).mkdir()
    with pytest.raises(ff.FormatError, match="scene.json: unreadable"):
        ff.read_json(tmp_path / "odd" / ff.SCENE_JSON)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        (("labels", "cell_label"), [0.5] * 5, "labels.cell_label has 5 entries"),
        (("candidates", "status"), 7, r"candidates\.status.* must be lists"),
        (("labels", "label"), "nan", "labels.label holds NaN or Inf values"),
        # a yaw or valid list of another length, a grid of another shape: scripts reading them (fresh labels, repeat
        # rollouts) zeroed the cells past the short list without a word
        (("candidates", "valid"), [1] * 2, "candidates.valid has 2 entries, candidates.xy has 36"),
        (("candidates", "yaw"), [0.0] * 3, "candidates.yaw has 3 entries"),
        (("candidates", "grid_shape"), [7, 9], r"grid_shape \[7, 9\] does not hold the 36 cells"),
    ],
)
def test_format_2_scene_records_are_checked(tmp_path, field, value, message):
    """read_scene accepted a format-2 scene.json whose per-cell labels or status had another length than its grid
    (its views index them), or NaN labels."""
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    sj = tmp_path / "styles" / rec["scene_id"] / ff.SCENE_JSON
    data = json.loads(sj.read_text())
    if value == "nan":
        data["labels"]["label"][0] = float("nan")
    else:
        data[field[0]][field[1]] = value
    sj.write_text(json.dumps(data))
    with pytest.raises(ff.FormatError, match=message):
        ff.read_scene(sj)


def test_read_sample_gives_the_target_world_and_names_a_bad_one(tmp_path):
    """predict_sr.py rolls out from read_sample's meta: it faces the target as the annotation did, and a bad
    target.pos is a FormatError naming scene.json, not a TypeError inside the rollout."""
    import json

    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    assert ff.read_sample(rec, rec["views"][0])["meta"]["sim"]["target_world"] == [1.0, 2.0]
    sj = tmp_path / "styles" / rec["scene_id"] / ff.SCENE_JSON
    bad = json.loads(sj.read_text())
    bad["target"]["pos"] = "here"
    sj.write_text(json.dumps(bad))
    rec = next(r for r in ff.iter_scenes(tmp_path, benchmark="styles") if r["scene_id"] == rec["scene_id"])
    with pytest.raises(ff.FormatError, match=r"scene.json: target.pos must be a list"):
        ff.read_sample(rec, rec["views"][0])


@pytest.mark.parametrize("bad", ["", ".", "..", "a/b", "/abs"])
def test_a_scene_id_that_is_no_folder_name_is_refused_before_anything_moves(tmp_path, bad):
    """retire_scene with a scene_id from a hand-edited manifest deleted folders: an absolute one rmtree'd that folder
    (the target of its move is the folder itself), "" the benchmark's retired scenes before failing to move it."""
    root = tmp_path / "data"
    (root / "styles" / ff.RETIRED / "old").mkdir(parents=True)
    victim = tmp_path / "victim"
    victim.mkdir()
    sid = str(victim) if bad == "/abs" else bad
    with pytest.raises(ValueError, match=r"^scene_dir: scene_id must be one folder name"):
        ff.retire_scene(root, "styles", sid)
    assert victim.is_dir() and (root / "styles" / ff.RETIRED / "old").is_dir()
    with pytest.raises(ValueError, match=r"^scene_dir: benchmark must be one folder name"):
        ff.scene_dir(root, "", "s0")
    with pytest.raises(ValueError, match=r"^staging_dir: scene_id must be one folder name"):
        ff.staging_dir(root, "styles", sid)
    assert ff.scene_dir(root, "styles", "s0") == root / "styles" / "s0"
    assert ff.staging_dir(root, "styles", "s0") == root / "styles" / ff.STAGING / "s0"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(split="Train"), r"scene.json: split 'Train' is not one of \['train', 'test'\]"),
        (lambda d: d.update(task="closedrawer"), r"scene.json: task 'closedrawer' is not one of"),
        (lambda d: d.update(benchmark="style"), r"scene.json: benchmark 'style' is not one of"),
        (lambda d: d.update(spec=[0, 1, 2]), r"scene.json: spec must be a record"),
    ],
)
def test_a_scene_record_no_filter_can_select_is_named(tmp_path, edit, message):
    """A scene.json with split 'Train' or a misspelt task was read, then matched no iter_scenes filter (left out
    without a word); a spec that is no record failed in read_sample with an AttributeError naming no file."""
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    sj = tmp_path / "styles" / rec["scene_id"] / ff.SCENE_JSON
    data = json.loads(sj.read_text())
    edit(data)
    sj.write_text(json.dumps(data))
    with pytest.raises(ff.FormatError, match=message):
        list(ff.iter_scenes(tmp_path, benchmark="styles", split="train"))


def test_a_view_record_without_its_kind_id_or_pose_is_named(tmp_path):
    """A view record without 'view' or 'view_id', a scene record without 'scene_id' ended in a bare KeyError, a
    listed base pose of two values in an IndexError, a text in float()'s error: none named scene.json."""
    make_floaff_dataset(tmp_path, problems=False, version=2)
    rec = next(ff.iter_scenes(tmp_path, benchmark="styles"))
    view = rec["views"][0]
    for key in ("view", "view_id"):
        bad = {k: v for k, v in view.items() if k != key}
        with pytest.raises(ff.FormatError, match=r"scene.json: a view record needs a 'view' and a 'view_id'"):
            ff.read_sample(rec, bad)
    with pytest.raises(ff.FormatError, match=r"scene.json: the scene record needs a 'scene_id'"):
        ff.read_sample({k: v for k, v in rec.items() if k != "scene_id"}, view)
    with pytest.raises(ff.FormatError, match=r"scene.json: view 'front_0000': base_pose_world must be \[x, y, yaw\]"):
        ff.read_sample(rec, {**view, "base_pose_world": [1.0, 2.0]})
    with pytest.raises(ff.FormatError, match=r"scene.json: the view's base_pose_world must hold numbers"):
        ff.read_sample(rec, {**view, "base_pose_world": "abc"})
    with pytest.raises(ff.NonFiniteFieldError, match=r"scene.json: the view's base_pose_world holds NaN"):
        ff.read_sample(rec, {**view, "base_pose_world": [float("nan"), 0.0, 0.0]})
    assert ff.read_sample(rec, view)["meta"]["view"] == view["view"]


def test_a_view_numpy_would_pickle_is_refused_when_written(tmp_path):
    """An object or ragged field was written without a word (pickled) and refused by every reader afterwards."""
    path = tmp_path / "v.npz"
    for bad in (np.array([{"x": 1}], dtype=object), [[1.0, 2.0], [3.0]]):
        with pytest.raises(ValueError, match=r"v.npz: field 'robot' is an object or ragged array"):
            ff.atomic_save_npz(path, {"scene_xyz": np.zeros((2, 3), np.float32), "robot": bad})
        assert not path.exists()
    ff.atomic_save_npz(path, {"robot": np.ones(2, np.float32)})
    assert np.load(path, allow_pickle=False)["robot"].tolist() == [1.0, 1.0]


def test_a_root_that_is_a_file_is_named_so(tmp_path):
    (tmp_path / "data").write_text("")
    with pytest.raises(ff.FormatError, match=r"data: dataset root is a file, not a folder"):
        list(ff.iter_scenes(tmp_path / "data"))
    with pytest.raises(ff.FormatError, match=r"nowhere: dataset root not found"):
        list(ff.iter_scenes(tmp_path / "nowhere"))
