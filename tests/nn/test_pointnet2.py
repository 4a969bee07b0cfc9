"""Channels-last PointNet++ vs the reference-style (Conv2d, sort, naive FPS) port on identical weights."""

from __future__ import annotations

import pytest
import torch

from floaff_zoo.nn import ops
from floaff_zoo.nn.nets import PerPointHead
from floaff_zoo.nn.pointnet2 import (
    FeaturePropagation,
    PointNet2Encoder,
    PointNet2Seg,
    SetAbstraction,
    SharedMLP,
    on_valid_rows,
)
from tests._scripts import load_benchmark

SSG = dict(
    in_channels=1,
    npoints=[64, 16, 4],
    radii=[[0.2], [0.4], [0.8]],
    nsamples=[[8], [8], [4]],
    mlps=[[[8, 8, 16]], [[16, 32]], [[32, 32]]],
    fp_mlps=[[32, 32], [32, 16], [16, 16]],
    head=[16],
    xyz_first=True,
)
MSG = dict(
    in_channels=1,
    npoints=[64, 16],
    radii=[[0.1, 0.2, 0.4], [0.4, 0.8]],
    nsamples=[[8, 16, 32], [16, 32]],
    mlps=[[[8, 8, 16], [8, 8, 16], [8, 12, 16]], [[16, 16, 32], [16, 24, 32]]],
    fp_mlps=[[32, 32], [32, 16]],
    head=[8],
    xyz_first=False,
)


@pytest.mark.parametrize("cfg", [SSG, MSG], ids=["ssg", "msg"])
@pytest.mark.parametrize("train", [True, False], ids=["train", "eval"])
def test_matches_reference_port(cfg, train):
    ref_mod = load_benchmark("reference_pointnet2")
    torch.manual_seed(0)
    ref = ref_mod.RefPointNet2Seg(**cfg)
    ours = PointNet2Seg(**cfg)
    # non-trivial BN running stats for eval mode
    for m in ref.modules():
        if isinstance(m, (torch.nn.BatchNorm1d, torch.nn.BatchNorm2d)):
            m.running_mean.uniform_(-0.1, 0.1)
            m.running_var.uniform_(0.5, 1.5)
            m.weight.data.uniform_(0.5, 1.5)
            m.bias.data.uniform_(-0.1, 0.1)
    ref_mod.convert_to_channels_last(ref, ours)
    ref.train(train)
    ours.train(train)
    g = torch.Generator().manual_seed(3)
    xyz = torch.rand(2, 256, 3, generator=g)
    feat = torch.randn(2, 256, 1, generator=g)
    fps = ours.encoder.sample(xyz, None)
    # our exact FPS gives the naive loop's indices on the first level
    assert torch.equal(fps[0], ref_mod.farthest_point_sample(xyz, cfg["npoints"][0]))
    with torch.no_grad():
        a = ref(xyz, feat, fps)
        b = ours(xyz, feat, None, fps)
    assert a.shape == b.shape == (2, 256)
    assert torch.allclose(a, b, atol=1e-4, rtol=1e-4), (a - b).abs().max()


def test_ball_query_same_as_reference_sort():
    ref_mod = load_benchmark("reference_pointnet2")
    xyz = torch.rand(2, 300, 3)
    centres = xyz[:, :40]
    assert torch.equal(ops.ball_query(0.2, 16, xyz, centres), ref_mod.query_ball_point(0.2, 16, xyz, centres))


def test_masked_points_never_grouped():
    torch.manual_seed(0)
    xyz = torch.rand(2, 128, 3)
    mask = torch.ones(2, 128, dtype=torch.bool)
    mask[:, 100:] = False
    xyz[:, 100:] = 0.0  # padding at the origin, as the collate pads
    sa = SetAbstraction(32, [0.3], [16], 0, [[8]])
    idx = sa.sample(xyz, mask)
    assert (idx < 100).all()
    groups = ops.ball_query(0.3, 16, xyz, ops.index_points(xyz, idx), mask)
    assert (groups < 100).all()
    # padding values do not change the features of a padded cloud
    enc = PointNet2Encoder(0, [32], [[0.3]], [[16]], [[[8]]], xyz_as_feat=True).eval()
    out1 = enc(xyz, None, mask)[-1][1]
    xyz2 = xyz.clone()
    xyz2[:, 100:] = 7.0
    out2 = enc(xyz2, None, mask)[-1][1]
    assert torch.allclose(out1, out2)


def test_group_all_respects_mask_and_grads_finite():
    torch.manual_seed(0)
    enc = PointNet2Encoder(1, [16], [[0.4]], [[8]], [[[8, 16]]], group_all_mlp=[16, 32])
    xyz = torch.rand(2, 64, 3)
    feat = torch.randn(2, 64, 1, requires_grad=True)
    mask = torch.ones(2, 64, dtype=torch.bool)
    mask[1, 10:] = False
    levels = enc(xyz, feat, mask)
    assert levels[-1][1].shape == (2, 1, 32)
    levels[-1][1].sum().backward()
    assert torch.isfinite(feat.grad).all()
    assert (feat.grad[1, 10:] == 0).all()  # padding has no influence


def _conv_grads(ref) -> list[torch.Tensor]:
    """Reference-port SA weight gradients in our Linear layout, in our parameter order."""
    out = []
    for rsa in ref.sa:
        for convs in rsa.conv_blocks:
            out += [conv.weight.grad[:, :, 0, 0] for conv in convs]
    return out


@pytest.mark.parametrize("cfg", [SSG, MSG], ids=["ssg", "msg"])
def test_training_gradients_match_reference_port(cfg):
    """Pooling before the last ReLU, the fused BN + max and the first Linear before grouping give the port's
    gradients and running statistics.

    In float64: max pooling routes each gradient to one winner, so float32 rounding (which differs
    between any two implementations) can flip a near-tie and move a weight gradient by a percent.
    """
    ref_mod = load_benchmark("reference_pointnet2")
    torch.manual_seed(0)
    ref = ref_mod.RefPointNet2Seg(**cfg)
    ours = PointNet2Seg(**cfg)
    ref_mod.convert_to_channels_last(ref, ours)
    ref, ours = ref.double(), ours.double()
    g = torch.Generator().manual_seed(5)
    xyz = torch.rand(2, 256, 3, generator=g, dtype=torch.float64)
    feat = torch.randn(2, 256, 1, generator=g, dtype=torch.float64)
    target = torch.rand(2, 256, generator=g, dtype=torch.float64)
    fps = ours.encoder.sample(xyz, None)
    for net, fwd in ((ref, lambda: ref(xyz, feat, fps)), (ours, lambda: ours(xyz, feat, None, fps))):
        net.train()
        torch.nn.functional.binary_cross_entropy_with_logits(fwd(), target).backward()
    ours_grads = [lin.weight.grad for sa in ours.encoder.levels for mlp in sa.mlps for lin in mlp.linears]
    for a, b in zip(_conv_grads(ref), ours_grads, strict=True):
        # 1e-5: our neighbour search and interpolation weights are float32 even for float64 features
        assert torch.allclose(a, b, atol=1e-6, rtol=1e-5), (a - b).abs().max()
    # running statistics follow the same batches (the first Linear's bias included)
    for rsa, osa in zip(ref.sa, ours.encoder.levels):
        for bns, mlp in zip(rsa.bn_blocks, osa.mlps):
            for bn, norm in zip(bns, mlp.norms):
                assert torch.allclose(bn.running_mean, norm.running_mean, atol=1e-7)
                assert torch.allclose(bn.running_var, norm.running_var, atol=1e-7)
                assert int(bn.num_batches_tracked) == int(norm.num_batches_tracked) == 1


def test_first_layer_before_grouping_matches_grouping_first(monkeypatch):
    """Both SA paths give the same outputs and input gradients, in train and eval mode."""
    import floaff_zoo.nn.pointnet2 as pn2

    torch.manual_seed(0)
    sa = SetAbstraction(16, [0.3, 0.5], [8, 12], 20, [[16, 24], [8, 8]], xyz_first=False)
    xyz = torch.rand(2, 96, 3)
    feat0 = torch.randn(2, 96, 20)
    idx = sa.sample(xyz, None)
    for train in (True, False):
        sa.train(train)
        results = []
        for threshold in (1, 10**6):  # per point first / grouped first
            monkeypatch.setattr(pn2, "GATHER_AFTER_FIRST_LAYER", threshold)
            feat = feat0.clone().requires_grad_()
            out = sa(xyz, feat, None, idx)[1]
            out.square().sum().backward()
            results.append((out.detach(), feat.grad))
        (a, ga), (b, gb) = results
        assert torch.allclose(a, b, atol=1e-5), (a - b).abs().max()
        assert torch.allclose(ga, gb, atol=1e-4), (ga - gb).abs().max()


@pytest.mark.parametrize("per_point", [True, False])
@pytest.mark.parametrize("first_mlp", [[16, 24], [16]])
def test_chunked_inference_equals_one_pass(per_point, first_mlp, monkeypatch):
    """Without gradients a row-wise level runs in chunks of centres with the one-pass outputs (one-layer MLPs
    included); batch statistics (train mode, or a BN without running statistics) are never chunked."""
    import floaff_zoo.nn.pointnet2 as pn2

    torch.manual_seed(0)
    sa = SetAbstraction(40, [0.3, 0.5], [8, 12], 20, [first_mlp, [8, 8]], xyz_first=False)
    for norm in sa.modules():
        if isinstance(norm, torch.nn.BatchNorm1d):  # non-trivial running statistics to fold
            norm.running_mean.uniform_(-0.5, 0.5)
            norm.running_var.uniform_(0.5, 2.0)
    sa.eval()
    xyz, feat = torch.rand(2, 96, 3), torch.randn(2, 96, 20)
    idx = sa.sample(xyz, None)
    monkeypatch.setattr(pn2, "GATHER_AFTER_FIRST_LAYER", 1 if per_point else 10**6)
    with torch.no_grad():
        monkeypatch.setattr(pn2, "CHUNK_ROWS", 10**9)
        whole = sa(xyz, feat, None, idx)[1]
        monkeypatch.setattr(pn2, "CHUNK_ROWS", 2 * 3 * 12)  # a few centres per chunk, last chunk ragged
        assert pn2._centres_per_chunk(sa.mlps[1], torch.zeros(2, 40, 12, dtype=torch.long)) == 40  # too few
        monkeypatch.setattr(pn2, "MIN_CHUNK_CENTRES", 3)
        assert pn2._centres_per_chunk(sa.mlps[1], torch.zeros(2, 40, 12, dtype=torch.long)) == 3
        chunked = sa(xyz, feat, None, idx)[1]
    assert torch.allclose(chunked, whole, atol=1e-6), (chunked - whole).abs().max()
    groups = torch.zeros(2, 40, 12, dtype=torch.long)
    with torch.no_grad():
        sa.mlps[1].norms[0].train()
        assert pn2._centres_per_chunk(sa.mlps[1], groups) == 40
        sa.mlps[1].norms[0].eval()
        sa.mlps[1].norms[0].running_mean = None  # batch statistics in eval mode (PFAL's frozen teacher)
        assert pn2._centres_per_chunk(sa.mlps[1], groups) == 40
    assert pn2._centres_per_chunk(sa.mlps[0], groups) == 40  # gradients on: never chunked


def test_reference_ops_run_a_zoo_model_with_the_same_outputs_and_restore():
    """The benchmark's reference counterpart of a model (port ops, same weights) predicts the same."""
    import floaff_zoo.nn.pointnet2 as pn2
    from floaff_zoo.contract import collate_samples
    from floaff_zoo.data.synthetic import make_synthetic_sample
    from floaff_zoo.models.pointnet2 import PointNet2Module

    ref_mod = load_benchmark("reference_pointnet2")
    torch.manual_seed(0)
    model = PointNet2Module(
        npoints=[64, 16], radii=[[0.4], [0.8]], nsamples=[[8], [8]], mlps=[[[8, 16]], [[16, 32]]], fp_mlps=[[32], [16]]
    ).eval()
    batch = collate_samples([make_synthetic_sample(i, num_points=256, floor_cells=8) for i in range(2)])
    before = (pn2.SharedMLP.forward, pn2.ball_query_multi, ops.point_kernel)
    with torch.no_grad():
        ours = model(batch)
        with ref_mod.reference_ops():
            assert pn2.ball_query_multi is not before[1]
            ref = model(batch)
    assert (pn2.SharedMLP.forward, pn2.ball_query_multi, ops.point_kernel) == before
    assert torch.allclose(ours, ref, atol=1e-5), (ours - ref).abs().max()


def test_fused_batchnorm_max_equals_batchnorm_then_max():
    """Values, gradients (z, BN affine, Linear bias = 0) and running stats, with negative BN weights and ties."""
    from floaff_zoo.nn.pointnet2 import _BatchNormMax

    g = torch.Generator().manual_seed(0)
    z0 = torch.randn(2, 6, 5, 4, generator=g, dtype=torch.float64) * 0.3 + 2.0
    z0[:, :, 3:] = z0[:, :, :1]  # padded groups: duplicate rows
    bias0 = torch.randn(4, generator=g, dtype=torch.float64)
    lin = torch.nn.Linear(3, 4).double()
    bn = torch.nn.BatchNorm1d(4).double()
    with torch.no_grad():
        lin.bias.copy_(bias0)
        bn.weight.copy_(torch.tensor([1.5, -0.7, 0.2, -2.0]))
        bn.bias.copy_(torch.randn(4, generator=g))
    gout = torch.randn(2, 6, 4, generator=g, dtype=torch.float64)

    z = z0.clone().requires_grad_()
    ref = bn((z + lin.bias).reshape(-1, 4)).view(z.shape).max(dim=2).values
    ref_grads = torch.autograd.grad(ref, (z, lin.bias, bn.weight, bn.bias), gout)

    bn2 = torch.nn.BatchNorm1d(4).double()
    bn2.load_state_dict({**bn.state_dict(), "running_mean": torch.zeros(4), "running_var": torch.ones(4)})
    z2 = z0.clone().requires_grad_()
    bias = bias0.clone().requires_grad_()
    out = _BatchNormMax.apply(z2, bias, bn2.weight, bn2.bias, bn2.running_mean, bn2.running_var, 0.1, bn2.eps, 2)
    grads = torch.autograd.grad(out, (z2, bias, bn2.weight, bn2.bias), gout)
    assert torch.allclose(out, ref, atol=1e-12)
    for a, b in zip(grads, ref_grads, strict=True):
        assert torch.allclose(a, b, atol=1e-10), (a - b).abs().max()
    assert torch.allclose(bn2.running_mean, bn.running_mean, atol=1e-12)
    assert torch.allclose(bn2.running_var, bn.running_var, atol=1e-12)


@pytest.mark.parametrize("path", ["kernel", "torch"])
def test_batch_mean_var_equals_var_mean_over_several_chunks(path, monkeypatch):
    """Two-pass statistics (rows not a multiple of the chunk or block) vs float64 var_mean, large offset."""
    import floaff_zoo.nn.pointnet2 as pn2
    from floaff_zoo.nn.pointnet2 import STATS_CHUNK_ROWS, batch_mean_var

    if path == "torch":
        monkeypatch.setattr(pn2, "point_kernel", lambda device: None)
    elif ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("the C++ kernels are unavailable here (no compiler)")
    g = torch.Generator().manual_seed(0)
    flat = torch.randn(2 * STATS_CHUNK_ROWS + 37, 5, generator=g) * torch.tensor([0.1, 1.0, 3.0, 0.5, 2.0]) + 30.0
    var, mean = batch_mean_var(flat)
    ref_var, ref_mean = torch.var_mean(flat.double(), dim=0, correction=0)
    assert torch.allclose(mean.double(), ref_mean, rtol=0, atol=1e-5)
    assert torch.allclose(var.double(), ref_var, rtol=1e-5, atol=0), (var.double() / ref_var - 1).abs().max()
    var64, mean64 = batch_mean_var(flat.double())
    assert torch.allclose(var64, ref_var, rtol=1e-12) and torch.allclose(mean64, ref_mean, rtol=1e-12)


def _bn_relu_case(dtype):
    g = torch.Generator().manual_seed(3)
    z0 = torch.randn(300, 5, generator=g, dtype=dtype) * torch.tensor([0.2, 1.0, 3.0, 0.5, 2.0], dtype=dtype) + 4.0
    bias0 = torch.randn(5, generator=g, dtype=dtype)
    bn = torch.nn.BatchNorm1d(5).to(dtype)
    with torch.no_grad():
        bn.weight.copy_(torch.tensor([1.5, -0.7, 0.2, -2.0, 1.0]))
        bn.bias.copy_(torch.randn(5, generator=g))
    gout = torch.randn(300, 5, generator=g, dtype=dtype)
    return z0, bias0, bn, gout


@pytest.mark.parametrize("reuse", [False, True], ids=["fresh", "reuse_z"])
def test_fused_batchnorm_relu_equals_batchnorm_then_relu(reuse):
    """Values, gradients (z, Linear bias = 0, BN affine) and running stats of the C++ BN+ReLU, float64."""
    from floaff_zoo.nn.pointnet2 import _BatchNormReLU

    if ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("the C++ kernels are unavailable here (no compiler)")
    z0, bias0, bn, gout = _bn_relu_case(torch.float64)
    z = z0.clone().requires_grad_()
    bias = bias0.clone().requires_grad_()
    ref = torch.relu(bn(z + bias))
    ref_grads = torch.autograd.grad(ref, (z, bias, bn.weight, bn.bias), gout)

    bn2 = torch.nn.BatchNorm1d(5).double()
    bn2.load_state_dict({**bn.state_dict(), "running_mean": torch.zeros(5), "running_var": torch.ones(5)})
    z2 = z0.clone().requires_grad_()
    lin_out = z2 * 1.0  # a non-leaf, as the Linear's output is
    bias2 = bias0.clone().requires_grad_()
    stats = (bn2.running_mean, bn2.running_var)
    out = _BatchNormReLU.apply(lin_out, bias2, bn2.weight, bn2.bias, *stats, 0.1, 1e-5, reuse)
    grads = torch.autograd.grad(out, (z2, bias2, bn2.weight, bn2.bias), gout, retain_graph=True)
    assert torch.allclose(out, ref, atol=1e-12)
    for a, b in zip(grads, ref_grads, strict=True):
        assert torch.allclose(a, b, atol=1e-10), (a - b).abs().max()
    assert torch.allclose(bn2.running_mean, bn.running_mean, atol=1e-12)
    assert torch.allclose(bn2.running_var, bn.running_var, atol=1e-12)
    if reuse:
        # the first backward wrote its gradient over z: a second one must fail, not read a stale z
        with pytest.raises(RuntimeError, match="modified by an inplace operation"):
            torch.autograd.grad(out, (z2,), gout)
    else:
        again = torch.autograd.grad(out, (z2,), gout)[0]
        assert torch.equal(again, grads[0])


def test_fused_batchnorm_max_reusing_z_gives_the_same_gradient_once():
    """``reuse_z`` writes the gradient over z: same result, and a second backward fails loudly."""
    from floaff_zoo.nn.pointnet2 import _BatchNormMax

    g = torch.Generator().manual_seed(1)
    z0 = torch.randn(2, 6, 5, 4, generator=g, dtype=torch.float64)
    gout = torch.randn(2, 6, 4, generator=g, dtype=torch.float64)
    results = []
    for reuse in (False, True):
        z = z0.clone().requires_grad_()
        bn = torch.nn.BatchNorm1d(4).double()
        out = _BatchNormMax.apply(
            z * 1.0, torch.zeros(4, dtype=torch.float64), bn.weight, bn.bias, None, None, 0.1, 1e-5, 2, reuse
        )
        results.append(torch.autograd.grad(out, (z,), gout, retain_graph=True)[0])
        if reuse:
            with pytest.raises(RuntimeError, match="modified by an inplace operation"):
                torch.autograd.grad(out, (z,), gout)
    assert torch.equal(results[0], results[1])


def test_shared_mlp_kernel_path_equals_torch_path(monkeypatch):
    """A train-mode pooled MLP on the C++ BN+ReLU and statistics kernels vs the torch ops, float32:
    outputs, input and weight gradients, running statistics."""
    import floaff_zoo.nn.pointnet2 as pn2
    from floaff_zoo.nn.pointnet2 import SharedMLP

    if ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("the C++ kernels are unavailable here (no compiler)")
    torch.manual_seed(0)
    ref_mlp = SharedMLP(4, [16, 24, 32]).train()
    x0 = torch.randn(3, 40, 8, 4)
    runs = []
    for use_kernel in (True, False):
        if not use_kernel:
            monkeypatch.setattr(pn2, "point_kernel", lambda device: None)
        mlp = SharedMLP(4, [16, 24, 32]).train()
        mlp.load_state_dict(ref_mlp.state_dict())
        x = x0.clone().requires_grad_()
        out = mlp.pooled(x, dim=2)
        out.square().sum().backward()
        stats = [torch.cat([n.running_mean, n.running_var]) for n in mlp.norms]
        runs.append((out.detach(), x.grad, [lin.weight.grad for lin in mlp.linears], stats))
    (a, ga, wa, sa), (b, gb, wb, sb) = runs
    assert torch.allclose(a, b, atol=1e-5), (a - b).abs().max()
    assert torch.allclose(ga, gb, atol=1e-4), (ga - gb).abs().max()
    for u, v in zip(wa + sa, wb + sb, strict=True):
        # sums over 960 rows in another order: float32 rounding, relative to the tensor's scale
        assert (u - v).abs().max() <= 1e-5 * u.abs().max(), (u - v).abs().max() / u.abs().max()


def test_bn_relu_kernels_reject_mismatched_inputs():
    kernel = ops.point_kernel(torch.device("cpu"))
    if kernel is None:
        pytest.skip("the C++ kernels are unavailable here (no compiler)")
    z = torch.randn(10, 4)
    with pytest.raises(RuntimeError, match="a must be"):
        kernel.affine_relu(z, torch.ones(3), torch.zeros(4))
    with pytest.raises(RuntimeError, match="dy must be"):
        kernel.relu_grad_sums(torch.randn(10, 5), z, z, torch.zeros(4))
    with pytest.raises(RuntimeError, match="z must be"):
        kernel.column_var_mean(z.t())


def test_inference_linear_equals_linear_and_relu(monkeypatch):
    """oneDNN's fused inference Linear(+ReLU) = F.linear (+ReLU) up to rounding; with gradients,
    bf16 or below the row threshold it is the plain op; an eval model predicts the same either way."""
    import torch.nn.functional as F

    import floaff_zoo.nn.pointnet2 as pn2
    from floaff_zoo.contract import collate_samples
    from floaff_zoo.data.synthetic import make_synthetic_sample
    from floaff_zoo.models.pointnet2 import PointNet2Module

    torch.manual_seed(0)
    x = torch.randn(2, pn2.ONEDNN_MIN_ROWS, 24)
    w, b = torch.randn(40, 24), torch.randn(40)
    with torch.no_grad():
        for relu in (False, True):
            want = F.linear(x, w, b)
            want = want.relu() if relu else want
            got = pn2.inference_linear(x, w, b, relu=relu)
            assert got.shape == (2, pn2.ONEDNN_MIN_ROWS, 40)
            assert torch.allclose(got, want, atol=1e-5), (got - want).abs().max()
        assert torch.allclose(pn2.inference_linear(x, w), F.linear(x, w), atol=1e-5)
        small = x[:, :3]
        assert torch.equal(pn2.inference_linear(small, w, b, relu=True), F.linear(small, w, b).relu())
        bf = pn2.inference_linear(x.bfloat16(), w.bfloat16(), b.bfloat16())
        assert bf.dtype == torch.bfloat16 and torch.equal(bf, F.linear(x.bfloat16(), w.bfloat16(), b.bfloat16()))
    wg = w.clone().requires_grad_()
    out = pn2.inference_linear(x, wg, b, relu=True)
    out.sum().backward()  # the plain ops carry the gradient
    assert torch.equal(out.detach(), F.linear(x, w, b).relu()) and wg.grad is not None

    model = PointNet2Module(
        npoints=[256, 64],
        radii=[[0.4], [0.8]],
        nsamples=[[16], [16]],
        mlps=[[[32, 32]], [[32, 64]]],
        fp_mlps=[[32], [32]],
    ).eval()
    batch = collate_samples([make_synthetic_sample(i, num_points=512, floor_cells=8) for i in range(2)])
    outs = []
    for enabled in (True, False):
        monkeypatch.setattr(pn2, "_ONEDNN_LINEAR", enabled and pn2._ONEDNN_LINEAR)
        with torch.inference_mode():
            outs.append(model(batch))
    assert torch.allclose(outs[0], outs[1], atol=1e-5), (outs[0] - outs[1]).abs().max()


@pytest.mark.parametrize("use_kernel", [True, False], ids=["kernel", "torch"])
def test_shared_mlp_two_forwards_before_one_backward(use_kernel, monkeypatch):
    """A train-mode MLP called twice before one backward (a siamese use; nn.BatchNorm1d allows it): the torch path
    (CUDA, autocast) wrote its running-mean correction in place into the statistics BN had saved for the first
    call's backward, which then raised. Gradients and statistics must equal nn.Sequential's."""
    import floaff_zoo.nn.pointnet2 as pn2
    from floaff_zoo.nn.pointnet2 import SharedMLP

    if use_kernel and ops.point_kernel(torch.device("cpu")) is None:
        pytest.skip("the C++ kernels are unavailable here (no compiler)")
    if not use_kernel:
        monkeypatch.setattr(pn2, "point_kernel", lambda device: None)
    torch.manual_seed(0)
    mlp = SharedMLP(4, [16, 8]).train()
    layers = []
    for lin, norm in zip(mlp.linears, mlp.norms, strict=True):
        layers += [
            torch.nn.Linear(4 if not layers else lin.in_features, lin.out_features),
            torch.nn.BatchNorm1d(lin.out_features),
            torch.nn.ReLU(),
        ]
        layers[-3].load_state_dict(lin.state_dict())
        layers[-2].load_state_dict(norm.state_dict())
    ref = torch.nn.Sequential(*layers).train()
    x1, x2 = torch.randn(30, 4), torch.randn(20, 4) * 2.0
    mlp(x1).square().sum().add(mlp(x2).sum()).backward()
    ref(x1).square().sum().add(ref(x2).sum()).backward()
    for lin, norm, r_lin, r_norm in zip(mlp.linears, mlp.norms, layers[0::3], layers[1::3], strict=True):
        torch.testing.assert_close(lin.weight.grad, r_lin.weight.grad, atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(norm.running_mean, r_norm.running_mean, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(norm.running_var, r_norm.running_var, atol=1e-5, rtol=1e-5)


def test_set_abstraction_sizes_must_be_whole_numbers():
    """int() cut 2.5 centres or neighbours to 2 and read True as 1, where the ops now refuse them by name."""
    for npoint, k, said in ((2.5, 16, "npoints: a level's centres"), (32, True, "nsamples: a ball's neighbours")):
        with pytest.raises(ValueError, match=f"{said} must be an integer >= 1, got"):
            SetAbstraction(npoint, [0.3], [k], 0, [[8]])


def test_shared_mlp_sizes_must_be_whole_numbers():
    """True built a layer of width 1; 2.5 and -1 failed inside nn.Linear with a message naming no argument. (A width
    of 0 is left to the models' check_layer_sizes, which names the model and the layer.)"""
    for in_channels, widths, said in ((4, [-1], "widths"), (4, [True], "widths"), (4, [8, 2.5], "widths")):
        with pytest.raises(ValueError, match=f"SharedMLP: {said}.* must be an integer >= 0"):
            SharedMLP(in_channels, widths)
    with pytest.raises(ValueError, match="SharedMLP: in_channels must be an integer >= 1, got -2"):
        SharedMLP(-2, [4])
    assert SharedMLP(4, []).out_channels == 4  # no layer: the identity (CFARNet's head=())


@pytest.mark.parametrize("train", [True, False])
def test_shared_mlp_mask_must_match_the_rows(train):
    """A transposed [N, B] or a [B, 1] mask was read at other rows' positions (in training) without an error."""
    mlp = SharedMLP(4, [8]).train(train)
    x = torch.randn(2, 5, 4)
    bad = torch.ones(5, 2, dtype=torch.bool)
    bad[0, 0] = False
    for mask in (bad, torch.ones(2, 1, dtype=torch.bool)):
        with pytest.raises(ValueError, match=r"SharedMLP: mask must be \[2, 5\] for x \[2, 5, 4\]"):
            mlp(x, mask)
    with pytest.raises(ValueError, match=r"on_valid_rows: mask must be \[2, 5\]"):
        on_valid_rows(mlp, x, bad)
    with pytest.raises(ValueError, match=r"PerPointHead: mask must be \[2, 5\]"):
        PerPointHead(4, 8).train(train)(x, bad)


def test_set_abstraction_refuses_bad_scales_and_channels():
    """True was a radius of 1 m and a text failed in math.isfinite; no scale gave 0 channels and a torch.cat error
    at the first batch, a group-all level without its MLP an IndexError, a negative in_channels a Linear error."""
    for radius in (True, "0.1", -0.1, float("nan")):
        with pytest.raises(ValueError, match="radii: a ball's radius must be a finite number > 0"):
            SetAbstraction(8, [radius], [4], 0, [[8]])
    with pytest.raises(ValueError, match="at least one scale"):
        SetAbstraction(8, [], [], 0, [])
    with pytest.raises(ValueError, match="a group-all level takes one MLP"):
        SetAbstraction(1, [], [], 0, [], group_all=True)
    for channels in (-1, 2.5):
        with pytest.raises(ValueError, match="SetAbstraction: in_channels must be an integer >= 0"):
            SetAbstraction(8, [0.3], [4], channels, [[8]])


def test_encoder_and_feature_propagation_name_inputs_of_the_wrong_shape():
    """Features of another width failed inside a Linear ("mat1 and mat2 shapes"), another N inside the gather or
    torch.cat; a shorter fps list or centres of another count ran silently (fewer levels, other centres)."""
    torch.manual_seed(0)
    enc = PointNet2Encoder(1, [8, 4], [[0.3], [0.5]], [[4], [4]], [[[8]], [[16]]])
    xyz, feat = torch.rand(2, 32, 3), torch.rand(2, 32, 1)
    for bad in (torch.rand(2, 32, 2), torch.rand(2, 30, 1), None):
        with pytest.raises(ValueError, match=r"PointNet2Encoder: feat must be \[2, 32, 1\] for xyz \[2, 32, 3\]"):
            enc(xyz, bad)
    with pytest.raises(ValueError, match=r"SetAbstraction: feat must be \[2, 32, 1\]"):
        enc.levels[0](xyz, torch.rand(2, 32, 3))
    fps = enc.sample(xyz, None)
    with pytest.raises(ValueError, match=r"PointNet2Encoder: fps needs one entry per level \(2\), got 1"):
        enc(xyz, feat, None, fps[:1])
    with pytest.raises(ValueError, match=r"PointNet2Encoder: srcs needs one entry per level \(2\), got 1"):
        enc(xyz, feat, None, fps, [None])
    with pytest.raises(ValueError, match=r"SetAbstraction: fps_idx must be \[2, 8\], got \[2, 5\]"):
        enc(xyz, feat, None, [fps[0][:, :5], fps[1]])
    fp = FeaturePropagation(5, [8])
    sparse, feat_sparse = xyz[:, :4], torch.rand(2, 4, 4)
    assert fp(xyz, sparse, torch.rand(2, 32, 1), feat_sparse).shape == (2, 32, 8)
    with pytest.raises(ValueError, match=r"FeaturePropagation: feat_dense must be \[2, 32, 1\]"):
        fp(xyz, sparse, torch.rand(2, 30, 1), feat_sparse)
    with pytest.raises(ValueError, match="must hold 5 channels together, got 2 \\+ 4"):
        fp(xyz, sparse, torch.rand(2, 32, 2), feat_sparse)
