"""Command-line model specs of the scripts (predict.named_models)."""

import json

import pytest


def test_named_models_reads_name_model_specs(tmp_path):
    from floaff_zoo.predict import named_models

    odd = tmp_path / "epoch=1.ckpt"
    odd.write_bytes(b"")
    got = named_models(["occ=a.ckpt", "hub.name", "occ=b.ckpt", "runs/x/epoch=1-step=9.ckpt", str(odd)])
    assert got == {
        "occ": ["a.ckpt", "b.ckpt"],
        "hub.name": ["hub.name"],
        "runs/x/epoch=1-step=9.ckpt": ["runs/x/epoch=1-step=9.ckpt"],
        str(odd): [str(odd)],
    }
    for bad in ("=a.ckpt", "occ="):
        with pytest.raises(ValueError, match="bad model argument"):
            named_models([bad])
    with pytest.raises(ValueError, match="bad model arguments 'cfar': pass a list"):  # was read letter by letter
        named_models("cfar")
    with pytest.raises(ValueError, match="bad model argument 3"):
        named_models([3])


# ------------------------------------------------------------------------------------------ bad input to predict
def _cloud(n_floor: int = 400) -> tuple:
    """A target blob 0.9 m up at (1.2, 0, 0.9) over a floor patch x in [0.4, 1.1], |y| <= 0.6: (xyz [N, 3],
    flag [N, 1] with +1 on the blob and -1 on a few obstacle points, target [3])."""
    import numpy as np

    rng = np.random.default_rng(0)
    t = np.array([1.2, 0.0, 0.9])
    blob = t + rng.normal(scale=0.02, size=(40, 3))
    floor = np.c_[rng.uniform(0.4, 1.1, n_floor), rng.uniform(-0.6, 0.6, n_floor), np.zeros(n_floor)]
    xyz = np.r_[blob, floor].astype(np.float32)
    flag = np.r_[np.ones(40), -np.ones(10), np.zeros(n_floor - 10)].astype(np.float32)[:, None]
    return xyz, flag, t


@pytest.fixture(scope="module")
def tiny_model():
    import torch

    from floaff_zoo.models.tiny import TinyPointNetModule

    torch.manual_seed(0)
    return TinyPointNetModule(width=8).eval()


def test_predict_refuses_a_scene_feat_whose_channel_0_is_not_the_flag(tiny_model):
    """Channel 0 is the target flag (-1, 0, +1; contract.py): RGB alone or a flag scaled to 0..255 used to run and
    return another pose without a word."""
    import numpy as np

    from floaff_zoo.predict import predict_from_points

    xyz, flag, t = _cloud()
    args = ([0.85, 1.03], t)
    assert predict_from_points(tiny_model, xyz, flag, None, *args, num_points=64).scores.size  # -1/0/+1 pass
    rgb = np.random.default_rng(1).uniform(0, 1, (len(xyz), 3)).astype(np.float32)
    with pytest.raises(ValueError, match=r"scene_feat channel 0 must be the target flag, -1 .* 0 .* \+1.*RGB"):
        predict_from_points(tiny_model, xyz, rgb, None, *args, num_points=64)
    with pytest.raises(ValueError, match=r"scene_feat channel 0 .* 50 of 440 points .*\[-255\.0, 255\.0\]"):
        predict_from_points(tiny_model, xyz, flag * 255, None, *args, num_points=64)


def test_predict_refuses_rgb_outside_0_1(tiny_model):
    """The README promises RGB in [0, 1] after the flag: 8-bit colours (or a NaN) ran without a word."""
    import numpy as np

    from floaff_zoo.predict import predict, predict_from_points

    xyz, flag, t = _cloud()
    args = ([0.85, 1.03], t)
    rgb = np.random.default_rng(1).uniform(0, 1, (len(xyz), 3)).astype(np.float32)
    feat = np.concatenate([flag, rgb], axis=1)
    assert predict_from_points(tiny_model, xyz, feat, None, *args, num_points=64).scores.size
    feat8 = feat.copy()
    feat8[:, 1:] = np.round(rgb * 255)
    with pytest.raises(ValueError, match=r"channels 1-3 are RGB in \[0, 1\]; \d+ of 440 points .*divide"):
        predict_from_points(tiny_model, xyz, feat8, None, *args, num_points=64)
    feat[7, 2] = np.nan
    with pytest.raises(ValueError, match=r"channels 1-3 .* 1 of 440 points .*nan"):
        predict_from_points(tiny_model, xyz, feat, None, *args, num_points=64)
    # the RGB-D entry clipped a float image to [0, 1]: 0..255 floats became a white scene
    depth, mask = np.full((24, 32), 1.2), np.zeros((24, 32), bool)
    mask[10:12, 14:16] = True
    pose = np.eye(4)
    pose[:3, 3] = [0.8, 0.0, 1.2]
    image = np.full((24, 32, 3), 200.0)
    with pytest.raises(ValueError, match=r"a float rgb must hold values in \[0, 1\], got 200 to 200: pass uint8"):
        predict(tiny_model, image, depth, (20.0, 20.0, 16.0, 12.0), pose, mask, [0.85, 1.03])


def test_predict_names_bad_scene_shapes(tiny_model):
    """A [N, 2] cloud gave numpy's bare reshape error and a [3, N] one 'the cloud has no ground point'."""
    from floaff_zoo.predict import predict_from_points

    xyz, flag, t = _cloud()
    args = ([0.85, 1.03], t)
    with pytest.raises(ValueError, match=r"scene_xyz must be \[N, 3\].*\(440, 2\)"):
        predict_from_points(tiny_model, xyz[:, :2], flag, None, *args)
    with pytest.raises(ValueError, match=r"scene_xyz must be \[N, 3\].*\(3, 440\).*scene_xyz\.T"):
        predict_from_points(tiny_model, xyz.T, flag, None, *args)
    with pytest.raises(ValueError, match=r"scene_feat must be \[N, C\] with N = 440 .*\(439, 1\)"):
        predict_from_points(tiny_model, xyz, flag[1:], None, *args)


def test_predict_refuses_bad_cells_and_huge_rasters(tiny_model):
    """cell=0 silently became the default cell and a tiny cell built a raster of hundreds of millions of cells."""
    import numpy as np

    from floaff_zoo.predict import predict, predict_from_points

    xyz, flag, t = _cloud()
    args = ([0.85, 1.03], t)
    for bad in (0, -0.1, float("nan")):
        with pytest.raises(ValueError, match=r"predict: cell must be a finite size > 0 m"):
            predict_from_points(tiny_model, xyz, flag, None, *args, cell=bad)
    # default grid: the (1.0, 1.2) m window at 1 mm is 2401 x 2001 cells
    with pytest.raises(ValueError, match=r"cell=0\.001 m makes the default grid's window .* 2401 x 2001 .*limit"):
        predict_from_points(tiny_model, xyz, flag, None, *args, cell=1e-3)
    # given candidates over 1.5 m x 1.5 m at 0.6 mm: 2501 x 2501 raster cells
    floor = np.array([[0.0, -0.75, 0.0], [1.5, 0.75, 0.0]], np.float32)
    with pytest.raises(
        ValueError, match=r"the returned raster of 2501 x 2501 = 6,255,001 cells \(limit 4,000,000\).*coarser cell"
    ):
        predict_from_points(tiny_model, xyz, flag, floor, *args, cell=6e-4)
    # the RGB-D path shares the rule: a camera 1.2 m up looking straight down on the floor
    depth, mask = np.full((24, 32), 1.2), np.zeros((24, 32), bool)
    mask[10:12, 14:16] = True
    pose = np.eye(4)
    pose[:3, 3] = [0.8, 0.0, 1.2]
    with pytest.raises(ValueError, match=r"predict: cell must be a finite size > 0 m"):
        predict(tiny_model, None, depth, (20.0, 20.0, 16.0, 12.0), pose, mask, [0.85, 1.03], cell=0)


def test_the_prediction_writer_refuses_nan_scores_naming_the_samples(tmp_path):
    """`floaff-zoo predict` wrote NaN scores (and NaN poses) of a model without an error or a count, where
    predict() raises FloatingPointError."""
    import torch

    from floaff_zoo.callbacks.predictions import PredictionWriter
    from tests.report._fake_world import ConstantModule, loader, make_samples, quiet_trainer

    class NaNOnTwo(ConstantModule):
        def forward(self, batch):
            out = torch.full_like(batch["floor_label"], 0.5)
            index = torch.tensor([m["index"] for m in batch["meta"]])
            out[index == 0] = float("nan")  # every score
            out[index == 3, :5] = float("inf")  # a few
            return out + 0.0 * self.net.weight.sum()

    writer = PredictionWriter(out_dir=str(tmp_path))
    with pytest.raises(
        FloatingPointError, match=r"NaNOnTwo returned NaN/Inf scores on .* 2 of 4 sample\(s\): fake0, fake3;"
    ):
        quiet_trainer([writer]).predict(NaNOnTwo(), dataloaders=loader(make_samples(4), batch_size=2))
    assert not list(tmp_path.glob("predictions*"))


def test_the_prediction_writer_removes_another_runs_files_and_says_so(tmp_path, capsys):
    """A predict run into a folder holding an earlier run's files overwrote them without a word and left the
    per-rank files of a run with another number of processes beside the new ones."""
    from floaff_zoo.callbacks.predictions import PredictionWriter
    from tests.report._fake_world import ConstantModule, loader, make_samples, quiet_trainer

    for stale in ("predictions_rank1.npz", "predictions_rank1.json", "notes.json"):
        (tmp_path / stale).write_text("{}")
    writer = PredictionWriter(out_dir=str(tmp_path))
    quiet_trainer([writer]).predict(ConstantModule(), dataloaders=loader(make_samples(2)))
    assert sorted(f.name for f in tmp_path.iterdir()) == ["notes.json", "predictions.json", "predictions.npz"]
    assert f"replaced the earlier predictions in {tmp_path}" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("out", "named"),
    [
        ("taken", r"out_dir .*taken is a file, not a folder"),
        ("taken/sub", r"out_dir .*taken/sub: .*taken is not a folder"),
        ("dangling", r"out_dir .*dangling is a dangling link, not a folder"),
        ("with_dir", r"with_dir/predictions.npz is a folder, where the predictions go"),
    ],
)
def test_the_prediction_writer_refuses_an_unwritable_folder_before_predicting(tmp_path, out, named):
    """An out_dir that is a file, or lies under one, or a dangling link failed in mkdir (FileExistsError,
    NotADirectoryError), a folder named predictions.npz in the rename, after the whole predict had run."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    from floaff_zoo.callbacks.predictions import PredictionWriter
    from tests.report._fake_world import ConstantModule, loader, make_samples, quiet_trainer

    class Counted(ConstantModule):
        steps = 0

        def predict_step(self, batch, batch_idx, dataloader_idx=0):
            Counted.steps += 1
            return super().predict_step(batch, batch_idx, dataloader_idx)

    (tmp_path / "taken").write_text("notes")
    (tmp_path / "dangling").symlink_to(tmp_path / "taken" / "sub")
    (tmp_path / "with_dir" / "predictions.npz").mkdir(parents=True)
    writer = PredictionWriter(out_dir=str(tmp_path / out))
    with pytest.raises(MisconfigurationException, match=named):
        quiet_trainer([writer]).predict(Counted(), dataloaders=loader(make_samples(2)))
    assert Counted.steps == 0 and (tmp_path / "taken").read_text() == "notes"


def test_a_reader_of_the_earlier_predictions_never_meets_half_of_the_new_ones(tmp_path):
    """predictions.json and .npz were rewritten in place: a reader of the earlier files got the start of one run's and
    the end of the other's (a killed run left a truncated file)."""
    from floaff_zoo.callbacks.predictions import PredictionWriter
    from tests.report._fake_world import ConstantModule, LabelModule, loader, make_samples, quiet_trainer

    trainer = quiet_trainer([PredictionWriter(out_dir=str(tmp_path))])
    trainer.predict(ConstantModule(), dataloaders=loader(make_samples(2)))
    first = {name: (tmp_path / name).read_bytes() for name in ("predictions.json", "predictions.npz")}
    readers = {name: open(tmp_path / name, "rb", buffering=0) for name in first}  # unbuffered: read from the file
    try:
        heads = {name: readers[name].read(len(data) // 2) for name, data in first.items()}
        trainer.predict(LabelModule(), dataloaders=loader(make_samples(3)))
        assert {name: heads[name] + readers[name].read() for name in first} == first
    finally:
        for reader in readers.values():
            reader.close()
    assert json.loads((tmp_path / "predictions.json").read_text())["n"] == 3


def test_resolve_model_uses_the_class_given_and_refuses_a_half_loaded_model(tmp_path):
    """A bare state dict could not be used even with its class given (load_model never got it), and a model built
    from weights that left layers untrained ran in predict(), which `floaff-zoo predict` refuses."""
    import torch

    from floaff_zoo.models.tiny import TinyPointNetModule
    from floaff_zoo.predict import resolve_model

    torch.manual_seed(0)
    state = tmp_path / "tiny_sd.pth"
    torch.save(TinyPointNetModule().state_dict(), state)
    assert isinstance(resolve_model(str(state), model_class=TinyPointNetModule), TinyPointNetModule)
    narrow = TinyPointNetModule(width=16).save_pretrained(tmp_path / "w16")
    with pytest.warns(UserWarning, match="skipped"):
        half = TinyPointNetModule(weights=str(narrow))
    with pytest.raises(ValueError, match=r"predict: TinyPointNetModule was built from weights that do not fit it"):
        resolve_model(half)


def test_a_config_value_a_class_refuses_names_the_exported_file(tmp_path):
    """Only a TypeError named the file; a ValueError of the constructor (a train field of a newer version) did not."""
    import json

    from floaff_zoo.hub import load_model
    from floaff_zoo.models.tiny import TinyPointNetModule

    out = TinyPointNetModule().save_pretrained(tmp_path / "tiny")
    cfg = out / "config.json" if out.is_dir() else out.parent / "config.json"
    data = json.loads(cfg.read_text())
    data["init_args"]["train"] = {"grad_clip": 1.0}
    cfg.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"tiny.*train has no field"):
        load_model(str(out))


def test_the_device_of_a_model_without_parameters_is_its_buffers():
    """The canonical prior without an AxisNet has buffers only: predict read the device from parameters alone and
    said cpu for a prior on another device (the batch stayed there; restore() moved the caller's prior for good)."""
    import torch

    from floaff_zoo.models.prior import CanonicalPriorModule
    from floaff_zoo.predict import module_device

    prior = CanonicalPriorModule(tasks=["CloseDrawer"])
    assert not list(prior.parameters()) and module_device(prior) == torch.device("cpu")
    assert module_device(prior.to("meta")) == torch.device("meta")
    assert module_device(torch.nn.Module()) == torch.device("cpu")


def test_predict_refuses_a_cloud_without_its_target_and_a_target_elsewhere(tiny_model):
    """A cloud that flags no point as the target, or a target_xyz in another unit or frame than the cloud, ran and
    returned a pose about nothing (predict() refused a mask without depth; both data readers refuse such samples)."""
    import numpy as np

    from floaff_zoo.predict import predict_from_points

    xyz, flag, t = _cloud()
    floor = np.c_[np.linspace(0.4, 1.0, 7), np.zeros(7), np.zeros(7)]
    with pytest.raises(ValueError, match=r"scene_feat flags no point of the cloud as the target .*none of 440"):
        predict_from_points(tiny_model, xyz, np.where(flag > 0, 0.0, flag), floor, [0.85, 1.03], t, num_points=64)
    for far in (t * 1000, t + [3.0, 0.0, 0.0]):  # millimetres; 3 m off
        with pytest.raises(ValueError, match=r"target_xyz .* m from the nearest of the 40 target-flagged points"):
            predict_from_points(tiny_model, xyz, flag, floor, [0.85, 1.03], far, num_points=64)
    near = t + [0.0, 0.3, -0.2]  # the front's centre, off the flagged points: still this target
    assert predict_from_points(tiny_model, xyz, flag, floor, [0.85, 1.03], near, num_points=64).scores.size == 7


def test_predict_refuses_candidates_off_the_floor(tiny_model):
    """Candidates are base positions at z = 0; the models read their z, so candidates given in a frame whose origin
    is above the floor were scored as other points without a word."""
    import numpy as np

    from floaff_zoo.predict import predict_from_points

    xyz, flag, t = _cloud()
    floor = np.c_[np.linspace(0.4, 1.0, 7), np.zeros(7), np.zeros(7)]
    on = predict_from_points(tiny_model, xyz, flag, floor, [0.85, 1.03], t, num_points=64)
    flat = predict_from_points(tiny_model, xyz, flag, floor[:, :2], [0.85, 1.03], t, num_points=64)
    assert np.array_equal(on.scores, flat.scores)
    with pytest.raises(ValueError, match=r"floor_xyz stands off the floor \(median z -0\.3 m"):
        predict_from_points(tiny_model, xyz, flag, floor + [0.0, 0.0, -0.3], [0.85, 1.03], t, num_points=64)
    # a robot's segmented floor points carry centimetres of sensor noise, as ground_mask keeps them: they pass
    noisy = floor + np.c_[np.zeros((7, 2)), [0.03, -0.031, 0.01, 0.0, -0.01, 0.025, 0.0]]
    predict_from_points(tiny_model, xyz, flag, noisy, [0.85, 1.03], t, num_points=64)


def test_zero_d_and_wrongly_shaped_arguments_are_named_with_their_shape():
    """A 0-d floor_xyz failed in len(), a 0-d target in numpy's indexing or reshape (default_target_yaw,
    default_floor_grid), a 0-d candidate set in candidate_spacing's; a [2, 2] intrinsics ran as (fx, fy, cx, cy) and
    a 0-d or [2, 2] robot was flattened into a descriptor without a word. Each is refused before any model loads,
    naming the argument and the shape given."""
    import re

    import numpy as np

    from floaff_zoo import predict as P

    xyz, flag, t = _cloud()
    floor = np.c_[np.linspace(0.4, 1.0, 7), np.zeros(7), np.zeros(7)]
    zero = np.asarray(1.0)

    def shape(a) -> str:
        return re.escape(str(np.shape(a)))

    cases = [
        ("floor_xyz", zero, r"floor_xyz must be \[M, 3\]"),
        ("floor_xyz", floor[0], r"floor_xyz must be \[M, 3\]"),
        ("target_xyz", zero, "target_xyz must be 3 finite values"),
        ("target_xyz", np.zeros((2, 3)), "target_xyz must be 3 finite values"),
        ("target_xyz", np.zeros(4), "target_xyz must be 3 finite values"),
        ("robot", zero, "robot must be the robot's descriptor numbers"),
        ("robot", np.ones((2, 2)), "robot must be the robot's descriptor numbers"),
        ("window", zero, "window must be two finite half-sizes"),
        ("window", np.ones((2, 2)), "window must be two finite half-sizes"),
    ]
    for name, bad, message in cases:
        args = {"floor_xyz": floor, "robot": [0.85, 1.03], "target_xyz": t, name: bad}
        if name == "window":
            args["floor_xyz"] = None  # the default grid reads it
        with pytest.raises(ValueError, match=f"predict: {message}.*{shape(bad)}"):
            P.predict_from_points("no-such-model-is-loaded", xyz, flag, **args)
    for k in (zero, np.ones((2, 2)), np.ones((2, 4))):
        with pytest.raises(ValueError, match=rf"predict: intrinsics must be .*got shape {shape(k)}"):
            P.backproject_depth(np.ones((4, 5)), k, np.eye(4))
    with pytest.raises(ValueError, match=rf"predict: target_xyz must be 3 finite values.*{shape(zero)}"):
        P.default_target_yaw(zero)
    with pytest.raises(ValueError, match=rf"predict: target_xyz must be 3 finite values.*{shape(zero)}"):
        P.default_floor_grid(zero, xyz)
    with pytest.raises(ValueError, match=rf"predict: window must be two finite half-sizes.*{shape(zero)}"):
        P.default_floor_grid(t, xyz, window=zero)
    with pytest.raises(ValueError, match=rf"predict: floor_xyz must be \[M, 2\] or \[M, 3\].*{shape(zero)}"):
        P.candidate_spacing(zero)


def test_ragged_huge_and_misnamed_arguments_are_named():
    """Ragged values gave numpy's 'inhomogeneous shape' naming no argument (the shape of the message failed too); a
    target of 1e39 m passed the float64 check and became inf in float32; default_floor_grid called its ``radius``
    grid_radius."""
    import numpy as np

    from floaff_zoo import predict as P

    xyz, flag, t = _cloud()
    with pytest.raises(ValueError, match=r"predict: target_xyz must be 3 finite values .*\(ragged or non-numeric\)"):
        P.predict_from_points("no-such-model-is-loaded", xyz, flag, None, [0.85, 1.03], [[1.0, 2.0], [3.0]])
    with pytest.raises(ValueError, match=r"predict: intrinsics must be .*\(ragged or non-numeric\)"):
        P.backproject_depth(np.ones((4, 5)), [[1.0, 0.0], [1.0]], np.eye(4))
    with pytest.raises(ValueError, match=r"predict: target_xyz must be 3 finite values .*1e\+39"):
        P.predict_from_points("no-such-model-is-loaded", xyz, flag, None, [0.85, 1.03], [1e39, 0.0, 0.0])
    with pytest.raises(ValueError, match="predict: radius must be a finite radius"):
        P.default_floor_grid(t, xyz, radius=-1.0)


def test_one_point_or_pair_in_a_batch_shape_is_read_as_that_point(tiny_model):
    """A target, window or robot given as a batch of one ([1, 3], [[rx, ry]], [1, R]) is that value: a [[rx, ry]]
    window failed in float(window[0]), and intrinsics may be a flat K of 9 values."""
    import numpy as np

    from floaff_zoo import predict as P

    xyz, flag, t = _cloud()
    grid = P.default_floor_grid(t, xyz, window=(0.6, 0.5))
    assert np.array_equal(P.default_floor_grid(t[None, None], xyz, window=[[0.6, 0.5]]), grid)
    one = P.predict_from_points(tiny_model, xyz, flag, None, [0.85, 1.03], t, num_points=64)
    batch = P.predict_from_points(tiny_model, xyz, flag, None, [[0.85, 1.03]], t[None], num_points=64)
    assert np.array_equal(one.scores, batch.scores)
    k = np.array([[50.0, 0.0, 2.0], [0.0, 50.0, 1.5], [0.0, 0.0, 1.0]])
    depth = np.ones((4, 5))
    for a, b in zip(P.backproject_depth(depth, k, np.eye(4)), P.backproject_depth(depth, k.reshape(-1), np.eye(4))):
        assert np.array_equal(a, b)


def test_a_robot_descriptor_of_the_wrong_size_names_the_argument(tiny_model):
    """The model's own check said 'the data gives robot descriptors of size 3; set model.init_args.robot_dim: 3',
    naming no argument of predict and advising a config change a pretrained model cannot take."""
    from floaff_zoo.contract import SampleError
    from floaff_zoo.predict import predict_from_points

    xyz, flag, t = _cloud()
    for robot in ([0.85, 1.03, 0.5], [0.85], []):
        with pytest.raises(SampleError, match=rf"predict: robot must be the 2 values .* got {len(robot)}"):
            predict_from_points(tiny_model, xyz, flag, None, robot, t, num_points=64)
    from floaff_zoo.models.tiny import TinyPointNetModule

    rgb_model = TinyPointNetModule(feat_channels=4, width=8).eval()  # reads the flag and RGB
    with pytest.raises(SampleError, match=r"predict: TinyPointNetModule reads 4 scene_feat channels .* got 1"):
        predict_from_points(rgb_model, xyz, flag, None, [0.85, 1.03], t, num_points=64)


def test_the_prediction_writer_writes_bf16_mixed_outputs_as_float32(tmp_path):
    """Under `--trainer.precision bf16-mixed` AxisNet's yaw (and angle error) come out of autocast as bfloat16, which
    numpy has no type for: `floaff-zoo predict` ran every batch, then lost them all to 'Got unsupported ScalarType
    BFloat16' in the writer."""
    import lightning as L
    import numpy as np

    from floaff_zoo.callbacks.predictions import PredictionWriter
    from floaff_zoo.data.synthetic import SyntheticDataModule
    from floaff_zoo.models.axisnet import AxisNetModule

    dm = SyntheticDataModule(num_train=2, num_val=2, num_test=3, batch_size=2, points_per_sample=128, num_points=128)
    trainer = L.Trainer(
        accelerator="cpu",
        precision="bf16-mixed",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[PredictionWriter(out_dir=str(tmp_path))],
    )
    trainer.predict(AxisNetModule(), datamodule=dm)
    with np.load(tmp_path / "predictions.npz") as z:
        assert z["yaw"].shape == (3,) and z["yaw"].dtype == np.float32
        assert np.isfinite(z["yaw"]).all()
    # AxisNet now returns float32 itself: the writer must take any model's bfloat16 output
    import torch

    from floaff_zoo.callbacks.predictions import gather_predictions

    arrays, _ = gather_predictions([{"yaw": torch.tensor([0.5, -1.25], dtype=torch.bfloat16)}])
    assert arrays["yaw"].dtype == np.float32 and arrays["yaw"].tolist() == [0.5, -1.25]


@pytest.mark.parametrize(
    "records, named",
    [
        ([{"scores": "S", "loss": "L"}], r"batch 0: every output must hold one entry per sample .* loss: a scalar"),
        ([{"scores": "S", "meta": [{}]}], r"batch 0: every output must hold one entry per sample .* meta: 1"),
        ([{"scores": "S", "extra": "X1"}], r"batch 0: every output must hold one entry per sample .* extra: 1"),
        (
            [{"scores": "S"}, {"scores": "S", "extra": "X2"}],
            r"batch 1 has tensor\(s\) \['extra'\] that batch 0 has not",
        ),
        (["S"], "batch 0: predict_step returned a Tensor, not a dict of tensors"),
    ],
)
def test_the_prediction_writer_refuses_outputs_out_of_step_with_the_samples(records, named):
    """A predict_step output of another length than the batch (a scalar loss, a [1, ...] tensor, a meta list one
    short) was written out of step with the samples, or failed in numpy's concatenate naming no key; a tensor that
    only a later batch returned was dropped without a word; a bare tensor record raised AttributeError."""
    import torch

    from floaff_zoo.callbacks.predictions import gather_predictions

    made = {"S": torch.rand(2, 5), "L": torch.tensor(1.0), "X1": torch.rand(1, 3), "X2": torch.rand(2)}
    records = [
        made[r] if isinstance(r, str) else {k: made[v] if isinstance(v, str) else v for k, v in r.items()}
        for r in records
    ]
    with pytest.raises(ValueError, match=named):
        gather_predictions(records)
    arrays, meta = gather_predictions([{"scores": made["S"], "meta": []}, {"scores": made["S"]}])  # no meta: fine
    assert arrays["scores"].shape == (4, 5) and meta == [{}] * 4
