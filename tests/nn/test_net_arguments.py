"""The baselines' networks (``floaff_zoo.nn.nets``) refuse bad sizes by name when built from Python."""

from __future__ import annotations

import pytest

from floaff_zoo.nn.nets import GMM, CrossAttention, PointNet2Net

SIZES = dict(
    feat_channels=1,
    robot_dim=2,
    npoints=[8, 4],
    radii=[[0.3], [0.5]],
    nsamples=[[4], [4]],
    mlps=[[[8]], [[16]]],
    fp_mlps=[[8], [8]],
)


@pytest.mark.parametrize("variant", ["SSG", "pointnet"])
def test_pointnet2_net_refuses_an_unknown_variant(variant):
    """Anything but "ssg" silently took the MSG channel order."""
    with pytest.raises(ValueError, match=f"PointNet2Net: variant must be 'ssg' or 'msg', got '{variant}'"):
        PointNet2Net(variant, **SIZES)


@pytest.mark.parametrize("value", [2.5, True, float("nan"), "1", -1])
def test_pointnet2_net_floor_feat_channels_must_be_a_whole_number(value):
    """int() cut 2.5 to 2 and read True as 1; NaN and a text failed in a comparison naming no argument."""
    with pytest.raises(ValueError, match="PointNet2Net: floor_feat_channels must be an integer >= 0"):
        PointNet2Net("ssg", **SIZES, floor_feat_channels=value)


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: GMM(4, 0), "GMM: num_components must be an integer >= 1, got 0"),
        (lambda: GMM(4, 2, 0), "GMM: dim must be an integer >= 1, got 0"),
        (lambda: CrossAttention(0, 1), "CrossAttention: dim must be an integer >= 1, got 0"),
        (lambda: CrossAttention(2.5, 1), "CrossAttention: dim must be an integer >= 1, got 2.5"),
    ],
)
def test_heads_refuse_sizes_by_name(build, message):
    """0 components built an empty head that failed in a reshape at the first batch; a dim of 0 a
    ZeroDivisionError, 2.5 a "not divisible by num_heads" message."""
    with pytest.raises(ValueError, match=message):
        build()


def test_layer_widths_and_encoder_channels_are_whole_numbers():
    """A fractional or negative width failed inside nn.Linear naming nothing; a negative encoder input built a
    narrower first level. A width of 0 reaches the model's check, which names the model and the layer."""
    from floaff_zoo.models.cfar import CFARModule
    from floaff_zoo.nn.cfar import plain_mlp
    from floaff_zoo.nn.pointnet2 import PointNet2Encoder

    with pytest.raises(ValueError, match="plain_mlp: widths: a layer's width must be an integer >= 0, got 2.5"):
        plain_mlp(4, [8, 2.5])
    with pytest.raises(ValueError, match="mlp: sizes: a layer's width must be an integer >= 0, got -1"):
        PointNet2Net("ssg", **{**SIZES, "robot_width": -1})
    with pytest.raises(ValueError, match=r"CFARModule: layer net\.head\.linears\.0 \(Linear\) has out_features 0"):
        CFARModule(head=[0])  # robot_width and the other single widths are each checked by name first
    assert len(plain_mlp(4, [])) == 0  # an empty list stays the identity
    with pytest.raises(ValueError, match="PointNet2Encoder: in_channels must be an integer >= 0, got -1"):
        PointNet2Encoder(-1, [8], [[0.3]], [[4]], [[[8]]], xyz_as_feat=True)
