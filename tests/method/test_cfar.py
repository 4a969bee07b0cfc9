"""CFAR: the canonical transform (crop, alignment, invariance, fallback) and the module through the CLI."""

import math
from pathlib import Path

import pytest
import torch
import yaml
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.cli import run_lightning
from floaff_zoo.contract import SampleError, collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.losses import masked_mse
from floaff_zoo.models.cfar import CFARModule
from floaff_zoo.nn.cfar import canonical_to_robot, canonical_transform, crop_mask, robot_from_canonical
from tests.conftest import block_first_footprint, quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
CFAR = "tests/configs/cfar_tiny.yaml"
AXIS = "tests/configs/axisnet_tiny.yaml"


def tiny_args(root: Path) -> dict:
    return yaml.safe_load((root / CFAR).read_text())["model"]["init_args"]


def _batch(n=4, points=256, seed=0):
    return collate_samples([make_synthetic_sample(seed + i, points, 8) for i in range(n)], points)


def _rotate_everything(batch, alpha: torch.Tensor, pivot: torch.Tensor):
    """Rotate scene, floor and target pose by alpha [B] about the vertical axis through pivot [B, 3]."""
    c, s = torch.cos(alpha)[:, None], torch.sin(alpha)[:, None]

    def rot(p):  # [B, K, 3]
        q = p - pivot[:, None]
        x, y = c * q[..., 0] - s * q[..., 1], s * q[..., 0] + c * q[..., 1]
        return torch.stack([x, y, q[..., 2]], -1) + pivot[:, None]

    out = dict(batch)
    out["scene_xyz"] = rot(batch["scene_xyz"])
    out["floor_xyz"] = rot(batch["floor_xyz"])
    out["target_xyz"] = rot(batch["target_xyz"][:, None])[:, 0]
    out["target_yaw"] = batch["target_yaw"] + alpha
    return out


def test_crop_removes_far_points_and_keeps_near_ones():
    g = torch.Generator().manual_seed(0)
    xyz = torch.rand(3, 500, 3, generator=g) * 4 - 2
    mask = torch.rand(3, 500, generator=g) > 0.1
    centre = torch.tensor([[0.0, 0.0, 0.5], [1.0, -0.5, 0.0], [-0.3, 0.2, 1.0]])
    keep, used = crop_mask(xyz, mask, centre, 1.2)
    d = (xyz - centre[:, None]).norm(dim=-1)
    assert torch.equal(keep, mask & (d <= 1.2))
    assert torch.equal(used, torch.full((3,), 1.2))
    canon = canonical_transform(xyz, mask, xyz[:, :10], centre, torch.zeros(3), 1.2)
    assert (canon.xyz[~keep] == 0).all()
    assert torch.allclose(canon.xyz.norm(dim=-1)[keep], d[keep], atol=1e-5)  # rigid: distances kept


def test_front_normal_faces_minus_y_and_round_trip():
    yaw = torch.tensor([0.0, 1.0, -2.5, math.pi])
    t = torch.tensor([[1.0, 2.0, 0.8]]).repeat(4, 1)
    normal = torch.stack([torch.cos(yaw), torch.sin(yaw), torch.zeros(4)], -1)
    pts = (t + normal)[:, None]  # one point 1 m in front of each target
    canon = canonical_transform(pts, torch.ones(4, 1, dtype=torch.bool), pts, t, yaw, 2.0)
    assert torch.allclose(canon.xyz[:, 0], torch.tensor([0.0, -1.0, 0.0]).expand(4, 3), atol=1e-6)
    back = canonical_to_robot(canon.floor_xyz, canon.centre, canon.angle)
    assert torch.allclose(back, pts, atol=1e-6)
    mat = robot_from_canonical(canon.centre, canon.angle)
    homo = torch.cat([canon.floor_xyz, torch.ones(4, 1, 1)], -1)
    assert torch.allclose((homo @ mat.transpose(1, 2))[..., :3], pts, atol=1e-6)


def test_empty_crop_grows_radius_then_names_the_sample():
    xyz = torch.tensor([[[1.4, 0.0, 0.0], [2.0, 0.0, 0.0]]]).repeat(2, 1, 1)
    mask = torch.ones(2, 2, dtype=torch.bool)
    centre = torch.zeros(2, 3)
    centre[1, 0] = -30.0  # hopeless
    keep, used = crop_mask(xyz[:1], mask[:1], centre[:1], 1.2)
    assert used.tolist() == pytest.approx([1.5])  # 1.2 -> 1.5 (x1.25 once) includes the 1.4 m point
    assert keep.tolist() == [[True, False]]
    with pytest.raises(SampleError, match=r"kitchen_7.*1\.25 3 times"):
        crop_mask(xyz, mask, centre, 1.2, names=["kitchen_3", "kitchen_7"])


def test_empty_crop_through_the_module_names_the_sample(root):
    m = CFARModule(**tiny_args(root))
    b = _batch(2)
    b["target_xyz"][0] += torch.tensor([40.0, 0.0, 0.0])
    with pytest.raises(SampleError, match="syn0"):
        m(b)


@pytest.mark.parametrize("seed", [0, 1])
def test_yaw_invariance_of_canonical_cloud_and_scores(root, seed):
    torch.manual_seed(seed)
    b = _batch(4, seed=10 * seed)
    alpha = (torch.rand(4) * 2 - 1) * math.pi
    pivot = torch.cat([torch.randn(4, 2) * 3, torch.zeros(4, 1)], -1)  # any vertical axis
    r = _rotate_everything(b, alpha, pivot)
    c0 = canonical_transform(b["scene_xyz"], b["scene_mask"], b["floor_xyz"], b["target_xyz"], b["target_yaw"], 1.3)
    c1 = canonical_transform(r["scene_xyz"], r["scene_mask"], r["floor_xyz"], r["target_xyz"], r["target_yaw"], 1.3)
    assert torch.equal(c0.mask, c1.mask)
    assert (c0.xyz - c1.xyz).abs().max() < 1e-5
    assert (c0.floor_xyz - c1.floor_xyz).abs().max() < 1e-5
    model = CFARModule(**tiny_args(root), yaw_source="gt", eval_yaw_source="gt").eval()
    with torch.no_grad():
        s0, s1 = model(b), model(r)
    assert (s0 - s1).abs().max() < 1e-4
    assert s0.std() > 1e-4  # the scores do depend on the input (the check above can fail)
    # without alignment the same rotation changes the prediction: the test is sensitive
    plain = CFARModule(**tiny_args(root), use_align=False).eval()
    plain.load_state_dict(model.state_dict())
    with torch.no_grad():
        assert (plain(b) - plain(r)).abs().max() > 1e-3


def test_ablation_switches(root):
    args = tiny_args(root)
    b = _batch(2)
    m = CFARModule(**args, use_sdl=False)
    s = torch.rand(2, b["floor_label"].shape[1])
    assert torch.allclose(m.affordance_loss(s, b), masked_mse(s, b["floor_label"], b["floor_mask"]))
    assert not torch.allclose(CFARModule(**args).affordance_loss(s, b), m.affordance_loss(s, b))
    nocrop = CFARModule(**args, use_crop=False)
    canon, _ = nocrop.canonicalize(b)
    assert torch.equal(canon.mask, b["scene_mask"])
    assert CFARModule(**args, use_align=False).eval_yaw_source == "none"
    with pytest.raises(MisconfigurationException, match="axisnet"):
        CFARModule(**args, yaw_source="axisnet")


def test_fit_test_predict_and_reload_outside_cli(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    base = ["--config", DATA, "--config", CFAR, *quiet_trainer_args(tmp_path)]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    assert Path(ckpt).is_file() and "val_rmse" in cli.trainer.callback_metrics
    cli_t = run_lightning(["test", *base, "--ckpt_path", ckpt])
    assert torch.isfinite(cli_t.trainer.callback_metrics["test_sim"])
    cli_p = run_lightning(["predict", *base, "--ckpt_path", ckpt])
    pred = cli_p.trainer.predict_loop.predictions[0]
    assert pred["robot_from_canonical"].shape == (2, 4, 4) and pred["scores"].shape[0] == 2
    m = CFARModule.load_from_checkpoint(ckpt, weights_only=True)
    assert m.hparams.crop_radius == 1.3 and m.train_cfg.loss == "aff" and m.train_cfg.lr == 0.003


def _test_with_axisnet(run_root: Path, ckpt: str, axisnet: str):
    """``floaff-zoo test`` of a tiny CFAR checkpoint with ``--model.init_args.axisnet`` (the LightningCLI)."""
    args = ["test", "--config", DATA, "--config", CFAR, *quiet_trainer_args(run_root), "--ckpt_path", ckpt]
    return run_lightning([*args, "--model.init_args.axisnet", axisnet])


def test_axisnet_is_frozen_embedded_and_used_at_eval(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    axis = run_lightning(
        ["fit", "--config", DATA, "--config", AXIS, *quiet_trainer_args(tmp_path / "axis"), "--trainer.max_epochs", "1"]
    )
    axis_ckpt = tmp_path / "axis.ckpt"
    Path(axis.trainer.checkpoint_callback.best_model_path).rename(axis_ckpt)
    cli = run_lightning(
        [
            "fit",
            "--config",
            DATA,
            "--config",
            CFAR,
            *quiet_trainer_args(tmp_path / "cfar"),
            "--model.init_args.axisnet",
            str(axis_ckpt),
            "--trainer.max_epochs",
            "1",
        ]
    )
    model = cli.model
    assert model.eval_yaw_source == "axisnet" and model.train_yaw_source == "gt"
    assert not any(p.requires_grad for p in model.axisnet.parameters())
    model.train()
    assert not model.axisnet.training  # stays in eval inside train()
    axis_state = torch.load(axis_ckpt, weights_only=True)["state_dict"]
    for k, v in model.axisnet.state_dict().items():
        assert torch.equal(v, axis_state["net." + k]), k  # frozen: unchanged by the fit
    student = cli.trainer.checkpoint_callback.best_model_path
    axis_ckpt.unlink()  # the student checkpoint alone rebuilds the AxisNet
    re = CFARModule.load_from_checkpoint(student, weights_only=True).eval()
    assert re.eval_yaw_source == "axisnet" and re.hparams.axisnet_arch["sha256"]
    b = _batch(2)
    yaw = re.estimate_yaw(b)
    assert yaw.shape == (2,)
    out = re.predict_step(b, 0)
    assert torch.allclose(out["yaw"], yaw)
    # swapping the orientation estimator of the trained model at test time: the named AxisNet is used
    axis2 = run_lightning(
        [
            "fit",
            "--config",
            DATA,
            "--config",
            AXIS,
            *quiet_trainer_args(tmp_path / "axis2"),
            "--trainer.max_epochs",
            "1",
            "--seed_everything",
            "7",
        ]
    )
    axis2_ckpt = axis2.trainer.checkpoint_callback.best_model_path
    with pytest.warns(UserWarning, match="the configured AxisNet wins"):  # a swap by a retrain at the same path too
        swapped = _test_with_axisnet(tmp_path / "cfar", student, axis2_ckpt)
    axis2_state = torch.load(axis2_ckpt, weights_only=True)["state_dict"]
    for k, v in swapped.model.axisnet.state_dict().items():
        assert torch.equal(v, axis2_state["net." + k]), k
    assert swapped.model.hparams.axisnet_arch["source"] == axis2_ckpt
    for k, v in swapped.model.net.state_dict().items():  # the CFAR weights are still the student's
        assert torch.equal(v, re.net.state_dict()[k]), k
    # the same through `weights` (a later PFAL stage initialised from this one with another AxisNet): the student's
    # stored AxisNet silently replaced the configured one, which its lineage still named
    init_args = yaml.safe_load(Path(CFAR).read_text())["model"]["init_args"]
    stage2 = CFARModule(**init_args, axisnet=axis2_ckpt, weights=student)
    for k, v in stage2.axisnet.state_dict().items():
        assert torch.equal(v, axis2_state["net." + k]), k
    assert stage2.weights_not_loaded == []
    for k, v in stage2.net.state_dict().items():
        assert torch.equal(v, re.net.state_dict()[k]), k
    # a CFAR trained on the simulator's yaw without any AxisNet is evaluated with one (the deployable path)
    plain = run_lightning(
        [
            "fit",
            "--config",
            DATA,
            "--config",
            CFAR,
            *quiet_trainer_args(tmp_path / "plain"),
            "--trainer.max_epochs",
            "1",
        ]
    )
    assert plain.model.axisnet is None
    given = _test_with_axisnet(tmp_path / "plain", plain.trainer.checkpoint_callback.best_model_path, axis2_ckpt)
    assert given.model.eval_yaw_source == "axisnet"
    for k, v in given.model.axisnet.state_dict().items():
        assert torch.equal(v, axis2_state["net." + k]), k


def _fit_with_switch(tmp_path, root, monkeypatch, switch: str) -> tuple[list[str], str]:
    """One epoch of the tiny CFAR config through the CLI with ``--model.init_args.<switch> true``: (the CLI arguments
    without the subcommand, the best checkpoint)."""
    monkeypatch.chdir(root)
    base = ["--config", DATA, "--config", CFAR, *quiet_trainer_args(tmp_path), f"--model.init_args.{switch}", "true"]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
    return base, cli.trainer.checkpoint_callback.best_model_path


def test_occupancy_input_reads_the_footprint_from_the_view(tmp_path, root, monkeypatch):
    """``occupancy_input``: an obstacle put into one floor point's base footprint changes that point's input and
    score; the switch trains, tests and reloads through the CLI."""
    from floaff_zoo.nn.placement import footprint_counts

    b = _batch(2)
    model = CFARModule(**tiny_args(root), occupancy_input=True, eval_yaw_source="gt").eval()
    assert model.net.head.linears[0].in_features == CFARModule(**tiny_args(root)).net.head.linears[0].in_features + 2
    occ = model.occupancy(b)
    assert occ.shape == (*b["floor_xyz"].shape[:2], 2) and torch.isfinite(occ).all()
    # park on floor point 0 of sample 0: put ten points 0.2 m tall just behind it (inside the footprint)
    blocked = block_first_footprint(b)
    count = footprint_counts(
        blocked["scene_xyz"], blocked["scene_mask"], b["floor_xyz"][..., :2], b["target_xyz"][..., :2]
    )
    assert count[0, 0] >= 10 and model.occupancy(blocked)[0, 0, 1] == 1.0
    # the feature is read per 1,024 valid points: the same cloud at twice the density gives the same input
    doubled = dict(blocked)
    doubled["scene_xyz"] = torch.cat([blocked["scene_xyz"]] * 2, dim=1)
    doubled["scene_mask"] = torch.cat([blocked["scene_mask"]] * 2, dim=1)
    assert torch.allclose(model.occupancy(doubled), model.occupancy(blocked))
    n_valid = blocked["scene_mask"].sum(1)
    assert torch.allclose(model.occupancy(blocked)[..., 0], torch.log1p(count * 1024 / n_valid[:, None]))
    with torch.no_grad():
        s1 = model(blocked)
        monkeypatch.setattr(model, "occupancy", lambda batch: torch.zeros_like(occ))  # same scene, no occupancy
        s0 = model(blocked)
        monkeypatch.undo()
    assert (s0[0, 0] - s1[0, 0]).abs() > 1e-6  # the score reads the occupancy channels
    with pytest.raises(ValueError, match="floor_feat must be"):
        model.net.logits(b["scene_xyz"], b["scene_feat"], b["scene_mask"], b["floor_xyz"], b["floor_mask"], b["robot"])
    # through the CLI: fit, test, reload with the switch kept
    base, ckpt = _fit_with_switch(tmp_path, root, monkeypatch, "occupancy_input")
    assert torch.isfinite(run_lightning(["test", *base, "--ckpt_path", ckpt]).trainer.callback_metrics["test_sim"])
    assert CFARModule.load_from_checkpoint(ckpt, weights_only=True).net.floor_feat_channels == 2


def test_coverage_input_reads_how_much_of_the_footprint_the_view_shows(tmp_path, root, monkeypatch):
    """``coverage_input``: one channel after the occupancy's, the share of each floor point's footprint the view's cloud
    shows; points put into one footprint raise it there and change that score; the switch trains and reloads."""
    from floaff_zoo.nn.placement import footprint_seen

    b = _batch(2)
    model = CFARModule(**tiny_args(root), occupancy_input=True, coverage_input=True, eval_yaw_source="gt").eval()
    plain = CFARModule(**tiny_args(root)).net.head.linears[0].in_features
    assert model.net.head.linears[0].in_features == plain + 3
    assert CFARModule(**tiny_args(root), coverage_input=True).net.head.linears[0].in_features == plain + 1
    feats = model.floor_features(b)
    assert feats.shape == (*b["floor_xyz"].shape[:2], 3)
    assert torch.equal(feats[..., :2], model.occupancy(b))
    torch.manual_seed(0)
    shown = block_first_footprint(b, n=40)
    shown["scene_xyz"][0, :40, :2] += torch.randn(40, 2) * 0.1  # spread over the footprint's sub-squares
    cov = footprint_seen(shown["scene_xyz"], shown["scene_mask"], b["floor_xyz"][..., :2], b["target_xyz"][..., :2])
    assert cov[0, 0] > feats[0, 0, 2] and torch.equal(model.floor_features(shown)[..., 2], cov)
    with torch.no_grad():
        s1 = model(shown)
        real = model.floor_features
        monkeypatch.setattr(
            model, "floor_features", lambda batch: torch.cat([real(batch)[..., :2], 0 * cov[..., None]], -1)
        )
        s0 = model(shown)
        monkeypatch.undo()
    assert (s0[0, 0] - s1[0, 0]).abs() > 1e-6  # the score reads the coverage channel
    _, ckpt = _fit_with_switch(tmp_path, root, monkeypatch, "coverage_input")
    assert CFARModule.load_from_checkpoint(ckpt, weights_only=True).net.floor_feat_channels == 1


def test_residual_scale_shrinks_the_learned_residual_towards_the_prior(root):
    """scores = sigmoid(scale * residual + logit(prior)): 0 reads the prior alone, 1 the model as trained."""
    args = tiny_args(root)
    b = _batch(2)
    m = CFARModule(**args, prior_residual=True).eval()
    canon, _ = m.canonicalize(b)
    tasks = m.prior.task_index([str(x.get("task")) for x in b["meta"]])
    m.prior.add(tasks, canon.floor_xyz[..., :2], b["floor_label"], b["floor_mask"])
    torch.nn.init.normal_(m.net.out.weight, std=0.5)  # a residual that is not zero
    logit = lambda p: torch.log(p) - torch.log1p(-p)  # noqa: E731
    with torch.no_grad():
        full = logit(m(b).double())
        m.hparams["residual_scale"] = 0.0
        prior = logit(m(b).double())
        m.hparams["residual_scale"] = 0.5
        half = logit(m(b).double())
    assert not torch.allclose(full, prior, atol=1e-3)
    assert torch.allclose(half, (full + prior) / 2, atol=1e-3)
    with pytest.raises(MisconfigurationException, match="residual_scale"):
        CFARModule(**args, prior_residual=True, residual_scale=-1.0)
    with pytest.raises(MisconfigurationException, match="residual_scale.*prior_residual"):
        CFARModule(**args, residual_scale=0.5)  # no prior to shrink towards: not silently ignored


def test_the_prior_is_read_at_the_canonical_floor_points(root):
    """With the residual scaled to 0 the scores are the prior alone: read in the canonical frame, they do not move
    when the whole input turns and shifts about a vertical axis (read in the robot frame, they did)."""
    b = _batch(2)
    m = CFARModule(**tiny_args(root), prior_residual=True, yaw_source="gt", eval_yaw_source="gt").eval()
    canon, _ = m.canonicalize(b)
    tasks = m.prior.task_index([str(x.get("task")) for x in b["meta"]])
    m.prior.add(tasks, canon.floor_xyz[..., :2], b["floor_label"], b["floor_mask"])
    m.hparams["residual_scale"] = 0.0
    r = _rotate_everything(b, torch.tensor([2.0, -1.0]), torch.tensor([[3.0, 1.0, 0.0], [-2.0, 0.5, 0.0]]))
    with torch.no_grad():
        s0, s1 = m(b), m(r)
    assert s0.std() > 1e-2  # the prior is not flat: the check below can fail
    assert (s0 - s1).abs().max() < 1e-4


def test_a_mistyped_teacher_batchnorm_mode_is_refused(root):
    """Anything but 'batch' ran the frozen teacher on its running statistics, without a word."""
    with pytest.raises(MisconfigurationException, match="distill_bn must be 'batch' or 'running', got 'batchnorm'"):
        CFARModule(**tiny_args(root), distill_bn="batchnorm")


def test_weights_with_a_part_the_model_lacks_are_not_all_loaded(tmp_path):
    """A CFAR trained over the canonical prior, built without it and given those weights, warned and was then
    evaluated without its prior (its head's residual scored alone); the unused part is now listed in
    weights_not_loaded, which `floaff-zoo test`/`validate`/`predict` refuse."""
    init_args = yaml.safe_load(Path(CFAR).read_text())["model"]["init_args"]
    with_prior = CFARModule(**{**init_args, "prior_residual": True}).save_pretrained(tmp_path / "with_prior")
    with pytest.warns(UserWarning, match=r"weights of \['prior'\] are not used"):
        plain = CFARModule(**{**init_args, "prior_residual": False}, weights=str(with_prior))
    assert plain.weights_not_loaded == ["prior.*: in the weights, no such part in this CFARModule"]


def test_the_alignment_jitter_is_within_its_degrees_in_training_and_off_in_evaluation(root):
    """``yaw_jitter_deg: 5`` turns each training sample's alignment by a random angle within +-5 deg (the paper's
    perturbation); evaluation is never perturbed."""
    args = {**tiny_args(root), "yaw_source": "gt", "eval_yaw_source": "manhattan"}
    b = _batch(32)
    torch.manual_seed(0)
    plain, jittered = CFARModule(**args, yaw_jitter_deg=0.0).train(), CFARModule(**args, yaw_jitter_deg=5.0).train()
    turned = math.degrees(1) * (jittered.canonicalize(b)[0].angle - plain.canonicalize(b)[0].angle)
    turned = (turned + 180) % 360 - 180
    assert turned.abs().max() <= 5.0 + 1e-3 and turned.abs().max() > 2.0 and turned.std() > 1.0, turned
    jittered.eval()
    plain.eval()
    assert torch.equal(jittered.canonicalize(b)[0].angle, plain.canonicalize(b)[0].angle)


def test_a_resumed_fit_averages_only_tasks_its_prior_lacks(root):
    """A resumed fit skips the prior's pass over the training data (it drew an epoch of the shuffle and augmentation
    streams for nothing), unless its data holds a task the checkpoint's prior has no labels of: skipping then left
    that task's prior empty."""
    from types import SimpleNamespace

    b = _batch(2)
    m = CFARModule(**tiny_args(root), prior_residual=True).eval()
    canon, _ = m.canonicalize(b)
    seen = [str(x.get("task")) for x in b["meta"]]
    m.prior.add(m.prior.task_index(seen), canon.floor_xyz[..., :2], b["floor_label"], b["floor_mask"])
    other = next(t for t in m.prior.tasks if t not in seen)

    def needs(ckpt_path, tasks):
        m._trainer = SimpleNamespace(ckpt_path=ckpt_path, datamodule=SimpleNamespace(tasks=tasks))
        return m.prior_needs_pass()

    assert needs(None, seen)  # a fresh fit makes its pass, as before
    assert not needs("last.ckpt", seen)  # resumed, every task in the prior
    assert needs("last.ckpt", [*seen, other])  # resumed on data with a task the prior lacks
    # that pass fills the missing task and leaves the tasks the prior has
    kept, counts = m.prior.sums.clone(), m.prior.counts.sum((1, 2)).clone()
    new = _batch(2, seed=1)
    for meta in new["meta"]:
        meta["task"] = other
    m._trainer.datamodule.train_dataloader = lambda: [new]
    m.fill_prior()
    o = m.prior.tasks.index(other)
    assert counts[o] == 0 and m.prior.counts[o].sum() > 0
    assert all(torch.equal(m.prior.sums[i], kept[i]) for i in range(len(m.prior.tasks)) if i != o)


@pytest.mark.parametrize(
    ("arg", "value", "shown"),
    [
        ("local_radii", [0.25, 0.5], r"teacher \[0\.2, 0\.4\] vs student \[0\.25, 0\.5\]"),
        ("local_npoints", [32, 16], r"teacher \[64\.0, 16\.0\] vs student \[32\.0, 16\.0\]"),
        ("local_nsamples", [4, 8], r"teacher \[8\.0, 8\.0\] vs student \[4\.0, 8\.0\]"),
    ],
)
def test_a_teacher_trained_with_other_local_sampling_is_refused(tmp_path, root, arg, value, shown):
    """The teacher is the student's encoder with the teacher's weights: a teacher trained with other local radii,
    centres or neighbour counts has weights of the same shapes, and ran silently with the student's sampling."""
    args = tiny_args(root)
    CFARModule(**args).save_pretrained(tmp_path / "stage1")
    same = CFARModule(**args, teacher=str(tmp_path / "stage1"))
    same.setup("fit")
    assert same.teacher is not None
    other = CFARModule(**{**args, arg: value}, teacher=str(tmp_path / "stage1"))
    with pytest.raises(ValueError, match=f"{arg}: {shown}"):
        other.setup("fit")
    assert other.teacher is None


@pytest.mark.parametrize("radius", [float("nan"), float("inf")])
def test_a_crop_radius_that_is_not_a_finite_positive_number_is_refused(root, radius):
    """A NaN crop radius passed the > 0 check, cropped every point away and raised a SampleError telling to check the
    samples' target_xyz / scene_xyz; the radius is now refused where it is given, by name."""
    with pytest.raises(MisconfigurationException, match=r"crop_radius must be a finite number > 0"):
        CFARModule(**{**tiny_args(root), "crop_radius": radius})
    xyz = torch.rand(1, 8, 3)
    with pytest.raises(ValueError, match=r"crop radius must be a finite number > 0"):
        crop_mask(xyz, torch.ones(1, 8, dtype=torch.bool), xyz[:, 0], radius)


@pytest.mark.parametrize(
    ("arg", "value"),
    [
        ("distill_weight", float("nan")),  # passed '< 0': no distillation, silently
        ("yaw_jitter_deg", -5.0),  # no jitter, silently
        ("yaw_jitter_deg", float("inf")),  # NaN angles, then a NaN loss naming samples
        ("manhattan_radius", -1.0),  # no face found: every sample kept its reference yaw
        ("residual_scale", "1.0"),  # a text (a quoted YAML value): a TypeError naming no argument
        ("distill_weight", True),  # a bool is no weight
    ],
)
def test_scalar_arguments_that_switch_a_part_off_silently_are_refused(root, arg, value):
    with pytest.raises(MisconfigurationException, match=rf"CFARModule: {arg} must be a finite number"):
        CFARModule(**{**tiny_args(root), arg: value})


@pytest.mark.parametrize("key", ["scene_xyz", "floor_xyz", "target_xyz"])
def test_a_nan_input_is_named_not_cropped_away(root, key):
    """CFAR's crop dropped a NaN scene point without a word (the other models named it); a NaN on padding is not
    an input and passes."""
    m = CFARModule(**tiny_args(root))
    b = _batch(2)
    b[key][1].view(-1)[0] = float("nan")
    with pytest.raises(SampleError, match=f"{key} holds NaN/Inf values in 1 sample.*syn1"):
        m.training_step(b, 0)
    b = _batch(2, points=256)
    b["scene_mask"] = torch.ones(b["scene_xyz"].shape[:2], dtype=torch.bool)
    b["scene_mask"][0, -1] = False
    b["scene_xyz"][0, -1] = float("nan")  # padding
    m.check_inputs(b)


def _teacher_saved_with(tmp_path: Path, root: Path, field: str, value: object) -> Path:
    """A teacher saved from the tiny CFAR whose config.json holds ``value`` as ``field``; its folder."""
    import json

    CFARModule(**tiny_args(root)).save_pretrained(tmp_path / "stage1")
    cfg = json.loads((tmp_path / "stage1" / "config.json").read_text())
    init = cfg["init_args"] if "init_args" in cfg else cfg
    init[field] = value
    (tmp_path / "stage1" / "config.json").write_text(json.dumps(cfg))
    return tmp_path / "stage1"


@pytest.mark.parametrize(
    ("field", "value", "shown"),
    [
        ("local_radii", ["near", "far"], r"local_radii must be a list of numbers, got \['near'"),
        ("local_npoints", "64", r"local_npoints must be a list of numbers, got '64'"),  # was read as [6.0, 4.0]
    ],
)
def test_a_teacher_whose_saved_sampling_is_not_numbers_is_named(tmp_path, root, field, value, shown):
    """A teacher file whose saved local radii are no numbers failed ``float()`` naming neither file nor field."""
    from floaff_zoo.models.cfar import TeacherError

    student = CFARModule(**tiny_args(root), teacher=str(_teacher_saved_with(tmp_path, root, field, value)))
    with pytest.raises(TeacherError, match=rf"teacher '.*stage1': {shown}"):
        student.setup("fit")


def test_a_teacher_whose_saved_sampling_is_not_numbers_is_one_line_at_the_console(tmp_path, root, monkeypatch, capsys):
    """It was a ValueError from the fit's setup: a traceback at the console, where the other teacher errors are one
    line."""
    from tests.conftest import console

    teacher = _teacher_saved_with(tmp_path, root, "local_radii", ["near", "far"])
    monkeypatch.chdir(root)
    args = ["fit", "--config", DATA, "--config", CFAR, *quiet_trainer_args(tmp_path / "run")]
    rc, _, err = console(monkeypatch, capsys, [*args, "--model.init_args.teacher", str(teacher)])
    errors = [line for line in err if line.startswith("floaff-zoo: error: ")]
    assert rc == 2 and len(errors) == 1 and f"teacher '{teacher}': local_radii must be a list" in errors[0], err
    assert not any("Traceback" in line for line in err)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ({"prior_residual": True, "prior_tasks": []}, r"prior_tasks needs >= 1 task"),  # read as every task
        ({"prior_residual": True, "prior_tasks": ["CloseDrawr"]}, r"unknown task\(s\) \['CloseDrawr'\] in prior_tasks"),
        ({"prior_tasks": ["CloseDrawer"]}, r"prior_tasks sets the prior's tasks; set prior_residual: true"),  # ignored
    ],
)
def test_prior_tasks_that_would_be_ignored_or_fail_at_the_first_batch_are_refused(root, args, message):
    """An unknown task failed at the first batch of another task ('has no grid'); [] and a list without
    prior_residual were silently read as every task / ignored."""
    with pytest.raises(MisconfigurationException, match=rf"CFARModule: {message}"):
        CFARModule(**tiny_args(root), **args)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"floor_feat_channels": 2.5}, "floor_feat_channels must be an integer >= 0, got 2.5"),
        ({"feat_channels": -1}, "feat_channels must be an integer >= 0, got -1"),
        ({"feat_channels": True}, "feat_channels must be an integer >= 0, got True"),
        ({"floor_encoder": "pointwise", "fourier_freqs": -1}, "fourier_freqs must be an integer >= 0, got -1"),
        ({"local_global_mlp": ()}, "local_global_mlp needs at least one width"),
        ({"local_radii": ("0.1", 0.3)}, "local_radii must be a finite number > 0, got '0.1'"),
        ({"floor_radii": (True, 0.5)}, "floor_radii must be a finite number > 0, got True"),
    ],
)
def test_cfar_net_refuses_sizes_by_name(kwargs, message):
    """int() cut 2.5 to 2 and read True as 1; a negative feat_channels dropped the last feature channels and a
    negative fourier_freqs failed inside nn.Linear; without local_global_mlp g was the first centre's features."""
    from floaff_zoo.nn.cfar import CFARNet

    with pytest.raises(ValueError, match=f"CFARNet: {message}"):
        CFARNet(**kwargs)
