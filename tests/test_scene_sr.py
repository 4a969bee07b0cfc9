"""scripts/scene_sr.py: runs pooled per name, SR per scene, and the scene bootstrap's paired differences."""

import math

import numpy as np
import pytest
import torch

from tests._scripts import load_script

ssr = load_script("scene_sr")


def test_parse_models_pools_runs_under_one_name():
    assert ssr.parse_models(["a=x.ckpt", "b=y", "a=z.ckpt", "hub.name.v1"]) == {
        "a": ["x.ckpt", "z.ckpt"],
        "b": ["y"],
        "hub.name.v1": ["hub.name.v1"],
    }
    with pytest.raises(SystemExit, match="bad model argument"):
        ssr.parse_models(["=x.ckpt"])


def _rows():
    """Two tasks x two scenes; model a wins every view of one scene per task, b half of every scene."""
    rows = []
    for task, scenes in (("PnPCounterToCab", ("p0", "p1")), ("CloseDrawer", ("d0", "d1"))):
        for k, sid in enumerate(scenes):
            for v in range(4 if k == 0 else 2):  # scenes of different sizes
                rows.append((task, sid, {"a": [k == 0, k == 0], "b": [v % 2 == 0, True]}))
    return rows


def test_per_scene_averages_runs_and_weights_views():
    table = ssr.per_scene(_rows(), ["a", "b"])
    assert table["p0"] == {"task": "PnPCounterToCab", "views": 4, "sr": {"a": 1.0, "b": 0.75}}
    assert table["p1"]["sr"] == {"a": 0.0, "b": 0.75} and table["p1"]["views"] == 2
    # SR over views, not over scenes: 8 of 12 views for a
    assert ssr.sr_all(table, list(table), "a") == pytest.approx(8 / 12)
    assert ssr.sr_all(table, ["p0", "p0"], "a") == 1.0


def test_scene_bootstrap_spreads_only_when_scenes_differ():
    table = ssr.per_scene(_rows(), ["a", "b"])
    res = ssr.summarize(table, ["a", "b"], draws=400, seed=0)
    assert res["models"]["b"]["scene_bootstrap_std"] == pytest.approx(0.0, abs=1e-12)  # b: 0.75 in every scene
    assert res["models"]["a"]["scene_bootstrap_std"] > 0.1  # a: all or nothing per scene
    d = res["differences"]["a - b"]
    assert d["diff"] == pytest.approx(8 / 12 - 0.75)
    assert d["p05"] < 0 < d["p95"]  # which scenes are drawn decides who is ahead
    assert res["models"]["a"]["PnPCounterToCab"] == pytest.approx(4 / 6)


def test_reason_shares_average_runs_per_task_and_overall():
    rows = [
        ("t1", "s", {"a": [True, False]}, {"a": ["success", "filtered_collision"]}),
        ("t1", "s", {"a": [False, False]}, {"a": ["collision", "not_open"]}),
        ("t2", "u", {"a": [False, False]}, {"a": ["ik_unreachable", "ik_unreachable"]}),
    ]
    rows = [(t, sid, out, {n: [ssr.failure_kind(r) for r in rs] for n, rs in why.items()}) for t, sid, out, why in rows]
    shares = ssr.reason_shares(rows, ["a"])["a"]
    assert list(shares) == ["t1", "t2", "all"]
    assert shares["t1"] == pytest.approx({"filtered_collision": 0.25, "rollout": 0.5, "success": 0.25})
    assert shares["t2"] == {"ik_unreachable": 1.0}
    assert sum(shares["all"].values()) == pytest.approx(1.0) and shares["all"]["rollout"] == pytest.approx(1 / 3)
    # a cell a budgeted preset never rolled out is no failed rollout, and has its own column when it occurs
    assert ssr.failure_kind("skipped_budget") == "skipped_budget" and ssr.failure_kind("not_open") == "rollout"
    assert "skipped_budget" not in ssr.breakdown_columns({"a": shares})
    skipped = ssr.reason_shares([("t1", "s", {"a": [False]}, {"a": [ssr.failure_kind("skipped_budget")]})], ["a"])
    assert ssr.breakdown_columns(skipped)[-1] == "skipped_budget"


def test_paired_difference_of_a_constant_shift_has_no_spread():
    rows = [(t, f"{t}{k}", {"a": [v < k + 1], "b": [v < k]}) for t in ("x", "y") for k in range(3) for v in range(4)]
    table = ssr.per_scene(rows, ["a", "b"])
    d = ssr.summarize(table, ["a", "b"], draws=200, seed=1)["differences"]["a - b"]
    assert d["diff"] == pytest.approx(0.25) and d["p05"] == pytest.approx(0.25) and d["p95"] == pytest.approx(0.25)
    boot = ssr.scene_bootstrap(table, ["a"], draws=50, seed=2)
    assert boot.shape == (50, 1) and np.all((boot >= 0) & (boot <= 1))


def test_bad_arguments_exit_with_a_message(tmp_path, capsys):
    with pytest.raises(SystemExit):
        ssr.main(["--draws", "0", "a=x"])
    assert "--draws must be >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # numpy's generator refused it after every model had been scored
        ssr.main(["--seed", "-1", "a=x"])
    assert "--seed must be >= 0, got -1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ssr.main(["--top-k", "0", "a=x"])
    assert "--top-k must be >= 1" in capsys.readouterr().err
    for args, msg in (
        (["--top-k", "10", "--footprint-margin", "-0.1"], "finite and >= 0"),
        (["--footprint-margin", "0.05"], "give --top-k > 1"),
        (["--full-cloud"], "give --top-k > 1"),
        (["--min-observed", "0.5"], "give --top-k > 1"),
        (["--top-k", "10", "--min-observed", "1.5"], "must be in [0, 1]"),
        (["--val-layout", "2"], "give --split val"),
    ):
        with pytest.raises(SystemExit):
            ssr.main([*args, "a=x"])
        assert msg in capsys.readouterr().err
    # an unknown model ends the script with a message naming it, not a traceback
    with pytest.raises(SystemExit, match="scene_sr: .*no-such-model.ckpt"):
        ssr.main(["--root", str(tmp_path), "a=no-such-model.ckpt"])


def test_residual_scales_parse_and_copy_only_prior_residual_runs():
    assert ssr.parse_scales(None) == [] and ssr.parse_scales("0,0.5,2") == [0.0, 0.5, 2.0]
    for bad in ("a,1", "-1", "nan", ""):  # "" was taken as no option
        with pytest.raises(SystemExit, match="--residual-scales"):
            ssr.parse_scales(bad)

    class Run:
        def __init__(self, prior):
            self.prior, self.hparams = prior, {"residual_scale": 1.0}

    nets = {"recipe": [Run(object()), Run(object())], "plain": [Run(None)]}
    out = ssr.with_residual_scales(nets, [0.0, 0.5])
    assert list(out) == ["recipe", "plain", "recipe@0", "recipe@0.5"]
    assert [r.hparams["residual_scale"] for r in out["recipe@0.5"]] == [0.5, 0.5]
    assert nets["recipe"][0].hparams["residual_scale"] == 1.0  # the originals are untouched
    assert ssr.with_residual_scales({"plain": nets["plain"]}, []) == {"plain": nets["plain"]}


def test_residual_scales_without_a_prior_residual_name_are_refused(monkeypatch, tmp_path, capsys):
    """--residual-scales with no NAME whose runs predict a residual added no row and said nothing (the JSON still
    listed the scales); it is refused naming the option, before any data is read."""
    import floaff_zoo.predict as pr

    monkeypatch.setattr(pr, "resolve_model", lambda name: torch.nn.Identity())
    with pytest.raises(SystemExit, match="scene_sr: --residual-scales .*no NAME's runs all have one"):
        ssr.main(["--root", str(tmp_path / "missing"), "--residual-scales", "0,0.5", "a=x.ckpt", "a=y.ckpt"])


def test_ensemble_averages_the_maps_of_a_name_with_several_runs():
    a0, a1 = np.array([[0.9, 0.1, 0.5]]), np.array([[0.1, 0.8, 0.6]])
    out = ssr.ensemble_scores({"a": [a0, a1], "solo": [a0]})
    assert list(out) == ["a", "solo", "a+ens"]  # one run has nothing to average
    assert len(out["a+ens"]) == 1 and np.allclose(out["a+ens"][0], [[0.5, 0.45, 0.55]])
    # the mean map's argmax is a cell neither run chose: an ensemble is not a vote between its members
    assert int(out["a+ens"][0].argmax()) == 2 and {int(a0.argmax()), int(a1.argmax())} == {0, 1}
    assert out["a"] == [a0, a1]
    assert ssr.ensembled({"a": [1, 2], "solo": [1]}) == ["a"]


def test_ensemble_without_a_pooled_name_is_refused_before_loading(tmp_path, capsys):
    with pytest.raises(SystemExit):
        ssr.main(["--root", str(tmp_path), "--ensemble", "a=x.ckpt", "b=y.ckpt"])
    assert "--ensemble averages the runs of one NAME" in capsys.readouterr().err


def _behind(batch) -> np.ndarray:
    """Scores [B, M] in (0, 1): the floor points farthest behind the robot first (a poor map: the footprint check
    matters)."""
    return torch.sigmoid(-batch["floor_xyz"][..., 0]).numpy()


def _noisy_labels(batch) -> np.ndarray:
    """Scores [B, M] in (0, 1): the labels plus a fixed ripple over the floor (some views pick a failure)."""
    xy = batch["floor_xyz"][..., :2]
    return torch.sigmoid(batch["floor_label"] + 2.5 * torch.sin(37 * xy[..., 0] + 11 * xy[..., 1])).numpy()


@pytest.fixture(scope="module")
def sim_scenes(tmp_path_factory):
    """One generated tiny test scene each of CloseDrawer and OpenSingleDoor: scene records and samples."""
    pytest.importorskip("mujoco")
    from floaff_zoo.contract import validate_sample
    from floaff_zoo.sim import fileformat as ff
    from floaff_zoo.sim import generate as gen

    out = tmp_path_factory.mktemp("scene_sr_sim")
    args = ["--preset", "tiny", "--out", str(out), "--tasks", "CloseDrawer", "OpenSingleDoor", "--n-train", "0"]
    assert gen.main([*args, "--n-test", "1", "--workers", "0", "--quiet"]) == 0
    scenes = {s["scene_id"]: s for s in ff.iter_scenes(out)}
    samples = [validate_sample(ff.read_sample(sc, v, out)) for sc in scenes.values() for v in sc["views"]]
    return scenes, samples


def test_annotated_outcomes_equal_the_callbacks_rollouts(sim_scenes):
    """scene_sr scores a choice by the annotated outcome of its cell; the test's callback rolls it out. Both must
    give the same SR, with and without the footprint check (``top_k``, ``free_space: cloud``)."""
    import lightning as L

    from floaff_zoo.callbacks import RolloutSuccessRate
    from tests.report._fake_world import ConstantModule, loader

    scenes, samples = sim_scenes
    seen = set()
    for scorer in (_behind, _noisy_labels):

        class Module(ConstantModule):
            def forward(self, batch, scorer=scorer):
                return torch.as_tensor(scorer(batch)) + 0.0 * self.net.weight.sum()

        for top_k in (1, 5):
            cb = RolloutSuccessRate(progress=False, top_k=top_k, free_space="cloud", oracle=False)
            trainer = L.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False, enable_checkpointing=False)
            trainer.callbacks.append(cb)
            res = trainer.test(Module(), dataloaders=loader(samples, 4), verbose=False)[0]
            rows = []
            for batch in loader(samples, 4):
                rows += ssr.view_outcomes(batch, {"m": [scorer(batch)]}, scenes, top_k)
            outcomes = [r[2]["m"][0] for r in rows]
            # the breakdown's verdict is the annotation's: success exactly where the outcome is one
            assert [r[3]["m"][0] == "success" for r in rows] == outcomes
            assert len(outcomes) == len(samples) > 0
            assert np.mean(outcomes) == pytest.approx(res["test_sr_all"]), (scorer.__name__, top_k)
            seen |= set(outcomes)
    assert seen == {True, False}  # both outcomes occur, so the agreement says something


def test_full_cloud_checks_the_batchs_stored_cloud_not_its_sample(sim_scenes):
    """``full_cloud`` reads the batch's ``full_xyz`` (every stored point, as the DataModule's ``full_cloud`` gives it):
    with the sample masked out it chooses as the full sample does; a batch without it is an error naming the fix."""
    from tests.report._fake_world import loader

    scenes, samples = sim_scenes
    stored = [{**s, "full_xyz": s["scene_xyz"].clone()} for s in samples]
    refused = 0  # views whose choice the cloud check changes: without them the comparison says nothing
    for batch in loader(stored, 4):
        blind = {**batch, "scene_mask": torch.zeros_like(batch["scene_mask"])}  # no point left in the sample
        scores = {"m": [_behind(batch)]}  # a poor map: the footprint check changes choices
        full = ssr.view_outcomes(batch, scores, scenes, top_k=5)
        assert ssr.view_outcomes(blind, scores, scenes, top_k=5, full_cloud=True) == full
        refused += sum(x != y for x, y in zip(ssr.view_outcomes(blind, scores, scenes, top_k=5), full))
    assert refused > 0
    batch = next(iter(loader(samples, 4)))
    with pytest.raises(ValueError, match="full_cloud: true"):
        ssr.view_outcomes(batch, {"m": [_behind(batch)]}, scenes, top_k=5, full_cloud=True)


def test_min_observed_changes_choices_only_among_free_cells(sim_scenes):
    """``min_observed`` 0 is the free-only check; a high share moves some views to other cells of their top-k (with
    another outcome: the tiny scenes' views see little of the floor)."""
    from tests.report._fake_world import loader

    scenes, samples = sim_scenes
    moved = 0
    for batch in loader(samples, 4):
        scores = {"m": [_noisy_labels(batch)]}
        free_only = ssr.view_outcomes(batch, scores, scenes, top_k=5)
        assert ssr.view_outcomes(batch, scores, scenes, top_k=5, min_observed=0.0) == free_only
        observed = ssr.view_outcomes(batch, scores, scenes, top_k=5, min_observed=0.9)
        moved += sum(x != y for x, y in zip(observed, free_only))
    assert moved > 0


def test_main_asks_the_datamodule_for_the_stored_cloud(monkeypatch, tmp_path):
    """``--full-cloud`` builds the DataModule with ``full_cloud=True`` (its batches then carry ``full_xyz``)."""
    import floaff_zoo.data.floaff_kitchen as fk
    import floaff_zoo.predict as pr

    seen: dict = {}

    class Spy:
        def __init__(self, **kwargs):
            seen.update(kwargs)
            raise ValueError("spy: stop before loading data")

    monkeypatch.setattr(fk, "FloAffKitchenDataModule", Spy)
    monkeypatch.setattr(pr, "resolve_model", lambda name: torch.nn.Identity())
    for flags, expected in ((["--top-k", "10", "--full-cloud"], True), (["--top-k", "10"], False)):
        with pytest.raises(SystemExit, match="spy: stop before loading data"):
            ssr.main(["--root", str(tmp_path), *flags, "m=some.ckpt"])
        assert seen["full_cloud"] is expected


def knife_edge_view(top_k: int = 3) -> tuple[dict, dict[str, dict], np.ndarray]:
    """One view whose top-k footprint check chooses another cell at the view's float32 pose than at the exact pose the
    callback rolls out (``target_world``: the annotation's float64 yaw from the rounded cell): two obstacle points of
    its cloud lie inside the best cell's footprint at the exact pose and outside it at the float32 one.

    Returns (batch of the view, {scene id: record} whose only successful cell is the one the callback chooses,
    scores [1, M]).
    """
    from floaff_zoo.callbacks.rollout import choose_pose, cloud_free
    from floaff_zoo.contract import collate_samples
    from floaff_zoo.floor import FOOTPRINT, _footprint_frame
    from floaff_zoo.frames import base_to_world
    from floaff_zoo.sim.kitchen import SceneSpec
    from tests.report._fake_world import make_samples, world_to_base

    for sample in make_samples(40, target_world=True):
        batch = collate_samples([sample])
        sim = sample["meta"]["sim"]
        base, facing = sim["base_pose_world"], sim["target_world"]
        floor, mask, target = (batch[k][0].numpy() for k in ("floor_xyz", "floor_mask", "target_xyz"))
        scores = np.linspace(1.0, 0.0, len(floor))
        exact = choose_pose(floor, scores, mask, target, base, 1, None, 0, None, facing)[0]
        f32 = choose_pose(floor, scores, mask, target, base)[0]
        # points on the exact footprint's front edge, stored as a float32 cloud in the view's base frame
        c, s = math.cos(exact[2]), math.sin(exact[2])
        a, w = (g.ravel() for g in np.meshgrid(FOOTPRINT[2] + np.linspace(-3e-7, 3e-7, 61), np.linspace(-0.2, 0.2, 41)))
        world = np.stack([exact[0] + c * a - s * w, exact[1] + s * a + c * w], axis=1)
        pts = np.c_[world_to_base(world, base), np.full(len(world), 0.5)].astype(np.float32)
        back = base_to_world(pts, base)
        edge = np.unique(
            pts[_footprint_frame(back, exact, FOOTPRINT)[0] & ~_footprint_frame(back, f32, FOOTPRINT)[0]], axis=0
        )
        if len(edge) < 2:
            continue
        cloud = edge[:2]
        cells = base_to_world(floor.astype(np.float64), base)[:, :2].round(2)
        free = cloud_free(cloud, base)
        chosen = [choose_pose(floor, scores, mask, target, base, top_k, free, 0, None, t)[0] for t in (facing, None)]
        by_callback, by_float32 = (int(np.linalg.norm(cells - np.asarray(p[:2]), axis=1).argmin()) for p in chosen)
        if by_callback == by_float32:
            continue
        batch = {**batch, "scene_xyz": torch.from_numpy(cloud)[None], "scene_mask": torch.ones(1, 2, dtype=torch.bool)}
        success = np.zeros(len(cells))
        success[by_callback] = 1.0
        sid = SceneSpec.from_dict(sim).scene_id
        scene = {"candidates": {"xy": cells.tolist(), "cell": 0.05}, "labels": {"success": success.tolist()}}
        return batch, {sid: scene}, scores[None]
    raise AssertionError("no view of the fake world puts a point between the two poses' footprints")


def test_top_k_checks_each_footprint_at_the_pose_the_callback_rolls_out():
    """``--top-k`` checked the footprints of poses rebuilt from the view's float32 points, whose yaw misses the exact
    pose the callback rolls out by ~1e-7 rad: a point on a footprint's edge freed a cell there that the callback
    refuses, and the script scored another cell than the test's for the same view."""
    batch, scenes, scores = knife_edge_view(top_k=3)
    rows = ssr.view_outcomes(batch, {"m": [scores]}, scenes, top_k=3)
    assert rows[0][2]["m"] == [True]  # the callback's cell: the only successful one


def test_label_cell_takes_the_nearest_cell_within_half_a_diagonal():
    cand = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1], [0.1, 0.1]])
    assert ssr.label_cell(cand, (0.1, 0.1, 0.0), 0.1, "s", off_grid=False) == 3
    assert ssr.label_cell(cand, (0.14, 0.04, 0.0), 0.1, "s", off_grid=True) == 1  # another lattice's cell
    assert ssr.label_cell(cand, (0.16, 0.16, 0.0), 0.1, "s", off_grid=True) is None  # outside the label window
    with pytest.raises(ValueError, match="off the scene's candidate grid"):
        ssr.label_cell(cand, (0.14, 0.04, 0.0), 0.1, "s", off_grid=False)


def test_deployment_queries_are_the_robots_grid_and_choices_take_the_nearest_label(sim_scenes):
    """``--deploy-queries``: the models are asked about ``predict``'s default grid of each view (every stored point),
    and a choice is scored by the label cell under it. A scorer that knows the labels of the cells under the queries
    must then succeed exactly in the views whose grid covers a successful label cell."""
    from floaff_zoo.frames import base_to_world
    from floaff_zoo.predict import default_floor_grid
    from floaff_zoo.sim.kitchen import SceneSpec
    from tests.report._fake_world import loader

    scenes, samples = sim_scenes
    stored = [{**s, "full_xyz": s["scene_xyz"].clone()} for s in samples]
    outside = 0  # views whose grid reaches outside the label window: without them the off_grid check says nothing
    for batch in loader(stored, 4):
        cell = float(next(iter(scenes.values()))["candidates"]["cell"])
        dep = ssr.deployment_queries(batch, cell)
        known = np.zeros(dep["floor_mask"].shape)  # 1: over a successful label cell, 0: a failed one, -1: none
        expect = []
        for i, meta in enumerate(batch["meta"]):
            grid = default_floor_grid(batch["target_xyz"][i].numpy(), batch["full_xyz"][i].numpy(), None, cell)
            n = int(dep["floor_mask"][i].sum())
            assert n == len(grid) and torch.equal(dep["floor_xyz"][i, :n], torch.from_numpy(grid))
            scene = scenes[SceneSpec.from_dict(meta["sim"]).scene_id]
            cand = np.asarray(scene["candidates"]["xy"], float)
            success = np.asarray(scene["labels"]["success"]) > 0
            world = base_to_world(grid, meta["sim"]["base_pose_world"])
            for j, xy in enumerate(world):
                c = ssr.label_cell(cand, xy, cell, "s", off_grid=True)
                known[i, j] = -1.0 if c is None else float(success[c])
            expect.append(bool((known[i, :n] == 1).any()))
        rows = ssr.view_outcomes(dep, {"m": [known]}, scenes, off_grid=True)
        assert [r[2]["m"][0] for r in rows] == expect
        unknown = -known  # prefers the cells outside the label window: their choices fail as off_grid
        off = ssr.view_outcomes(dep, {"m": [unknown]}, scenes, off_grid=True)
        assert all(r[3]["m"][0] == ssr.OFF_GRID and not r[2]["m"][0] for r, k in zip(off, known) if (k == -1).any())
        outside += sum(bool((k == -1).any()) for k in known)
    assert outside > 0
    with pytest.raises(ValueError, match="full_cloud: true"):
        ssr.deployment_queries(next(iter(loader(samples, 4))), 0.1)


def test_mask_centroid_targets_is_the_mean_of_the_flagged_points(tmp_path, capsys):
    from floaff_zoo.contract import collate_samples
    from floaff_zoo.data.synthetic import make_synthetic_sample

    batch = collate_samples([make_synthetic_sample(0, num_points=256), make_synthetic_sample(1, num_points=200)])
    out, kept = ssr.mask_centroid_targets(batch)
    assert kept == 0
    for i in range(2):
        flagged = batch["scene_mask"][i] & (batch["scene_feat"][i, :, 0] > 0)
        torch.testing.assert_close(out["target_xyz"][i], batch["scene_xyz"][i][flagged].mean(dim=0))
    feat = batch["scene_feat"].clone()
    feat[1, :, 0] = 0.0  # the second view's sample shows no target point: it keeps the task's target, counted
    out, kept = ssr.mask_centroid_targets({**batch, "scene_feat": feat})
    assert kept == 1 and torch.equal(out["target_xyz"][1], batch["target_xyz"][1])
    with pytest.raises(SystemExit):
        ssr.main(["--root", str(tmp_path), "--target-from-mask", "a=x.ckpt"])
    assert "give --deploy-queries" in capsys.readouterr().err


def test_a_model_without_a_floor_map_exits_naming_it(tmp_path):
    """An AxisNet checkpoint was scored as floor maps: the script went on to the data and failed somewhere unrelated."""
    import re

    from tests.test_val_sr import axisnet_ckpt

    ckpt = axisnet_ckpt(tmp_path / "axisnet.ckpt")
    with pytest.raises(SystemExit, match=rf"scene_sr: {re.escape(str(ckpt))}: .*AxisNetModule predicts no floor map"):
        ssr.main(["--root", str(tmp_path / "missing"), f"a={ckpt}"])


def test_a_generated_row_name_that_is_a_given_name_is_refused(tmp_path, capsys):
    """NAME@s and NAME+ens replaced the runs of a NAME given that way, and the table scored the copies under it."""

    class Run:
        def __init__(self, prior):
            self.prior, self.hparams = prior, {"residual_scale": 1.0}

    with pytest.raises(ValueError, match=r"would name rows \['recipe@0'\]"):
        ssr.with_residual_scales({"recipe": [Run(object())], "recipe@0": [Run(None)]}, [0.0])
    with pytest.raises(SystemExit) as done:
        ssr.main(["--root", str(tmp_path), "--ensemble", "a=x.ckpt", "a=y.ckpt", "a+ens=z.ckpt"])
    assert done.value.code == 2 and "--ensemble would name rows ['a+ens']" in capsys.readouterr().err
