"""AxisNet: the yaw metric, augmentation consistency and a short real fit through the CLI."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from floaff_zoo.cli import run_lightning
from floaff_zoo.contract import SampleError, collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.models.axisnet import AngleErrorDeg, AxisNetModule
from floaff_zoo.nn.axisnet import angle_error_deg, axis_inputs, rotate_about_target, yaw_from_vector, yaw_to_vector
from tests.conftest import quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
AXIS = "tests/configs/axisnet_tiny.yaml"


def _batch(n=4, points=256):
    return collate_samples([make_synthetic_sample(i, points, 8) for i in range(n)], points)


def test_angle_error_metric_matches_numpy_and_wraps():
    rng = np.random.default_rng(0)
    p, g = rng.uniform(-math.pi, math.pi, 50), rng.uniform(-math.pi, math.pi, 50)
    ref = np.degrees(np.abs(np.angle(np.exp(1j * (p - g))))).mean()
    m = AngleErrorDeg()
    m.update(torch.tensor(p[:20]), torch.tensor(g[:20]))
    m.update(torch.tensor(p[20:]), torch.tensor(g[20:]))
    assert float(m.compute()) == pytest.approx(ref, abs=1e-4)
    wrap = angle_error_deg(torch.tensor([math.radians(179.0)]), torch.tensor([math.radians(-179.0)]))
    assert float(wrap) == pytest.approx(2.0, abs=1e-4)
    with pytest.raises(ValueError, match="NaN"):
        m.update(torch.tensor([float("nan")]), torch.tensor([0.0]))


def test_angle_error_counts_a_repeated_sample_once():
    """DistributedSampler pads the last rank-batches with repeats: the floor-map metrics drop them by index, AxisNet's
    monitored angle error counted them twice."""
    m = AngleErrorDeg()
    yaw = torch.tensor([math.radians(10.0), math.radians(20.0)])
    m.update(yaw, torch.zeros(2), torch.tensor([0, 1]))
    m.update(torch.tensor([math.radians(20.0), math.radians(60.0)]), torch.zeros(2), torch.tensor([1, 2]))
    assert float(m.compute()) == pytest.approx((10.0 + 20.0 + 60.0) / 3, abs=1e-4)
    synced = AngleErrorDeg()  # a fresh one: compute() caches its value until the next update
    synced.update(yaw, torch.zeros(2), torch.tensor([0, 1]))
    synced.rows = torch.cat(synced.rows)  # as a DDP sync leaves a cat state: one tensor (`if self.rows` raised)
    assert float(synced.compute()) == pytest.approx(15.0, abs=1e-4)
    assert math.isnan(float(AngleErrorDeg().compute()))  # nothing seen


def test_yaw_vector_round_trip():
    yaw = torch.linspace(-3.1, 3.1, 17)
    assert torch.allclose(yaw_from_vector(yaw_to_vector(yaw)), yaw, atol=1e-6)


def test_rotation_augmentation_turns_inputs_and_label_together():
    b = _batch()
    delta = torch.tensor([0.3, -1.2, 1.5, 0.0])
    x0, m0 = axis_inputs(b["scene_xyz"], b["scene_feat"], b["scene_mask"], b["target_xyz"], 1.3)
    rot = rotate_about_target(b["scene_xyz"], b["target_xyz"], delta)
    x1, m1 = axis_inputs(rot, b["scene_feat"], b["scene_mask"], b["target_xyz"], 1.3)
    assert torch.equal(m0, m1)  # a sphere crop about the target does not change under the rotation
    c, s = torch.cos(delta)[:, None], torch.sin(delta)[:, None]
    xr = c * x0[..., 0] - s * x0[..., 1]
    assert torch.allclose(x1[..., 0], xr, atol=1e-5)
    assert torch.allclose(x1[..., 3], x0[..., 3])


def test_axisnet_input_is_cropped_and_scaled():
    b = _batch(2)
    x, mask = axis_inputs(b["scene_xyz"], b["scene_feat"], b["scene_mask"], b["target_xyz"], 1.0)
    d = (b["scene_xyz"] - b["target_xyz"][:, None]).norm(dim=-1)
    assert torch.equal(mask, b["scene_mask"] & (d <= 1.0))
    assert (x[..., :3].norm(dim=-1)[mask] <= 1.0 + 1e-6).all()
    assert (x[~mask] == 0).all()


def test_axisnet_inference_pools_each_cloud_as_the_training_path_does():
    """Without gradients (eval-mode BN) each cloud's valid points are pooled on their own: same output as the
    scatter + masked max of the training path, an all-masked cloud included."""
    from floaff_zoo.nn.axisnet import AxisNet

    torch.manual_seed(0)
    net = AxisNet(widths=(16, 32), head=(8,))
    for norm in net.point_mlp.norms:
        norm.running_mean.uniform_(-0.3, 0.3)
        norm.running_var.uniform_(0.5, 2.0)
    net.eval()
    x = torch.randn(3, 50, 4)
    mask = torch.rand(3, 50) > 0.4
    mask[2] = False
    with torch.no_grad():
        fast = net(x, mask)
    with torch.enable_grad():
        slow = net(x, mask)
    assert torch.allclose(fast, slow.detach(), atol=1e-6), (fast - slow).abs().max()


def test_axisnet_empty_crop_names_the_sample():
    b = _batch(2)
    b["target_xyz"][1] += 50.0
    m = AxisNetModule(widths=[8], head=[8])
    with pytest.raises(SampleError, match="syn1"):
        m(b)


def test_axisnet_learns_yaw_in_a_short_fit(tmp_path, root, monkeypatch):
    """A real (short) fit through the CLI: mean validation error < 10 deg on unseen synthetic scenes."""
    monkeypatch.chdir(root)
    cli = run_lightning(
        [
            "fit",
            "--config",
            DATA,
            "--config",
            AXIS,
            *quiet_trainer_args(tmp_path),
            "--data.init_args.num_train",
            "256",
            "--data.init_args.num_val",
            "64",
            "--data.init_args.batch_size",
            "32",
            "--model.init_args.widths",
            "[32, 64, 64]",
            "--model.init_args.head",
            "[32]",
            "--model.init_args.train.lr",
            "0.005",
            "--trainer.max_epochs",
            "10",
        ]
    )
    ckpt_cb = cli.trainer.checkpoint_callback
    assert ckpt_cb.monitor == "val_angle_error_deg" and ckpt_cb.mode == "min"
    assert float(ckpt_cb.best_model_score) < 10.0
    best = AxisNetModule.load_from_checkpoint(ckpt_cb.best_model_path, weights_only=True).eval()
    b = collate_samples([make_synthetic_sample(900_000 + i, 256, 8) for i in range(32)], 256)
    with torch.no_grad():
        err = angle_error_deg(best(b), b["target_yaw"])
    assert float(err.mean()) < 10.0
    # predict returns yaw, not floor scores
    out = best.predict_step(b, 0)
    assert out["yaw"].shape == (32,) and "scores" not in out
    assert Path(ckpt_cb.best_model_path).is_file()
    # `floaff-zoo test` on an AxisNet run: the angle error is reported, the figure step (floor maps) is skipped
    cfg = Path(ckpt_cb.best_model_path).parents[1] / "config.yaml"
    cli_t = run_lightning(["test", "--config", str(cfg), *quiet_trainer_args(tmp_path), "--ckpt_path", "best"])
    report = json.loads((Path(cli_t.trainer.log_dir) / "report.json").read_text())
    assert report["metrics"]["test_angle_error_deg"] < 10.0 and not report.get("figures")


@pytest.mark.parametrize("radius", [float("nan"), float("inf"), "1.3", None])
def test_a_crop_radius_that_is_not_a_finite_positive_number_is_refused(radius):
    """NaN passed the > 0 check and cropped every point away (a SampleError blaming the samples); inf kept every
    point and divided every coordinate to 0, so the yaw was the same for any scene; a text or None raised a TypeError
    naming no argument."""
    with pytest.raises(ValueError, match=r"crop_radius must be a finite number > 0"):
        AxisNetModule(crop_radius=radius)


@pytest.mark.parametrize(
    ("arg", "value"), [("rot_aug_deg", -90.0), ("rot_aug_deg", float("nan")), ("jitter_sigma", -0.01)]
)
def test_an_augmentation_size_that_switches_it_off_silently_is_refused(arg, value):
    with pytest.raises(ValueError, match=rf"AxisNetModule: {arg} must be a finite number >= 0"):
        AxisNetModule(**{arg: value})


def test_the_yaw_is_float32_under_bf16_autocast_and_reaches_the_predictions_file():
    """Under bf16-mixed the yaw came out in bfloat16 (AxisNet's last Linear and atan2 ran in it): rounded to ~1 deg,
    and the prediction writer's .numpy() refused the record (AxisNet's predict, and CFAR's with an AxisNet yaw)."""
    from floaff_zoo.callbacks.predictions import gather_predictions
    from floaff_zoo.models.cfar import CFARModule

    torch.manual_seed(0)
    batch = _batch()
    arch = {"widths": [8, 8], "head": [8], "crop_radius": 1.3, "source": "random", "sha256": None}
    cfar = CFARModule(
        local_npoints=[32, 8], local_nsamples=[8, 8], floor_npoints=[8, 4], floor_nsamples=[4, 4], axisnet_arch=arch
    )
    for model in (AxisNetModule(widths=[8, 8], head=[8]).eval(), cfar.eval()):
        with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
            record = model.predict_step(batch, 0)
        assert record["yaw"].dtype == torch.float32, type(model).__name__
        arrays, _ = gather_predictions([record])
        assert arrays["yaw"].shape == (4,)


def test_an_empty_widths_list_is_refused_not_replaced_by_the_default():
    """[] built the default [64, 128, 256] without a word (``head: []`` is honoured: no hidden layer)."""
    with pytest.raises(ValueError, match=r"AxisNetModule: widths needs >= 1 width \(null for \[64, 128, 256\]\)"):
        AxisNetModule(widths=[])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ({"widths": [8.5]}, r"widths\[0\] must be an integer >= 1, got 8.5"),  # failed in torch.empty, unnamed
        ({"widths": [8, True]}, r"widths\[1\] must be an integer >= 1, got True"),
        ({"widths": "64"}, r"widths must be a list of integers >= 1, got '64'"),
        ({"head": [2.5]}, r"head\[0\] must be an integer >= 1, got 2.5"),
    ],
)
def test_a_width_that_is_not_a_whole_number_is_refused_by_name(args, message):
    with pytest.raises(ValueError, match=rf"AxisNetModule: {message}"):
        AxisNetModule(**args)


def test_bad_inference_inputs_and_metric_indices_are_named():
    """A scene_feat of another shape (or no channel) failed in torch.cat or the first Linear; an index of another
    length than the batch failed in torch.stack."""
    b = _batch(2, 64)
    model = AxisNetModule(widths=[8], head=[8])
    for feat in (b["scene_feat"][:, 1:], b["scene_feat"][:1], b["scene_feat"][..., :0]):
        with pytest.raises(ValueError, match=r"axis_inputs: scene_feat must be \[2, 64, C >= 1\]"):
            model.estimate_yaw(b["scene_xyz"], feat, b["scene_mask"], b["target_xyz"])
    with pytest.raises(ValueError, match=r"AngleErrorDeg: index must have 3 entries, got \[2\]"):
        AngleErrorDeg().update(torch.zeros(3), torch.zeros(3), torch.arange(2))


@pytest.mark.parametrize("radius", [float("nan"), -1.0, "1.3", None])
def test_a_recorded_axisnet_crop_radius_is_checked(radius):
    """A NaN or negative recorded crop_radius built a CFAR whose AxisNet cropped every point away (blaming the
    samples); a text failed float() naming nothing."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    from floaff_zoo.models.yaw import build_axisnet

    arch = {"widths": [8], "head": [8], "crop_radius": radius}
    with pytest.raises(MisconfigurationException, match=r"O: axisnet_arch.crop_radius must be a finite number > 0"):
        build_axisnet(arch, "O")
