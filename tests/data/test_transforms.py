"""Per-sample transforms and how the DataModule applies them."""

import math

import numpy as np
import pytest
import torch

from floaff_zoo.contract import SampleError, validate_sample
from floaff_zoo.data.plot import plot
from floaff_zoo.data.synthetic import SyntheticDataModule, make_synthetic_sample
from floaff_zoo.data.transforms import (
    Jitter,
    LateralMirror,
    OfficialNormalize,
    ResamplePoints,
    SampleTransform,
    TargetCrop,
    YawPerturb,
    fps_indices,
    rotate_sample,
    transforms_config,
)
from floaff_zoo.nn.cfar import canonical_transform


def _sample():
    s = make_synthetic_sample(3, num_points=200, floor_cells=6)
    s["meta"]["sim"] = {"base_pose_world": [1.0, 2.0, 0.3]}
    return s


def test_resample_random_and_fps():
    s = _sample()
    s["scene_mask"][150:] = False
    rng = np.random.default_rng(0)
    out = ResamplePoints(64)(s, rng)
    assert out["scene_xyz"].shape == (64, 3) and out["scene_mask"].all()
    valid = {tuple(p) for p in s["scene_xyz"][:150].tolist()}
    assert all(tuple(p) in valid for p in out["scene_xyz"].tolist())  # only valid points drawn
    up = ResamplePoints(400)(s, rng)
    assert up["scene_xyz"].shape == (400, 3)
    fps = ResamplePoints(16, method="fps")(s, np.random.default_rng(1))
    assert len({tuple(p) for p in fps["scene_xyz"].tolist()}) == 16
    # FPS spreads points: its minimum pairwise distance beats a random subset's
    xyz = np.random.default_rng(0).uniform(size=(500, 3))
    idx = fps_indices(xyz, 20)
    d = np.linalg.norm(xyz[idx, None] - xyz[None, idx], axis=-1) + np.eye(20) * 9
    rnd = xyz[:20]
    d2 = np.linalg.norm(rnd[:, None] - rnd[None], axis=-1) + np.eye(20) * 9
    assert d.min() > d2.min()
    with pytest.raises(ValueError, match="method"):
        ResamplePoints(8, method="grid")


def test_target_crop_keeps_the_target_surroundings():
    s = _sample()
    s["scene_mask"][150:] = False
    target = s["target_xyz"]
    d = (s["scene_xyz"] - target).norm(dim=1)
    radius = float(d[:150].median())
    out = TargetCrop(radius, min_points=4)(s, np.random.default_rng(0))
    validate_sample(out)
    inside = (d <= radius) & s["scene_mask"]
    assert out["scene_xyz"].shape[0] == int(inside.sum()) and out["scene_mask"].all()
    assert torch.equal(out["scene_xyz"], s["scene_xyz"][inside])  # order kept, masked points gone
    assert torch.equal(out["scene_feat"], s["scene_feat"][inside])
    assert torch.equal(out["floor_xyz"], s["floor_xyz"]) and torch.equal(out["floor_label"], s["floor_label"])
    # too few points inside: the nearest valid ones are kept instead
    few = TargetCrop(1e-6, min_points=10)(s, np.random.default_rng(0))
    assert few["scene_xyz"].shape[0] == 10
    assert (few["scene_xyz"] - target).norm(dim=1).max() <= d[:150].sort().values[9] + 1e-6
    s["scene_mask"][:] = False
    with pytest.raises(SampleError, match="no valid point"):
        TargetCrop(1.0)(s, np.random.default_rng(0))
    with pytest.raises(ValueError, match="radius"):
        TargetCrop(0.0)
    with pytest.raises(ValueError, match="min_points"):
        TargetCrop(1.0, min_points=0)


def test_yaw_perturb_is_consistent():
    s = _sample()
    out = YawPerturb(5.0)(s, np.random.default_rng(4))
    ang = math.atan2(float(out["target_xyz"][1]), float(out["target_xyz"][0])) - math.atan2(
        float(s["target_xyz"][1]), float(s["target_xyz"][0])
    )
    assert abs(ang) <= math.radians(5) + 1e-6 and abs(ang) > 0
    # rigid rotation about the robot origin: distances to the target, radii and z are preserved
    for key in ("scene_xyz", "floor_xyz"):
        d0 = (s[key] - s["target_xyz"]).norm(dim=1)
        d1 = (out[key] - out["target_xyz"]).norm(dim=1)
        assert torch.allclose(d0, d1, atol=1e-5)
        assert torch.allclose(s[key].norm(dim=1), out[key].norm(dim=1), atol=1e-5)
    assert float(out["target_yaw"]) == pytest.approx(float(s["target_yaw"]) + ang, abs=1e-5)
    assert out["meta"]["sim"]["base_pose_world"][2] == pytest.approx(0.3 - ang)
    assert s["meta"]["sim"]["base_pose_world"][2] == 0.3  # input untouched
    back = rotate_sample(out, -ang)
    assert torch.allclose(back["scene_xyz"], s["scene_xyz"], atol=1e-5)
    # the stored cloud (full_xyz) turns with the scene, so a footprint check in it stays in the sample's frame
    s["full_xyz"] = s["scene_xyz"].clone()
    turned = rotate_sample(s, 0.2)
    assert torch.allclose(turned["full_xyz"], turned["scene_xyz"], atol=1e-6)


def test_lateral_mirror_flips_the_canonical_frame_laterally():
    s = _sample()
    s["target_yaw"] = torch.tensor(0.7)
    out = LateralMirror(p=1.0)(s, np.random.default_rng(0))
    validate_sample(out)
    for key in ("scene_xyz", "floor_xyz"):
        assert torch.equal(out[key][:, 0], s[key][:, 0]) and torch.equal(out[key][:, 2], s[key][:, 2])
        assert torch.equal(out[key][:, 1], -s[key][:, 1])
    assert torch.equal(out["floor_label"], s["floor_label"]) and torch.equal(out["scene_feat"], s["scene_feat"])
    assert float(out["target_yaw"]) == pytest.approx(-0.7)
    s2 = {**s, "full_xyz": s["scene_xyz"].clone()}
    assert torch.equal(LateralMirror(p=1.0)(s2, np.random.default_rng(0))["full_xyz"], out["scene_xyz"])
    # a mirror-image kitchen: no simulator scene matches it, so nothing can roll it out
    assert "sim" not in out["meta"] and out["meta"]["mirrored"] is True and "sim" in s["meta"]

    def canon(x):
        return canonical_transform(
            x["scene_xyz"][None],
            x["scene_mask"][None],
            x["floor_xyz"][None],
            x["target_xyz"][None],
            x["target_yaw"].reshape(1),
            None,
        )

    # in CFAR's canonical frame (front towards -y) the reflection is x -> -x: a left hinge becomes a right one
    a, b = canon(s), canon(out)
    assert torch.allclose(b.floor_xyz[..., 0], -a.floor_xyz[..., 0], atol=1e-5)
    assert torch.allclose(b.floor_xyz[..., 1:], a.floor_xyz[..., 1:], atol=1e-5)
    assert torch.allclose(b.xyz[..., 0], -a.xyz[..., 0], atol=1e-5)
    # p is a probability; p = 0 never reflects
    assert LateralMirror(p=0.0)(s, np.random.default_rng(0)) is s
    hits = sum("mirrored" in LateralMirror(0.5)(s, np.random.default_rng(i))["meta"] for i in range(200))
    assert 70 < hits < 130
    with pytest.raises(ValueError, match="p must be"):
        LateralMirror(p=1.5)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: YawPerturb(True), r"YawPerturb: max_deg must be a finite number >= 0, got True"),  # ran as 1 degree
        (lambda: YawPerturb(float("nan")), r"YawPerturb: max_deg must be a finite number >= 0, got nan"),
        (lambda: Jitter("0.005"), r"Jitter: sigma must be a finite number >= 0, got '0.005'"),  # a TypeError
        (lambda: Jitter(0.005, clip="0.01"), r"Jitter: clip must be a finite number > 0 or null \(no clipping\)"),
        (lambda: Jitter(0.005, clip=0.0), r"Jitter: clip must be a finite number > 0 or null \(no clipping\)"),
        # each passed its constructor: a NaN min_points kept no point, True ran as 1, the rest failed in numpy/torch
        (lambda: ResamplePoints(True), r"ResamplePoints: num_points must be an integer >= 1, got True"),
        (lambda: ResamplePoints(2.5), r"ResamplePoints: num_points must be an integer >= 1, got 2.5"),
        (lambda: ResamplePoints(None), r"ResamplePoints: num_points must be an integer >= 1, got None"),
        (lambda: TargetCrop(float("inf")), r"TargetCrop: radius must be a finite number > 0, got inf"),
        (lambda: TargetCrop("1.2"), r"TargetCrop: radius must be a finite number > 0, got '1.2'"),
        (lambda: TargetCrop(1.2, float("nan")), r"TargetCrop: min_points must be an integer >= 1, got nan"),
        (lambda: TargetCrop(1.2, 2.5), r"TargetCrop: min_points must be an integer >= 1, got 2.5"),
        (lambda: LateralMirror(True), r"LateralMirror: p must be a finite number >= 0 and <= 1, got True"),
        (lambda: LateralMirror("0.5"), r"LateralMirror: p must be a finite number >= 0 and <= 1, got '0.5'"),
    ],
)
def test_transform_sizes_are_refused_by_name(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_jitter_and_official_normalize():
    s = _sample()
    out = Jitter(0.005)(s, np.random.default_rng(0))
    diff = out["scene_xyz"] - s["scene_xyz"]
    assert 0.003 < float(diff.std()) < 0.007 and torch.equal(out["floor_xyz"], s["floor_xyz"])
    clipped = Jitter(0.1, clip=0.01)(s, np.random.default_rng(0))
    assert float((clipped["scene_xyz"] - s["scene_xyz"]).abs().max()) <= 0.01 + 1e-6
    n = OfficialNormalize()(s, np.random.default_rng(0))
    assert torch.allclose(n["scene_xyz"].mean(0), torch.zeros(3), atol=1e-5)
    assert float(n["scene_xyz"].norm(dim=1).max()) == pytest.approx(1.0)
    assert torch.equal(n["floor_xyz"], s["floor_xyz"])


def test_transforms_config_and_datamodule_application():
    assert transforms_config([YawPerturb(3.0)])[0] == {"class": "floaff_zoo.data.transforms.YawPerturb", "max_deg": 3.0}

    class Flip(SampleTransform):
        def __call__(self, sample, rng):
            out = dict(sample)
            out["scene_xyz"] = -sample["scene_xyz"]
            return out

    dm = SyntheticDataModule(
        num_train=4,
        num_val=4,
        num_test=4,
        batch_size=4,
        num_points=None,
        collate_mode="pad",
        train_transforms=[YawPerturb(5.0)],
        eval_transforms=[Flip()],
    )
    dm.setup("fit")
    raw = dm.datasets["val"][0]["scene_xyz"]
    v1 = next(iter(dm.val_dataloader()))["scene_xyz"][0]
    v2 = next(iter(dm.val_dataloader()))["scene_xyz"][0]
    assert torch.allclose(v1, -raw) and torch.equal(v1, v2)  # eval: deterministic
    torch.manual_seed(0)
    t1 = next(iter(dm.train_dataloader()))
    t2 = next(iter(dm.train_dataloader()))
    assert not torch.equal(t1["target_yaw"], t2["target_yaw"])  # train: fresh draws

    class Hooked(SyntheticDataModule):
        def sample_transform(self, sample, split):
            sample = dict(sample)
            sample["robot"] = sample["robot"] * 0 + (1.0 if split == "train" else 2.0)
            return sample

    h = Hooked(num_train=2, num_val=2, num_test=2, batch_size=2)
    h.setup("fit")
    assert (next(iter(h.train_dataloader()))["robot"] == 1).all()
    assert (next(iter(h.val_dataloader()))["robot"] == 2).all()


def test_plot_writes_png(tmp_path):
    s = validate_sample(_sample())
    s["scene_feat"][:5, 0] = -1
    fig = plot(s, tmp_path / "a.png", scores=torch.rand(s["floor_xyz"].shape[0]))
    assert (tmp_path / "a.png").stat().st_size > 1000 and fig is not None


def test_plot_refuses_a_folder_a_suffix_and_scores_it_cannot_draw(tmp_path):
    """A folder as path wrote <folder>.png beside it and returned as if done; an unknown suffix, scores of another
    length than the floor and a floor_mask of another length ended in matplotlib's or numpy's error naming no field."""
    s = validate_sample(_sample())
    m = s["floor_xyz"].shape[0]
    (tmp_path / "out").mkdir()
    for path, scores, named in (
        (tmp_path / "out", None, "is a folder"),
        (tmp_path / "a.pngx", None, "cannot write '.pngx' pictures"),
        (tmp_path / "a.png", torch.rand(m - 1), f"scores has {m - 1} entries for {m} floor points"),
    ):
        with pytest.raises(ValueError, match=named):
            plot(s, path, scores=scores)
    with pytest.raises(ValueError, match=f"floor_mask has 3 entries for {m} points"):
        plot({**s, "floor_mask": torch.ones(3, dtype=torch.bool)}, tmp_path / "b.png")
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out"]


def test_synthetic_task_names_are_checked():
    with pytest.raises(ValueError, match=r"unknown tasks \['CloseDrawerr'\]"):
        SyntheticDataModule(tasks=["CloseDrawerr"])
    with pytest.raises(ValueError, match="empty tasks list"):  # it stood for CloseDrawer, as None does
        SyntheticDataModule(tasks=[])
    assert SyntheticDataModule().tasks == ["CloseDrawer"]


def test_datamodule_sizes_are_checked_up_front():
    """A bad size used to fail inside the first batch (``zeros: Dimension size must be non-negative``) or in the
    DataLoader, naming no field; None still means the batch's largest cloud/floor (and batch_size for eval)."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    bad_sizes = [("batch_size", 0), ("batch_size", 2.5), ("eval_batch_size", 0), ("num_workers", -1)]
    bad_sizes += [("num_points", -5), ("num_points", 0), ("num_floor", 0)]
    for field, bad in bad_sizes:
        with pytest.raises(ValueError, match=rf"data\.{field} must be an integer >= [01].* got {bad}$") as err:
            SyntheticDataModule(num_train=2, num_val=1, num_test=1, **{field: bad})
        assert isinstance(err.value, MisconfigurationException)  # `floaff-zoo` prints those as one line
    dm = SyntheticDataModule(num_train=2, num_val=1, num_test=1, batch_size=3, num_points=None, num_floor=None)
    assert dm.eval_batch_size == 3 and dm.num_points is None and dm.num_floor is None


def test_fit_with_a_negative_num_points_names_the_field_before_any_batch(tmp_path, root):
    from floaff_zoo.cli import run_lightning
    from tests.conftest import quiet_trainer_args

    args = ["fit", "--config", str(root / "configs/data/synthetic_tiny.yaml")]
    args += ["--config", str(root / "configs/models/tiny_pointnet.yaml"), "--trainer.max_epochs", "1"]
    args += ["--trainer.logger", "false", "--data.init_args.num_points", "-5", *quiet_trainer_args(tmp_path)]
    with pytest.raises(Exception) as err:  # noqa: PT011 - jsonargparse wraps the DataModule's error
        run_lightning(args)
    chain, exc = [], err.value
    while exc is not None:
        chain.append(str(exc))
        exc = exc.__cause__ or exc.__context__
    assert any("data.num_points must be an integer >= 1 or null" in m and "got -5" in m for m in chain), chain
    assert not list(tmp_path.rglob("*.ckpt"))


def test_predict_reads_the_inputs_that_test_scored():
    """predict reads the test split but drew its resampling and eval transforms from another seed stream, so
    ``floaff-zoo predict`` wrote maps of other inputs than the ones ``test`` had scored."""
    dm = SyntheticDataModule(
        num_train=2, num_val=2, num_test=4, points_per_sample=512, num_points=128, eval_transforms=[YawPerturb(5.0)]
    )
    dm.setup("test")
    dm.setup("predict")
    test, predict = next(iter(dm.test_dataloader())), next(iter(dm.predict_dataloader()))
    for key in ("scene_xyz", "target_yaw", "floor_xyz"):
        assert torch.equal(test[key], predict[key]), key


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("num_train", -1),
        ("num_val", 2.5),
        ("floor_per_sample", 0),
        ("points_per_sample", 0),
        ("max_yaw_deg", float("nan")),
        ("max_yaw_deg", float("inf")),
        ("max_yaw_deg", -10.0),
    ],
)
def test_the_learnability_probes_settings_are_named_up_front(field, value):
    """The probe checked none of its sizes: a negative split size failed in the DataLoader (``__len__() should
    return >= 0``), floor_per_sample 0 at the first batch (``floor_xyz is empty``), a NaN or infinite
    max_yaw_deg in numpy at the first sample, each naming no field; a negative max_yaw_deg drew the positive range."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    from floaff_zoo.data.learnability import CanonicalProbeDataModule

    with pytest.raises(ValueError, match=rf"data\.{field} must be") as err:
        CanonicalProbeDataModule(**{field: value})
    assert isinstance(err.value, MisconfigurationException)
    CanonicalProbeDataModule(num_train=0, floor_per_sample=1, max_yaw_deg=0.0)  # the edges stay allowed


def test_a_transform_names_the_file_of_a_sample_without_a_valid_point():
    """ResamplePoints / TargetCrop named the sample id only; a dataset's parse gives them the file in meta."""
    s = validate_sample(make_synthetic_sample(0, 64, 4))
    s["scene_mask"][:] = False
    s["meta"] = {**s["meta"], "path": "/data/styles/x/views/front_0000.npz"}
    for t in (ResamplePoints(16), TargetCrop(1.0)):
        with pytest.raises(SampleError, match=r"sample syn0 \(/data/styles/x/views/front_0000\.npz\) has no valid"):
            t(s, np.random.default_rng(0))


@pytest.mark.parametrize("module", ["synthetic", "learnability"])
@pytest.mark.parametrize("field", ["num_train", "num_val"])
def test_a_split_larger_than_the_seed_stride_is_refused(module, field):
    """Split k's sample i is seeded by seed + k * 100000 + i: a train (or val) split of more samples than that held
    the first samples of the next split, so validation (or test) silently scored samples the model trained on."""
    from floaff_zoo.data.learnability import CanonicalProbeDataModule

    cls = SyntheticDataModule if module == "synthetic" else CanonicalProbeDataModule
    with pytest.raises(ValueError, match=rf"data\.{field} must be <= 100000 .* got 100001"):
        cls(**{field: 100_001})
    dm = cls(**{field: 100_000})  # the edge: the splits touch, none overlaps
    dm.setup("fit")
    assert dm.datasets["val"].seed == dm.datasets["train"].seed + 100_000


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda s: fps_indices(np.zeros((5, 3)), 6), r"fps_indices: k must be an integer >= 0 and <= 5, got 6"),
        (lambda s: fps_indices(np.zeros((5, 3)), 2, -1), r"fps_indices: start must be an integer >= 0 and <= 4"),
        (lambda s: fps_indices(np.full((5, 3), np.nan), 2), r"fps_indices: xyz contains NaN/Inf"),
        (lambda s: fps_indices(np.zeros(5), 2), r"fps_indices: xyz must be \[n, 3\], got \[5\]"),
        (lambda s: rotate_sample(s, float("nan")), r"rotate_sample: angle must be a finite number, got nan"),
    ],
)
def test_the_public_helpers_refuse_bad_arguments_by_name(call, message):
    """k > n repeated the first index, start=-1 came back as an index, NaN points picked the start k times, a NaN
    angle made every coordinate NaN: all without a word; a [n] cloud failed in numpy's sum."""
    with pytest.raises(ValueError, match=message):
        call(_sample())


def test_official_normalize_names_a_sample_without_a_valid_point():
    s = validate_sample(make_synthetic_sample(0, 64, 4))
    s["scene_mask"][:] = False
    with pytest.raises(SampleError, match=r"OfficialNormalize: sample syn0 has no valid point"):  # torch's max()
        OfficialNormalize()(s, np.random.default_rng(0))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ({"num_floor": -1}, r"make_probe_sample: num_floor must be an integer >= 1, got -1"),  # every cell but one
        ({"num_points": 2.5}, r"make_probe_sample: num_points must be an integer >= 1, got 2.5"),
        ({"max_yaw_deg": float("nan")}, r"make_probe_sample: max_yaw_deg must be a finite number >= 0, got nan"),
    ],
)
def test_make_probe_sample_names_a_bad_argument(args, message):
    from floaff_zoo.data.learnability import make_probe_sample

    with pytest.raises(ValueError, match=message):
        make_probe_sample(0, **args)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("train_transforms", [YawPerturb(5.0), "Jitter"], r"data\.train_transforms\[1\] must be a SampleTransform"),
        ("eval_transforms", [{"class_path": "Jitter"}], r"data\.eval_transforms\[0\] must be a SampleTransform"),
        ("train_transforms", [YawPerturb], r"data\.train_transforms\[0\] must be a SampleTransform"),  # the class
        ("train_transforms", YawPerturb(5.0), r"data\.train_transforms must be a list of transforms"),
        ("eval_transforms", "YawPerturb", r"data\.eval_transforms must be a list of transforms"),
    ],
)
def test_a_transform_list_entry_that_is_no_transform_is_named_at_construction(field, value, message):
    """A text or a dict in a transform list failed at the first sample ("'str' object is not callable"), a single
    transform for the list failed as "not iterable", and a text was taken letter by letter."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    with pytest.raises(ValueError, match=message) as err:
        SyntheticDataModule(**{field: value})
    assert isinstance(err.value, MisconfigurationException)
    assert SyntheticDataModule(train_transforms=(YawPerturb(5.0),), eval_transforms=[]).train_transforms[0].max_deg == 5


def test_numpy_sizes_and_seed_reach_the_loaders_as_python_ints():
    """The checks take numpy's integers, but DataLoader refused batch_size np.int64(2) and torch's manual_seed seed
    np.int64(3) at the first batch; a seed past 64 bits failed there as "Overflow when unpacking long long"."""
    dm = SyntheticDataModule(
        num_train=4, num_val=2, num_test=2, batch_size=np.int64(2), eval_batch_size=np.int32(2), seed=np.int64(3)
    )
    dm.setup("fit")
    assert len(next(iter(dm.train_dataloader()))["robot"]) == 2 == len(next(iter(dm.val_dataloader()))["robot"])
    with pytest.raises(
        ValueError, match=r"data\.seed must be an integer >= 0 and <= 18446744073709551615, got 18446744073709551616"
    ):
        SyntheticDataModule(seed=2**64)
