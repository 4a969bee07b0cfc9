"""FPS over a cloud smaller than a level's centre count repeats a point; the repeats must change nothing.

A view's floor holds a median of 150 points, NavAff's floor encoder asks for 256 (demo) or 512 (paper size)
centres: FPS fills the rest with the first floor point. A repeated centre groups the same neighbours as its
first occurrence, so its features are the same; it must not count again in the training-mode batch statistics
nor in the decoder's 3-NN interpolation, i.e. a level with more centres than points must give what a level with
exactly as many centres gives.
"""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch
import yaml
from torch import nn

from floaff_zoo.models.cfar import CFARModule
from floaff_zoo.nn.nets import NavAffNet, SceneEncoderDecoder
from floaff_zoo.nn.ops import farthest_point_sample
from floaff_zoo.nn.pointnet2 import PointNet2Encoder, SetAbstraction, repeat_sources

ROOT = Path(__file__).resolve().parents[2]


def _stats(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in model.state_dict().items() if k.endswith(("running_mean", "running_var"))}


@pytest.mark.parametrize("tolerant", [False, True])
def test_repeat_sources_find_what_fps_repeats(tolerant):
    """Every FPS of the zoo repeats its first centre once a cloud runs out, even with padding and points that share
    a position: the repeats are exactly the entries that index a point chosen before."""
    from floaff_zoo.nn.cfar import tolerant_fps

    torch.manual_seed(0)
    xyz = torch.rand(3, 9, 3)
    xyz[1, 4] = xyz[1, 2]  # two points at one position
    mask = torch.ones(3, 9, dtype=torch.bool)
    mask[2, 5:] = False  # padding
    idx = (tolerant_fps if tolerant else farthest_point_sample)(xyz, mask, 12)
    seen_before = torch.tensor([[row[j] in row[:j] for j in range(12)] for row in idx.tolist()])
    src = repeat_sources(idx)
    assert (src != torch.arange(12)).equal(seen_before) and seen_before.any()
    assert idx.gather(1, src).equal(idx)  # each repeat points at its first occurrence
    assert repeat_sources(idx[:, :5]) is None  # 9 or 5 valid points: no repeat among the first 5 centres


@pytest.mark.parametrize("per_point", [False, True])
def test_set_abstraction_training_statistics_ignore_repeated_centres(per_point):
    torch.manual_seed(0)
    channels = 16 if per_point else 2  # 16: the first Linear runs per point before grouping
    xyz = torch.rand(2, 7, 3)
    feat = torch.randn(2, 7, channels)
    exact = SetAbstraction(7, [0.3, 0.6], [4, 8], channels, [[8, 8], [8, 16]]).train()
    more = copy.deepcopy(exact)
    more.npoint = 12  # 5 repeats per cloud
    new_a, out_a = exact(xyz, feat)
    new_b, out_b = more(xyz, feat)
    torch.testing.assert_close(new_b[:, :7], new_a)
    torch.testing.assert_close(out_b[:, :7], out_a, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(out_b[:, 7:], out_b[:, :1].expand(-1, 5, -1))  # FPS repeats the first point
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-6, rtol=1e-5, msg=key)


def test_encoder_kept_masks_flag_the_repeats_only():
    torch.manual_seed(0)
    enc = PointNet2Encoder(0, [6, 4], [[0.3], [0.6]], [[4], [4]], [[[8]], [[8]]])
    xyz = torch.rand(1, 4, 3)
    masks = enc.kept_masks(enc.sources(enc.sample(xyz, None)))
    assert masks[0].tolist() == [[True] * 4 + [False] * 2]
    assert masks[1] is None


def _navaff(train: bool) -> NavAffNet:
    torch.manual_seed(0)
    net = NavAffNet(npoints=(10, 6, 3), num_heads=2, dropout=0.0)
    return net.train(train)


@pytest.mark.parametrize("train", [False, True])
def test_navaff_scores_do_not_depend_on_surplus_floor_centres(train):
    """Floor sa1 with as many centres as floor points, or three times as many (the surplus repeats): same scores."""
    torch.manual_seed(1)
    b, n_scene, n_floor = 2, 64, 10
    scene = torch.rand(b, n_scene, 3) * torch.tensor([2.0, 2.0, 1.0])
    feat = torch.rand(b, n_scene, 1)
    floor = torch.cat([torch.rand(b, n_floor, 2) * 2.0, torch.zeros(b, n_floor, 1)], dim=-1)
    smask, fmask = torch.ones(b, n_scene, dtype=torch.bool), torch.ones(b, n_floor, dtype=torch.bool)
    robot = torch.rand(b, 2)
    exact = _navaff(train)
    more = copy.deepcopy(exact)
    more.encoder_floor.levels[0].npoint = 3 * n_floor
    a = exact(scene, feat, smask, floor, fmask, robot, fps=exact.sample(scene, smask, floor, fmask))
    c = more(scene, feat, smask, floor, fmask, robot, fps=more.sample(scene, smask, floor, fmask))
    torch.testing.assert_close(c, a, atol=1e-5, rtol=1e-4)
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-5, rtol=1e-4, msg=key)


def test_cfar_floor_features_do_not_depend_on_surplus_floor_centres():
    """CFAR's floor encoder in training: a floor under its sa1 centre count gives the same features and statistics."""
    args = yaml.safe_load((ROOT / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
    torch.manual_seed(0)
    exact = CFARModule(**args).net.train()  # floor sa1: 16 centres
    more = copy.deepcopy(exact)
    more.floor_encoder.levels[0].npoint = 40
    torch.manual_seed(1)
    floor = torch.cat([torch.rand(2, 16, 2) * 2.0 - 1.0, torch.zeros(2, 16, 1)], dim=-1)
    fmask = torch.ones(2, 16, dtype=torch.bool)
    torch.testing.assert_close(more.encode_floor(floor, fmask), exact.encode_floor(floor, fmask), atol=1e-5, rtol=1e-4)
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-5, rtol=1e-4, msg=key)


def test_cfar_local_context_does_not_depend_on_surplus_local_centres():
    """CFAR's local context interpolates the floor from the last local level's centres; a crop with fewer points
    than that level's centres repeats one, which filled several of the 3 neighbours (eval logits moved by 0.018)."""
    args = yaml.safe_load((ROOT / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
    torch.manual_seed(0)
    exact = CFARModule(**args).net.eval()
    for m in exact.modules():  # statistics and an output layer that let every input reach the logits
        if isinstance(m, nn.BatchNorm1d):
            m.running_mean.normal_()
            m.running_var.uniform_(0.5, 2.0)
    nn.init.normal_(exact.out.weight)
    n = exact.local_encoder.levels[-2].npoint  # the crop holds exactly as many points as the level's centres
    more = copy.deepcopy(exact)
    more.local_encoder.levels[-2].npoint = n + 5
    torch.manual_seed(1)
    size = max(n, exact.local_encoder.levels[0].npoint)
    mask = torch.zeros(2, size, dtype=torch.bool)
    mask[:, :n] = True
    xyz = torch.where(mask[..., None], torch.rand(2, size, 3) * 0.6 - 0.3, 0.0)
    feat = torch.randn(2, size, exact.feat_channels)
    floor = torch.cat([torch.rand(2, 200, 2) * 0.6 - 0.3, torch.zeros(2, 200, 1)], dim=-1)
    fmask = torch.ones(2, 200, dtype=torch.bool)
    robot = torch.randn(2, args.get("robot_dim", 2))
    with torch.no_grad():
        a, _ = exact.logits(xyz, feat, mask, floor, fmask, robot)
        b, _ = more.logits(xyz, feat, mask, floor, fmask, robot)
    torch.testing.assert_close(b, a, atol=1e-5, rtol=1e-4)


def test_group_all_level_statistics_ignore_repeated_centres():
    """CFAR's local encoder ends in a group-all level; its batch statistics ran over the repeats of the level below."""
    torch.manual_seed(0)
    xyz, feat = torch.rand(2, 7, 3), torch.randn(2, 7, 2)
    exact = PointNet2Encoder(2, [7], [[0.4]], [[4]], [[[8]]], group_all_mlp=[8, 16]).train()
    more = copy.deepcopy(exact)
    more.levels[0].npoint = 12
    torch.testing.assert_close(more(xyz, feat)[-1][1], exact(xyz, feat)[-1][1], atol=1e-5, rtol=1e-4)
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-6, rtol=1e-5, msg=key)


def test_scene_decoder_gives_repeated_seeds_their_first_occurrences_row_in_training():
    """The scene decoder keeps repeats out of its batch statistics (their training rows are 0 there), but the floor FP
    and the vote heads read every stop-level row: each repeat must carry its first occurrence's row, as in eval."""
    torch.manual_seed(0)
    net = SceneEncoderDecoder(1, 2, 8, [12, 4], [[0.3], [0.6]], [[4], [4]], [[[8]], [[16]]], [[16]], True).train()
    xyz, feat, mask, robot = (
        torch.rand(2, 5, 3),
        torch.rand(2, 5, 1),
        torch.ones(2, 5, dtype=torch.bool),
        torch.rand(2, 2),
    )
    fps = net.sample(xyz, mask)
    _, rows, _ = net(xyz, feat, mask, robot, fps)
    assert rows.shape[1] == 12 and rows.abs().sum(-1).gt(0).all()
    torch.testing.assert_close(rows[:, 5:], rows[:, :1].expand(-1, 7, -1))  # FPS repeats the first point


def _randomise_statistics(net: nn.Module) -> None:
    """Eval-mode running statistics away from (0, 1), so every path of the network reaches its output."""
    for m in net.modules():
        if isinstance(m, nn.BatchNorm1d):
            m.running_mean.normal_()
            m.running_var.uniform_(0.5, 2.0)


def _small_cloud(n: int, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Two clouds of n points in a 0.6 m box, with one feature channel: xyz [2, n, 3], feat [2, n, 1], mask [2, n]."""
    torch.manual_seed(seed)
    return torch.rand(2, n, 3) * 0.6, torch.rand(2, n, 1), torch.ones(2, n, dtype=torch.bool)


def test_pointnet2_seg_logits_do_not_depend_on_surplus_centres():
    """PointNet2Seg in training with as many level-1 centres as points, or more (the surplus repeats the first): same
    per-point logits and statistics: the decoder's FP layers keep the repeats out of their batch statistics (fails
    without the centre masks). In eval the masks change nothing here (every input point is a level-1 centre, its own
    nearest neighbour), so eval is not tested. The encoder's next-level mask changes no ball-query level: a ball
    that holds a repeat holds its first occurrence, the lowest index, which is also what the query pads with; the
    group-all test above covers it."""
    from floaff_zoo.nn.pointnet2 import PointNet2Seg

    n = 12
    torch.manual_seed(0)
    exact = PointNet2Seg(1, [n, 8], [[0.15], [0.25]], [[4], [4]], [[[8]], [[16]]], [[16], [16]], head=[8])
    _randomise_statistics(exact)
    nn.init.normal_(exact.out.weight)
    exact.train()
    more = copy.deepcopy(exact)
    more.encoder.levels[0].npoint = n + 9
    xyz, feat, mask = _small_cloud(n)
    a, b = exact(xyz, feat, mask), more(xyz, feat, mask)
    torch.testing.assert_close(b, a, atol=1e-5, rtol=1e-4)
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-5, rtol=1e-4, msg=key)


def test_scene_decoder_rows_do_not_depend_on_surplus_centres():
    """SceneEncoderDecoder (PointNet++, VoteNet- and H3DNet-style nets) decoded to level 1, in training: its first n
    rows, and its statistics, are the same with exactly n level-1 centres or with a surplus that repeats the first
    (fails without the centre masks; in eval they change nothing here, as above)."""
    n = 12
    torch.manual_seed(0)
    args = (1, 2, 8, [n, 8, 3], [[0.15], [0.25], [0.8]], [[4], [4], [4]], [[[8]], [[16]], [[16]]], [[16], [16]], True)
    exact = SceneEncoderDecoder(*args)
    _randomise_statistics(exact)
    exact.train()
    more = copy.deepcopy(exact)
    more.encoder.levels[0].npoint = n + 9
    xyz, feat, mask = _small_cloud(n)
    robot = torch.rand(2, 2)
    _, a, _ = exact(xyz, feat, mask, robot, None)
    _, b, _ = more(xyz, feat, mask, robot, None)
    torch.testing.assert_close(b[:, :n], a, atol=1e-5, rtol=1e-4)
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-5, rtol=1e-4, msg=key)


@pytest.mark.parametrize("train", [False, True])
def test_pointnet2_floor_scores_do_not_depend_on_surplus_scene_centres(train):
    """PointNet2Net interpolates its floor points from the scene decoder's stop-level centres: with a surplus of
    level-1 centres (the small presets' 1,024-point clouds under SSG's 1,024 centres) the repeats of the first centre
    filled the floor points' 3-NN next to it, so the scores moved with the surplus, in eval as in training."""
    from floaff_zoo.nn.nets import PointNet2Net

    n = 12
    torch.manual_seed(0)
    sizes = ([n, 8, 3], [[0.15], [0.25], [0.8]], [[4], [4], [4]], [[[8]], [[16]], [[16]]], [[16], [16], [16]])
    exact = PointNet2Net("ssg", 1, 2, *sizes, robot_width=8, head_width=8, dropout=0.0)
    _randomise_statistics(exact)
    exact.train(train)
    more = copy.deepcopy(exact)
    more.scene.encoder.levels[0].npoint = n + 9
    xyz, feat, mask = _small_cloud(n)
    floor = torch.rand(2, 20, 3) * 0.6
    floor[..., 2] = 0.0
    args = (floor, torch.ones(2, 20, dtype=torch.bool), torch.rand(2, 2), torch.rand(2, 3))
    a, b = exact(xyz, feat, mask, *args), more(xyz, feat, mask, *args)
    torch.testing.assert_close(b, a, atol=1e-6, rtol=1e-5)


def _floor(n: int = 30) -> tuple[torch.Tensor, torch.Tensor]:
    torch.manual_seed(2)
    return torch.cat([torch.rand(2, n, 2) * 0.6, torch.zeros(2, n, 1)], dim=-1), torch.ones(2, n, dtype=torch.bool)


def _seed_voting_sizes(name: str, n: int) -> dict:
    """Sizes of a VoteNet- or H3DNet-style net (or module) with as many seeds and proposals as a cloud of ``n``
    points has distinct points."""
    extra = {"floor_fp": [8, 8]} if name.startswith("VoteNet") else {"fuse_width": 8}
    return dict(
        npoints=[n, n, 4], radii=[[0.2], [0.4], [0.8]], nsamples=[[4], [4], [4]], mlps=[[[8]], [[16]], [[16]]],
        seed_fp=[[16]], num_proposals=n, proposal_radius=0.3, proposal_nsample=4, proposal_width=8, robot_width=8,
        head_width=8, dropout=0.0, **extra,
    )  # fmt: skip


def _with_surplus_seeds(net: nn.Module, n: int) -> nn.Module:
    """A copy of a net from :func:`_seed_voting_sizes` with more seeds and proposals than the cloud's ``n`` distinct
    points (FPS repeats the first seed, then the first proposal)."""
    more = copy.deepcopy(net)
    more.backbone.encoder.levels[0].npoint = n + 8
    more.backbone.encoder.levels[1].npoint = n + 4  # the seed level
    for agg in more.aggregate if isinstance(more.aggregate, nn.ModuleList) else [more.aggregate]:
        agg.num_proposals = agg.sa.npoint = n + 5
    return more


def _batch_statistics(net: nn.Module, *inputs: torch.Tensor) -> None:
    """Set the running statistics to those of one training pass over ``inputs``, then eval mode.

    Random running statistics (``_randomise_statistics``) collapse the seeds' and proposals' features in eval: the
    proposals' features were within 3e-4 of each other, so how the floor's 3-NN weighed them hardly showed."""
    norms = [m for m in net.modules() if isinstance(m, nn.BatchNorm1d)]
    for m in norms:
        m.momentum = 1.0
    with torch.no_grad():
        net.train()(*inputs)
    for m in norms:
        m.momentum = 0.1
    net.eval()


@pytest.mark.parametrize("train", [False, True])
@pytest.mark.parametrize("name", ["VoteNetNet", "H3DNetNet"])
def test_seed_voting_scores_do_not_depend_on_surplus_seeds_or_proposals(name, train):
    """A cloud with fewer distinct points than seeds (256 by default) repeats the first seed, and fewer distinct votes
    than proposals repeat the first proposal: H3DNet's primitive (a softmax-weighted mean over the seeds) counted the
    first seed's vote once per repeat, the floor's 3-NN from the proposals took a repeated proposal two or three
    times (VoteNet's eval scores moved by 0.06), and in training the repeats entered the vote and proposal heads'
    batch statistics."""
    from floaff_zoo.nn import nets

    n = 12
    torch.manual_seed(0)
    exact = getattr(nets, name)(1, 2, **_seed_voting_sizes(name, n))
    _randomise_statistics(exact)
    nn.init.normal_(exact.head.out.weight)  # scores that move with the head's inputs
    exact.train()
    xyz, feat, mask = _small_cloud(n)
    floor, fmask = _floor()
    robot, target = torch.rand(2, 2), torch.rand(2, 3) * 0.6
    # floor points beside the first proposals (the first one is what FPS repeats), whose 3-NN it would fill
    _, probe = copy.deepcopy(exact)(xyz, feat, mask, floor, fmask, robot, target)
    near = probe["proposal_xyz"] if "proposal_xyz" in probe else probe["vote_xyz"][:, 0]
    floor = torch.cat([floor, near[:, :3].detach() + 0.2], dim=1)
    fmask = torch.ones(floor.shape[:2], dtype=torch.bool)
    if not train:
        _batch_statistics(exact, xyz, feat, mask, floor, fmask, robot, target)
    more = _with_surplus_seeds(exact, n)
    a, aux_a = exact(xyz, feat, mask, floor, fmask, robot, target)
    b, aux_b = more(xyz, feat, mask, floor, fmask, robot, target)
    assert "seed_mask" not in aux_a and aux_b["seed_mask"].sum(dim=1).tolist() == [n, n]
    torch.testing.assert_close(b, a, atol=1e-5, rtol=1e-4)
    if "primitive_xyz" in aux_a:
        torch.testing.assert_close(aux_b["primitive_xyz"], aux_a["primitive_xyz"], atol=1e-5, rtol=1e-4)
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-5, rtol=1e-4, msg=key)


@pytest.mark.parametrize("train", [False, True])
@pytest.mark.parametrize("name", ["VoteNetModule", "H3DNetModule"])
def test_seed_vote_losses_count_each_distinct_seed_once(name, train):
    """A repeated seed votes as its first occurrence: the vote losses, means over the seeds, counted the first seed's
    vote error once per repeat. With as many seeds as distinct points or a surplus: the same vote loss, and the same
    gradients, in training (mean over the votes) and in evaluation (mean over samples)."""
    from floaff_zoo.models.h3dnet import H3DNetModule
    from floaff_zoo.models.votenet import VoteNetModule

    n = 12
    cls = {"VoteNetModule": VoteNetModule, "H3DNetModule": H3DNetModule}[name]
    torch.manual_seed(0)
    exact = cls(**_seed_voting_sizes(name, n))
    _randomise_statistics(exact.net)
    exact.train(train)
    more = copy.deepcopy(exact)
    more.net = _with_surplus_seeds(exact.net, n)
    xyz, feat, mask = _small_cloud(n)
    floor, fmask = _floor()
    torch.manual_seed(3)
    batch = {
        "scene_xyz": xyz, "scene_feat": feat, "scene_mask": mask, "floor_xyz": floor, "floor_mask": fmask,
        "floor_label": torch.rand(floor.shape[:2]), "robot": torch.rand(2, 2), "target_xyz": torch.rand(2, 3) * 0.6,
        "target_yaw": torch.rand(2) * 6.0 - 3.0,
    }  # fmt: skip
    # H3DNet: with a radius no seed reaches, every kept seed votes (the fallback); VoteNet has no radius
    for radius in (None, 1e-6) if name == "H3DNetModule" else (None,):
        losses, masks = [], []
        for model in (exact, more):
            model.zero_grad()
            if radius is not None:
                model.hparams["vote_radius"] = radius
            _, aux = model.forward_with_aux(batch)
            losses.append(model.vote_loss(batch, aux))
            losses[-1].backward()
            masks.append(aux.get("seed_mask"))
        assert masks[0] is None and masks[1].sum(dim=1).tolist() == [n, n]
        torch.testing.assert_close(losses[1], losses[0], atol=1e-6, rtol=1e-5, msg=f"vote_radius {radius}")
        for (key, p), q in zip(exact.net.named_parameters(), more.net.parameters()):
            if p.grad is None:
                assert q.grad is None, key
            else:
                torch.testing.assert_close(q.grad, p.grad, atol=1e-5, rtol=1e-4, msg=key)


@pytest.mark.parametrize("train", [False, True])
def test_n2m_pooled_code_does_not_depend_on_surplus_last_level_centres(train):
    """N2M pools its last level max ⊕ mean: the mean counted the first centre once per repeat."""
    from floaff_zoo.nn.nets import N2MNet

    n = 5
    torch.manual_seed(0)
    exact = N2MNet(1, [n, n], [[0.3], [0.6]], [[4], [4]], [[[8]], [[16]]], decoder=(16,), dropout=0.0)
    _randomise_statistics(exact)
    exact.train(train)
    more = copy.deepcopy(exact)
    more.encoder.levels[0].npoint = n + 3
    more.encoder.levels[1].npoint = n + 2
    xyz, feat, mask = _small_cloud(n)
    for got, want in zip(more(xyz, feat, mask), exact(xyz, feat, mask)):
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-4)
    for key, value in _stats(exact).items():
        torch.testing.assert_close(_stats(more)[key], value, atol=1e-5, rtol=1e-4, msg=key)


def test_vote_losses_on_mixed_batches():
    """A batch mixing a sample whose seeds repeat with one whose do not, and one without a target: each distinct seed's
    vote counts once in the training mean, each sample's own mean in evaluation, a sample without a target 0."""
    from floaff_zoo.models.votenet import vote_loss, vote_loss_per_sample

    # vote distances to the target at the origin: 1, 2 (then two repeats of the first seed); 3, 5, 7, 9
    dist = torch.tensor([[1.0, 2, 1, 1], [3, 5, 7, 9]])
    votes = torch.stack([dist, torch.zeros_like(dist), torch.zeros_like(dist)], dim=-1)
    gt = torch.zeros(2, 1, 3)
    kept = torch.tensor([[True, True, False, False], [True, True, True, True]])
    both = torch.tensor([[True], [True]])
    assert float(vote_loss(votes, gt, both, kept)) == pytest.approx((1 + 2 + 3 + 5 + 7 + 9) / 6)
    assert vote_loss_per_sample(votes, gt, both, kept).tolist() == pytest.approx([1.5, 6.0])
    first_only = torch.tensor([[True], [False]])
    assert float(vote_loss(votes, gt, first_only, kept)) == pytest.approx(1.5)
    assert vote_loss_per_sample(votes, gt, first_only, kept).tolist() == pytest.approx([1.5, 0.0])
    assert float(vote_loss(votes, gt, both)) == pytest.approx((1 + 2 + 1 + 1 + 3 + 5 + 7 + 9) / 8)  # no mask: all


def _count_repeat_sources(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Patch ``repeat_sources`` wherever it is looked up; the returned list gets one entry per call that asks the device
    whether an FPS level repeats (a host sync: a call on None asks nothing)."""
    from floaff_zoo.nn import nets, pointnet2

    calls: list[int] = []

    def counted(idx):
        if idx is not None:
            calls.append(idx.shape[1])
        return repeat_sources(idx)

    for module in (pointnet2, nets):
        monkeypatch.setattr(module, "repeat_sources", counted)
    return calls


def _fps_levels(fps) -> int:
    """FPS levels (group-all levels sample none) in a net's ``sample`` output, nested for NavAff."""
    if isinstance(fps, tuple):
        return sum(_fps_levels(f) for f in fps)
    return sum(idx is not None for idx in fps)


@pytest.mark.parametrize("train", [False, True])
@pytest.mark.parametrize("name", ["PointNet2Seg", "PointNet2Net", "VoteNetNet", "H3DNetNet", "N2MNet", "NavAffNet"])
def test_one_repeat_lookup_per_fps_level_and_forward(name, train, monkeypatch):
    """Whether an FPS level repeats a centre is a host sync (``repeat_sources``): a forward pass finds it once per level
    and hands it on (the encoder, every set-abstraction level, the decoder and the heads each found it again: a VoteNet
    training step waited on the device 7 more times)."""
    from floaff_zoo.nn import nets
    from floaff_zoo.nn.pointnet2 import PointNet2Seg

    n = 12
    torch.manual_seed(0)
    xyz, feat, mask = _small_cloud(n)
    floor, fmask = _floor()
    robot, target = torch.rand(2, 2), torch.rand(2, 3) * 0.6
    levels = ([n + 9, 8, 3], [[0.15], [0.25], [0.8]], [[4], [4], [4]], [[[8]], [[16]], [[16]]])
    if name == "PointNet2Seg":
        net = PointNet2Seg(1, *levels, [[16], [16], [16]], head=[8])
        fps, run = net.encoder.sample(xyz, mask), lambda fps: net(xyz, feat, mask, fps)
    elif name == "PointNet2Net":
        net = nets.PointNet2Net("ssg", 1, 2, *levels, [[16], [16], [16]], robot_width=8, head_width=8, dropout=0.0)
        fps, run = net.sample(xyz, mask), lambda fps: net(xyz, feat, mask, floor, fmask, robot, target, fps)
    elif name == "N2MNet":
        net = nets.N2MNet(1, [n + 3, n + 2], [[0.3], [0.6]], [[4], [4]], [[[8]], [[16]]], decoder=(16,), dropout=0.0)
        fps, run = net.sample(xyz, mask), lambda fps: net(xyz, feat, mask, fps)
    elif name == "NavAffNet":
        net = nets.NavAffNet(npoints=(3 * floor.shape[1], 6, 3), num_heads=2, dropout=0.0)
        fps = net.sample(xyz, mask, floor, fmask)
        run = lambda fps: net(xyz, feat, mask, floor, fmask, robot, fps)  # noqa: E731
    else:
        net = _with_surplus_seeds(getattr(nets, name)(1, 2, **_seed_voting_sizes(name, n)), n)
        fps, run = net.sample(xyz, mask), lambda fps: net(xyz, feat, mask, floor, fmask, robot, target, fps)
    net.train(train)
    proposals = [net.aggregate] if name == "VoteNetNet" else list(net.aggregate) if name == "H3DNetNet" else []
    first = fps[1][0] if name == "NavAffNet" else fps[0]  # NavAff: the floor encoder's first level
    assert repeat_sources(first) is not None  # a cloud with fewer points than centres: FPS repeats the first one
    calls = _count_repeat_sources(monkeypatch)
    run(fps)
    assert len(calls) == _fps_levels(fps) + len(proposals), calls  # one per level, vote aggregation's FPS included


@pytest.mark.parametrize("train", [False, True])
def test_cfar_one_repeat_lookup_per_fps_level_and_forward(train, monkeypatch):
    """As above for CFAR's net, which samples its local and floor levels itself (``sample_levels``)."""
    args = yaml.safe_load((ROOT / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
    torch.manual_seed(0)
    net = CFARModule(**args).net.train(train)
    n = net.local_encoder.levels[-2].npoint - 3  # fewer points than the last local level's centres
    mask = torch.zeros(2, 64, dtype=torch.bool)
    mask[:, :n] = True
    xyz = torch.where(mask[..., None], torch.rand(2, 64, 3) * 0.6 - 0.3, 0.0)
    feat = torch.randn(2, 64, net.feat_channels)
    floor = torch.cat([torch.rand(2, 10, 2) * 0.6 - 0.3, torch.zeros(2, 10, 1)], dim=-1)  # under 16 floor centres
    calls = _count_repeat_sources(monkeypatch)
    net.logits(xyz, feat, mask, floor, torch.ones(2, 10, dtype=torch.bool), torch.randn(2, args.get("robot_dim", 2)))
    levels = [sa for sa in (*net.local_encoder.levels, *net.floor_encoder.levels) if not sa.group_all]
    assert sorted(calls) == sorted(sa.npoint for sa in levels)
