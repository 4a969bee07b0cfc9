"""The canonical prior (grid op and module through the CLI) and the training-free yaw estimates."""

import math

import pytest
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.cli import run_lightning
from floaff_zoo.models.prior import CanonicalPriorModule
from floaff_zoo.nn.prior import CanonicalLabelGrid
from floaff_zoo.nn.yaw import heading_yaw, local_normals, manhattan_yaw
from tests.conftest import quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
PRIOR = "configs/models/canonical_prior.yaml"


def test_grid_mean_per_task_and_cell():
    grid = CanonicalLabelGrid(["A", "B"], cell=0.1, extent=1.0, smooth_sigma_cells=0.0)
    xy = torch.tensor([[[0.0, 0.0], [0.01, 0.04], [0.5, -0.4]]])
    grid.add(torch.tensor([0]), xy, torch.tensor([[1.0, 0.0, 0.5]]), torch.tensor([[True, True, True]]))
    grid.add(torch.tensor([1]), xy, torch.tensor([[0.2, 0.2, 0.2]]), torch.tensor([[True, False, True]]))
    got = grid.read(torch.tensor([0, 1]), torch.tensor([[[-0.04, 0.02], [0.52, -0.41]], [[-0.04, 0.02], [5.0, 5.0]]]))
    # task A: the two labels of the first cell average to 0.5; task B: outside the grid -> fill (0)
    assert torch.allclose(got, torch.tensor([[0.5, 0.5], [0.2, 0.0]]))
    assert grid.seen_tasks() == ["A", "B"]
    with pytest.raises(ValueError, match="'C' has no grid"):
        grid.task_index(["A", "C"])


def test_grid_read_follows_new_labels_and_loaded_state():
    grid = CanonicalLabelGrid(["A"], cell=0.1, extent=1.0, smooth_sigma_cells=1.0)
    xy, task, mask = torch.zeros(1, 3, 2), torch.tensor([0]), torch.ones(1, 3, dtype=torch.bool)
    assert torch.equal(grid.read(task, xy), torch.zeros(1, 3))  # empty: fill
    grid.add(task, xy, torch.ones(1, 3), mask)
    assert torch.allclose(grid.read(task, xy), torch.ones(1, 3))  # the cached map was refreshed
    other = CanonicalLabelGrid(["A"], cell=0.1, extent=1.0, smooth_sigma_cells=1.0)
    other.read(task, xy)
    other.load_state_dict(grid.state_dict())
    assert torch.allclose(other.read(task, xy), torch.ones(1, 3))


def test_grid_smoothing_keeps_a_constant_map_constant():
    grid = CanonicalLabelGrid(["A"], cell=0.1, extent=1.0, smooth_sigma_cells=1.5)
    g = torch.stack(torch.meshgrid(torch.linspace(-1.0, 0.9, 20), torch.linspace(-1.0, 0.9, 20), indexing="ij"), -1)
    xy = g.reshape(1, -1, 2)
    grid.add(torch.tensor([0]), xy, torch.full((1, xy.shape[1]), 0.3), torch.ones(1, xy.shape[1], dtype=torch.bool))
    assert torch.allclose(grid.read(torch.tensor([0]), xy), torch.full((1, xy.shape[1]), 0.3), atol=1e-5)


def _lattice(cell: float, n: int) -> torch.Tensor:
    """Points at multiples of ``cell`` within n cells of the origin, [1, (2n+1)^2, 2] float64 (a label grid)."""
    k = torch.arange(-n, n + 1, dtype=torch.float64) * cell
    return torch.stack(torch.meshgrid(k, k, indexing="ij"), -1).reshape(1, -1, 2)


def _turn(xy: torch.Tensor, deg: float) -> torch.Tensor:
    a = math.radians(deg)
    rot = torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]], dtype=xy.dtype)
    return xy @ rot.T


@pytest.mark.parametrize("deg", [0.3, -0.3, 1e-6])
def test_grid_cells_hold_label_lattice_points_under_small_turns(deg):
    # generated labels sit at multiples of their spacing in the canonical frame: a yaw estimate a fraction of a
    # degree off must not move any of them into another cell (it did when the cell edges lay on the lattice)
    xy = _lattice(0.1, 15)  # up to 1.5 m from the target, the label grid's reach
    centred = CanonicalLabelGrid(["A"], cell=0.05, extent=3.0)
    assert torch.equal(centred.cells(_turn(xy, deg))[0], centred.cells(xy)[0])
    edges = CanonicalLabelGrid(["A"], cell=0.05, extent=3.0, centred=False)
    assert not torch.equal(edges.cells(_turn(xy, deg))[0], edges.cells(xy)[0])


def test_grid_state_without_binning_entry_loads_as_edge_binned():
    # checkpoints written before the grid recorded its binning accumulated with cell edges on the lattice
    old = CanonicalLabelGrid(["A"], cell=0.1, extent=1.0, smooth_sigma_cells=0.0, centred=False)
    xy, task = _lattice(0.1, 3).float() + 0.05, torch.tensor([0])
    old.add(task, xy, torch.rand(1, xy.shape[1]), torch.ones(1, xy.shape[1], dtype=torch.bool))
    state = {k: v for k, v in old.state_dict().items() if k != "centred"}
    new = CanonicalLabelGrid(["A"], cell=0.1, extent=1.0, smooth_sigma_cells=0.0)
    new.load_state_dict(state)  # strict: the missing entry is not an error
    assert not bool(new.centred) and "centred" not in state  # the caller's dict is left as it was
    assert torch.equal(new.read(task, xy), old.read(task, xy))
    fresh = CanonicalLabelGrid(["A"], cell=0.1, extent=1.0, smooth_sigma_cells=0.0)
    fresh.load_state_dict(CanonicalLabelGrid(["A"], cell=0.1, extent=1.0).state_dict())
    assert bool(fresh.centred)


def test_grid_map_is_float32_under_autocast():
    """Under bf16-mixed the smoothing ran in bf16 inside the test step and the cached map kept it: the prior's scores
    moved by up to 0.007 and the argmax cell of a few per cent of views changed."""
    grid = CanonicalLabelGrid(["A"], cell=0.1, extent=1.0, smooth_sigma_cells=1.0)
    xy, task = _lattice(0.1, 8).float(), torch.tensor([0])
    grid.add(
        task,
        xy,
        torch.rand(1, xy.shape[1], generator=torch.Generator().manual_seed(0)),
        torch.ones(1, xy.shape[1], dtype=torch.bool),
    )
    with torch.autocast("cpu", dtype=torch.bfloat16):
        under = grid.read(task, xy)
    grid._maps = None
    assert under.dtype == torch.float32 and torch.equal(under, grid.read(task, xy))


def test_grid_geometry_is_checked():
    """A centred grid whose extent is no multiple of its cell put its centres off the lattice (labels on edges
    again); a state of another (cell, extent) with the same size loaded silently, reading every label elsewhere."""
    with pytest.raises(ValueError, match="extent to be a multiple of cell, got cell=0.1, extent=1.25"):
        CanonicalLabelGrid(["A"], cell=0.1, extent=1.25)
    CanonicalLabelGrid(["A"], cell=0.1, extent=1.25, centred=False)  # edge binning has no such constraint
    small, large = CanonicalLabelGrid(["A"], cell=0.05, extent=3.0), CanonicalLabelGrid(["A"], cell=0.1, extent=6.0)
    assert small.size == large.size
    with pytest.raises(RuntimeError, match=r"saved grid has cell 0.05 m and extent 3.0 m, this model is configured"):
        large.load_state_dict(small.state_dict())
    older = {k: v for k, v in small.state_dict().items() if k != "geometry"}  # saved before the entry existed
    CanonicalLabelGrid(["A"], cell=0.05, extent=3.0).load_state_dict(older)


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"cell": float("nan")}, "cell"),  # failed converting NaN to an integer, naming nothing
        ({"extent": float("inf")}, "extent"),  # an OverflowError naming nothing
        ({"smooth_sigma_cells": float("inf")}, "smooth_sigma_cells"),  # the same, at the first read
        ({"smooth_sigma_cells": -1.0}, "smooth_sigma_cells"),  # smoothing silently off
        ({"fill": float("nan")}, "fill"),  # unseen cells read NaN
        ({"cell": None}, "cell"),  # a TypeError naming nothing
        ({"fill": "0"}, "fill"),  # the same
    ],
)
def test_grid_sizes_that_break_it_later_are_refused_by_name(kwargs, named):
    with pytest.raises(ValueError, match=rf"CanonicalLabelGrid: .*{named}"):
        CanonicalLabelGrid(["A"], **kwargs).read(torch.zeros(1, dtype=torch.long), torch.zeros(1, 1, 2))


def test_a_manhattan_radius_that_finds_no_face_is_refused():
    """A radius <= 0 (or NaN) found no point: every sample kept its reference yaw, without a word."""
    with pytest.raises(MisconfigurationException, match=r"CanonicalPriorModule: manhattan_radius must be a finite"):
        CanonicalPriorModule(manhattan_radius=0.0)


def _box_scene(yaw: float, n: int = 1500, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Points on the vertical faces and top of a 2 x 0.6 m counter whose front normal has ``yaw``; target in front."""
    g = torch.Generator().manual_seed(seed)
    u, h = torch.rand(n, generator=g) * 2 - 1, torch.rand(n, generator=g) * 0.9
    face = torch.randint(0, 3, (n,), generator=g)
    # counter frame: front face at y = -0.3 (normal -y), back wall at y = +0.3, top at z = 0.9
    x = torch.where(face == 2, u, u)
    y = torch.where(
        face == 0,
        torch.full_like(u, -0.3),
        torch.where(face == 1, torch.full_like(u, 0.3), torch.rand(n, generator=g) * 0.6 - 0.3),
    )
    z = torch.where(face == 2, torch.full_like(u, 0.9), h)
    local = torch.stack([x, y, z], -1)
    phi = yaw + math.pi / 2  # rotate the counter's -y normal onto `yaw`
    c, s = math.cos(phi), math.sin(phi)
    world = torch.stack([c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1], local[:, 2]], -1)
    target = torch.tensor([1.5, 0.3, 0.5])
    return (world + target)[None], target[None]


@pytest.mark.parametrize("yaw_deg", [180.0, 160.0, -150.0, 135.0 + 30.0])
def test_manhattan_yaw_snaps_a_rough_reference_onto_the_faces(yaw_deg):
    xyz, target = _box_scene(math.radians(yaw_deg))
    mask = torch.ones(xyz.shape[:2], dtype=torch.bool)
    rough = torch.tensor([math.radians(yaw_deg + 35.0)])  # a reference 35 deg off still picks the right face
    est = manhattan_yaw(xyz, mask, target, radius=2.0, reference=rough)
    err = abs((math.degrees(float(est[0])) - yaw_deg + 180.0) % 360.0 - 180.0)
    assert err < 2.0


def test_manhattan_yaw_is_unmoved_by_a_cloud_padded_with_copies():
    """collate_mode resample (and predict) pad a sparse cloud by repeating points: neighbourhoods of copies read as
    perfectly planar at an arbitrary normal, and the estimate moved by 2-16 deg on 120 points padded to 1024."""
    yaw_deg = 160.0
    xyz, target = _box_scene(math.radians(yaw_deg), n=120, seed=3)
    padded = xyz[:, torch.randint(0, 120, (1024,), generator=torch.Generator().manual_seed(0))]
    mask = torch.ones(padded.shape[:2], dtype=torch.bool)
    est = manhattan_yaw(padded, mask, target, radius=2.0, reference=torch.tensor([math.radians(yaw_deg)]))
    assert abs((math.degrees(float(est[0])) - yaw_deg + 180.0) % 360.0 - 180.0) < 1.0


def test_manhattan_yaw_without_reference_uses_the_heading_and_falls_back():
    xyz, target = _box_scene(math.radians(170.0))
    mask = torch.ones(xyz.shape[:2], dtype=torch.bool)
    est = manhattan_yaw(xyz, mask, target, radius=2.0)
    assert abs(math.degrees(float(est[0])) - 170.0) < 2.0  # heading ~190 deg is within 45 deg of the front
    # no point near the target: the heading itself
    far = manhattan_yaw(xyz + 50.0, mask, target, radius=2.0)
    assert torch.allclose(far, heading_yaw(target))


def _face(yaw: float, centre: list[float], n: int, seed: int) -> torch.Tensor:
    """n points [n, 3] on a 0.6 m wide, 0.9 m high vertical face through ``centre`` whose outward normal has ``yaw``."""
    g = torch.Generator().manual_seed(seed)
    u, z = (torch.rand(n, generator=g) * 2 - 1) * 0.3, torch.rand(n, generator=g) * 0.9
    side = torch.tensor([-math.sin(yaw), math.cos(yaw), 0.0])
    return torch.tensor(centre) + u[:, None] * side + z[:, None] * torch.tensor([0.0, 0.0, 1.0])


def _err_deg(est: torch.Tensor, yaw_deg: float) -> float:
    return abs((math.degrees(float(est[0])) - yaw_deg + 180.0) % 360.0 - 180.0)


def test_manhattan_yaw_picks_any_of_the_four_directions_in_range_from_the_reference():
    """A side view: the front (100 deg) is 90 deg from the face direction mod 90 (10 deg) and ~90 deg from the
    heading (~191 deg); the reference (120 deg) picks it, and the yaw comes back in [-pi, pi)."""
    xyz, target = _box_scene(math.radians(100.0))
    mask = torch.ones(xyz.shape[:2], dtype=torch.bool)
    assert _err_deg(manhattan_yaw(xyz, mask, target, 2.0, torch.tensor([math.radians(120.0)])), 100.0) < 2.0
    xyz, target = _box_scene(math.radians(-100.0))  # base -10 deg + 270 deg: wrapped to -100 deg, not 260 deg
    est = manhattan_yaw(xyz, mask, target, 2.0, torch.tensor([math.radians(-80.0)]))
    assert -math.pi <= float(est[0]) < math.pi and abs(math.degrees(float(est[0])) + 100.0) < 2.0


def test_manhattan_yaw_reads_the_nearest_valid_points_and_only_vertical_faces():
    target = torch.tensor([[1.0, 0.0, 0.4]])
    near = _face(math.radians(170.0), [1.0, 0.0, 0.0], 1100, 0)  # within 0.6 m of the target
    far = _face(math.radians(140.0), [-0.4, 0.6, 0.0], 1100, 1)  # 1.5-1.7 m away, 30 deg off the near axes
    ref = torch.tensor([math.radians(180.0)])
    xyz = torch.cat([far, near])[None]  # over MAX_POINTS within the radius: the 1,024 nearest are the near face
    assert _err_deg(manhattan_yaw(xyz, torch.ones(1, 2200, dtype=torch.bool), target, 2.0, ref), 170.0) < 1.0
    few = torch.cat([far[:300], near[:300]])[None]
    mask = torch.arange(600)[None] >= 300  # the far face is masked out
    assert _err_deg(manhattan_yaw(few, mask, target, 2.0, ref), 170.0) < 1.0
    # a slanted face (|n_z| = 0.6, its horizontal normal 22.5 deg off the axes) is no vertical face, whichever
    # sign its PCA normal takes
    g = torch.Generator().manual_seed(5)
    phi, uv = math.radians(192.5), torch.rand(600, 2, generator=g) - 0.5
    normal = torch.tensor([0.8 * math.cos(phi), 0.8 * math.sin(phi), 0.6])
    across = torch.tensor([-math.sin(phi), math.cos(phi), 0.0])
    slanted = torch.tensor([1.0, 0.0, 0.6]) + uv[:, :1] * across + uv[:, 1:] * torch.linalg.cross(normal, across)
    xyz = torch.cat([near[:600], slanted])[None]
    assert _err_deg(manhattan_yaw(xyz, torch.ones(1, 1200, dtype=torch.bool), target, 2.0, ref), 170.0) < 1.0


def test_manhattan_yaw_keeps_the_reference_with_k_points_or_fewer():
    near = _face(math.radians(170.0), [1.0, 0.0, 0.0], 12, 0)[None]  # MANHATTAN_K points: no k-NN neighbourhood
    ref = torch.tensor([math.radians(177.0)])
    est = manhattan_yaw(near, torch.ones(1, 12, dtype=torch.bool), torch.tensor([[1.0, 0.0, 0.4]]), 2.0, ref)
    assert torch.allclose(est, ref)


def test_local_normals_are_face_normals_and_planarity_is_high_on_faces_only():
    g = torch.Generator().manual_seed(0)
    wall = _face(math.radians(30.0), [0.0, 0.0, 0.0], 200, 0)
    normals, planarity = local_normals(wall)
    # PCA normals have either sign
    assert torch.allclose(
        (normals[:, :2] @ torch.tensor([math.cos(math.pi / 6), 0.5])).abs(), torch.ones(200), atol=1e-4
    )
    assert float(planarity.min()) > 0.99
    line = torch.cat([torch.rand(200, 1, generator=g), 0.01 * torch.randn(200, 2, generator=g)], 1)  # a cable
    assert float(local_normals(line)[1].mean()) < 0.8  # 1 - smallest / middle eigenvalue: ~0.5 on a line


def test_estimate_yaw_heading_faces_the_robot_and_axisnet_manhattan_snaps_axisnet():
    from floaff_zoo.models.yaw import axisnet_yaw, estimate_yaw
    from floaff_zoo.nn.axisnet import AxisNet

    xyz, target = _box_scene(math.radians(100.0))
    batch = {"scene_xyz": xyz, "scene_mask": torch.ones(xyz.shape[:2], dtype=torch.bool), "target_xyz": target}
    batch["scene_feat"] = torch.zeros(*xyz.shape[:2], 1)
    # the target at (1.5, 0.3): its front faces back to the robot at the origin
    assert torch.allclose(
        estimate_yaw(batch, "heading", None, 1.3, 2.0, "t"), torch.atan2(-target[:, 1], -target[:, 0])
    )
    net = AxisNet(4, [8], [8]).eval()
    with torch.no_grad():  # an AxisNet whose yaw is 13 deg whatever it sees, far from the heading (191 deg)
        net.out.weight.zero_()
        net.out.bias.copy_(torch.tensor([math.sin(math.radians(13.0)), math.cos(math.radians(13.0))]))
    ref = axisnet_yaw(batch, net, 1.3)
    snapped = estimate_yaw(batch, "axisnet_manhattan", net, 1.3, 2.0, "t")
    assert torch.allclose(snapped, manhattan_yaw(xyz, batch["scene_mask"], target, 2.0, ref))
    # AxisNet's reference picks another of the four directions than the heading would: the reference is used
    assert not torch.allclose(snapped, manhattan_yaw(xyz, batch["scene_mask"], target, 2.0))


_X, _M, _T = torch.rand(2, 40, 3), torch.ones(2, 40, dtype=torch.bool), torch.zeros(2, 3)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        # a NaN or negative radius found no face: every sample kept its reference yaw, silently
        (lambda: manhattan_yaw(_X, _M, _T, float("nan")), r"manhattan_yaw: radius must be a finite number > 0"),
        (lambda: manhattan_yaw(_X, _M, _T, -1.0), r"manhattan_yaw: radius must be a finite number > 0, got -1"),
        # a [B + 1] reference gave B + 1 yaws; the rest failed in indexing naming no argument
        (lambda: manhattan_yaw(_X, _M, _T, 1.0, torch.zeros(3)), r"manhattan_yaw: reference must be \[2\], got \[3\]"),
        (lambda: manhattan_yaw(_X, _M[:, 1:], _T, 1.0), r"manhattan_yaw: scene_mask must be \[2, 40\], got \[2, 39\]"),
        (lambda: manhattan_yaw(_X, _M, _T[0], 1.0), r"manhattan_yaw: target_xyz must be \[2, 3\], got \[3\]"),
        (lambda: manhattan_yaw(_X[0], _M, _T, 1.0), r"manhattan_yaw: scene_xyz must be \[B, N, 3\], got \[40, 3\]"),
        (lambda: heading_yaw(_T[0]), r"heading_yaw: target_xyz must be \[B, 3\], got \[3\]"),
        (lambda: local_normals(_X[0], 0), r"local_normals: k must be an integer >= 1, got 0"),  # every point planar
        (lambda: local_normals(_X[0, :5]), r"local_normals: xyz must be \[N, 3\] with N > k = 12, got \[5, 3\]"),
    ],
)
def test_the_yaw_estimates_refuse_bad_arguments_by_name(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_prior_fits_and_tests_through_the_cli(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    base = [
        "--config",
        DATA,
        "--config",
        PRIOR,
        *quiet_trainer_args(tmp_path),
        "--data.init_args.tasks",
        "[CloseDrawer, PnPCounterToCab]",
    ]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
    model = cli.model
    assert sorted(model.net.seen_tasks()) == ["CloseDrawer", "PnPCounterToCab"]
    assert not any(p.requires_grad for p in model.parameters())
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    pcc = {}
    for src in ("gt", "none"):
        t = run_lightning(["test", *base, "--ckpt_path", ckpt, "--model.init_args.eval_yaw_source", src])
        pcc[src] = float(t.trainer.callback_metrics["test_pcc"])
    # the synthetic labels are a function of the canonical position (and the robot): aligned is far better
    assert pcc["gt"] > 0.6 and pcc["gt"] > pcc["none"] + 0.1, pcc
    re = CanonicalPriorModule.load_from_checkpoint(ckpt, weights_only=True)
    assert torch.equal(re.net.sums, model.net.sums.cpu())


def test_prior_rejects_unknown_tasks_and_missing_axisnet():
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    with pytest.raises(MisconfigurationException, match="unknown task"):
        CanonicalPriorModule(tasks=["CloseDrawr"])
    with pytest.raises(MisconfigurationException, match="no AxisNet"):
        CanonicalPriorModule(eval_yaw_source="axisnet")


def test_an_empty_task_list_is_refused_not_read_as_every_task():
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    with pytest.raises(MisconfigurationException, match=r"CanonicalPriorModule: tasks needs >= 1 task \(null for all"):
        CanonicalPriorModule(tasks=[])
    # a text was read letter by letter as unknown tasks; a task named twice passed
    with pytest.raises(MisconfigurationException, match="tasks must be a list of task names, got the text"):
        CanonicalPriorModule(tasks="CloseDrawer")
    with pytest.raises(MisconfigurationException, match="tasks names a task twice"):
        CanonicalPriorModule(tasks=["CloseDrawer", "CloseDrawer"])


def test_shipped_prior_rebuilds_its_axisnet_and_weights_alone_warns():
    name = "canonical-prior.floaff-small-layouts.v1"
    full = CanonicalPriorModule.from_pretrained(name)
    assert full.axisnet is not None and full.eval_yaw_source == "axisnet_manhattan"
    with pytest.warns(UserWarning, match=r"\['axisnet'\] are not used"):
        bare = CanonicalPriorModule(weights=name)  # initialisation only: no AxisNet configured
    assert bare.axisnet is None and bare.eval_yaw_source == "manhattan"
    assert torch.equal(bare.net.sums, full.net.sums)


def test_an_unrotated_prior_is_read_unrotated():
    """A grid filled with yaw_source none holds target-centred, unrotated labels: by default it is read so."""
    assert CanonicalPriorModule(yaw_source="none").eval_yaw_source == "none"
    assert CanonicalPriorModule(yaw_source="none", eval_yaw_source="manhattan").eval_yaw_source == "manhattan"


def test_a_grid_loaded_under_another_task_order_reads_each_task_from_its_own_layer():
    """The grid saved its layers but not which task each held: loaded with the tasks in another order (a ``tasks``
    argument given with a checkpoint) every task read another task's average."""
    from floaff_zoo.nn.prior import CanonicalLabelGrid

    tasks = ["PnPCounterToCab", "OpenSingleDoor", "CloseDrawer", "CloseDoubleDoor"]
    saved = CanonicalLabelGrid(tasks, cell=0.5, extent=1.0)
    for i in range(len(tasks)):
        saved.sums[i].fill_(float(i + 1))
        saved.counts[i].fill_(1.0)
    state = saved.state_dict()
    other = CanonicalLabelGrid(list(reversed(tasks)), cell=0.5, extent=1.0)
    other.load_state_dict(state)
    for name in tasks:
        assert float(other.sums[other.tasks.index(name)].mean()) == float(tasks.index(name) + 1), name
    with pytest.raises(RuntimeError, match=r"the saved grid holds tasks .* configured for \['CloseDrawer'"):
        CanonicalLabelGrid(["CloseDrawer", "OpenSingleDoor", "PnPCounterToCab", "CloseDoubleDoot"], 0.5, 1.0
                           ).load_state_dict(state)  # fmt: skip
    legacy = {k: v for k, v in state.items() if k != "task_names"}  # saved before the grid named its tasks
    assert CanonicalLabelGrid(tasks, cell=0.5, extent=1.0).load_state_dict(legacy, strict=True).missing_keys == []


def test_a_checkpoints_axisnet_is_kept_when_the_configured_one_was_only_rebuilt():
    """A configured AxisNet rebuilt from an architecture record without a sha256 (its weights still to come from the
    checkpoint) replaced the checkpoint's trained AxisNet with its own random weights."""
    from floaff_zoo.models.yaw import build_axisnet, keep_configured_axisnet

    arch = {"crop_radius": 1.2, "widths": [8, 8, 8], "head": [8], "sha256": None}
    trained, _ = build_axisnet(arch, "test")
    rebuilt, _ = build_axisnet(arch, "test")
    with torch.no_grad():
        for p in trained.parameters():
            p.add_(1.0)
    checkpoint = {"state_dict": {f"axisnet.{k}": v.clone() for k, v in trained.state_dict().items()}}
    checkpoint["hyper_parameters"] = {"axisnet_arch": dict(arch)}
    keep_configured_axisnet(checkpoint, rebuilt, arch)
    for k, v in trained.state_dict().items():
        assert torch.equal(checkpoint["state_dict"][f"axisnet.{k}"], v), k
    # one loaded from a file of its own (a sha256) still replaces the checkpoint's, and says so: an AxisNet retrained
    # at the configured path is swapped in as silently as one named on purpose
    with pytest.warns(
        UserWarning, match=r"checkpoint's AxisNet \(sha256 unrecorded.*replaced by the configured one \(sha256 abab"
    ):
        keep_configured_axisnet(checkpoint, rebuilt, dict(arch, sha256="ab" * 32))
    for k, v in rebuilt.state_dict().items():
        assert torch.equal(checkpoint["state_dict"][f"axisnet.{k}"], v), k


def test_a_fit_on_several_processes_is_refused_naming_the_option():
    """Each process would sum its own shard of the labels; DDP itself refused the module with a message about
    gradients that names no option."""
    import lightning
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    trainer = lightning.Trainer(accelerator="cpu", devices=2, strategy="ddp_spawn", logger=False)
    model = CanonicalPriorModule(tasks=["CloseDrawer"])
    model.trainer = trainer
    with pytest.raises(MisconfigurationException, match="--trainer.devices 1"):
        model.setup("fit")
    model.setup("test")  # testing on several processes is fine


def test_weights_of_other_tasks_are_refused_not_loaded_into_the_wrong_layers(tmp_path):
    """The grid's task names are a byte tensor: weights of other tasks whose names had another total length had them
    skipped as a shape mismatch while the sums and counts loaded, so CloseDrawer read OpenSingleDoor's labels."""
    saved = CanonicalPriorModule(tasks=["PnPCounterToCab", "OpenSingleDoor"])
    saved.net.sums[1] += 2.0
    path = saved.save_pretrained(tmp_path / "prior")
    with pytest.raises(RuntimeError, match=r"the saved grid holds tasks \['PnPCounterToCab', 'OpenSingleDoor'\]"):
        CanonicalPriorModule(tasks=["PnPCounterToCab", "CloseDrawer"], weights=str(path))
    reordered = CanonicalPriorModule(tasks=["OpenSingleDoor", "PnPCounterToCab"], weights=str(path))
    assert reordered.net.sums[0].max() == 2.0 and reordered.weights_not_loaded == []


@pytest.mark.parametrize("tasks", ["CloseDrawer", ["a", "a"], ["a\nb", "c"], [1, 2], ["", "a"], []])
def test_grid_tasks_must_be_distinct_one_line_names(tasks):
    """A text was read letter by letter as tasks, a repeated name's second grid was never read or filled, a newline
    split the saved names into other tasks, and numbers failed in str.join naming no argument."""
    with pytest.raises(ValueError, match="CanonicalLabelGrid: tasks must be"):
        CanonicalLabelGrid(tasks)


def test_grid_refuses_a_nan_label_it_would_keep():
    """A NaN label made its cell's mean NaN for good; a NaN on a masked point is not read."""
    grid = CanonicalLabelGrid(["a"], smooth_sigma_cells=0.0)
    xy = torch.zeros(1, 2, 2)
    task = torch.zeros(1, dtype=torch.long)
    label = torch.tensor([[float("nan"), 1.0]])
    grid.add(task, xy, label, torch.tensor([[False, True]]))
    assert grid.read(task, xy).tolist() == [[1.0, 1.0]]
    with pytest.raises(ValueError, match="CanonicalLabelGrid: label contains 1 NaN"):
        grid.add(task, xy, label, torch.ones(1, 2, dtype=torch.bool))
