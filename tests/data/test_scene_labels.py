"""Scene-label files (data.scene_labels) and FloAffKitchenDataModule(train_labels=...) through the real CLI."""

from pathlib import Path

import numpy as np
import pytest
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.cli import run_lightning
from floaff_zoo.contract import SampleError
from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
from floaff_zoo.data.scene_labels import MADE_FROM, SceneLabels, read_scene_labels, write_scene_labels
from floaff_zoo.frames import base_to_world
from floaff_zoo.sim import fileformat as ff
from tests.conftest import quiet_trainer_args


def _labels_of_views(root: Path, bench: str, ids: list[str], seed: int = 0) -> tuple[dict, dict]:
    """A label file's content for scenes ``ids`` whose cells are their views' own floor points, random labels.

    Returns ({scene id: (xy, label, cell)}, {sample id: the label each of the view's floor points should get}).
    """
    rng = np.random.default_rng(seed)
    table, want = {}, {}
    for sid in ids:
        xy, lab = [], []
        for v in ff.read_scene(ff.scene_dir(root, bench, sid))["views"]:
            with np.load(ff.scene_dir(root, bench, sid) / v["file"]) as z:
                w = base_to_world(z["floor_xyz"][:, :2], z["base_pose_world"])
            new = rng.uniform(0, 1, len(w)).astype(np.float32)
            xy.append(w)
            lab.append(new)
            want[f"{bench}/{sid}/{v['view_id']}"] = new
        table[sid] = (np.concatenate(xy), np.concatenate(lab), 1e-3)
    return table, want


def test_file_round_trip_and_bad_files(tmp_path):
    path = tmp_path / "labels.npz"
    xy = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])
    write_scene_labels(path, {"a": (xy, np.array([0.0, 0.5, 1.0]), 0.1)}, {"episodes": 4})
    table, setting = read_scene_labels(path)
    assert setting == {"episodes": 4} and table["a"][1].tolist() == [0.0, 0.5, 1.0] and table["a"][2] == 0.1
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        read_scene_labels(tmp_path / "missing.npz")
    (tmp_path / "corrupt.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="corrupt.npz is not a readable"):
        read_scene_labels(tmp_path / "corrupt.npz")
    (tmp_path / "truncated.npz").write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # a cut-off copy
    with pytest.raises(ValueError, match="truncated.npz is not a readable"):
        read_scene_labels(tmp_path / "truncated.npz")
    for bad, match in (
        ((np.zeros((3, 2)), np.array([0.0, 2.0, 1.0]), 0.1), "scene b has non-finite values or labels outside"),
        ((np.zeros((3, 2)), np.array([0.0, np.nan, 1.0]), 0.1), "scene b has non-finite"),
        ((np.zeros((3, 2)), np.array([0.0, -0.5, 1.0]), 0.1), "scene b has non-finite values or labels outside"),
        ((np.zeros((3, 2)), np.zeros(2), 0.1), r"scene b has xy \[3, 2\], label \[2\]"),
        # an inf spacing put every floor point on the grid; a scene of no cell failed at the first sample (numpy's
        # argmin of an empty sequence); a spacing of shape [2] was a TypeError that escaped the data module's check
        ((np.zeros((3, 2)), np.zeros(3), np.inf), r"scene b has xy \[3, 2\], label \[3\], cell inf"),
        ((np.zeros((0, 2)), np.zeros(0), 0.1), r"scene b has xy \[0, 2\], label \[0\], cell 0.1"),
        ((np.zeros((3, 2)), np.zeros(3), np.array([0.1, 0.1])), r"scene b has xy \[3, 2\], label \[3\], cell nan"),
    ):
        write_scene_labels(path, {"b": bad}, {})
        with pytest.raises(ValueError, match=match):
            read_scene_labels(path)
    np.savez(path, setting="{}", **{"c/xy": np.zeros((1, 2))})
    with pytest.raises(ValueError, match="scene c lacks the entry"):
        read_scene_labels(path)
    # a setting that is no JSON (a JSONDecodeError naming no file) and xy as text (a TypeError from isfinite)
    np.savez(path, setting="not json", **{"d/xy": np.zeros((1, 2)), "d/label": np.zeros(1), "d/cell": 0.1})
    with pytest.raises(ValueError, match=f"{path}: its 'setting' entry is not JSON"):
        read_scene_labels(path)
    np.savez(path, setting="{}", **{"d/xy": np.array([["a", "b"]]), "d/label": np.zeros(1), "d/cell": 0.1})
    with pytest.raises(ValueError, match=f"{path}: scene d has xy of <U1"):
        read_scene_labels(path)
    # a setting that is no JSON object (an AttributeError naming no file at the data module's check), a made_from of
    # another shape (read as a file written before it was kept: used unchecked) and complex cells (their imaginary
    # part dropped with a warning; a complex spacing was a TypeError)
    good = {"d/xy": np.zeros((1, 2)), "d/label": np.zeros(1), "d/cell": 0.1}
    for setting in ("[1, 2]", '{"made_from": ["d"]}', '{"made_from": {"d": 7}}'):
        np.savez(path, setting=setting, **good)
        with pytest.raises(ValueError, match=f"{path}: its 'setting' must be a JSON object"):
            read_scene_labels(path)
    # a cell listed twice: a floor point took the first one's label without a word
    np.savez(path, setting="{}", **{**good, "d/xy": np.zeros((2, 2)), "d/label": np.array([0.0, 1.0])})
    with pytest.raises(ValueError, match=f"{path}: scene d lists a cell's xy twice"):
        read_scene_labels(path)
    for key, value in (("d/xy", np.zeros((1, 2)) + 1j), ("d/cell", np.complex128(0.1))):
        np.savez(path, setting="{}", **{**good, key: value})
        with pytest.raises(ValueError, match=f"{path}: scene d has xy"):
            read_scene_labels(path)


def _sample(pose, floor_xy, sid="s1"):
    m = len(floor_xy)
    return {
        "floor_xyz": torch.tensor(np.c_[floor_xy, np.zeros(m)], dtype=torch.float32),
        "floor_label": torch.full((m,), 0.25),
        "floor_mask": torch.ones(m, dtype=torch.bool),
        "meta": {"scene_id": sid, "sample_id": f"x/{sid}/front_0000", "sim": {"base_pose_world": list(pose)}},
    }


def test_transform_maps_floor_points_to_their_cells(tmp_path):
    cells = np.array([[1.0, 2.0], [1.1, 2.0], [1.0, 2.1]])
    path = tmp_path / "l.npz"
    write_scene_labels(path, {"s1": (cells, np.array([0.1, 0.2, 0.3]), 0.1)}, {})
    t = SceneLabels(str(path))
    pose = (1.0, 2.0, np.pi / 2)  # base at the first cell, facing +y: base x is world y, base y is world -x
    out = t(_sample(pose, np.array([[0.0, 0.0], [0.1, 0.0], [0.0, -0.1]])), np.random.default_rng(0))
    assert out["floor_label"].tolist() == pytest.approx([0.1, 0.3, 0.2])
    with pytest.raises(SampleError, match="1 floor point"):
        t(_sample(pose, np.array([[0.0, 0.0], [0.05, 0.0]])), np.random.default_rng(0))
    padded = _sample(pose, np.array([[0.0, 0.0], [0.05, 0.0]]))
    padded["floor_mask"][1] = False  # padding off the grid: neither refused nor relabelled
    assert t(padded, np.random.default_rng(0))["floor_label"].tolist() == pytest.approx([0.1, 0.25])
    with pytest.raises(SampleError, match="scene s2 has no labels in .*l.npz"):
        t(_sample(pose, np.zeros((1, 2)), sid="s2"), np.random.default_rng(0))
    import pickle

    assert pickle.loads(pickle.dumps(t))(_sample(pose, np.zeros((1, 2))), None)["floor_label"].item() == (
        pytest.approx(0.1)
    )


def test_fit_with_train_labels_through_the_cli(tmp_path, root, monkeypatch, floaff_root):
    monkeypatch.chdir(root)
    data_root = floaff_root[0]
    ids = [s["scene_id"] for s in ff.iter_scenes(data_root, benchmark="layouts", split="train")]
    table, want = _labels_of_views(data_root, "layouts", ids)
    labels = tmp_path / "train_labels.npz"
    made_from = {sid: ff.labels_digest(ff.read_scene(ff.scene_dir(data_root, "layouts", sid))) for sid in ids}
    write_scene_labels(labels, table, {"source": "test", MADE_FROM: made_from})
    args = [
        "fit",
        "--config",
        "configs/data/floaff_layouts.yaml",
        "--config",
        "configs/models/tiny_pointnet.yaml",
        "--data.init_args.root",
        str(data_root),
        "--data.init_args.num_points",
        "256",
        "--data.init_args.batch_size",
        "2",
        "--data.init_args.train_labels",
        str(labels),
        "--trainer.max_epochs",
        "1",
        *quiet_trainer_args(tmp_path / "runs"),
    ]
    cli = run_lightning(args)
    assert Path(cli.trainer.checkpoint_callback.best_model_path).is_file()
    dm = cli.datamodule
    train, val = dm.train_dataloader().dataset, dm.val_dataloader().dataset
    assert len(train) and len(val)
    for i in range(len(train)):  # relabelled, through the config's YawPerturb and Jitter as well
        s = train[i]
        assert s["floor_label"].numpy() == pytest.approx(want[s["meta"]["sample_id"]], abs=1e-6)
    for i in range(len(val)):  # validation keeps the generated labels
        s = val[i]
        bench, sid, vid = s["meta"]["sample_id"].split("/")
        with np.load(ff.scene_dir(data_root, bench, sid) / "views" / f"{vid}.npz") as z:
            assert s["floor_label"].numpy() == pytest.approx(z["floor_label"])
    # a label file without one of the train scenes fails before training, naming the file and the scene
    train_id = dm.split_scenes["train"][0]
    write_scene_labels(labels, {k: v for k, v in table.items() if k != train_id}, {})
    with pytest.raises(MisconfigurationException, match=f"train_labels .*train_labels.npz has no labels .*{train_id}"):
        run_lightning(args)
    # a file made from another copy of the data (one train scene's generated labels differ) fails before training,
    # naming the file and the scene: it was trained on without a word
    write_scene_labels(labels, table, {MADE_FROM: {**made_from, train_id: "0" * 16}})
    with pytest.raises(MisconfigurationException, match=f"train_labels.npz was made from other .*{train_id}"):
        run_lightning(args)


def test_a_label_file_without_its_source_digests_is_used_with_a_warning(tmp_path, floaff_root):
    data_root = floaff_root[0]
    ids = [s["scene_id"] for s in ff.iter_scenes(data_root, benchmark="layouts", split="train")]
    labels = tmp_path / "old.npz"
    write_scene_labels(labels, _labels_of_views(data_root, "layouts", ids)[0], {"source": "written before digests"})
    dm = FloAffKitchenDataModule(root=str(data_root), benchmark="layouts", train_labels=str(labels), num_points=64)
    dm.setup("fit")
    with pytest.warns(UserWarning, match="old.npz does not record which generated labels"):
        assert len(dm.train_dataloader().dataset)


def test_datamodule_names_a_missing_label_file(floaff_root, tmp_path):
    dm = FloAffKitchenDataModule(
        root=str(floaff_root[0]), benchmark="layouts", train_labels=str(tmp_path / "nope.npz"), num_points=64
    )
    dm.setup("test")  # testing never reads the training labels
    assert len(dm.test_dataloader().dataset)
    with pytest.raises(MisconfigurationException, match="nope.npz does not exist"):
        dm.train_dataloader()


def test_a_label_file_written_again_misses_the_cache_as_a_pre_transform(floaff_root, tmp_path):
    """As a pre-transform, SceneLabels keyed the sample cache by the file's path alone: a label file written again
    under the same name (fresh_labels.py with other episodes) served the old labels from the cache, silently."""
    data_root = floaff_root[0]
    ids = [s["scene_id"] for s in ff.iter_scenes(data_root, benchmark="layouts")]
    labels = tmp_path / "labels.npz"
    for seed in (0, 1):
        table, want = _labels_of_views(data_root, "layouts", ids, seed)
        write_scene_labels(labels, table, {})
        dm = FloAffKitchenDataModule(
            root=str(data_root), benchmark="layouts", num_points=64, pre_transforms=[SceneLabels(str(labels))]
        )
        dm.setup("test")
        ds = dm.datasets["test"]
        assert len(ds)
        for i in range(len(ds)):
            s = ds[i]
            assert s["floor_label"].numpy() == pytest.approx(want[s["meta"]["sample_id"]], abs=1e-6)
    with pytest.raises(FileNotFoundError, match="gone.npz does not exist"):  # named at setup, not skipped per sample
        FloAffKitchenDataModule(
            root=str(data_root), benchmark="layouts", pre_transforms=[SceneLabels(str(tmp_path / "gone.npz"))]
        ).setup("test")
