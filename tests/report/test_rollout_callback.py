"""RolloutSuccessRate with a fake rollout service (success = deterministic function of the world pose)."""

import math
import warnings

import lightning as L
import numpy as np
import pytest
import torch

from floaff_zoo.callbacks.rollout import (
    RolloutSuccessRate,
    base_to_world,
    bootstrap_std,
    check_clouds,
    choose_pose,
    cloud_free,
    cloud_observed,
    pose_to_world,
    summarize_episodes,
)
from tests.report._fake_jobs import BASE_RATE
from tests.report._fake_world import ConstantModule, FakeService, LabelModule, loader, make_samples, quiet_trainer


def _trainer(cb):
    return quiet_trainer([cb])


def test_base_to_world_round_trip():
    pose = (1.0, -2.0, math.pi / 2)
    p = base_to_world(np.array([[1.0, 0.0, 0.3]]), pose)
    assert np.allclose(p, [[1.0, -1.0, 0.3]])  # x forward of a base facing +y is world +y
    w = pose_to_world((1.0, 0.0, 0.0), pose)
    assert np.allclose(w, (1.0, -1.0, math.pi / 2))


def test_choose_pose_top_k_skips_blocked_footprints():
    floor = np.array([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    scores = np.array([0.9, 0.8, 0.1])
    target = np.array([0.0, 0.0, 0.9])
    base = (0.0, 0.0, 0.0)
    assert choose_pose(floor, scores, None, target, base, top_k=1)[0][:2] == (1.0, 0.0)
    pose, rank = choose_pose(floor, scores, None, target, base, top_k=3, is_free=lambda x, y, yaw: x > 1.5)
    assert (pose[:2], rank) == ((2.0, 0.0), 1)
    assert math.isclose(pose[2], math.pi)  # heading toward the target
    # nothing free -> top-1
    assert choose_pose(floor, scores, None, target, base, top_k=3, is_free=lambda *a: False)[1] == 0


def test_choose_pose_prefers_free_poses_that_pass_the_stricter_check():
    floor = np.array([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0], [4.0, 0, 0]])
    scores = np.array([0.9, 0.8, 0.7, 0.6])
    target, base = np.array([0.0, 0.0, 0.9]), (0.0, 0.0, 0.0)
    free = lambda x, y, yaw: x > 1.5  # noqa: E731
    # the best free and preferred candidate wins over a better-scored free one
    pose, rank = choose_pose(floor, scores, None, target, base, 4, free, prefer=lambda x, y, yaw: x > 2.5)
    assert (pose[:2], rank) == ((3.0, 0.0), 2)
    # a preferred candidate that is not free never wins
    assert choose_pose(floor, scores, None, target, base, 4, free, prefer=lambda x, y, yaw: x < 1.5)[1] == 1
    # none of the top-k preferred: the free-only choice; outside the top-k nothing counts
    assert choose_pose(floor, scores, None, target, base, 4, free, prefer=lambda *a: False)[1] == 1
    assert choose_pose(floor, scores, None, target, base, 2, free, prefer=lambda x, y, yaw: x > 3.5)[1] == 1


def test_choose_pose_and_check_clouds_refuse_bad_arguments():
    floor, scores, target, base = np.array([[1.0, 0, 0], [2.0, 0, 0]]), np.array([0.9, 0.8]), np.zeros(3), (0, 0, 0)
    for top_k in (0, -3, 2.5):  # 0 and -3 ran as 1, 2.5 failed as a slice
        with pytest.raises(ValueError, match=f"choose_pose: top_k must be an integer >= 1, got {top_k}"):
            choose_pose(floor, scores, None, target, base, top_k=top_k)
    batch = {"scene_xyz": torch.zeros(1, 4, 3), "scene_mask": torch.ones(1, 4, dtype=torch.bool)}
    for free_space in ("Cloud", "sim"):  # a KeyError named no argument
        with pytest.raises(ValueError, match=f"check_clouds: free_space must be one of .*got '{free_space}'"):
            check_clouds(batch, free_space)


def test_cloud_observed_reads_the_footprint_coverage_in_the_world():
    """A view whose robot faces +y sees floor points ahead of it; a pose there is observed, one beside it is not."""
    base = (1.0, 2.0, math.pi / 2)
    ahead = np.array([[x, y, 0.0] for x in np.arange(0.6, 1.3, 0.05) for y in np.arange(-0.3, 0.3, 0.05)])
    observed = cloud_observed(ahead, base, 0.5)
    assert observed(1.0, 2.0 + 0.9 + 0.2, math.pi / 2)  # the world pose 0.9 m + 0.2 m ahead of the view's robot
    assert not observed(3.0, 2.0, 0.0)
    for bad in (float("nan"), 1.5):  # every footprint read as unseen
        with pytest.raises(ValueError, match="cloud_observed: min_observed must be a finite number >= 0 and <= 1"):
            cloud_observed(ahead, base, bad)


def test_constant_map_uses_documented_tie_break():
    floor = np.array([[3.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    picks = {choose_pose(floor, np.zeros(3), None, np.zeros(3), (0.0, 0.0, 0.0), seed=s)[0][:2] for s in range(30)}
    assert picks == {(3.0, 0.0), (1.0, 0.0), (2.0, 0.0)}  # seeded random tie-break covers every candidate
    assert choose_pose(floor, np.zeros(3), None, np.zeros(3), (0.0, 0.0, 0.0), seed=7) == choose_pose(
        floor, np.zeros(3), None, np.zeros(3), (0.0, 0.0, 0.0), seed=7
    )


def test_summary_and_bootstrap():
    eps = [
        {"task": "A", "view": "front", "success": True, "oracle_success": True},
        {"task": "A", "view": "side", "success": False, "oracle_success": True},
        {"task": "B", "view": "side", "success": False, "oracle_success": True},
        {"task": "B", "view": "front", "success": True, "oracle_success": False},
    ]
    s = summarize_episodes(eps, n_bootstrap=500)
    assert s["model"]["front"]["mean"] == 1.0 and s["model"]["side"]["mean"] == 0.0
    assert s["model"]["all"] == {"mean": 0.5, "std": pytest.approx(0.25, abs=0.05), "n": 4}
    assert s["oracle"]["tasks"]["B"]["mean"] == 0.5
    assert bootstrap_std([1, 1, 1]) == 0.0 and bootstrap_std([1]) == 0.0
    # bootstrap std of a mean of 400 fair coins ~ sqrt(.25/400) = 0.025
    assert bootstrap_std(np.arange(400) % 2, 2000) == pytest.approx(0.025, abs=0.004)
    with pytest.raises(ValueError, match="bootstrap_std: outcomes must be 0/1"):
        bootstrap_std([1, float("nan"), 0])  # a NaN std before
    with pytest.raises(ValueError, match="bootstrap_std: n_bootstrap must be an integer >= 0, got 1.5"):
        bootstrap_std([1, 0, 1], 1.5)


def test_oracle_and_perfect_model_succeed_constant_map_scores_base_rate():
    samples = make_samples(160)
    cb = RolloutSuccessRate(service=FakeService, progress=False)
    res = _trainer(cb).test(LabelModule(), dataloaders=loader(samples), verbose=False)[0]
    assert res["test_sr_all"] == 1.0 and res["test_oracle_sr_all"] == 1.0
    for key in (
        "test_sr_front",
        "test_sr_side",
        "test_sr_CloseDrawer",
        "test_sr_OpenSingleDoor",
        "test_sr_all_std",
        "test_oracle_sr_front",
        "test_oracle_sr_CloseDrawer",
        "test_rollout_seconds",
    ):
        assert key in res, key
    assert cb.summaries["test"]["n_evaluated"] == 160 and cb.summaries["test"]["model"]["front"]["n"] == 80

    cb = RolloutSuccessRate(service=FakeService, progress=False)
    res = _trainer(cb).test(ConstantModule(), dataloaders=loader(samples), verbose=False)[0]
    assert res["test_oracle_sr_all"] == 1.0
    assert abs(res["test_sr_all"] - BASE_RATE) < 0.12, res["test_sr_all"]
    svc = FakeService.instances[-1]
    assert svc.closed  # the service is closed at teardown
    # model and oracle jobs are deduplicated by (scene, rounded pose)
    keys = {(s.scene_id, round(p[0], 2), round(p[1], 2), round(p[2], 2)) for s, p in svc.jobs}
    assert len(keys) == len(svc.jobs) <= 320


def test_validation_every_n_epochs_logs_val_rollout_success():
    samples = make_samples(8)
    cb = RolloutSuccessRate(service=FakeService, progress=False, every_n_val_epochs=2, max_val_samples=4, on_test=False)
    trainer = L.Trainer(
        accelerator="cpu",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        enable_checkpointing=False,
        callbacks=[cb],
        max_epochs=2,
        num_sanity_val_steps=1,
        limit_train_batches=1,
    )
    n0 = len(FakeService.instances)
    trainer.fit(LabelModule(), train_dataloaders=loader(samples), val_dataloaders=loader(samples, 2))
    assert trainer.callback_metrics["val_rollout_success"] == 1.0
    assert cb.summaries["val"]["n_evaluated"] == 4  # capped
    assert len(FakeService.instances) == n0 + 1  # one service for the whole fit (its cache persists)


def test_validation_summary_counts_the_samples_the_cap_left_out():
    """Past max_val_samples the callback stopped looking: the sim samples the cap left out and the samples without sim
    after it were counted nowhere (n_skipped 0, no n_capped), so a capped SR read as the whole split's."""
    samples = make_samples(8)
    for s in samples[5:]:  # the last 3 cannot be rolled out (no sim metadata), all after the cap
        s["meta"].pop("sim")
    cb = RolloutSuccessRate(service=FakeService, progress=False, every_n_val_epochs=1, max_val_samples=2, on_test=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _trainer(cb).validate(LabelModule(), dataloaders=loader(samples, 2), verbose=False)
    summary = cb.summaries["val"]
    assert (summary["n_evaluated"], summary["n_capped"], summary["n_skipped"]) == (2, 3, 3)


def test_samples_without_sim_are_skipped_with_one_warning():
    samples = make_samples(6)
    for s in samples:
        s["meta"].pop("sim")
    cb = RolloutSuccessRate(service=FakeService, progress=False)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        res = _trainer(cb).test(ConstantModule(), dataloaders=loader(samples, 2), verbose=False)[0]
    msgs = [str(w.message) for w in rec if "RolloutSuccessRate" in str(w.message)]
    assert len(msgs) == 1 and "skipped 6" in msgs[0]
    assert not any(k.startswith("test_sr") for k in res)
    assert cb.summaries["test"]["available"] is False


def test_bad_sim_metadata_is_named():
    samples = make_samples(2)
    samples[1]["meta"]["sim"]["layout_id"] = 99
    cb = RolloutSuccessRate(service=FakeService, progress=False)
    with pytest.raises(ValueError, match="fake1.*layout_id"):
        _trainer(cb).test(ConstantModule(), dataloaders=loader(samples), verbose=False)


def _obstacle(x: float, y: float, n: int = 4) -> np.ndarray:
    """n obstacle points [n, 3] float32 stacked 1 cm apart at (x, y) from 0.5 m up: distinct points, since the
    footprint check counts one point repeated as one."""
    return np.array([[x, y, 0.5 + 0.01 * k] for k in range(n)], np.float32)


def test_top_k_with_cloud_free_space_avoids_an_observed_obstacle():
    """free_space='cloud': the best pose whose footprint holds furniture points of the view's own cloud is passed
    over for the next free one, with no simulator in the loop."""
    import torch

    from floaff_zoo.contract import best_pose
    from floaff_zoo.floor import footprint_blocked

    samples = make_samples(16)
    for s in samples:
        x, y, yaw = best_pose(
            s["floor_xyz"], s["floor_label"], s["floor_mask"], s["target_xyz"], seed=s["meta"]["index"]
        )[0]
        back = _obstacle(x - 0.2 * math.cos(yaw), y - 0.2 * math.sin(yaw))  # behind the origin
        s["scene_xyz"] = torch.cat([s["scene_xyz"], torch.from_numpy(back)])
        s["scene_feat"] = torch.cat([s["scene_feat"], torch.ones(4, s["scene_feat"].shape[1])])
        s["scene_mask"] = torch.cat([s["scene_mask"], torch.ones(4, dtype=torch.bool)])
    for top_k in (1, 8):
        cb = RolloutSuccessRate(service=FakeService, progress=False, top_k=top_k, free_space="cloud", oracle=True)
        _trainer(cb).test(LabelModule(), dataloaders=loader(samples), verbose=False)
        eps = cb.episodes["test"]
        assert cb.summaries["test"]["free_space"] == "cloud"
        for e, s in zip(eps, samples):  # the Oracle stands on the label's argmax whatever the check says
            seed = s["meta"]["index"]
            argmax = best_pose(s["floor_xyz"], s["floor_label"], s["floor_mask"], s["target_xyz"], seed=seed)[0]
            assert np.allclose(e["oracle_pose"], pose_to_world(argmax, s["meta"]["sim"]["base_pose_world"]))
        if top_k == 1:
            assert all(e["rank"] == 0 for e in eps)
            continue
        assert all(e["rank"] > 0 for e in eps)  # the argmax is blocked in every view
        for e, s in zip(eps, samples):
            world = base_to_world(s["scene_xyz"].numpy(), s["meta"]["sim"]["base_pose_world"])
            assert not footprint_blocked(world, e["pose"])


class ProposingModule(LabelModule):
    """A perfect map, and a placement procedure of its own that stands 0.3 m ahead, 0.1 m left, turned 0.2 rad."""

    def propose_pose(self, item):
        assert item["scene_xyz"].shape[0] == 1  # one sample, as N2M's and C2F-Exp's procedures take it
        return (0.3, 0.1, 0.2)


def test_pose_source_model_rolls_out_the_models_own_placement():
    """N2M's and C2F-Exp's SR stood on their maps' argmax, never on their own published placement procedures."""
    samples = make_samples(6)
    cb = RolloutSuccessRate(service=FakeService, progress=False, pose_source="model", oracle=True)
    _trainer(cb).test(ProposingModule(), dataloaders=loader(samples), verbose=False)
    assert cb.summaries["test"]["pose_source"] == "model"
    for e, s in zip(cb.episodes["test"], samples):
        base = s["meta"]["sim"]["base_pose_world"]
        assert np.allclose(e["pose"], pose_to_world((0.3, 0.1, 0.2), base))
        assert not np.allclose(e["pose"], e["oracle_pose"])  # the map's argmax is not what was rolled out
    cb = RolloutSuccessRate(service=FakeService, progress=False)
    _trainer(cb).test(ProposingModule(), dataloaders=loader(samples), verbose=False)
    assert cb.summaries["test"]["pose_source"] == "map"
    assert all(np.allclose(e["pose"], e["oracle_pose"]) for e in cb.episodes["test"])  # the perfect map's argmax


def test_pose_source_model_needs_a_placement_procedure_and_top_1():
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    with pytest.raises(ValueError, match="pose_source must be one of"):
        RolloutSuccessRate(pose_source="models")
    with pytest.raises(ValueError, match="top_k must be 1, got 5"):
        RolloutSuccessRate(pose_source="model", top_k=5)
    cb = RolloutSuccessRate(service=FakeService, progress=False, pose_source="model")
    with pytest.raises(MisconfigurationException, match="LabelModule has no placement procedure of its own"):
        _trainer(cb).test(LabelModule(), dataloaders=loader(make_samples(2)), verbose=False)


def test_free_space_is_checked():
    with pytest.raises(ValueError, match="free_space"):
        RolloutSuccessRate(free_space="cloudy")


@pytest.mark.parametrize(
    "kwargs, message",
    [
        # 2.5 failed at the end of the epoch (a slice, a round(), a resample size); True or NaN ran as another value
        ({"top_k": 2.5}, "top_k must be an integer >= 1, got 2.5"),
        ({"top_k": float("nan")}, "top_k must be an integer >= 1, got nan"),
        ({"top_k": True}, "top_k must be an integer >= 1, got True"),
        ({"top_k": "3"}, "top_k must be an integer >= 1, got '3'"),
        ({"n_bootstrap": 1.5}, "n_bootstrap must be an integer >= 0, got 1.5"),
        ({"cache_decimals": 2.5}, "cache_decimals must be an integer >= 0, got 2.5"),
        ({"max_val_samples": 2.5}, r"max_val_samples must be an integer >= 1 or null \(all\), got 2.5"),
        ({"every_n_val_epochs": 1.5}, "every_n_val_epochs must be an integer >= 0, got 1.5"),
        ({"workers": 1.5}, "workers must be an integer >= 1, got 1.5"),
        ({"backend": "Ray"}, r"backend must be one of \['local', 'ray'\], got 'Ray'"),
        ({"oracle": "no"}, "oracle must be true or false, got 'no'"),
        ({"on_test": "false"}, "on_test must be true or false, got 'false'"),
    ],
)
def test_constructor_refuses_bad_values_before_any_epoch(kwargs, message):
    with pytest.raises(ValueError, match=f"RolloutSuccessRate: {message}"):
        RolloutSuccessRate(service=FakeService, progress=False, **kwargs)


def test_ray_backend_without_ray_is_refused_at_construction(monkeypatch):
    """The default service is built when the first rollout runs: without ray that failed after the whole epoch."""
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else find_spec(name, *a))
    with pytest.raises(ValueError, match="backend 'ray' needs the 'ray' package"):
        RolloutSuccessRate(backend="ray")
    RolloutSuccessRate(backend="ray", service=FakeService)  # an injected service need not be ray's


def test_cloud_free_margin_grows_the_footprint_on_every_side():
    """An obstacle 5 cm outside each side of the footprint is free at margin 0 and blocked at margin 0.1."""
    from floaff_zoo.floor import FOOTPRINT

    length, width, front = FOOTPRINT
    pose = (0.0, 0.0, 0.0)  # world = base frame: the view's robot stands at the origin facing +x
    for x, y in ((front + 0.05, 0.0), (front - length - 0.05, 0.0), (0.0, width / 2 + 0.05), (0.0, -width / 2 - 0.05)):
        cloud = _obstacle(x, y, n=2)
        assert cloud_free(cloud, pose)(*pose)
        assert not cloud_free(cloud, pose, margin=0.1)(*pose), (x, y)


def _stored_obstacle(samples: list[dict]) -> list[dict]:
    """Give every sample a stored cloud (``full_xyz``) that holds, besides its own points, four obstacle points in
    the footprint of the label's argmax pose; the batch's sample (``scene_xyz``) stays without them."""
    import torch

    from floaff_zoo.contract import best_pose

    for s in samples:
        x, y, yaw = best_pose(
            s["floor_xyz"], s["floor_label"], s["floor_mask"], s["target_xyz"], seed=s["meta"]["index"]
        )[0]
        back = _obstacle(x - 0.2 * math.cos(yaw), y - 0.2 * math.sin(yaw))
        s["full_xyz"] = torch.cat([s["scene_xyz"], torch.from_numpy(back)])
    return samples


def test_full_cloud_free_space_reads_the_stored_cloud_not_the_sample():
    """free_space='full_cloud' sees an obstacle that only the stored cloud holds; 'cloud' (the batch's sample) does not,
    so the two choose differently on the same batch."""
    from floaff_zoo.floor import footprint_blocked

    samples = _stored_obstacle(make_samples(16))
    chosen = {}
    for free_space in ("cloud", "full_cloud"):
        cb = RolloutSuccessRate(service=FakeService, progress=False, top_k=8, free_space=free_space, oracle=False)
        _trainer(cb).test(LabelModule(), dataloaders=loader(samples), verbose=False)
        assert cb.summaries["test"]["free_space"] == free_space
        chosen[free_space] = cb.episodes["test"]
    assert all(e["rank"] == 0 for e in chosen["cloud"])  # the sample holds no obstacle: the argmax stands
    assert all(e["rank"] > 0 for e in chosen["full_cloud"])  # the stored cloud blocks the argmax in every view
    for e, s in zip(chosen["full_cloud"], samples):
        world = base_to_world(s["full_xyz"].numpy(), s["meta"]["sim"]["base_pose_world"])
        assert not footprint_blocked(world, e["pose"])


def test_full_cloud_free_space_without_a_stored_cloud_is_refused():
    """A batch without full_xyz is named at its first batch; a DataModule with full_cloud false before any epoch."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    cb = RolloutSuccessRate(service=FakeService, progress=False, top_k=8, free_space="full_cloud", oracle=False)
    with pytest.raises(ValueError, match="full_xyz.*full_cloud: true"):
        _trainer(cb).test(LabelModule(), dataloaders=loader(make_samples(4)), verbose=False)
    no_sim = make_samples(4)  # nothing to roll out (MoMa-Kitchen-like): skipped and counted, not refused
    for s in no_sim:
        s["meta"].pop("sim")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _trainer(cb).test(LabelModule(), dataloaders=loader(no_sim), verbose=False)
    assert cb.summaries["test"]["available"] is False and cb.summaries["test"]["n_skipped"] == 4

    class NoStoredCloud(L.LightningDataModule):
        full_cloud = False

        def test_dataloader(self):
            return loader(make_samples(4))

    cb = RolloutSuccessRate(service=FakeService, progress=False, top_k=8, free_space="full_cloud", oracle=False)
    with pytest.raises(MisconfigurationException, match="NoStoredCloud has full_cloud: false"):
        _trainer(cb).test(LabelModule(), datamodule=NoStoredCloud(), verbose=False)


def test_a_chosen_cell_is_rolled_out_at_the_annotations_exact_pose():
    """A pose chosen from the view's float32 base frame rounds to its cell's (x, y), but its yaw missed the annotated
    one (atan2 toward the target in float64, rounded to 6 decimals) by 1e-6 rad in some views, which flips
    knife-edge rollouts; with the target's world (x, y) in meta['sim'] every chosen and Oracle pose is the
    annotation's to the last decimal."""
    samples = make_samples(60, target_world=True)
    cb = RolloutSuccessRate(service=FakeService, progress=False)
    _trainer(cb).test(ConstantModule(), dataloaders=loader(samples), verbose=False)
    by_id = {s["meta"]["sample_id"]: s for s in samples}
    for ep in cb.episodes["test"]:
        s = by_id[ep["sample_id"]]
        sim = s["meta"]["sim"]
        cells = base_to_world(np.asarray(s["floor_xyz"], dtype=np.float64), sim["base_pose_world"])[:, :2].round(2)
        tx, ty = sim["target_world"]
        annotated = {(x, y, round(math.atan2(ty - y, tx - x), 6)) for x, y in cells.tolist()}
        for key in ("pose", "oracle_pose"):
            assert tuple(round(v, 6) for v in ep[key]) in annotated, (ep["sample_id"], key, ep[key])


def test_facing_pose_rounds_the_position_and_faces_the_target_from_it():
    from floaff_zoo.frames import facing_pose

    x, y, yaw = facing_pose((1.0000004, -0.4999996, 2.0), (2.0, 0.5))
    assert (x, y) == (1.0, -0.5) and yaw == math.atan2(1.0, 1.0)


def test_a_stood_in_sample_counts_once_toward_the_validation_cap():
    """A view that broke after setup is stood in for by the next record, which then arrives twice (as the stand-in and
    in its own place): both counted toward max_val_samples, so validation scored 3 views where 4 were asked for."""
    from floaff_zoo.contract import collate_samples

    samples = make_samples(6)
    stand_in = dict(samples[2], meta=dict(samples[2]["meta"], replaces=samples[1]["meta"]["sample_id"]))
    order = [samples[0], stand_in, samples[2], samples[3], samples[4], samples[5]]
    cb = RolloutSuccessRate(service=FakeService, progress=False, max_val_samples=4)
    cb._start("val", True)
    for b in range(0, len(order), 2):
        batch = collate_samples(order[b : b + 2])
        # the validation hook, as the trainer calls it with validation_step's scores
        cb.on_validation_batch_end(None, None, {"scores": batch["floor_label"]}, batch, b // 2)
    want = [samples[i]["meta"]["sample_id"] for i in (0, 2, 3, 4)]
    # the stand-in's own copy is not collected at all (no pose chosen for it), so nothing is left for _pool to drop
    assert [e["sample_id"] for e in cb._pending["val"]] == want
    assert [e["sample_id"] for e in cb._pool("val", cb._pending["val"], False)] == want
