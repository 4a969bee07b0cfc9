"""Baseline models (PointNet++, VoteNet-, H3DNet-, NavAff, N2M-, C2F-Exp-style): shapes, masks,
gradients, NavAff parameter count, N2M NLL, C2F-Exp determinism, bad inputs, CLI round trips."""

from __future__ import annotations

import glob
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from floaff_zoo.contract import collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.models.c2f_exp import C2FExpModule
from floaff_zoo.models.h3dnet import H3DNetModule
from floaff_zoo.models.n2m import N2MModule
from floaff_zoo.models.navaff import NavAffModule
from floaff_zoo.models.pointnet2 import PointNet2Module
from floaff_zoo.models.prior import CanonicalPriorModule
from floaff_zoo.models.votenet import VoteNetModule
from tests.conftest import block_first_footprint

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests" / "configs" / "models"
NAMES = ["pointnet2_ssg", "pointnet2_msg", "votenet", "h3dnet", "navaff", "n2m", "c2f_exp"]
CLASSES = {
    "PointNet2Module": PointNet2Module,
    "VoteNetModule": VoteNetModule,
    "H3DNetModule": H3DNetModule,
    "NavAffModule": NavAffModule,
    "N2MModule": N2MModule,
    "C2FExpModule": C2FExpModule,
}


def tiny_model(name: str):
    cfg = yaml.safe_load((TINY / f"{name}_tiny.yaml").read_text())["model"]
    cls = CLASSES[cfg["class_path"].rsplit(".", 1)[1]]
    return cls(**cfg.get("init_args", {}))


@pytest.fixture
def batch():
    """Two synthetic samples; the second padded (fewer scene and floor points)."""
    a = make_synthetic_sample(0, num_points=256, floor_cells=8)
    b = make_synthetic_sample(1, num_points=200, floor_cells=6)
    return collate_samples([a, b])


@pytest.mark.parametrize("name", NAMES)
def test_forward_shapes_range_grads_and_padding(name, batch):
    torch.manual_seed(0)
    model = tiny_model(name)
    scores = model(batch)
    assert scores.shape == batch["floor_label"].shape
    assert torch.isfinite(scores).all() and scores.min() >= 0 and scores.max() <= 1
    if not model.trainable:
        return
    loss, out, extra = model.model_step(batch)
    loss.backward()
    grads = [p.grad for p in model.parameters() if p.requires_grad]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert any(g.abs().sum() > 0 for g in grads)
    # padding content never matters (eval mode: no batch statistics, no dropout)
    model.eval()
    with torch.no_grad():
        ref = model(batch)
        moved = dict(batch)
        moved["scene_xyz"] = batch["scene_xyz"].clone()
        moved["scene_xyz"][1, 200:] = 9.0
        moved["floor_xyz"] = batch["floor_xyz"].clone()
        moved["floor_xyz"][1, 36:] = -9.0
        out2 = model(moved)
    assert torch.allclose(ref[:, :36], out2[:, :36], atol=1e-5)


def _lin(i: int, o: int) -> int:
    return i * o + o


def _chain(i: int, widths: list[int]) -> int:
    """Linear(+bias) + BatchNorm (2 params per channel) per layer."""
    total = 0
    for w in widths:
        total += _lin(i, w) + 2 * w
        i = w
    return total


def test_navaff_parameter_count_matches_architecture():
    """Official layer list (docs/background.md §3), counted by hand; the dead Conv1D1/Conv1D2 are not built."""
    sa1 = [[32, 32, 64], [64, 64, 128], [64, 96, 128]]
    sa23 = [[128, 128, 256], [128, 196, 256]]

    def encoder(first_in: int) -> int:  # grouped input = l0 points + relative xyz
        return (
            sum(_chain(first_in, m) for m in sa1)
            + sum(_chain(320 + 3, m) for m in sa23)
            + sum(_chain(512 + 3, m) for m in sa23)
        )

    expected = (
        encoder(4 + 3)  # global: xyz + flag
        + encoder(3 + 3)  # floor: xyz
        + _lin(2, 256)
        + _lin(256, 512)  # robot token
        + 512 * 512
        + 512 * 1024
        + _lin(512, 512)  # q, kv (no bias), proj
        + _chain(1024, [768, 512])
        + _chain(832, [768, 512])
        + _chain(518, [512, 512])
        + _lin(512, 64)
        + 2 * 64
        + _lin(64, 1)  # head
    )
    model = NavAffModule()
    assert sum(p.numel() for p in model.parameters()) == expected == 4_977_937
    assert model.hparams["train"] == {**model.hparams["train"], "loss": "navaff", "lr": 8e-4, "weight_decay": 1e-3}


def test_navaff_attention_has_no_residual():
    from floaff_zoo.nn.nets import CrossAttention

    attn = CrossAttention(16, 8, 0.0)
    for p in attn.parameters():
        torch.nn.init.zeros_(p)
    q = torch.randn(1, 4, 16)
    assert torch.equal(attn(q, torch.randn(1, 5, 16)), torch.zeros(1, 4, 16))


def test_n2m_nll_decreases(batch):
    torch.manual_seed(0)
    model = tiny_model("n2m")
    model.hparams["dropout"] = 0.0
    model.configure_models()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    first = None
    for _ in range(15):
        loss, _, _ = model.model_step(batch)
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    model.eval()
    with torch.no_grad():
        final = model.nll(model.gmm(batch), batch).item()
    assert final < first - 0.5, (first, final)


def test_n2m_learns_nothing_from_a_view_without_success(batch):
    """A view whose labels are all 0 had its first stored floor point taken as the success the GMM must explain.
    Training leaves it out; evaluation averages over samples, so it adds 0 there."""
    model = tiny_model("n2m").eval()  # the GMMs without dropout
    failed = {**batch, "floor_label": batch["floor_label"].clone()}
    failed["floor_label"][1] = 0.0
    with torch.no_grad():
        gmm = model.gmm(failed)
        turned = {**failed, "floor_xyz": failed["floor_xyz"].clone()}
        n = int(failed["floor_mask"][1].sum())
        turned["floor_xyz"][1, :n] = failed["floor_xyz"][1, :n].flip(0)  # the same view, stored in another order
        only_first = {k: (v[:1] if torch.is_tensor(v) else v[:1]) for k, v in failed.items()}
        first = float(model.nll(model.gmm(only_first), only_first))
        assert float(model.nll(gmm, failed)) == pytest.approx(first / 2)
        model.train()
        assert float(model.nll(gmm, failed)) == pytest.approx(float(model.nll(gmm, turned)))
        assert float(model.nll(gmm, failed)) == pytest.approx(first)
    nothing = {**failed, "floor_label": torch.zeros_like(failed["floor_label"])}
    loss = model.nll(model.gmm(nothing), nothing)
    assert float(loss) == 0.0 and loss.requires_grad


def test_votenet_votes_for_nothing_in_a_view_without_success(batch):
    """A view whose labels are all 0 selected every floor point as a good position to vote for (noise targets).
    Training leaves it out; evaluation averages over samples, so it adds 0 there."""
    model = tiny_model("votenet").eval()  # the votes without dropout
    failed = {**batch, "floor_label": batch["floor_label"].clone()}
    failed["floor_label"][1] = 0.0
    only_first = {k: v[:1] for k, v in failed.items()}
    with torch.no_grad():
        _, aux = model.forward_with_aux(failed)
        _, aux_first = model.forward_with_aux(only_first)
        first = float(model.vote_loss(only_first, aux_first))
        assert float(model.vote_loss(failed, aux)) == pytest.approx(first / 2)
        model.train()
        assert float(model.vote_loss(failed, aux)) == pytest.approx(first)
    nothing = {**failed, "floor_label": torch.zeros_like(failed["floor_label"])}
    _, aux = model.forward_with_aux(nothing)
    loss = model.vote_loss(nothing, aux)
    assert float(loss) == 0.0 and loss.requires_grad


def test_n2m_refuses_a_ranking_term_it_would_not_train_with():
    """train.rank_weight only moved N2M's logged aff_loss: a run that set it trained exactly as without it."""
    from floaff_zoo.models.base import FloAffTrainConfig

    cfg = yaml.safe_load((TINY / "n2m_tiny.yaml").read_text())["model"].get("init_args", {})
    with pytest.raises(ValueError, match=r"train.rank_weight has no effect on it \(got 0.1\)"):
        N2MModule(**{**cfg, "train": FloAffTrainConfig(rank_weight=0.1)})


def test_n2m_propose_pose_collision_free(batch):
    torch.manual_seed(0)
    model = tiny_model("n2m").eval()
    item = {k: (v[0] if torch.is_tensor(v) else v[0]) for k, v in batch.items()}
    x, y, yaw = model.propose_pose(item)
    assert all(map(lambda v: isinstance(v, float), (x, y, yaw))) and -3.2 < yaw < 3.2
    assert model.propose_pose(item) == (x, y, yaw)  # deterministic
    from floaff_zoo.nn.placement import footprint_collides, occupied_cells

    cells = occupied_cells(batch["scene_xyz"][0], batch["scene_mask"][0])
    assert not footprint_collides(cells, torch.tensor([[x, y, yaw]]))[0]


def test_n2m_falls_back_to_the_densest_candidate_when_every_one_collides(batch, monkeypatch):
    """The fallback was the heaviest component's mean, whatever its density: a wide, heavy component beat a narrow
    one whose samples are far denser."""
    import floaff_zoo.models.n2m as n2m
    from floaff_zoo.nn.nets import gmm_log_prob

    model = tiny_model("n2m").eval()
    means = torch.tensor([[[5.0, 5.0, 0.0], [0.5, 0.0, 0.0]]])
    cov = torch.stack([torch.eye(3) * 4.0, torch.eye(3) * 1e-3])[None]
    logw = torch.log(torch.tensor([[0.6, 0.4]]))
    monkeypatch.setattr(model, "gmm", lambda item: (means, cov, logw))
    monkeypatch.setattr(n2m, "footprint_collides", lambda cells, cand, *a: torch.ones(len(cand), dtype=torch.bool))
    pose = model.propose_pose({k: v[:1] if torch.is_tensor(v) else v[:1] for k, v in batch.items()})
    assert torch.dist(torch.tensor(pose[:2]), means[0, 1, :2]) < 0.2, pose  # in the narrow component
    assert gmm_log_prob(torch.tensor([[pose]]), means, cov, logw).item() > 0


def test_footprint_geometry():
    from floaff_zoo.nn.placement import footprint_collides

    cells = torch.tensor([[0.1, 0.0]])  # 0.1 m ahead: inside (front part 0.17 * 0.63 = 0.107)
    assert footprint_collides(cells, torch.tensor([[0.0, 0.0, 0.0]]))[0]
    # turned around, the cell is 0.1 m behind: still inside (0.52 m of footprint behind)
    assert footprint_collides(cells, torch.tensor([[0.0, 0.0, 3.14159]]))[0]
    assert not footprint_collides(torch.tensor([[-0.6, 0.0]]), torch.tensor([[0.0, 0.0, 3.14159]]))[0]
    behind = torch.tensor([[-0.5, 0.0]])  # 0.5 m behind: inside (0.83 * 0.63 = 0.52)
    assert footprint_collides(behind, torch.tensor([[0.0, 0.0, 0.0]]))[0]
    assert not footprint_collides(torch.tensor([[0.2, 0.0]]), torch.tensor([[0.0, 0.0, 0.0]]))[0]
    assert not footprint_collides(torch.tensor([[0.0, 0.3]]), torch.tensor([[0.0, 0.0, 0.0]]))[0]


def test_c2f_exp_deterministic_in_range_and_training_free(batch):
    model = C2FExpModule()
    a, b = model(batch), model(batch)
    assert torch.equal(a, b)
    assert a.min() >= 0 and a.max() <= 1 and (a.amax(dim=1) == 1).all()
    assert (a[~batch["floor_mask"]] == 0).all()
    assert C2FExpModule.trainable is False and sum(p.numel() for p in model.parameters()) == 0
    pose = model.propose_pose({k: (v[0] if torch.is_tensor(v) else v[0]) for k, v in batch.items()})
    assert pose == model.propose_pose({k: (v[0] if torch.is_tensor(v) else v[0]) for k, v in batch.items()})
    g = batch["target_xyz"][0, :2]
    d = float(torch.dist(torch.tensor(pose[:2]), g))
    assert 0.4 <= d <= 1.2


def test_a_c2f_scorer_sees_the_same_context_keys_in_every_round_and_the_final_pose(batch, monkeypatch):
    """The final pose gave a plugged-in scorer only cells, g, round and mu: one reading target_yaw (as in the
    search rounds) worked in forward and failed in propose_pose and predict_step."""
    import floaff_zoo.nn.c2f as c2f

    seen: list[set[str]] = []

    def yaw_scorer(candidates, weights, context):
        seen.append(set(context))
        return weights * (1 + 0 * context["target_yaw"])

    monkeypatch.setitem(c2f.SCORERS, "yaw_reader", yaw_scorer)
    model = C2FExpModule(scorer="yaw_reader")
    model.propose_pose({k: (v[0] if torch.is_tensor(v) else v[0]) for k, v in batch.items()})
    assert len(seen) > 1 and all(keys == seen[0] for keys in seen), seen
    assert {"cells", "g", "target_yaw", "round", "mu", "sigma", "alpha"} == seen[-1]


def test_c2f_exp_alpha_schedule_and_scorers():
    from floaff_zoo.nn.c2f import alpha_schedule, resolve_scorer

    alphas = [alpha_schedule(t, 3, 0.5) for t in range(4)]
    assert alphas == sorted(alphas) and 0 < alphas[0] < 0.25 < alphas[-1] <= 0.5
    assert resolve_scorer("floaff_zoo.nn.c2f:clearance_scorer") is resolve_scorer("clearance")
    with pytest.raises(ValueError, match="unknown C2F-Exp scorer"):
        resolve_scorer("gpt4o")


def test_bad_inputs(batch):
    model = tiny_model("pointnet2_ssg")
    bad = dict(batch)
    bad["scene_xyz"] = batch["scene_xyz"].clone()
    bad["scene_xyz"][0, 3, 1] = float("nan")
    with pytest.raises(ValueError, match="scene_xyz contains 1 NaN"):
        model(bad)
    empty = dict(batch)
    empty["scene_mask"] = batch["scene_mask"].clone()
    empty["scene_mask"][1] = False
    with pytest.raises(ValueError, match=r"scene_mask: sample\(s\) \[1\]"):
        model(empty)
    nofloor = dict(batch)
    nofloor["floor_mask"] = torch.zeros_like(batch["floor_mask"])
    with pytest.raises(ValueError, match="floor_mask"):
        tiny_model("navaff")(nofloor)


def test_fewer_valid_points_than_centres_fall_back(batch):
    """A scene with 20 valid points and 64 first-level centres: FPS repeats valid points."""
    model = tiny_model("pointnet2_ssg").eval()
    few = dict(batch)
    few["scene_mask"] = batch["scene_mask"].clone()
    few["scene_mask"][0, 20:] = False
    with torch.no_grad():
        out = model(few)
    assert torch.isfinite(out).all()


def test_bf16_flag_runs(batch):
    torch.manual_seed(0)
    cfg = yaml.safe_load((TINY / "pointnet2_ssg_tiny.yaml").read_text())["model"]["init_args"]
    m32 = PointNet2Module(**cfg).eval()
    m16 = PointNet2Module(**{**cfg, "bf16": True}).eval()
    m16.load_state_dict(m32.state_dict())
    with torch.no_grad():
        a, b = m32(batch), m16(batch)
    assert b.dtype == torch.float32 and (a - b).abs().max() < 0.05
    # a bf16 training step: the fp32-only fast paths (narrow Linear, fused BN + max) step aside
    m16.train()
    loss, _, _ = m16.model_step(batch)
    loss.backward()
    grads = [p.grad for p in m16.parameters() if p.requires_grad]
    assert torch.isfinite(loss) and all(g is not None and torch.isfinite(g).all() for g in grads)


@pytest.mark.slow
def test_compile_flag_trains_on_a_padded_batch(batch):
    """``compile: true`` trains (inductor compiles the backward too) and matches the eager model."""
    torch.manual_seed(0)
    cfg = yaml.safe_load((TINY / "pointnet2_ssg_tiny.yaml").read_text())["model"]["init_args"]
    eager = PointNet2Module(**cfg).eval()
    compiled = PointNet2Module(**{**cfg, "compile": True})
    compiled.load_state_dict(eager.state_dict())
    compiled.train()
    for _ in range(2):
        loss, _, _ = compiled.model_step(batch)
        loss.backward()
        assert torch.isfinite(loss)
    compiled.load_state_dict(eager.state_dict())
    compiled.eval()
    with torch.no_grad():
        torch.testing.assert_close(compiled(batch), eager(batch), atol=1e-4, rtol=1e-3)


def test_pointnet2_occupancy_input_reads_the_footprint(batch, monkeypatch, tmp_path):
    """``PointNet2Module(occupancy_input=True)`` (the fairness check of CFAR's input): the floor skip grows by the two
    ``footprint_occupancy`` channels, an obstacle in floor point 0's footprint changes its score, the channels are
    checked, and the switch trains, tests and reloads through the CLI."""
    import floaff_zoo.models.pointnet2 as pn2
    from floaff_zoo.nn.placement import footprint_occupancy

    torch.manual_seed(0)
    cfg = yaml.safe_load((TINY / "pointnet2_ssg_tiny.yaml").read_text())["model"]["init_args"]
    plain = PointNet2Module(**cfg)
    model = PointNet2Module(**cfg, occupancy_input=True).eval()
    assert model.net.floor_fp.mlp.linears[0].in_features == plain.net.floor_fp.mlp.linears[0].in_features + 2
    blocked = block_first_footprint(batch)  # obstacle points in floor point 0's base footprint
    occ = footprint_occupancy(blocked["scene_xyz"], blocked["scene_mask"], blocked["floor_xyz"], blocked["target_xyz"])
    assert occ[0, 0, 1] == 1.0
    with torch.no_grad():
        s1 = model(blocked)
        monkeypatch.setattr(pn2, "footprint_occupancy", lambda *a: torch.zeros_like(occ))  # same scene, no occupancy
        s0 = model(blocked)
        monkeypatch.undo()
    assert (s0[0, 0] - s1[0, 0]).abs() > 1e-6
    args = [blocked[k] for k in ("scene_xyz", "scene_feat", "scene_mask", "floor_xyz", "floor_mask", "robot")]
    with pytest.raises(ValueError, match="floor_feat must be"):
        model.net(*args, blocked["target_xyz"], floor_feat=occ[..., :1])
    with pytest.raises(ValueError, match="floor_feat given"):
        plain.net(*args, blocked["target_xyz"], floor_feat=occ)
    # through the CLI: fit, test, reload with the switch kept
    from floaff_zoo.cli import main

    cli_cfg = [
        "--config",
        str(ROOT / "configs/data/synthetic_tiny.yaml"),
        "--config",
        str(TINY / "pointnet2_ssg_tiny.yaml"),
    ]
    cli_cfg += ["--model.init_args.occupancy_input", "true"]
    assert main(["fit", *cli_cfg, "--trainer.max_epochs", "1", *_cli_common(tmp_path)]) == 0
    ckpt = sorted(glob.glob(str(tmp_path / "**" / "*.ckpt"), recursive=True))[-1]
    assert main(["test", *cli_cfg, "--ckpt_path", ckpt, *_cli_common(tmp_path)]) == 0
    assert PointNet2Module.load_from_checkpoint(ckpt, weights_only=True).net.floor_feat_channels == 2


# --------------------------------------------------------------------------- CLI round trips
def _cli_common(tmp_path: Path) -> list[str]:
    return [
        "--trainer.default_root_dir",
        str(tmp_path),
        "--trainer.accelerator",
        "cpu",
        "--trainer.enable_progress_bar",
        "false",
    ]


@pytest.mark.parametrize("name", NAMES)
def test_cli_round_trip(name, tmp_path):
    from floaff_zoo.cli import main

    cfg = ["--config", str(ROOT / "configs/data/synthetic_tiny.yaml"), "--config", str(TINY / f"{name}_tiny.yaml")]
    if name == "c2f_exp":
        with pytest.raises(Exception, match="training-free"):
            main(["fit", *cfg, "--trainer.fast_dev_run", "2", *_cli_common(tmp_path)])
        assert main(["test", *cfg, *_cli_common(tmp_path)]) == 0
        assert main(["predict", *cfg, *_cli_common(tmp_path)]) == 0
        return
    assert main(["fit", *cfg, "--trainer.fast_dev_run", "2", *_cli_common(tmp_path)]) == 0
    ckpts = sorted(glob.glob(str(tmp_path / "**" / "*.ckpt"), recursive=True))
    assert ckpts, "fit wrote no checkpoint"
    assert main(["test", *cfg, "--ckpt_path", ckpts[-1], *_cli_common(tmp_path)]) == 0
    assert main(["predict", *cfg, "--ckpt_path", ckpts[-1], *_cli_common(tmp_path)]) == 0


def test_prediction_hides_padding_and_names_the_chosen_pose(batch):
    """predict_step passed the scores of the batch's padded floor points (xyz 0, 0, 0) through unchanged, so an
    argmax over ``predictions.npz`` could stand the robot at its own origin; it now writes NaN there and the pose
    the success-rate callback would choose (``best_pose``)."""
    from floaff_zoo.contract import best_pose
    from floaff_zoo.models.base import FloAffModule

    mask = batch["floor_mask"]
    scores = torch.where(mask, torch.full(mask.shape, 0.5), torch.ones(mask.shape))  # padding scores highest
    scores[1, 5] = 0.9
    out = FloAffModule.prediction(batch, scores)
    assert torch.isnan(out["scores"][~mask]).all() and torch.isnan(out["floor_xyz"][~mask]).all()
    torch.testing.assert_close(out["scores"][mask], scores[mask])
    expected = best_pose(batch["floor_xyz"][1], scores[1], mask[1], batch["target_xyz"][1], seed=1)[0]
    torch.testing.assert_close(out["best_pose"][1], torch.tensor(expected, dtype=torch.float32))
    assert out["best_pose"].shape == (2, 3) and torch.isfinite(out["best_pose"]).all()


@pytest.mark.parametrize("name", ["n2m", "c2f_exp"])
def test_proposed_poses_reach_the_predictions_file(name, batch):
    """N2M's and C2F-Exp's proposed poses were a list, which the prediction writer dropped without a word."""
    from floaff_zoo.callbacks.predictions import gather_predictions

    model = tiny_model(name).eval()
    with torch.no_grad():
        record = model.predict_step(batch, 0)
    arrays, _ = gather_predictions([record, record])
    assert arrays["poses"].shape == (4, 3) and np.isfinite(arrays["poses"]).all()
    with pytest.warns(UserWarning, match=r"\['notes'\] are not tensors"):
        gather_predictions([{**record, "notes": ["a", "b"]}])


@pytest.mark.parametrize(
    ("arg", "value"),
    [
        ("sigma_dist", 0.0),  # an all-zero map
        ("sigma_bias", 0.0),
        ("sigma_decay", 0.0),
        ("cell", 0.0),  # an occupancy grid of overflowed indices: every candidate free
        ("max_alpha", 2.0),  # a negative exponent on the semantic term
        ("clearance", float("nan")),
        ("r_max", float("inf")),
        ("manhattan_radius", -1.0),
    ],
)
def test_c2f_exp_refuses_sizes_that_break_its_search_by_name(arg, value):
    """These passed the constructor and ran: most gave a map of zeros or of garbage, no error at all."""
    with pytest.raises(ValueError, match=rf"C2FExpModule: .*{arg}"):
        C2FExpModule(**{arg: value})


@pytest.mark.parametrize(
    ("name", "arg", "value"),
    [
        ("votenet", "vote_weight", -1.0),  # trained the votes away from the good positions, silently
        ("votenet", "vote_label_threshold", float("nan")),  # every vote target but the argmax dropped
        ("h3dnet", "vote_weight", float("nan")),  # a NaN loss naming only samples
        ("h3dnet", "face_offset", float("inf")),
        ("n2m", "occupancy_cell", 0.0),  # occupancy on overflowed cells: no candidate ever collided
        ("n2m", "footprint_width", -0.5),  # the same: an empty footprint
        ("n2m", "num_pose_samples", 0),  # torch's 'cannot sample n_sample <= 0 samples' at predict
        ("n2m", "lambda_weights", float("nan")),
        ("votenet", "vote_weight", None),  # the comparison's TypeError named no argument
    ],
)
def test_loss_weights_and_sizes_that_break_later_are_refused_by_name(name, arg, value):
    cfg = yaml.safe_load((TINY / f"{name}_tiny.yaml").read_text())["model"]
    cls = CLASSES[cfg["class_path"].rsplit(".", 1)[1]]
    with pytest.raises(ValueError, match=rf"{cls.__name__}: {arg} must be"):
        cls(**{**cfg.get("init_args", {}), arg: value})


@pytest.mark.parametrize(
    ("cls", "args", "named"),
    [
        (PointNet2Module, {"variant": "SSG"}, "variant"),  # built the MSG sizes, silently
        (C2FExpModule, {"yaw_source": "gtt"}, "yaw_source"),  # failed at the first batch
        (CanonicalPriorModule, {"yaw_source": "GT"}, "yaw_source"),  # refused only at the first training batch
        (PointNet2Module, {"feat_channels": -1}, "feat_channels"),  # sliced a channel off, then a shape error
        (VoteNetModule, {"robot_dim": 2.0}, "robot_dim"),  # torch's TypeError named no argument
    ],
)
def test_an_unknown_choice_or_a_bad_channel_count_is_refused_by_name(cls, args, named):
    """The CLI checks a Literal's choices itself; Python, checkpoints and hub configs did not."""
    with pytest.raises(ValueError, match=rf"{cls.__name__}: {named} must be"):
        cls(**args)


@pytest.mark.parametrize(
    ("cls", "args", "message"),
    [
        # a flag given a text or a number: "false" was true
        ("cfar", {"use_crop": "false"}, "use_crop must be true or false, got 'false'"),
        ("prior", {"centred": "no"}, "centred must be true or false, got 'no'"),
        (PointNet2Module, {"bf16": 1}, "bf16 must be true or false, got 1"),
        # a count that passed every bound: range(nan) failed at the first batch; True was 1 round
        (C2FExpModule, {"rounds": float("nan")}, "rounds must be an integer, got nan"),
        (C2FExpModule, {"rounds": True}, "rounds must be an integer, got True"),
        (C2FExpModule, {"seed": "abc"}, "seed must be an integer, got 'abc'"),  # int('abc') at the first batch
        # failed inside torch or Python naming no argument
        ("tiny", {"width": 0.5}, "width must be an integer >= 1, got 0.5"),
        (PointNet2Module, {"npoints": 64}, "npoints must be a list of integers or null, got 64"),
        ("cfar", {"head": 256}, "head must be a list of integers or null, got 256"),
        ("cfar", {"local_mlps": [[32, "64"]]}, r"local_mlps\[0\]\[1\] must be an integer, got '64'"),
        (C2FExpModule, {"scorer": 0.5}, "scorer must be a text, got 0.5"),
        (C2FExpModule, {"r_max": None}, "r_max must be a number, got None"),
    ],
)
def test_a_wrongly_typed_init_arg_is_refused_by_name(cls, args, message):
    """The CLI checks types itself; Python, checkpoints and hub configs did not: a text for a flag was true, and a
    number for a list or a float for a width failed inside torch with an error that named no argument."""
    from floaff_zoo.models.cfar import CFARModule
    from floaff_zoo.models.tiny import TinyPointNetModule

    cls = {"cfar": CFARModule, "prior": CanonicalPriorModule, "tiny": TinyPointNetModule}.get(cls, cls)
    with pytest.raises(ValueError, match=rf"{cls.__name__}: {message}"):
        cls(**args)


@pytest.mark.parametrize("name", ["pointnet2_ssg", "votenet", "h3dnet", "navaff", "n2m"])
@pytest.mark.parametrize("value", [1.0, float("nan"), 1.5, -0.1])
def test_a_dropout_outside_zero_to_one_is_refused_by_name(name, value):
    """1 zeroed every activation (a constant map, no error); NaN failed at the first training batch; torch's own
    error for the rest named neither the model nor the argument."""
    cfg = yaml.safe_load((TINY / f"{name}_tiny.yaml").read_text())["model"]
    cls = CLASSES[cfg["class_path"].rsplit(".", 1)[1]]
    with pytest.raises(ValueError, match=rf"{cls.__name__}: dropout must be a finite number >= 0 and < 1"):
        cls(**{**cfg.get("init_args", {}), "dropout": value})


@pytest.mark.parametrize(
    ("name", "arg", "value", "message"),
    [
        ("pointnet2_ssg", "mlps", [[[]], [[16, 32]], [[32, 32]]], "mlps: every scale needs >= 1 width"),  # IndexError
        ("pointnet2_msg", "mlps", [[[8], []], [[16], [16]], [[16], [16]]], "mlps: every scale needs >= 1 width"),
        ("navaff", "num_heads", 0, "num_heads must be an integer >= 1"),  # ZeroDivisionError
        ("navaff", "num_heads", -8, "num_heads must be an integer >= 1"),  # a shape error at the first batch
        ("navaff", "num_heads", 2.0, "num_heads must be an integer >= 1"),  # a float in a reshape
    ],
)
def test_an_empty_scale_or_no_attention_head_is_refused_at_construction(name, arg, value, message):
    cfg = yaml.safe_load((TINY / f"{name}_tiny.yaml").read_text())["model"]
    cls = CLASSES[cfg["class_path"].rsplit(".", 1)[1]]
    with pytest.raises(ValueError, match=message):
        cls(**{**cfg.get("init_args", {}), arg: value})


def test_a_user_model_whose_hints_name_an_import_only_a_type_checker_sees_still_builds():
    """The choice check reads the init's type hints: a user's model whose hint names a TYPE_CHECKING import (a
    string the module cannot resolve) failed to build with a NameError."""
    from floaff_zoo.models.tiny import TinyPointNetModule

    class UserModel(TinyPointNetModule):
        def __init__(self, width: int = 8, extra: "OnlyForTypeCheckers | None" = None) -> None:  # noqa: F821
            super().__init__(width=width)

    assert UserModel().hparams["width"] == 8


def test_a_choice_hint_that_also_takes_any_number_takes_any_number():
    """``Literal["auto"] | float`` refused 0.5 as 'not one of [auto]'."""
    from typing import Literal

    from floaff_zoo.models.base import literal_choices

    assert literal_choices(Literal["a", "b"] | None) == ("a", "b", None)
    assert literal_choices(Literal["auto"] | float) == ()
    assert literal_choices(float) == ()


def test_an_empty_list_saved_when_it_meant_the_default_still_loads():
    """Checkpoints and hub configs written when ``[]`` meant the default (AxisNet's widths, the prior's tasks, CFAR's
    prior_tasks) loaded before ``[]`` was refused."""
    from floaff_zoo.models.axisnet import AxisNetModule
    from floaff_zoo.models.cfar import CFARModule
    from floaff_zoo.models.prior import CanonicalPriorModule

    assert AxisNetModule.upgrade_init_args({"widths": []})["widths"] is None
    assert CanonicalPriorModule.upgrade_init_args({"tasks": []})["tasks"] is None
    assert CFARModule.upgrade_init_args({"prior_residual": True, "prior_tasks": []})["prior_tasks"] is None
    kept = {"prior_residual": True, "prior_tasks": ["CloseDrawer"]}
    assert CFARModule.upgrade_init_args(kept)["prior_tasks"] == ["CloseDrawer"]
    AxisNetModule(**AxisNetModule.upgrade_init_args({"widths": []}))


@pytest.mark.parametrize(
    ("field", "cut", "message"),
    [
        ("target_xyz", lambda t: t[:, :2], r"target_xyz must be \[B=2, 3\], got \[2, 2\]"),  # trained silently
        ("robot", lambda t: t[:, 0], r"robot must be \[B=2, R\], got \[2\]"),
        ("scene_feat", lambda t: t[:, :100], r"scene_feat must be \[B=2, N=256, C\], got \[2, 100, 1\]"),
        ("floor_label", lambda t: t[:, :10], r"floor_label must be \[B=2, M=64\], got \[2, 10\]"),
        ("robot", lambda t: t[:1], r"robot must be \[B=2, R\], got \[1, 2\]"),
        ("meta", lambda t: t[:1], r"meta must hold B=2 entries, got 1"),
    ],
)
def test_a_batch_whose_fields_disagree_on_their_sizes_is_refused_naming_the_field(field, cut, message):
    """A user's collate or a hand-built batch need not follow the contract's shapes: a 2-column target_xyz trained
    TinyPointNet without a word, the others failed inside torch naming no field."""
    from floaff_zoo.contract import SampleError
    from floaff_zoo.models.tiny import TinyPointNetModule

    batch = collate_samples([make_synthetic_sample(i, num_points=256, floor_cells=8) for i in range(2)])
    batch[field] = cut(batch[field])
    model = TinyPointNetModule(width=8)
    for step in (model.training_step, model.validation_step, model.predict_step):
        with pytest.raises(SampleError, match=rf"^batch field {message}"):
            step(batch, 0)


@pytest.mark.parametrize(
    ("name", "arg", "value", "message"),
    [
        ("votenet", "proposal_radius", 0, "proposal_radius must be a finite number > 0"),  # reported as "radii"
        ("h3dnet", "proposal_radius", float("nan"), "proposal_radius must be a finite number > 0"),
        ("votenet", "num_proposals", 0, "num_proposals must be an integer >= 1"),  # reported as "npoints"
        ("h3dnet", "proposal_nsample", -1, "proposal_nsample must be an integer >= 1"),  # reported as "nsamples"
        ("h3dnet", "fuse_width", 0, "fuse_width must be an integer >= 1"),  # "SharedMLP: in_channels"
        ("pointnet2_ssg", "robot_width", -1, "robot_width must be an integer >= 1"),  # "mlp: sizes"
        ("pointnet2_msg", "head_width", 0, "head_width must be an integer >= 1"),  # named the layer only
    ],
)
def test_a_zero_or_negative_size_is_refused_by_its_own_name(name, arg, value, message):
    """The nets worded a bad proposal radius or count by their own parameter, which is another init arg of the model
    (``radii``, ``npoints``), and an empty width by the layer it left empty."""
    cfg = yaml.safe_load((TINY / f"{name}_tiny.yaml").read_text())["model"]
    cls = CLASSES[cfg["class_path"].rsplit(".", 1)[1]]
    with pytest.raises(ValueError, match=rf"{cls.__name__}: {message}"):
        cls(**{**cfg.get("init_args", {}), arg: value})


def test_tiny_pointnet_refuses_a_width_of_zero_by_name():
    from floaff_zoo.models.tiny import TinyPointNetModule

    with pytest.raises(ValueError, match="TinyPointNetModule: width must be an integer >= 1, got 0"):
        TinyPointNetModule(width=0)
