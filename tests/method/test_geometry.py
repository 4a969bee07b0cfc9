"""Hand-computed cases for the method's geometry that the shape and round-trip tests leave free: the crop boundary
and its per-sample fallback, the sign of the extra alignment angle, AxisNet's (sin, cos) convention, the label turn
of its rotation augmentation, and the N2M footprint."""

import math

import torch

from floaff_zoo.models.axisnet import AxisNetModule
from floaff_zoo.nn.axisnet import yaw_from_vector, yaw_to_vector
from floaff_zoo.nn.cfar import canonical_transform, crop_mask
from floaff_zoo.nn.placement import footprint_collides, occupied_cells


def test_crop_keeps_a_point_on_the_sphere_and_grows_only_the_empty_samples_radius():
    """||p - t|| <= r (paper): a point at exactly r stays. The fallback grows the radius of the sample without a
    point only: a sample's crop must not depend on the other samples of its batch."""
    xyz = torch.tensor(
        [
            [[1.25, 0.0, 0.0], [0.75, 1.0, 0.0], [1.4, 0.0, 0.0]],  # two points at exactly 1.25 m, one beyond
            [[1.4, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, 0.0]],  # nothing within 1.25 m: grows to 1.5625 m
        ]
    )
    mask = torch.ones(2, 3, dtype=torch.bool)
    keep, used = crop_mask(xyz, mask, torch.zeros(2, 3), 1.25)
    assert keep.tolist() == [[True, True, False], [True, False, False]]
    assert used.tolist() == [1.25, 1.25 * 1.25]


def test_the_extra_angle_turns_the_canonical_frame_counter_clockwise():
    """``extra_angle`` adds to the alignment: +90 deg about the target takes the front point from -y to +x."""
    t = torch.tensor([[1.0, 2.0, 0.5]])
    pts = t[:, None] + torch.tensor([[[1.0, 0.0, 0.0]]])  # 1 m in front of a target whose front yaw is 0
    mask = torch.ones(1, 1, dtype=torch.bool)
    canon = canonical_transform(pts, mask, pts, t, torch.zeros(1), 2.0, extra_angle=torch.tensor([math.pi / 2]))
    assert torch.allclose(canon.xyz[0, 0], torch.tensor([1.0, 0.0, 0.0]), atol=1e-6)
    assert torch.allclose(canon.floor_xyz[0, 0], torch.tensor([1.0, 0.0, 0.0]), atol=1e-6)


def test_yaw_vector_is_sin_then_cos():
    """q_o = (sin, cos) (paper): the shipped AxisNet weights were trained on it, so a round trip is not enough."""
    yaw = torch.tensor([0.0, math.pi / 2, math.pi, -math.pi / 2])
    want = torch.tensor([[0.0, 1.0], [1.0, 0.0], [0.0, -1.0], [-1.0, 0.0]])
    assert torch.allclose(yaw_to_vector(yaw), want, atol=1e-6)
    assert torch.allclose(yaw_from_vector(want), torch.tensor([0.0, math.pi / 2, math.pi, -math.pi / 2]), atol=1e-6)


def test_rotation_augmentation_turns_the_label_with_the_points():
    """After the augmentation the point 1 m along the front normal still lies along the (turned) label yaw."""
    torch.manual_seed(0)
    yaw = torch.tensor([0.3, -2.0, 2.8, 1.0])
    t = torch.tensor([[1.0, 0.5, 0.8], [2.0, -1.0, 0.9], [0.0, 0.0, 1.0], [-1.0, 2.0, 0.7]])
    normal = torch.stack([torch.cos(yaw), torch.sin(yaw), torch.zeros(4)], -1)
    xyz = torch.stack([t + normal, t], 1)  # [4, 2, 3]: the front point, the target
    batch = {"scene_xyz": xyz, "target_xyz": t, "target_yaw": yaw[:, None]}
    out = AxisNetModule(widths=[8], head=[8], rot_aug_deg=90.0, jitter_sigma=0.0).augment(batch)
    turned = out["target_yaw"].reshape(-1)
    assert (turned - yaw).abs().max() > 0.3  # the augmentation did turn (the check below can fail)
    want = t + torch.stack([torch.cos(turned), torch.sin(turned), torch.zeros(4)], -1)
    assert torch.allclose(out["scene_xyz"][:, 0], want, atol=1e-5)
    assert torch.allclose(out["scene_xyz"][:, 1], t, atol=1e-6)  # turned about the target


def test_footprint_collides_on_hand_cases():
    """Footprint 0.63 x 0.5 m, 83 % of its length behind the base: 0.523 m behind, 0.107 m ahead, 0.25 m aside."""
    cells = torch.tensor([[0.1, 0.0], [0.2, 0.0], [-0.5, 0.0], [-0.6, 0.0], [0.0, 0.24], [0.0, 0.26]])
    hit = [footprint_collides(c[None], torch.tensor([[0.0, 0.0, 0.0]])).item() for c in cells]
    assert hit == [True, False, True, False, True, False]
    # a base at (1, 2) facing +y: ahead is +y, behind -y, aside x
    cells = torch.tensor([[1.0, 2.1], [1.0, 2.2], [1.0, 1.5], [1.0, 1.45], [0.8, 2.0], [1.3, 2.0]])
    hit = [footprint_collides(c[None], torch.tensor([[1.0, 2.0, math.pi / 2]])).item() for c in cells]
    assert hit == [True, False, True, False, True, False]


def test_occupied_cells_are_cell_centres_above_the_floor():
    xyz = torch.tensor([[0.031, -0.011, 0.3], [0.035, -0.019, 0.4], [0.5, 0.5, 0.25], [0.9, 0.9, 0.1]])
    cells = occupied_cells(xyz, cell=0.02, z_min=0.25)  # the point at z_min is floor
    assert torch.allclose(cells, torch.tensor([[0.03, -0.01]]))


def test_the_prior_reads_the_floor_in_cfars_canonical_frame():
    """The canonical prior centres and turns the floor itself: it must be CFAR's frame, or the residual adds the
    prior of other cells."""
    from floaff_zoo.contract import collate_samples
    from floaff_zoo.data.synthetic import make_synthetic_sample
    from floaff_zoo.models.prior import CanonicalPriorModule

    b = collate_samples([make_synthetic_sample(i, 64, 4) for i in range(2)], 64)
    xy, yaw = CanonicalPriorModule(yaw_source="gt").canonical_floor(b, "gt")
    canon = canonical_transform(b["scene_xyz"], b["scene_mask"], b["floor_xyz"], b["target_xyz"], yaw, None)
    assert torch.allclose(xy, canon.floor_xyz[..., :2], atol=1e-6)
