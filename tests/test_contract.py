import math

import numpy as np
import pytest
import torch

from floaff_zoo.contract import (
    FloorGrid,
    SampleError,
    batch_item,
    best_pose,
    check_batch,
    collate_samples,
    validate_sample,
)
from floaff_zoo.data.synthetic import make_synthetic_sample


def _sample(n=10, m=6, **over):
    s = {
        "scene_xyz": np.random.rand(n, 3).astype(np.float32),
        "scene_feat": np.zeros((n, 1), np.float32),
        "floor_xyz": np.random.rand(m, 3).astype(np.float32),
        "floor_label": np.random.rand(m).astype(np.float32),
        "robot": np.array([0.85, 1.03], np.float32),
        "target_xyz": np.zeros(3, np.float32),
        "target_yaw": 0.0,
        "meta": {"sample_id": "s1", "dataset": "unit"},
    }
    s.update(over)
    return s


def test_validate_fills_masks_and_types():
    s = validate_sample(_sample())
    assert s["scene_mask"].dtype == torch.bool and s["scene_mask"].all()
    assert s["floor_label"].dtype == torch.float32 and s["target_yaw"].shape == ()


@pytest.mark.parametrize(
    "over, field",
    [
        ({"floor_label": np.zeros(5, np.float32)}, "floor_label has 5 values but floor_xyz has 6"),
        ({"scene_xyz": np.full((10, 3), np.nan, np.float32)}, "scene_xyz contains"),
        ({"scene_xyz": np.zeros((10, 2), np.float32)}, "scene_xyz must be [N, 3]"),
        ({"floor_label": np.full(6, 2.0, np.float32)}, "floor_label must lie in [0, 1]"),
    ],
)
def test_validate_names_field_and_sample(over, field):
    with pytest.raises(SampleError) as err:
        validate_sample(_sample(**over))
    assert field in str(err.value) and "s1" in str(err.value)


def test_missing_field_is_named():
    s = _sample()
    del s["robot"]
    with pytest.raises(SampleError, match="robot"):
        validate_sample(s)


def test_collate_pad_and_resample():
    a, b = validate_sample(_sample(10, 6)), validate_sample(_sample(4, 3))
    batch = collate_samples([a, b], mode="pad")
    assert batch["scene_xyz"].shape == (2, 10, 3) and batch["floor_xyz"].shape == (2, 6, 3)
    assert batch["scene_mask"][1].sum() == 4 and batch["floor_mask"][1].sum() == 3
    assert torch.equal(batch["floor_label"][1, :3], b["floor_label"])
    assert (batch["floor_label"][1, 3:] == 0).all()
    res = collate_samples([a, b], num_points=8, mode="resample", generator=torch.Generator().manual_seed(0))
    assert res["scene_mask"].all() and res["scene_xyz"].shape == (2, 8, 3)
    # resampled points are real points of the sample
    pts = {tuple(p) for p in b["scene_xyz"].tolist()}
    assert all(tuple(p) in pts for p in res["scene_xyz"][1].tolist())
    with pytest.raises(SampleError, match="empty batch"):
        collate_samples([])


def test_floor_grid_round_trip():
    s = make_synthetic_sample(3, floor_cells=8)
    xy = np.stack(np.meshgrid(np.arange(5) * 0.05, np.arange(4) * 0.05), -1).reshape(-1, 2) + 1.0
    grid = FloorGrid.from_points(xy, cell=0.05)
    assert grid.shape == (4, 5)
    vals = np.arange(len(xy), dtype=float)
    raster = grid.rasterize(xy, vals)
    assert np.allclose(grid.sample(raster, xy), vals)
    assert np.isnan(grid.sample(raster, np.array([[10.0, 10.0]]))).all()
    assert s["floor_xyz"].shape[0] == 64


def test_best_pose_tie_break_and_heading():
    floor = torch.tensor([[1.0, 0, 0], [2.0, 0, 0], [0.5, 0.5, 0]])
    target = torch.tensor([3.0, 0, 0.9])
    # "nearest": a constant map picks the point closest to the target
    ((x, y, yaw),) = best_pose(floor, torch.zeros(3), None, target, tie_break="nearest")
    assert (x, y) == (2.0, 0.0) and abs(yaw) < 1e-9
    poses = best_pose(floor, torch.tensor([0.1, 0.2, 0.9]), torch.tensor([True, True, False]), target, k=2)
    assert poses[0][:2] == (2.0, 0.0) and poses[1][:2] == (1.0, 0.0)
    ((x, y, yaw),) = best_pose(floor, torch.tensor([0.0, 0.0, 1.0]), None, target)
    assert math.isclose(yaw, math.atan2(-0.5, 2.5))


def test_best_pose_tie_break_does_not_depend_on_the_batch_padding():
    """The permutation was drawn over the padded length, so a tied map chose another cell when a larger view shared
    its batch (SR changed with eval_batch_size and between DDP and one process)."""
    floor = torch.tensor([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    padded = torch.cat([floor, torch.zeros(5, 3)])
    mask = torch.arange(8) < 3
    target = torch.zeros(3)
    for s in range(20):
        alone = best_pose(floor, torch.ones(3), None, target, k=3, seed=s)
        assert best_pose(padded, torch.ones(8), mask, target, k=3, seed=s) == alone


def test_best_pose_random_tie_break_is_seeded_and_uniform():
    floor = torch.stack([torch.arange(10.0), torch.zeros(10), torch.zeros(10)], 1)
    target = torch.tensor([20.0, 0, 0])
    flat = torch.zeros(10)
    picks = [best_pose(floor, flat, None, target, seed=s)[0][0] for s in range(400)]
    assert picks[:20] == [best_pose(floor, flat, None, target, seed=s)[0][0] for s in range(20)]
    counts = np.bincount(np.asarray(picks, dtype=int), minlength=10)
    assert counts.min() > 15 and counts.max() < 70  # roughly uniform (expected 40 each)
    # a strict maximum always wins, whatever the seed
    assert all(best_pose(floor, torch.eye(10)[3], None, target, seed=s)[0][0] == 3.0 for s in range(20))


@pytest.mark.parametrize(
    "change, message",
    [
        # fewer scores than points ranked only the first points; more failed as an index naming nothing
        ({"scores": torch.tensor([0.1, 0.9])}, "scores has 2 entries for 3 floor points"),
        ({"scores": torch.rand(5)}, "scores has 5 entries for 3 floor points"),
        ({"mask": torch.tensor([True, False])}, "mask has 2 entries for 3 floor points"),
        ({"target_xyz": torch.tensor([float("nan"), 0.0, 0.0])}, "target_xyz must be 3 finite values"),  # NaN yaw
        ({"target_xyz": torch.zeros(2)}, "target_xyz must be 3 finite values"),
        ({"floor_xyz": torch.tensor([[1.0, 0, 0], [float("nan"), 0, 0], [3.0, 0, 0]])}, "floor_xyz holds NaN"),
        ({"floor_xyz": torch.ones(3)}, r"floor_xyz must be \[M, 3\]"),
        # k 0 returned no pose, -1 all but the last, 2.5 failed as a slice
        ({"k": 0}, "k must be an integer >= 1, got 0"),
        ({"k": -1}, "k must be an integer >= 1, got -1"),
        ({"k": 2.5}, "k must be an integer >= 1, got 2.5"),
        ({"seed": -1}, "seed must be an integer >= 0, got -1"),
    ],
)
def test_best_pose_refuses_bad_input_naming_it(change, message):
    args = {
        "floor_xyz": torch.tensor([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]]),
        "scores": torch.tensor([0.1, 0.9, 0.5]),
        "mask": None,
        "target_xyz": torch.zeros(3),
    }
    with pytest.raises(ValueError, match=f"best_pose: {message}"):
        best_pose(**{**args, **change})


def test_full_cloud_is_checked_and_padded_never_resampled():
    """The optional stored cloud: validated (shape, NaN named), zero-padded to the batch's largest with full_mask,
    kept whole when the scene points are resampled; a batch where only some samples have one is refused."""
    a = validate_sample(_sample(10, 6, full_xyz=np.random.rand(40, 3).astype(np.float32)))
    b = validate_sample(_sample(4, 3, full_xyz=np.random.rand(25, 3).astype(np.float32)))
    batch = collate_samples([a, b], num_points=8, mode="resample", generator=torch.Generator().manual_seed(0))
    assert batch["scene_xyz"].shape == (2, 8, 3) and batch["full_xyz"].shape == (2, 40, 3)
    assert batch["full_mask"].sum(1).tolist() == [40, 25]
    assert torch.equal(batch["full_xyz"][1, :25], b["full_xyz"]) and (batch["full_xyz"][1, 25:] == 0).all()
    assert "full_xyz" not in collate_samples([validate_sample(_sample())])
    with pytest.raises(SampleError, match="full_xyz is in some samples.*s1"):
        collate_samples([a, validate_sample(_sample())])
    for bad, msg in (
        (np.zeros((5, 2), np.float32), r"full_xyz must be \[K >= 1, 3\]"),
        (np.full((5, 3), np.nan), "NaN"),
    ):
        with pytest.raises(SampleError, match=msg) as err:
            validate_sample(_sample(full_xyz=bad))
        assert "s1" in str(err.value)


def test_pad_truncation_warns_once(monkeypatch):
    """collate_mode 'pad' with num_points below a cloud's size kept its first points without a word: on a cloud in
    image-row order (the generated views) that drops the near rows, the target among them."""
    import warnings

    import floaff_zoo.contract as contract
    from floaff_zoo.data.synthetic import make_synthetic_sample

    monkeypatch.setattr(contract, "_TRUNCATION_WARNED", False)
    samples = [make_synthetic_sample(0, num_points=256), make_synthetic_sample(1, num_points=256)]
    with pytest.warns(UserWarning, match="keeps the first 100 of 256 valid points"):
        contract.collate_samples(samples, num_points=100, mode="pad")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        contract.collate_samples(samples, num_points=100, mode="pad")  # once per process
        contract.collate_samples(samples, num_points=256, mode="pad")  # no truncation, no warning


def test_a_sample_with_no_valid_scene_point_is_named():
    """A mask with every point padding: TinyPointNet scored the sample from nothing, CFAR blamed its crop radius and
    resampling failed naming no sample."""
    for name in ("scene_mask", "floor_mask"):
        s = _sample(m=6)
        s[name] = np.zeros(len(s[name.replace("mask", "xyz")]), bool)
        with pytest.raises(SampleError, match=f"{name} marks no point valid"):
            validate_sample(s)
    batch = collate_samples([validate_sample(_sample(m=6)), validate_sample(_sample(m=4))], mode="pad")
    batch["scene_mask"][1] = False
    with pytest.raises(SampleError, match=r"1 sample\(s\) in the batch have no valid scene point"):
        check_batch(batch)


def test_fields_of_more_than_one_axis_are_not_flattened():
    """A [M, 2] label matched a floor of 2M points, a [2, 5] mask 10 points and a [2, 2] robot became 4 values;
    [M, 1] and [1, M] stay vectors."""
    m = 6
    assert validate_sample(_sample(m=m, floor_label=np.zeros((m, 1), np.float32)))["floor_label"].shape == (m,)
    assert validate_sample(_sample(robot=np.ones((1, 2), np.float32)))["robot"].shape == (2,)
    for name, value in (
        ("floor_label", np.zeros((6, 2), np.float32)),
        ("scene_mask", np.ones((2, 5), bool)),
        ("robot", np.ones((2, 2), np.float32)),
    ):
        kw = {"floor_xyz": np.random.rand(12, 3).astype(np.float32)} if name == "floor_label" else {}
        with pytest.raises(SampleError, match=f"{name} must be a vector, got \\[{value.shape[0]}, {value.shape[1]}\\]"):
            validate_sample(_sample(**kw, **{name: value}))


def test_a_sample_or_meta_that_is_no_dict_is_named():
    """A list meta failed in dict() with a TypeError naming no sample; a list sample on .get."""
    with pytest.raises(SampleError, match="sample: meta must be a dict \\(or absent\\), got list"):
        validate_sample(_sample(meta=[("sample_id", "s1")]))
    with pytest.raises(SampleError, match="a sample must be a dict of the contract's fields, got list"):
        validate_sample([1, 2])  # type: ignore[arg-type]
    assert validate_sample(_sample(meta=None))["meta"] == {}


def test_batch_item_refuses_an_index_outside_the_batch():
    batch = collate_samples([validate_sample(_sample()), validate_sample(_sample())])
    assert batch_item(batch, 1)["scene_xyz"].shape == (1, 10, 3)
    for i in (-1, 2, 1.5):  # -1 gave empty tensors beside the last sample's meta
        with pytest.raises(ValueError, match=f"batch_item: i must be an integer >= 0 and <= 1, got {i}"):
            batch_item(batch, i)


def test_check_batch_names_a_non_finite_label_on_a_valid_floor_point():
    """A batch built by hand or by a user's data module: a NaN label made the loss NaN, and the rank term dropped
    its sample without a word (NaN > 0 is False). Padding may hold anything."""
    batch = collate_samples([validate_sample(_sample(m=6)), validate_sample(_sample(m=4))], mode="pad")
    check_batch(batch)
    batch["floor_label"][1, 4] = float("nan")  # padding of the shorter sample
    check_batch(batch)
    batch["floor_label"][1, 0] = float("inf")
    with pytest.raises(SampleError, match=r"floor_label holds NaN/Inf values in 1 sample"):
        check_batch(batch)


def test_check_batch_names_a_label_outside_0_1_on_a_valid_floor_point():
    """validate_sample refuses such a label; a user's collate does not pass through it, and a label of 5 trained
    every model silently. Padding may hold anything."""
    batch = collate_samples([validate_sample(_sample(m=6)), validate_sample(_sample(m=4))], mode="pad")
    batch["floor_label"][1, 5] = 5.0  # padding of the shorter sample
    check_batch(batch)
    batch["floor_label"][0, 2] = -0.5
    with pytest.raises(SampleError, match=r"floor_label holds values outside \[0, 1\] in 1 sample"):
        check_batch(batch)


def test_check_batch_names_a_non_finite_target_yaw():
    """H3DNet's target primitives, CFAR's `gt` yaw and AxisNet's loss read it; a NaN made maps and losses NaN."""
    batch = collate_samples([validate_sample(_sample()), validate_sample(_sample())])
    batch["target_yaw"][0] = float("nan")
    with pytest.raises(SampleError, match=r"target_yaw holds NaN/Inf values in 1 sample"):
        check_batch(batch)


def test_best_pose_ties_are_scores_equal_to_six_decimals():
    """1e-8 apart is a tie (the tie-break decides), 2e-6 apart is not (the higher score wins whatever the seed)."""
    floor = torch.tensor([[1.0, 0, 0], [2.0, 0, 0]])
    target = torch.zeros(3)  # the first point is the nearer one
    tied = torch.tensor([0.5, 0.50000001], dtype=torch.float64)
    assert best_pose(floor, tied, None, target, tie_break="nearest")[0][:2] == (1.0, 0.0)
    apart = torch.tensor([0.5, 0.500002], dtype=torch.float64)
    for tie_break in ("nearest", "random"):
        for seed in range(5):
            assert best_pose(floor, apart, None, target, tie_break=tie_break, seed=seed)[0][:2] == (2.0, 0.0)


def test_best_pose_nearest_is_the_planar_distance_then_the_lower_index():
    target = torch.tensor([0.0, 0.0, 0.9])
    # x offsets 0.5 and 1, planar distances 2.06 and 1
    floor = torch.tensor([[0.5, 2.0, 0.0], [1.0, 0.0, 0.0]])
    assert best_pose(floor, torch.zeros(2), None, target, tie_break="nearest")[0][:2] == (1.0, 0.0)
    ring = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])  # all at distance 1
    poses = best_pose(ring, torch.zeros(3), None, target, k=3, tie_break="nearest")
    assert [p[:2] for p in poses] == [(0.0, 1.0), (1.0, 0.0), (-1.0, 0.0)]


def test_best_pose_leaves_out_points_without_a_finite_score():
    floor = torch.tensor([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    poses = best_pose(floor, torch.tensor([float("nan"), 0.2, 0.1]), None, torch.zeros(3), k=3)
    assert [p[:2] for p in poses] == [(2.0, 0.0), (3.0, 0.0)]
    with pytest.raises(SampleError, match="no valid floor point with a finite score"):
        best_pose(floor, torch.full((3,), float("nan")), None, torch.zeros(3))


def test_floor_grid_rounds_to_cell_centres_and_averages_each_cell():
    """Cells are centred on multiples of ``cell``: 0.049 and 0.051 fall in the cell at 0.05; a raster cell holds the
    mean of its points, NaN where none falls; points past the edge (one column or row beyond) are left out."""
    xy = np.array([[0.049, 0.051], [0.149, 0.151], [0.151, 0.149]])
    grid = FloorGrid.from_points(xy, cell=0.05)
    assert grid.origin == pytest.approx((0.05, 0.05)) and grid.shape == (3, 3)
    wide = FloorGrid.from_points(xy, cell=0.05, margin=2)
    assert wide.origin == pytest.approx((-0.05, -0.05)) and wide.shape == (7, 7)
    outside = np.array([[0.21, 0.05], [0.05, 0.21]])  # column 3 / row 3 of a 3 x 3 grid
    raster = grid.rasterize(np.concatenate([xy, outside]), [5.0, 1.0, 3.0, 100.0, 100.0])
    want = np.full((3, 3), np.nan)
    want[0, 0], want[2, 2] = 5.0, 2.0
    np.testing.assert_allclose(raster, want)
    assert np.isnan(grid.sample(raster, outside)).all()
    centres = grid.centers()
    assert centres.shape == (3, 3, 2) and centres[2, 1] == pytest.approx((0.1, 0.15))  # row i is y, column j is x
