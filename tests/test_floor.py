"""floaff_zoo.floor: the observed-floor-cell rule shared by the generator (format v2) and predict's defaults."""

import math
import subprocess
import sys

import numpy as np
import pytest

from floaff_zoo.floor import CANDIDATE_WINDOW, FLOOR_Z_MAX, FloorLattice, ground_mask, observed_cells


def test_target_window_is_the_annotation_grid():
    # annotate.candidate_grid: x° = j * cell (|x°| <= r_x), y° = i * cell (|y°| <= r_y), row-major (y°, x°);
    # world = target + x° * lateral - y° * normal, lateral = normal turned by +90 deg (sim.views target frame)
    t, yaw, cell = np.array([1.3, -0.4]), 0.7, 0.2
    lat = FloorLattice.target_window(t, yaw, cell, 1.0, 1.2)
    assert lat.shape == (13, 11)
    n = np.array([math.cos(yaw), math.sin(yaw)])
    side = np.array([-n[1], n[0]])
    ys, xs = np.arange(-6, 7) * cell, np.arange(-5, 6) * cell
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    grid = t + xx.reshape(-1, 1) * side - yy.reshape(-1, 1) * n
    assert np.allclose(lat.centers(), grid, atol=1e-12)
    idx, inside = lat.index_of(grid + 0.09 * np.array([0.6, -0.8]))  # any point of a cell maps to it
    assert inside.all() and np.array_equal(idx, np.arange(len(grid)))


def test_observed_cells_count_ground_points_only():
    lat = FloorLattice((0.0, 0.0), math.radians(37.0), 0.1, (3, 4))
    centres = lat.centers()
    rng = np.random.default_rng(0)

    def jitter(k):
        return rng.uniform(-0.045, 0.045, (k, 2)) @ np.array(  # inside the rotated square
            [[math.cos(lat.angle), math.sin(lat.angle)], [-math.sin(lat.angle), math.cos(lat.angle)]]
        )

    floor_cells, obstacle_cells, high_floor = [0, 5, 17, 40, 62], [1, 6, 30], [2]
    pts = [np.c_[centres[floor_cells] + jitter(5), rng.uniform(-0.01, 0.019, 5)]]
    pts.append(np.c_[centres[obstacle_cells] + jitter(3), np.full(3, 0.4)])  # furniture: not ground
    pts.append(np.c_[centres[high_floor] + jitter(1), [FLOOR_Z_MAX + 1e-3]])  # 2.1 cm: not ground
    pts.append(np.array([[5.0, 5.0, 0.0], [np.nan, 0.0, 0.0]]))  # outside the lattice; not finite
    pts.append(np.c_[centres[[17]] + jitter(1), [0.0]])  # a second point in cell 17
    xyz = np.concatenate(pts)
    seen = observed_cells(xyz, lat)
    assert seen.shape == (lat.shape[0] * lat.shape[1],) and seen.dtype == bool
    assert np.flatnonzero(seen).tolist() == floor_cells
    assert np.flatnonzero(observed_cells(xyz, lat, min_points=2)).tolist() == [17]
    assert ground_mask(xyz).sum() == 5 + 1 + 1  # the point outside the lattice is ground too
    assert observed_cells(xyz, lat, z_max=0.5)[obstacle_cells].all()
    assert not observed_cells(np.zeros((0, 3)), lat).any()
    with pytest.raises(ValueError, match="min_points"):
        observed_cells(xyz, lat, min_points=0)
    with pytest.raises(ValueError, match="cell"):
        FloorLattice((0.0, 0.0), 0.0, 0.0, (1, 1))


def test_disc_cut_and_default_window():
    lat = FloorLattice.around(np.zeros(2), 0.3, 0.2, 0.5)
    assert lat.shape == (5, 5) and lat.within(0.5).sum() == 21
    assert CANDIDATE_WINDOW == (1.0, 1.2)


def test_floor_module_is_numpy_only():
    code = "import sys, floaff_zoo.floor; assert 'torch' not in sys.modules, 'floaff_zoo.floor imported torch'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_footprint_blocked_sees_obstacles_inside_the_base_rectangle():
    from floaff_zoo.floor import FOOTPRINT, footprint_blocked

    length, width, front = FOOTPRINT
    # a base at the origin heading +x covers x in [front - length, front], |y| <= width / 2
    box = np.array([[front - 0.1, 0.0, 0.5], [front - 0.2, 0.1, 0.3]])  # two points of furniture inside
    assert footprint_blocked(box, (0.0, 0.0, 0.0))
    assert not footprint_blocked(box[:1], (0.0, 0.0, 0.0))  # one stray point is noise
    # ... also when a short cloud was padded to its sample size by repeating it (TargetCrop + resample collate)
    assert not footprint_blocked(np.repeat(box[:1], 3, axis=0), (0.0, 0.0, 0.0))
    assert footprint_blocked(
        box[:1] + [[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]], (0.0, 0.0, 0.0)
    )  # two points, one above the other
    assert not footprint_blocked(box + [0.0, 0.0, 1.0], (0.0, 0.0, 0.0))  # above the robot (z > 1.2 m)
    assert not footprint_blocked(box * [1, 1, 0], (0.0, 0.0, 0.0))  # floor points never block
    assert not footprint_blocked(box + [front + 0.05, 0.0, 0.0], (0.0, 0.0, 0.0))  # in front of the base
    # the rectangle turns with the heading: 0.4 m ahead of a base facing +x is inside one facing -x
    ahead = np.array([[0.4, 0.0, 0.5], [0.45, 0.05, 0.5]])
    assert not footprint_blocked(ahead, (0.0, 0.0, 0.0))
    assert footprint_blocked(ahead, (0.0, 0.0, math.pi))
    assert not footprint_blocked(ahead, (0.0, 0.0, math.pi / 2))  # 0.4 m beside a base facing +y
    assert not footprint_blocked(np.full((3, 3), np.nan), (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"\[N, 3\], got \[4, 2\]"):
        footprint_blocked(np.zeros((4, 2)), (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="min_points"):
        footprint_blocked(box, (0.0, 0.0, 0.0), min_points=0)


def test_footprint_coverage_is_the_share_of_the_footprint_the_cloud_shows():
    from floaff_zoo.floor import FOOTPRINT, footprint_coverage

    length, width, front = FOOTPRINT  # 0.63 x 0.5 m: 7 x 5 sub-squares of 0.1 m
    pose = (0.0, 0.0, 0.0)
    assert footprint_coverage(np.zeros((0, 3)), pose) == 0.0
    # one floor point at the centre of every sub-square: fully seen; points outside the rectangle add nothing
    a = front - length + 0.1 * (np.arange(7) + 0.5)
    a[-1] = front - 0.01  # the last sub-square is 0.03 m deep
    b = -width / 2 + 0.1 * (np.arange(5) + 0.5)
    grid = np.array([[x, y, 0.0] for x in a for y in b])
    assert footprint_coverage(grid, pose) == pytest.approx(1.0)
    outside = grid + [length + 0.2, 0.0, 0.0]
    assert footprint_coverage(np.concatenate([grid[:7], outside]), pose) == pytest.approx(7 / 35)
    # two points in one sub-square count once; obstacle points count as seen too; NaN points are ignored
    assert footprint_coverage(np.array([[a[0], b[0], 0.0], [a[0], b[0] + 0.01, 0.7], [np.nan, 0, 0]]), pose) == (
        pytest.approx(1 / 35)
    )
    # the rectangle turns with the heading: the grid seen from a base facing -x is behind it, out of the footprint
    assert footprint_coverage(grid, (0.0, 0.0, math.pi)) < 0.3
    with pytest.raises(ValueError, match=r"\[N, 3\], got \[4, 2\]"):
        footprint_coverage(np.zeros((4, 2)), pose)
    with pytest.raises(ValueError, match="cell"):
        footprint_coverage(grid, pose, cell=0.0)


def test_footprint_counts_agree_with_footprint_blocked():
    """The batched torch count behind CFAR's occupancy input calls blocked exactly what the callback's check does."""
    import torch

    from floaff_zoo.contract import best_pose
    from floaff_zoo.floor import footprint_blocked
    from floaff_zoo.nn.placement import footprint_counts

    rng = np.random.default_rng(0)
    b, n, m = 3, 400, 60
    xyz = rng.uniform([-1.5, -1.5, -0.05], [1.5, 1.5, 1.5], size=(b, n, 3))
    xyz[1, :5] = np.nan  # invalid points never count
    mask = rng.random((b, n)) > 0.2
    floor = np.concatenate([rng.uniform(-1.2, 1.2, size=(b, m, 2)), np.zeros((b, m, 1))], axis=-1)
    target = rng.uniform(-0.3, 0.3, size=(b, 3))
    counts = footprint_counts(
        torch.tensor(xyz), torch.tensor(mask), torch.tensor(floor[..., :2]), torch.tensor(target[:, :2]), chunk=7
    )
    assert counts.shape == (b, m)
    blocked = 0
    for i in range(b):
        poses = best_pose(floor[i], -np.arange(m, dtype=float), None, target[i], k=m)  # floor points in order
        for j, pose in enumerate(poses):
            for k in (1, 2, 5):
                assert bool(counts[i, j] >= k) == footprint_blocked(xyz[i][mask[i]], pose, min_points=k), (i, j, k)
            blocked += int(counts[i, j] >= 2)
    assert 0 < blocked < b * m  # both outcomes occur: the comparison can fail
    # shapes are checked, naming the argument
    t = [torch.tensor(xyz), torch.tensor(mask), torch.tensor(floor[..., :2]), torch.tensor(target[:, :2])]
    for i, (name, bad) in enumerate(
        [("xyz", t[0][..., :2]), ("mask", t[1][:, :-1]), ("floor_xy", t[2][:2]), ("target_xy", t[3][:, :1])]
    ):
        args = list(t)
        args[i] = bad
        with pytest.raises(ValueError, match=f"{name} must be"):
            footprint_counts(*args)


def test_footprint_seen_agrees_with_footprint_coverage():
    """The batched torch share behind CFAR's coverage input equals the numpy one, chunk by chunk."""
    import torch

    from floaff_zoo.contract import best_pose
    from floaff_zoo.floor import footprint_coverage
    from floaff_zoo.nn.placement import footprint_seen

    rng = np.random.default_rng(1)
    b, n, m = 3, 300, 50
    xyz = rng.uniform([-1.5, -1.5, -0.05], [1.5, 1.5, 1.5], size=(b, n, 3))
    xyz[2, :4] = np.nan  # invalid points are not seen
    mask = rng.random((b, n)) > 0.3
    floor = np.concatenate([rng.uniform(-1.2, 1.2, size=(b, m, 2)), np.zeros((b, m, 1))], axis=-1)
    target = rng.uniform(-0.3, 0.3, size=(b, 3))
    t = [torch.tensor(xyz), torch.tensor(mask), torch.tensor(floor[..., :2]), torch.tensor(target[:, :2])]
    seen = footprint_seen(*t, chunk=7)
    assert seen.shape == (b, m)
    for i in range(b):
        poses = best_pose(floor[i], -np.arange(m, dtype=float), None, target[i], k=m)  # floor points in order
        ref = [footprint_coverage(xyz[i][mask[i]], pose) for pose in poses]
        assert np.allclose(seen[i].numpy(), ref)
    assert 0 < float(seen.min()) < float(seen.max()) <= 1  # shares differ: the comparison can fail
    with pytest.raises(ValueError, match="mask must be"):
        footprint_seen(t[0], t[1][:, :-1], t[2], t[3])
    with pytest.raises(ValueError, match="cell"):
        footprint_seen(*t, cell=float("nan"))


def test_grown_footprint_adds_the_margin_on_every_side():
    from floaff_zoo.floor import FOOTPRINT, grown_footprint

    length, width, front = FOOTPRINT
    assert grown_footprint(0.0) == FOOTPRINT
    grown = grown_footprint(0.05)
    assert grown == pytest.approx((length + 0.1, width + 0.1, front + 0.05))
    assert grown[2] - grown[0] == pytest.approx(front - length - 0.05)  # the back edge moves back by the margin
    for bad in (-0.1, float("nan"), float("inf"), "0.1", True):  # a text was a TypeError naming nothing
        with pytest.raises(ValueError, match="grown_footprint: margin must be a finite number >= 0"):
            grown_footprint(bad)
    with pytest.raises(ValueError, match="grown_footprint: footprint length must be"):
        grown_footprint(0.1, (float("nan"), 0.5, 0.3))  # a NaN base grew into a NaN one


def test_floor_queries_refuse_clouds_that_are_not_n_by_3_and_poses_that_are_not_finite():
    """observed_cells / ground_mask reshaped any array to [-1, 3]: a [3, N] or [N, 2] cloud gave other cells without a
    word; a NaN pose put no point inside the footprint, so footprint_blocked called it free."""
    from floaff_zoo.floor import footprint_blocked, footprint_coverage

    rng = np.random.default_rng(0)
    xyz = np.c_[rng.uniform(-1, 1, (300, 2)), np.zeros(300)]
    lat = FloorLattice.around(np.zeros(2), 0.0, 0.2, 1.0)
    assert observed_cells(xyz, lat).sum() > 0
    for bad in (xyz.T, xyz[:, :2], xyz.ravel()):
        with pytest.raises(ValueError, match=r"observed_cells: xyz must be \[N, 3\]"):
            observed_cells(bad, lat)
        with pytest.raises(ValueError, match=r"ground_mask: xyz must be \[N, 3\]"):
            ground_mask(bad)
    from floaff_zoo.predict import default_floor_grid  # its observed cells come from observed_cells

    with pytest.raises(ValueError, match=r"observed_cells: xyz must be \[N, 3\]"):
        default_floor_grid(np.array([0.5, 0.0, 0.8]), xyz.T)
    box = np.array([[0.0, 0.0, 0.3], [0.1, 0.1, 0.3], [-0.2, 0.1, 0.5]])
    assert footprint_blocked(box, (0.0, 0.0, 0.0))
    bad_poses = ((float("nan"), 0.0, 0.0), (0.0, 0.0), (0.0, 0.0, float("inf")), ("x", 0.0, 0.0), [[0.0], 1.0, 2.0])
    for pose in (*bad_poses, (True, 0.0, 0.0), np.array([False, True, False])):  # bools were read as 1 m and 0 m
        with pytest.raises(ValueError, match=r"footprint_blocked: pose must be 3 finite values"):
            footprint_blocked(box, pose)
        with pytest.raises(ValueError, match=r"footprint_coverage: pose must be 3 finite values"):
            footprint_coverage(box, pose)
    # a NaN or negative size, or an empty or NaN height range, put no point inside: every pose was free
    nan = float("nan")
    for footprint, said in (((nan, 0.5, 0.3), "footprint length must be"), ((0.8, -0.5, 0.3), "footprint width must"),
                            ((0.8, 0.5), r"footprint must be \(length, width, front\)")):  # fmt: skip
        with pytest.raises(ValueError, match=f"footprint_blocked: {said}"):
            footprint_blocked(box, (0.0, 0.0, 0.0), footprint=footprint)
        with pytest.raises(ValueError, match=f"footprint_coverage: {said}"):
            footprint_coverage(box, (0.0, 0.0, 0.0), footprint=footprint)
    for z_range, said in (((nan, 1.2), "z_range low must be"), ((1.2, 0.02), "z_range must have low < high")):
        with pytest.raises(ValueError, match=f"footprint_blocked: {said}"):
            footprint_blocked(box, (0.0, 0.0, 0.0), z_range=z_range)
    with pytest.raises(ValueError, match="footprint_blocked: min_points must be an integer >= 1, got 1.5"):
        footprint_blocked(box, (0.0, 0.0, 0.0), min_points=1.5)  # a float count was compared as it was


def test_a_lattice_refuses_a_half_size_that_is_no_integer_and_a_centre_that_is_not_two_values():
    """FloorLattice took half (1.5, 2) as a lattice of 4.0 rows whose centres sat half a cell off its centre, and a
    centre of one value as (c, c), both without a word."""
    assert FloorLattice((0.5, -0.2), 0.3, 0.1, (np.int64(1), 2)).shape == (3, 5)  # numpy ints are integers
    for half in ((1.5, 2), (1.0, 2.0), (1, 2, 3), 2):
        with pytest.raises(ValueError, match=r"FloorLattice: half must be two integers \(ny, nx\)"):
            FloorLattice((0.0, 0.0), 0.0, 0.1, half)
    for centre in ((0.5,), (0.5, 0.0, 0.8), np.zeros((1, 2))):
        with pytest.raises(ValueError, match=r"FloorLattice: centre must be two values \(x, y\)"):
            FloorLattice(centre, 0.0, 0.1, (1, 2))
    with pytest.raises(ValueError, match=r"half sizes \(ny, nx\) must be >= 0"):
        FloorLattice((0.0, 0.0), 0.0, 0.1, (-1, 2))


def test_footprint_occupancy_rescales_counts_to_the_reference_cloud_size():
    """Counts are expressed for OCCUPANCY_REF_POINTS = 1024 valid points; the flag is rescaled count >= 2."""
    import torch

    from floaff_zoo.nn.placement import footprint_occupancy

    xyz = torch.zeros(3, 1024, 3)
    xyz[:, :, 0] = 5.0  # out of every footprint
    xyz[:, 0] = torch.tensor([0.0, 0.0, 0.5])  # one obstacle point on the base parked at the origin
    mask = torch.zeros(3, 1024, dtype=torch.bool)
    mask[0, :512] = True  # 512 valid points: 1 point counts as 2
    mask[1] = True  # 1024 valid points: 1 point is 1, under the flag's 2
    floor = torch.zeros(3, 1, 3)
    target = torch.tensor([[1.0, 0.0, 0.5]]).expand(3, 3)  # the base faces +x; sample 2 has no valid point
    occ = footprint_occupancy(xyz, mask, floor, target)
    expected = [[math.log1p(2.0), 1.0], [math.log1p(1.0), 0.0], [0.0, 0.0]]
    assert torch.allclose(occ[:, 0], torch.tensor(expected))
