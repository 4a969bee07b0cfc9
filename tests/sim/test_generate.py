"""Benchmark generator: planning, file format, end-to-end tiny run, resume, worker-count determinism, retries."""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim import generate as gen
from floaff_zoo.sim.presets import PAPER_VIEW_TOTALS, PRESETS, get_preset, view_counts


# ------------------------------------------------------------------------------------------------ no simulation
def test_plan_is_deterministic_and_splits_are_scene_level():
    p = get_preset("small")
    a = gen.plan_jobs(p, 7, list(range(6)), list(range(8)))
    b = gen.plan_jobs(p, 7, list(range(6)), list(range(8)))
    assert a == b and len(a) == 2 * 4 * (5 + 1)
    assert len({j.seeds[0] for j in a}) == len(a)  # every slot has its own seed
    assert gen.plan_jobs(p, 8, list(range(6)), list(range(8)))[0].seeds != a[0].seeds
    for j in a:
        if j.benchmark == "styles":
            assert (j.style_id == 7) == (j.split == "test") and j.layout_id != 5
        else:
            assert (j.layout_id == 5) == (j.split == "test") and j.style_id != 7


def test_a_slots_kitchen_does_not_depend_on_the_other_tasks_asked():
    """The kitchen of a slot followed its task's position in --tasks: a rerun that added a task before it drew every
    slot of the later tasks again (and an interrupted one left two scenes in one slot)."""
    ids = (list(range(6)), list(range(8)))

    def kitchens(tasks):
        jobs = gen.plan_jobs(get_preset("small", tasks=tasks), 0, *ids)
        return {j.key: (j.layout_id, j.style_id, j.seeds) for j in jobs if j.task == "CloseDrawer"}

    assert kitchens(("CloseDrawer",)) == kitchens(("OpenSingleDoor", "CloseDrawer")) == kitchens(PRESETS["small"].tasks)


def test_repeated_or_unsupported_settings_are_refused():
    with pytest.raises(ValueError, match=r"tasks: \['CloseDrawer'\] given more than once"):
        get_preset("tiny", tasks=("CloseDrawer", "CloseDrawer")).validate()
    with pytest.raises(ValueError, match=r"benchmarks: \['styles'\] given more than once"):
        get_preset("tiny", benchmarks=("styles", "styles")).validate()
    with pytest.raises(ValueError, match="r_arm must be None"):
        get_preset("tiny", r_arm=1.0).validate()


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("tasks", (), r"tasks must be a non-empty tuple of names, got \(\)"),  # a run of no scene, exit 0
        ("benchmarks", (), r"benchmarks must be a non-empty tuple of names, got \(\)"),
        ("tasks", "CloseDrawer", "tasks must be a non-empty tuple of names, got 'CloseDrawer'"),  # letter by letter
        ("use_paper_view_counts", "false", "use_paper_view_counts must be true or false, got 'false'"),  # was true
        ("floor_only", 0, "floor_only must be true or false, got 0"),
    ],
)
def test_names_and_switches_of_another_type_are_refused_by_name(field, value, message):
    """An empty tasks or benchmarks planned no scene and the run ended "done" with nothing; a text was read letter by
    letter ("unknown task(s) ['C', 'l', ...]"); the switch "false" was true (the paper's view counts)."""
    with pytest.raises(ValueError, match=message):
        get_preset("tiny", **{field: value})


def test_a_preset_name_that_is_not_a_text_is_refused_by_name():
    """A list failed with "unhashable type: 'list'"."""
    with pytest.raises(ValueError, match=r"unknown preset \['tiny'\]; choose from"):
        get_preset(["tiny"])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("sigma_cells", float("nan"), "sigma_cells must be a finite number >= 0, got nan"),
        ("sigma_cells", -1.0, "sigma_cells must be a finite number >= 0, got -1.0"),
        ("front_rx", float("nan"), "front_rx must be a finite number >= 0, got nan"),
        ("side_ry", -0.5, "side_ry must be a finite number >= 0, got -0.5"),
        ("max_dist", 0.0, "max_dist must be a finite number > 0, got 0.0"),
        ("front_rx", 0.0, r"front_rx must be > 0 \(its view region holds no base position\), got 0.0"),
        ("side_rx", 2.5, r"side_rx must be < max_dist \(its view region holds no base position\), got 2.5"),
        ("max_dist", float("inf"), "max_dist must be a finite number > 0, got inf"),
        ("cell", "0.05", "cell must be a finite number > 0, got '0.05'"),  # a TypeError naming nothing
        ("image_size", 64.0, "image_size must be an integer >= 1, got 64.0"),  # the renderer takes whole pixels
        ("views_per_scene", (1.5, 2), r"views_per_scene \(front\) must be an integer >= 0, got 1.5"),
        ("views_per_scene", (2,), r"views_per_scene must be \(front, side\), got \(2,\)"),
        ("views_per_scene", (2, 2, 2), r"views_per_scene must be \(front, side\), got \(2, 2, 2\)"),
        ("views_per_scene", 4, r"views_per_scene must be \(front, side\), got 4"),  # a TypeError naming nothing
        ("min_target_pixels", 0, "min_target_pixels must be an integer >= 1, got 0"),  # views without their target
        ("min_target_pixels", 2.5, "min_target_pixels must be an integer >= 1, got 2.5"),
    ],
)
def test_sizes_that_would_be_ignored_or_fail_each_scene_are_refused_by_name(field, value, message):
    """A NaN or negative sigma_cells skipped the label smoothing without a word (annotate smooths when sigma > 0); a
    NaN or negative view region gave none of its views, and such a max_dist none at all (every slot dropped after its
    annotation), without naming the setting; a views_per_scene of one number failed the plan with an IndexError and
    a third number was ignored."""
    with pytest.raises(ValueError, match=message):
        get_preset("tiny", **{field: value})


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"seed": 1.5}, ValueError, "seed must be an integer, got 1.5"),  # cut to seed 1, recorded as 1
        ({"seed": True}, ValueError, "seed must be an integer, got True"),
        ({"workers": 1.5}, ValueError, "workers must be an integer >= 0, got 1.5"),  # a TypeError in the pool
        ({"workers": "2"}, ValueError, "workers must be an integer >= 0, got '2'"),
        ({"preset": "tiny"}, TypeError, "preset must be a GenPreset"),  # an AttributeError on 'validate'
        ({"address": "ray://head:10001"}, ValueError, "address 'ray://head:10001' names a ray cluster"),  # ignored
    ],
)
def test_generate_refuses_a_seed_workers_or_preset_of_another_type_before_the_folder(tmp_path, kwargs, error, message):
    args = {"preset": get_preset("tiny"), "seed": 0, "workers": 0, **kwargs}
    with pytest.raises(error, match=message):
        gen.generate(tmp_path / "o", quiet=True, job_fn=_error_job, **args)
    assert not (tmp_path / "o").exists()
    with pytest.raises(ValueError, match="seed must be an integer, got 2.5"):
        gen.derive_seed(2.5, "views")


def test_plan_refuses_repeated_layout_or_style_ids():
    """With the held-out id also among the seen ones, the test split's kitchens were not unseen."""
    with pytest.raises(ValueError, match=r"layout ids given more than once: \[0, 0\]"):
        gen.plan_jobs(get_preset("tiny"), 0, [0, 0], [0, 1])
    with pytest.raises(ValueError, match=r"style ids given more than once: \[0, 1, 1\]"):
        gen.plan_jobs(get_preset("tiny"), 0, [0, 1], [0, 1, 1])


def test_a_slots_scenes_are_found_whatever_kitchen_they_hold(tmp_path):
    """Every committed scene whose scene.json names the slot, found by the slot and not by the slot's seeds; a scene
    drawn with other per-scene view counts (the paper preset under another --n-train) is not resumed."""
    (job,) = gen.plan_jobs(get_preset("tiny", tasks=("CloseDrawer",), n_test=0), 0, list(range(6)), list(range(8)))
    for sid, slot in (("L4_S3_s1_CloseDrawer", job.key), ("L0_S0_s2_CloseDrawer", "styles/CloseDrawer/train1")):
        ff.atomic_write_json(ff.scene_dir(tmp_path, "styles", sid) / ff.SCENE_JSON, {"slot": slot, "status": "ok"})
    assert gen.slot_scenes(tmp_path, job) == ["L4_S3_s1_CloseDrawer"]
    sid = gen._scene_id(gen._spec(job, job.seeds[0]))
    rec = {
        "slot": job.key,
        "status": "ok",
        "format_version": ff.FORMAT_VERSION,
        "generator_version": gen.GENERATOR_VERSION,
        "min_views": 0,
        "views_requested": [job.n_front, job.n_side],
    }
    ff.atomic_write_json(ff.scene_dir(tmp_path, "styles", sid) / ff.SCENE_JSON, rec)
    assert gen.find_done(tmp_path, job) == sid
    rec["views_requested"] = [job.n_front + 1, job.n_side]
    ff.atomic_write_json(ff.scene_dir(tmp_path, "styles", sid) / ff.SCENE_JSON, rec)
    assert gen.find_done(tmp_path, job) is None


def test_a_scene_job_leaves_no_compiled_kitchen_behind(monkeypatch):
    """A worker keeps its process for the whole run and no slot or attempt draws another's kitchen: the compiled
    models it cached grew by ~70 MB per attempt (GBs over a dense run)."""
    import types

    from floaff_zoo.sim import annotate, kitchen

    no_positive = types.SimpleNamespace(success=np.zeros(4, bool), label=np.zeros(4))
    monkeypatch.setattr(annotate, "annotate_scene", lambda *args, **kw: no_positive)
    (job,) = gen.plan_jobs(get_preset("tiny", tasks=("CloseDrawer",), n_test=0), 0, list(range(6)), list(range(8)))
    job = dataclasses.replace(job, seeds=job.seeds[:2])
    before = set(kitchen._CACHE)
    res = gen.run_job(job, "unused", get_preset("tiny").to_dict(), False)
    assert res["status"] == "dropped" and len(res["attempts"]) == 2
    assert set(kitchen._CACHE) == before


@pytest.mark.parametrize("forced_by", ["sampler", "acceptance"])
def test_a_scene_whose_regions_give_no_view_is_dropped_not_committed(monkeypatch, tmp_path, forced_by):
    """A scene whose view regions yielded no acceptable view was committed with no view (no sample, counted nowhere);
    it is now an attempt dropped for want of a view, listed in the manifest's drops, and the slot tries the next
    seed's kitchen. Forced by a sampler that finds nothing, or by the real sampler whose every rendered view the
    generator's acceptance test (view_rejection) refuses."""
    from floaff_zoo.sim import fileformat as ff
    from floaff_zoo.sim import views

    refused = []
    if forced_by == "sampler":
        monkeypatch.setattr(views, "sample_view_poses", lambda *args, **kw: [])
    else:
        monkeypatch.setattr(gen, "view_rejection", lambda *args: refused.append(1) or "no_floor_cell")
    preset = get_preset("tiny", tasks=("CloseDrawer",), n_test=0)
    (job, *_) = gen.plan_jobs(preset, 0, list(range(6)), list(range(8)))
    job = dataclasses.replace(job, seeds=job.seeds[:1])
    res = gen.run_job(job, str(tmp_path), preset.to_dict(), False)
    assert res["status"] == "dropped" and [a["outcome"] for a in res["attempts"]] == ["dropped_no_view"]
    assert "kept view" in res["reason"]
    assert (forced_by == "acceptance") == bool(refused)  # rendered views reached the acceptance test
    assert not list(ff.iter_scenes(tmp_path, benchmark=job.benchmark))
    assert not any((tmp_path / job.benchmark / ff.STAGING).glob("*"))  # the staged files went too
    entry = {"benchmark": job.benchmark, "task": job.task, "split": job.split}
    manifest = {"scenes": {job.key: {**res, **entry, "status": "dropped"}}}
    gen._summarise(manifest)
    assert [d["reason"] for d in manifest["drops"]][0] == "no view kept"
    assert manifest["counts"]["scenes_dropped"] == 1 and manifest["counts"]["views_total"] == 0


def test_a_kitchen_whose_reset_is_blocked_is_dropped_before_annotation(monkeypatch, tmp_path):
    """Generator 2.3.1: a kitchen where a part the reset opens stops below half its travel (a closing task half done
    at reset) is not annotated; the slot tries the next seed's kitchen, and the manifest lists the drop."""
    import types

    from floaff_zoo.sim import annotate
    from floaff_zoo.sim.tasks import Task

    annotated = []
    no_positive = types.SimpleNamespace(success=np.zeros(4, bool), label=np.zeros(4))
    monkeypatch.setattr(
        annotate, "annotate_scene", lambda scene, **kw: annotated.append(scene.spec.seed) or no_positive
    )
    first = []

    def blocked_first(self, scene):  # the slot's first kitchen is blocked, the second is not
        first.append(scene.spec.seed)
        return {"drawer_target_slide": 0.3} if len(first) == 1 else {}

    monkeypatch.setattr(Task, "blocked_parts", blocked_first)
    preset = get_preset("tiny", tasks=("CloseDrawer",), n_test=0)
    (job, *_) = gen.plan_jobs(preset, 0, list(range(6)), list(range(8)))
    job = dataclasses.replace(job, seeds=job.seeds[:2])
    res = gen.run_job(job, str(tmp_path), preset.to_dict(), False)
    assert [a["outcome"] for a in res["attempts"]] == ["dropped_reset_blocked", "dropped_no_positive"]
    assert res["attempts"][0]["blocked"] == {"drawer_target_slide": 0.3}
    assert annotated == [job.seeds[1]]  # the blocked kitchen was never annotated
    assert res["status"] == "dropped" and "resets" in res["reason"]
    entry = {"benchmark": job.benchmark, "task": job.task, "split": job.split}
    manifest = {"scenes": {job.key: {**res, **entry, "status": "dropped"}}}
    gen._summarise(manifest)
    reasons = [d["reason"] for d in manifest["drops"]]
    assert reasons[:2] == ["a part the reset opens is blocked", "no positive candidate"], reasons
    assert manifest["counts"]["scenes_dropped"] == 1


def test_paper_view_counts_match_the_appendix_table():
    p = PRESETS["paper"]
    total = 0
    for bench, tasks in PAPER_VIEW_TOTALS.items():
        for task, (tf, ts, ef, es) in tasks.items():
            tr = [view_counts(p, bench, task, "train", i) for i in range(p.n_train)]
            te = [view_counts(p, bench, task, "test", i) for i in range(p.n_test)]
            assert sum(f for f, _ in tr) == tf and sum(s for _, s in tr) == ts
            assert sum(f for f, _ in te) == ef and sum(s for _, s in te) == es
            total += tf + ts + ef + es
    assert total == 24782
    with pytest.raises(ValueError, match="unknown task"):
        get_preset("tiny", tasks=("Nope",))


def test_floor_cells_drop_furniture_and_behind_the_wall():
    # target at the origin facing -y (yaw -pi/2); a counter 0.6 deep behind it (y in [0, 0.6]) and a thin wall
    # behind the counter (y in [0.6, 0.65]) spanning the whole grid; the grid covers y in [-1, 1]
    cell = 0.1
    xs = np.arange(-10, 11) * cell
    ys = np.arange(-10, 11) * cell
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    grid = np.stack([xx.ravel(), yy.ravel()], axis=1)
    counter = np.array([[-3, 0.0], [3, 0.0], [3, 0.6], [-3, 0.6]])
    wall = np.array([[-3, 0.6], [3, 0.6], [3, 0.65], [-3, 0.65]])
    m = gen.floor_cells(grid, (21, 21), [counter, wall], np.zeros(2), -np.pi / 2, cell)
    y = grid[:, 1]
    assert m[y < -0.01].all()  # everything in front of the counter is floor
    assert not m[(y > 0.01) & (y < 0.6)].any()  # inside the counter
    assert not m[y > 0.66].any()  # behind the wall: free of furniture but not part of the room
    with pytest.raises(ValueError, match="grid_shape"):
        gen.floor_cells(grid, (20, 21), [counter], np.zeros(2), 0.0, cell)


def test_cell_labels_rule():
    from floaff_zoo.sim.annotate import FILTERED, ROLLED_OUT, SKIPPED, cell_labels

    label = np.array([1.0, 0.6, 0.3, 0.0, 0.8, 0.2], np.float32)  # the smoothed rollout map
    status = np.array([ROLLED_OUT, FILTERED, ROLLED_OUT, FILTERED, SKIPPED, ROLLED_OUT])
    lab, known = cell_labels(label, status)
    assert lab.dtype == np.float32 and known.dtype == bool
    assert lab.tolist() == pytest.approx([1.0, 0.0, 0.3, 0.0, 0.8, 0.2])  # filtered -> 0, else the map
    assert known.tolist() == [True, True, True, True, False, True]  # skipped (never rolled out) -> unknown
    with pytest.raises(ValueError, match="status"):
        cell_labels(label, status[:-1])
    with pytest.raises(ValueError, match="unknown status"):
        cell_labels(label, np.full(6, 7))


def test_view_rejection_rule():
    label = np.array([0.0, 0.9, 1.0, 0.5, 0.7], np.float32)
    success = np.array([False, False, True, True, False])
    seen = lambda *i: np.isin(np.arange(5), i)  # noqa: E731
    assert gen.view_rejection(seen(), label, success) == "no_floor_cell"
    assert gen.view_rejection(seen(0, 1, 4), label, success) == "no_positive_cell"
    assert gen.view_rejection(seen(1, 3), label, success) == "best_cell_fails"  # 0.9 (failed) outranks 0.5
    assert gen.view_rejection(seen(1, 2, 3), label, success) is None
    assert gen.view_rejection(seen(0, 3), label, success) is None


def test_candidate_window_matches_every_task():
    from floaff_zoo.floor import CANDIDATE_WINDOW
    from floaff_zoo.sim.tasks import candidate_region

    for task in ("PnPCounterToCab", "OpenSingleDoor", "CloseDrawer", "CloseDoubleDoor"):
        assert tuple(candidate_region(task)) == CANDIDATE_WINDOW, task


def test_observed_footprint_is_the_simulated_robots():
    from floaff_zoo.floor import FOOTPRINT
    from floaff_zoo.sim import robot

    assert FOOTPRINT == (robot.FOOTPRINT_LENGTH, robot.FOOTPRINT_WIDTH, robot.FOOTPRINT_FRONT)


def test_grid_lattice_checks_the_grid():
    from floaff_zoo.floor import FloorLattice

    lat = FloorLattice.target_window(np.array([0.5, 1.0]), 0.4, 0.25, 1.0, 1.2)
    assert gen.grid_lattice(lat.centers(), lat.shape, 0.25, np.array([0.5, 1.0]), 0.4) == lat
    with pytest.raises(ValueError, match="does not reproduce"):
        gen.grid_lattice(lat.centers() + 0.01, lat.shape, 0.25, np.array([0.5, 1.0]), 0.4)
    with pytest.raises(ValueError, match="odd sizes"):
        gen.grid_lattice(lat.centers()[:-9], (8, 9), 0.25, np.array([0.5, 1.0]), 0.4)


def _view(n=5, m=4):
    return {
        "scene_xyz": np.zeros((n, 3), np.float32),
        "scene_feat": np.zeros((n, 4), np.float32),
        "floor_xyz": np.zeros((m, 3), np.float32),
        "floor_label": np.full(m, 0.5, np.float32),
        "robot": np.array([0.85, 1.03], np.float32),
        "target_xyz": np.zeros(3, np.float32),
        "target_yaw": np.float32(0.1),
        "base_pose_world": np.zeros(3, np.float32),
    }


def test_fileformat_roundtrip_and_errors(tmp_path):
    v = _view()
    ff.atomic_save_npz(tmp_path / "a.npz", v)
    back = ff.read_view(tmp_path / "a.npz")
    assert set(back) == set(v) and all(np.array_equal(back[k], v[k]) for k in v)
    assert not list(tmp_path.glob(".*"))  # no temp files left
    bad = dict(v, floor_label=np.zeros(3, np.float32))
    with pytest.raises(ff.FormatError, match="floor_label.*M=3"):
        ff.validate_view(bad, "x.npz")
    with pytest.raises(ff.FormatError, match="NaN"):
        ff.validate_view(dict(v, target_xyz=np.array([np.nan, 0, 0], np.float32)))
    with pytest.raises(ff.FormatError, match="float64"):
        ff.validate_view(dict(v, scene_xyz=np.zeros((5, 3))))
    with pytest.raises(ff.FormatError, match="missing field 'robot'"):
        ff.validate_view({k: a for k, a in v.items() if k != "robot"})
    (tmp_path / "c.npz").write_bytes(b"not a zip")
    with pytest.raises(ff.FormatError, match="c.npz"):
        ff.read_view(tmp_path / "c.npz")
    (tmp_path / "stage").mkdir()
    with pytest.raises(ff.FormatError, match="without scene.json"):
        ff.commit_scene_dir(tmp_path / "stage", tmp_path / "final")
    (tmp_path / "s.json").write_text("{broken")
    with pytest.raises(ff.FormatError, match="s.json"):
        ff.read_json(tmp_path / "s.json")


def test_iter_scenes_refuses_a_filter_no_scene_can_match(tmp_path):
    """A misspelt benchmark, split or task (``--benchmark Layouts`` of scripts/predict_sr.py) yielded no scene and no
    word: the scripts then reported an empty split."""
    (tmp_path / "layouts").mkdir()
    for kw, named in (
        (
            {"benchmark": "Layouts"},
            r"benchmark 'Layouts'.*'layouts', 'styles'|benchmark 'Layouts'.*'styles', 'layouts'",
        ),
        ({"split": "val"}, r"split 'val'.*'train', 'test'"),
        ({"task": "CloseDrawers"}, r"task 'CloseDrawers'.*CloseDrawer"),
    ):
        with pytest.raises(ValueError, match=named):
            list(ff.iter_scenes(tmp_path, **kw))
    assert not list(ff.iter_scenes(tmp_path, benchmark="layouts", split="test", task="CloseDrawer"))


def test_failing_job_is_retried_once_then_reported(tmp_path, monkeypatch):
    calls = []

    def boom(job, out, preset_dict, save_images):
        calls.append(job.key)
        # a half-written staging dir must not survive
        ff.staging_dir(out, job.benchmark, "half").mkdir(parents=True, exist_ok=True)
        return {
            "key": job.key,
            "status": "error",
            "scene_id": None,
            "attempts": [],
            "reason": "RuntimeError: boom",
            "traceback": "tb",
            "wall_s": 0.0,
        }

    p = get_preset("tiny", tasks=("CloseDrawer",), n_test=0)
    man = gen.generate(tmp_path, p, seed=0, workers=0, quiet=True, job_fn=boom)
    assert calls == ["styles/CloseDrawer/train0"] * 2
    s = man["scenes"]["styles/CloseDrawer/train0"]
    assert s["status"] == "failed" and s["tries"] == 2 and "boom" in s["reason"]
    assert man["counts"]["scenes_failed"] == 1 and man["counts"]["scenes_ok"] == 0
    assert not (tmp_path / "styles" / ff.STAGING).exists()
    monkeypatch.setattr(gen, "run_job", boom)
    assert (
        gen.main(
            [
                "--preset",
                "tiny",
                "--tasks",
                "CloseDrawer",
                "--n-test",
                "0",
                "--out",
                str(tmp_path),
                "--workers",
                "0",
                "--quiet",
            ]
        )
        == 1
    )


def _error_job(job, out, preset_dict, save_images):
    """A run_job stand-in whose every slot fails at once (multi-line reason, as a traceback's last line may be)."""
    return {
        "key": job.key,
        "status": "error",
        "scene_id": None,
        "attempts": [],
        "reason": "RuntimeError: boom\n at x",
        "traceback": "tb",
        "wall_s": 0.0,
    }


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--cell", "0"], "cell must be a finite number > 0, got 0.0"),
        (["--cell", "inf"], "cell must be a finite number > 0, got inf"),
        (["--views", "-1", "2"], r"views_per_scene \(front\) must be an integer >= 0, got -1"),
        (["--views", "0", "0"], r"views_per_scene: at least one front or side view per scene"),
        (["--n-train", "0", "--n-test", "0"], "at least one scene, got 0/0"),
        (["--image-size", "0"], "image_size must be an integer >= 1, got 0"),
        (["--max-candidates", "-3"], r"max_candidates must be an integer >= 1 or null \(no cap\), got -3"),
    ],
)
def test_cli_refuses_bad_settings_in_one_line_before_any_scene(tmp_path, capsys, monkeypatch, flags, message):
    """These settings gave a raw traceback (get_preset ran outside main's try) or, for --image-size 0, ran every
    scene's annotation before failing it."""
    import re

    monkeypatch.setattr(gen, "run_job", _error_job)
    out = tmp_path / "o"
    assert gen.main(["--preset", "tiny", "--out", str(out), "--workers", "0", "--quiet", *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("floaff-zoo generate: error: ") and err.count("\n") == 1 and re.search(message, err)
    assert not out.exists()


def test_cli_refuses_an_out_that_is_a_file(tmp_path, capsys, monkeypatch):
    """--out naming a file gave a raw FileExistsError traceback."""
    monkeypatch.setattr(gen, "run_job", _error_job)
    (tmp_path / "f").write_text("x")
    for out, why in ((tmp_path / "f", "exists and is not a folder"), (tmp_path / "f" / "sub", "cannot create")):
        assert gen.main(["--preset", "tiny", "--out", str(out), "--workers", "0", "--quiet"]) == 2
        assert f"floaff-zoo generate: error: --out {out}: {why}" in capsys.readouterr().err
    assert (tmp_path / "f").read_text() == "x"


def test_cli_prints_the_first_failure_reasons(tmp_path, capsys, monkeypatch):
    """Failed scenes printed only "0 scenes ok ... 4 failed"; the reasons were only in manifest.json."""
    monkeypatch.setattr(gen, "run_job", _error_job)
    assert gen.main(["--preset", "tiny", "--out", str(tmp_path), "--workers", "0", "--quiet"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert "4 failed" in err[0]
    assert err[1:] == [
        "[generate] failed styles/CloseDrawer/test0: RuntimeError: boom at x",
        "[generate] failed styles/CloseDrawer/train0: RuntimeError: boom at x",
        "[generate] failed styles/OpenSingleDoor/test0: RuntimeError: boom at x",
        "[generate] ... and 1 more failed slot(s): see manifest.json",
    ]


def test_dead_worker_process_is_retried_once_then_failed(tmp_path):
    sys.path.insert(0, str(Path(__file__).parent))
    import _crash_job

    p = get_preset("tiny", tasks=("CloseDrawer",), n_test=0)
    man = gen.generate(tmp_path / "a", p, seed=0, workers=1, quiet=True, job_fn=_crash_job.crash_always)
    s = man["scenes"]["styles/CloseDrawer/train0"]
    assert s["status"] == "failed" and s["tries"] == 2 and "worker died" in s["reason"]
    # the crash in the shared pool is not counted (any job in flight there might have caused it): two more tries,
    # each in a worker process of its own
    assert len(list((tmp_path / "a").glob("tries_*"))) == 3
    assert not (tmp_path / "a" / "styles" / ff.STAGING).exists()
    assert ff.read_manifest(tmp_path / "a")["status"] == "done"
    man = gen.generate(tmp_path / "b", p, seed=0, workers=1, quiet=True, job_fn=_crash_job.error_then_drop)
    s = man["scenes"]["styles/CloseDrawer/train0"]
    assert s["status"] == "dropped" and s["tries"] == 2 and man["counts"]["scenes_dropped"] == 1


def test_a_dead_worker_fails_only_its_own_slot(tmp_path):
    """A worker that dies breaks its whole pool: the slots in flight beside it were failed with it, twice, so one
    crashing scene took the run's other slots down. Now they run again each in a process of their own."""
    sys.path.insert(0, str(Path(__file__).parent))
    import _crash_job

    p = get_preset("tiny", tasks=("CloseDrawer",), n_train=3, n_test=1)
    man = gen.generate(tmp_path, p, seed=0, workers=2, quiet=True, job_fn=_crash_job.crash_first_slot)
    status = {k: (s["status"], s["tries"]) for k, s in man["scenes"].items()}
    assert status.pop("styles/CloseDrawer/train0") == ("failed", 2)
    assert set(status.values()) == {("dropped", 1)} and len(status) == 3


def _commit_first_seed(job, out, preset_dict, save_images, status="ok", attempt=0):
    """A run_job stand-in: commits a bare scene of its slot (the ``attempt``-th seed's id), returns ``status``."""
    sid = gen._scene_id(gen._spec(job, job.seeds[attempt]))
    rec = {
        "format_version": ff.FORMAT_VERSION,
        "generator_version": gen.GENERATOR_VERSION,
        "benchmark": job.benchmark,
        "split": job.split,
        "slot": job.key,
        "spec": {},
        "task": job.task,
        "target": {},
        "candidates": {"xy": []},
        "labels": {"success": [], "label": []},
        "views": [],
        "n_views": {"front": 0, "side": 0},
        "min_views": preset_dict["min_views"],
        "views_requested": [job.n_front, job.n_side],
        "views_rejected": {},
        "status": "ok",
    }
    ff.atomic_write_json(ff.scene_dir(out, job.benchmark, sid) / ff.SCENE_JSON, rec)
    ok = status == "ok"
    return {"key": job.key, "status": status, "scene_id": sid if ok else None, "attempts": [], "wall_s": 0.0}


def _count_scene_json_reads(monkeypatch) -> Counter[str]:
    """scene id -> how many times its scene.json is read from now on (``Path.read_text`` counted)."""
    reads: Counter[str] = Counter()
    real = Path.read_text

    def counted(self, *args, **kw):
        if self.name == ff.SCENE_JSON and self.is_file():
            reads[self.parent.name] += 1
        return real(self, *args, **kw)

    monkeypatch.setattr(Path, "read_text", counted)
    return reads


def test_a_run_reads_each_scene_json_once_where_it_can(tmp_path, monkeypatch):
    """After each job the driver read every committed scene.json again to find the slot's earlier scenes (a run of n
    scenes read the first one n + 1 times), and a resumed slot's scene.json was read four times. A scene committed by
    a job that then failed (a worker that died after the commit) is still found and retired."""
    import functools

    reads = _count_scene_json_reads(monkeypatch)
    p = get_preset("tiny", tasks=("CloseDrawer",), n_train=4, n_test=0)
    man = gen.generate(tmp_path, p, seed=0, workers=0, quiet=True, job_fn=_commit_first_seed)
    assert man["counts"]["scenes_ok"] == 4
    assert len(reads) == 4 and set(reads.values()) == {1}  # the check of what the job committed
    reads.clear()
    man = gen.generate(tmp_path, p, seed=0, workers=0, quiet=True, job_fn=_commit_first_seed)
    assert all(s["resumed"] for s in man["scenes"].values())
    # the start's slot map, the resume's find_done, the resumed scene's checked read
    assert len(reads) == 4 and set(reads.values()) == {3}
    topped = dataclasses.replace(p, min_views=1)  # no scene resumes: each slot's job runs again, and fails
    fail = functools.partial(_commit_first_seed, status="error", attempt=1)
    man = gen.generate(tmp_path, topped, seed=0, workers=0, quiet=True, job_fn=fail)
    assert man["counts"]["scenes_failed"] == 4 and not list(ff.iter_scenes(tmp_path))
    assert {len(s["retired"]) for s in man["scenes"].values()} == {2}


def test_a_left_out_slots_scene_json_is_read_once(tmp_path, monkeypatch):
    """A rerun with fewer slots read a left-out slot's scene.json at the start (the slot map), again for the previous
    manifest's entry and again by its slot: three reads of a record the run held from the first one."""
    p = get_preset("tiny", tasks=("CloseDrawer",), n_train=4, n_test=0)
    gen.generate(tmp_path, p, seed=0, workers=0, quiet=True, job_fn=_commit_first_seed)
    reads = _count_scene_json_reads(monkeypatch)
    fewer = get_preset("tiny", tasks=("CloseDrawer",), n_train=2, n_test=0)
    man = gen.generate(tmp_path, fewer, seed=0, workers=0, quiet=True, job_fn=_commit_first_seed)
    left = [s for s in man["scenes"].values() if s.get("in_plan") is False]
    assert len(left) == 2 and all(s["status"] == "ok" for s in left)
    assert {reads[s["scene_id"]] for s in left} == {1}


def test_ray_backend_without_ray_says_pip_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # ray is a dev dependency: simulate a user without it
    p = get_preset("tiny", tasks=("CloseDrawer",), n_test=0)
    with pytest.raises(SystemExit, match="pip install ray"):
        gen.generate(tmp_path, p, workers=1, backend="ray", quiet=True)


# ------------------------------------------------------------------------------------------------ end to end
def _labels(root: Path) -> dict[str, tuple]:
    """slot -> (scene_id, success, label, floor_label / floor_index / floor_known / scene_xyz bytes of every view)."""
    out = {}
    for rec in ff.iter_scenes(root):
        views = [ff.read_view(Path(rec["dir"]) / v["file"]) for v in rec["views"]]
        out[rec["slot"]] = (
            rec["scene_id"],
            tuple(rec["labels"]["success"]),
            np.asarray(rec["labels"]["label"], np.float32).tobytes(),
            tuple(v["floor_label"].tobytes() for v in views),
            tuple(v["floor_index"].tobytes() + v["floor_known"].tobytes() for v in views),
            tuple(v["scene_xyz"].tobytes() for v in views),
        )
    return out


# a mini override of the tiny preset keeps the fast suite well under a minute: one task, 1 train + 1 test scene,
# a 0.25 m grid, at most 8 rollouts per scene, one view of each kind
MINI = dict(tasks=("CloseDrawer",), cell=0.25, max_candidates=8, views_per_scene=(1, 1), image_size=48)


@pytest.fixture(scope="module")
def mini_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("mini")
    man = gen.generate(out, get_preset("tiny", **MINI), seed=0, workers=2, quiet=True)
    return out, man


def _check_run(out: Path, man: dict, p) -> list[dict]:
    """Manifest counts vs files, labels, views, pictures; returns the scene records."""
    c = man["counts"]
    assert man["status"] == "done" and c["scenes_failed"] == 0 and c["scenes_pending"] == 0
    assert c["scenes_ok"] + c["scenes_dropped"] == len(man["scenes"]) == len(p.tasks) * (p.n_train + p.n_test)
    scenes = list(ff.iter_scenes(out))
    assert len(scenes) == c["scenes_ok"] == len(man["scenes"])  # these tasks never run out of seeds
    assert c["views_front"] == sum(s["n_views"]["front"] for s in scenes) > 0
    assert c["views_side"] == sum(s["n_views"]["side"] for s in scenes) > 0
    assert c["views_total"] == c["views_front"] + c["views_side"]
    assert json.loads((out / ff.MANIFEST).read_text())["counts"] == c
    assert sum(len(s["views"]) for s in scenes) == c["views_total"]
    for task in p.tasks:
        recs = [s for s in scenes if s["task"] == task]
        assert {s["split"] for s in recs} == {"train", "test"}
        succ = np.concatenate([np.asarray(s["labels"]["success"]) for s in recs])
        assert succ.sum() >= 1 and (succ == 0).sum() >= 1, task  # >= 1 positive and >= 1 negative cell
    for why in ("no_floor_cell", "no_positive_cell", "best_cell_fails"):
        assert c[f"views_rejected_{why}"] == sum(s["views_rejected"][why] for s in scenes)
    for s in scenes:
        d = Path(s["dir"])
        assert s["format_version"] == ff.FORMAT_VERSION == 2 and s["generator_version"] == gen.GENERATOR_VERSION
        assert (d / "topdown.png").stat().st_size > 1000
        assert all((d / f).is_file() for f in s["pictures"])
        assert s["annotation_counts"]["rolled_out"] <= p.max_candidates
        on_floor = np.asarray(s["candidates"]["on_floor"], bool)
        assert 0 < on_floor.sum() < len(on_floor)  # some grid cells lie inside furniture
        _check_v2_labels(s)
        seen_sets = set()
        for v in s["views"]:
            sample = ff.read_sample(s, v)
            assert sample["scene_xyz"].shape[0] > 0 and sample["scene_feat"][:, 0].max() == 1.0  # the target is seen
            assert sample["meta"]["view"] == v["view"] and sample["meta"]["sim"]["seed"] == s["spec"]["seed"]
            seen_sets.add(_check_v2_view(s, v, sample))
        # the floor points depend on the view (two views of one region may still see the same few cells)
        assert len(seen_sets) > 1 or len(s["views"]) == 1
    assert max(len(s["views"]) for s in scenes) > 1  # (a scene may keep one view: the other one rejected)
    assert not (out / "styles" / ff.STAGING).exists()
    return scenes


def _check_v2_labels(s: dict) -> None:
    """Scene-level v2 label rule: filtered -> 0 (known), rolled out -> the smoothed map, skipped -> unknown."""
    from floaff_zoo.sim.annotate import FILTERED, ROLLED_OUT, SKIPPED

    status = np.asarray(s["candidates"]["status"])
    label = np.asarray(s["labels"]["label"], np.float32)
    cell_label = np.asarray(s["labels"]["cell_label"], np.float32)
    known = np.asarray(s["labels"]["known"], bool)
    reasons = np.asarray(s["labels"]["reasons"])
    assert (cell_label[status == FILTERED] == 0).all() and known[status == FILTERED].all()
    assert np.array_equal(cell_label[status != FILTERED], label[status != FILTERED])
    assert np.array_equal(known, status != SKIPPED) and (reasons[status == SKIPPED] == "skipped_budget").all()
    assert np.asarray(s["labels"]["success"], bool)[status != ROLLED_OUT].sum() == 0
    assert (status == ROLLED_OUT).sum() == s["annotation_counts"]["rolled_out"]


def _check_v2_view(s: dict, v: dict, sample: dict) -> bytes:
    """A v2 view stores the grid cells its own cloud observes as ground, with their v2 labels."""
    from floaff_zoo.sim.views import base_to_world

    arr = ff.read_view(Path(s["dir"]) / v["file"])
    idx, pose = arr["floor_index"], arr["base_pose_world"].astype(np.float64)
    grid = np.asarray(s["candidates"]["xy"])
    lat = gen.grid_lattice(
        grid,
        tuple(s["candidates"]["grid_shape"]),
        s["candidates"]["cell"],
        np.asarray(s["target"]["pos"])[:2],
        s["target"]["yaw"],
    )
    seen = gen.view_floor_cells(sample["scene_xyz"], pose, lat)
    assert np.array_equal(idx, np.flatnonzero(seen)) and len(idx) == v["n_floor_cells"] > 0
    world = base_to_world(sample["floor_xyz"].astype(np.float64), pose)
    assert np.allclose(world[:, :2], grid[idx], atol=1e-4) and np.allclose(world[:, 2], 0.0, atol=1e-6)
    assert np.array_equal(sample["floor_label"], np.asarray(s["labels"]["cell_label"], np.float32)[idx])
    assert np.array_equal(sample["floor_known"], np.asarray(s["labels"]["known"], bool)[idx])
    success = np.asarray(s["labels"]["success"], bool)[idx]
    assert success.any() and success.sum() == v["n_positive_cells"]  # views without a positive are resampled
    best = sample["floor_label"] >= sample["floor_label"].max() - 1e-6
    assert success[best].all()  # ... and so are views whose best-labelled cell failed: the label's argmax succeeds
    return idx.tobytes()


def test_mini_end_to_end(mini_run):
    out, man = mini_run
    _check_run(out, man, get_preset("tiny", **MINI))


def test_predict_default_floor_reproduces_the_views_floor(mini_run):
    """predict's default floor queries (floaff_zoo.floor, no simulator field) are the view's own floor points when
    given the view's target yaw and the dataset's cell: at most one cell in 50 may differ, for a ground point lying
    within float32 round-off of a cell border."""
    from scipy.spatial import cKDTree

    from floaff_zoo.predict import default_floor_grid

    out, _ = mini_run
    for s in ff.iter_scenes(out):
        for v in s["views"]:
            sample = ff.read_sample(s, v)
            ours = default_floor_grid(
                sample["target_xyz"], sample["scene_xyz"], float(sample["target_yaw"]), cell=s["candidates"]["cell"]
            )
            theirs = sample["floor_xyz"]
            unmatched = (cKDTree(theirs[:, :2]).query(ours[:, :2])[0] > 1e-3).sum()
            unmatched += (cKDTree(ours[:, :2]).query(theirs[:, :2])[0] > 1e-3).sum()
            assert unmatched <= max(1, len(theirs) // 50), (s["scene_id"], v["view_id"], unmatched, len(theirs))


def test_resume_regenerates_only_the_deleted_scene_identically_with_one_worker(mini_run, tmp_path):
    src, _ = mini_run
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    before = _labels(out)
    victim = sorted(before)[0]
    (ff.scene_dir(out, "styles", before[victim][0]) / ff.SCENE_JSON).unlink()
    keep = {
        k: (ff.scene_dir(out, "styles", v[0]) / ff.SCENE_JSON).stat().st_mtime_ns
        for k, v in before.items()
        if k != victim
    }
    # workers=1 now vs workers=2 for the original: the regenerated arrays must be byte-identical
    man = gen.generate(out, get_preset("tiny", **MINI), seed=0, workers=1, quiet=True)
    assert [k for k, s in man["scenes"].items() if not s.get("resumed")] == [victim]
    for k, t in keep.items():
        assert (ff.scene_dir(out, "styles", before[k][0]) / ff.SCENE_JSON).stat().st_mtime_ns == t
    assert _labels(out) == before
    assert man["counts"]["scenes_ok"] == len(before)


def test_view_requests_top_up_the_missing_views_front_first():
    job = gen.SceneJob("styles", "CloseDrawer", "train", 0, 0, 0, (1,), 2, 3)
    served: list[int] = []

    def run(min_views: int, per_request: dict[str, int]) -> list[tuple[str, int]]:
        """Serve each request with at most per_request[kind] views; return the requests made."""
        served.clear()
        reqs = []
        for kind, n in gen.view_requests(job, get_preset("tiny", min_views=min_views), lambda: sum(served)):
            reqs.append((kind, n))
            served.append(min(n, per_request[kind]))
        return reqs

    assert run(0, {"front": 9, "side": 9}) == [("front", 2), ("side", 3)]  # off: the preset's own counts
    assert run(4, {"front": 9, "side": 9}) == [("front", 2), ("side", 3)]  # reached: nothing more
    assert run(8, {"front": 9, "side": 9}) == [("front", 2), ("side", 3), ("front", 3)]
    # a front region that yields nothing leaves the gap to the side region
    assert run(8, {"front": 0, "side": 9}) == [("front", 2), ("side", 3), ("front", 5), ("side", 5)]
    with pytest.raises(ValueError, match="min_views"):
        get_preset("tiny", min_views=-1).validate()


def test_top_up_keeps_the_presets_views_and_adds_to_min_views(mini_run, tmp_path):
    """min_views draws the preset's views first, identically, then adds views from the same regions."""
    src, _ = mini_run
    man = gen.generate(tmp_path, get_preset("tiny", **MINI, min_views=3), seed=0, workers=0, quiet=True)
    assert man["status"] == "done" and man["config"]["min_views"] == 3
    before = {s["scene_id"]: s for s in ff.iter_scenes(src)}
    after = list(ff.iter_scenes(tmp_path))
    assert sorted(s["scene_id"] for s in after) == sorted(before)
    for s in after:
        old = before[s["scene_id"]]
        assert len(s["views"]) >= 3 > len(old["views"]) and s["labels"] == old["labels"]
        for v in old["views"]:  # the preset's own views come first and are unchanged
            a = ff.read_view(Path(old["dir"]) / v["file"])
            b = ff.read_view(Path(s["dir"]) / v["file"])
            assert all(np.array_equal(a[k], b[k]) for k in a), (s["scene_id"], v["view_id"])


def test_resume_keeps_only_scenes_drawn_with_the_same_top_up(mini_run, tmp_path):
    src, _ = mini_run
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    preset = get_preset("tiny", **MINI)
    from floaff_zoo.sim.kitchen import LAYOUTS, STYLES

    jobs = gen.plan_jobs(preset, 0, list(LAYOUTS), list(STYLES))
    assert all(gen.find_done(out, j, 0) for j in jobs)
    assert not any(gen.find_done(out, j, 3) for j in jobs)  # drawn without the top-up: regenerate
    # a scene written before scene.json recorded min_views counts as topped up when it holds enough views
    rec_path = ff.scene_dir(out, jobs[0].benchmark, gen.find_done(out, jobs[0], 0)) / ff.SCENE_JSON
    rec = json.loads(rec_path.read_text())
    del rec["min_views"]
    rec_path.write_text(json.dumps(rec))
    assert gen.find_done(out, jobs[0], len(rec["views"])) and not gen.find_done(out, jobs[0], len(rec["views"]) + 1)
    # a scene of another generator minor version (other rollouts, other labels) is regenerated; a patch version is not
    for version, kept in ((gen.GENERATOR_VERSION, True), ("2.0.0", False), (gen.GENERATOR_VERSION + "-dev", True)):
        rec["generator_version"] = version
        rec_path.write_text(json.dumps(rec))
        assert bool(gen.find_done(out, jobs[0], len(rec["views"]))) is kept, version


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    man = gen.generate(out, get_preset("tiny"), seed=0, workers=2, quiet=True)
    return out, man


@pytest.mark.slow
def test_tiny_preset_end_to_end(tiny_run):
    out, man = tiny_run
    _check_run(out, man, PRESETS["tiny"])
    assert man["wall_s"] < 240  # the preset's budget is < 2 min on 2 idle cores; leave room for a shared machine


@pytest.mark.slow
def test_tiny_same_seed_same_arrays_for_one_or_two_workers(tiny_run, tmp_path):
    src, _ = tiny_run
    gen.generate(tmp_path, get_preset("tiny"), seed=0, workers=1, quiet=True)
    assert _labels(tmp_path) == _labels(src)


def test_resume_refuses_other_settings_and_names_them(mini_run, tmp_path):
    """A folder made with one grid cell (or seed, image size, ...) is not resumed with another: its finished scenes
    would be kept and the manifest would record settings they were not made with (slots and top-ups may change)."""
    src, _ = mini_run
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    manifest = (out / ff.MANIFEST).read_text()
    for kw, seed, named in (
        ({"cell": 0.1}, 0, "cell 0.25 -> 0.1"),
        ({"image_size": 96}, 0, "image_size"),
        ({}, 1, "seed 0 -> 1"),
    ):
        with pytest.raises(ValueError, match=f"{out}: its scenes were generated with other settings.*{named}"):
            gen.generate(out, get_preset("tiny", **{**MINI, **kw}), seed=seed, workers=0, quiet=True)
        assert (out / ff.MANIFEST).read_text() == manifest  # refused before anything is written
    man = gen.generate(out, get_preset("tiny", **MINI), seed=0, workers=0, quiet=True)  # the recorded settings
    assert man["status"] == "done" and all(s.get("resumed") for s in man["scenes"].values())


def test_cli_refuses_views_with_paper_counts_and_an_address_without_ray(tmp_path, capsys):
    assert gen.main(["--preset", "paper", "--views", "2", "2", "--out", str(tmp_path / "p")]) == 2
    assert "--views: the 'paper' preset spreads the paper's view counts" in capsys.readouterr().err
    assert gen.main(["--preset", "tiny", "--address", "10.0.0.1:6379", "--out", str(tmp_path / "t")]) == 2
    assert "--address names a ray cluster: give it with --backend ray" in capsys.readouterr().err
    assert not (tmp_path / "p").exists() and not (tmp_path / "t").exists()


def _copy_with_an_old_scene(mini_run, tmp_path) -> tuple[Path, dict]:
    """A copy of the mini run whose first scene says another generator minor version made it (a rerun must
    regenerate its slot): (the copy, that scene's record)."""
    src, _ = mini_run
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    victim = sorted(ff.iter_scenes(out), key=lambda s: s["scene_id"])[0]
    path = Path(victim["dir"]) / ff.SCENE_JSON
    path.write_text(json.dumps({**json.loads(path.read_text()), "generator_version": "2.0.0"}))
    return out, victim


def test_a_scene_a_rerun_cannot_replace_is_retired_not_read(mini_run, tmp_path):
    """A slot whose scene must be regenerated (here: made by another generator minor version) and whose
    regeneration fails leaves no stale scene for the readers: the old folder moves to .retired/ and the manifest
    says so."""
    sys.path.insert(0, str(Path(__file__).parent))
    import _crash_job

    out, victim = _copy_with_an_old_scene(mini_run, tmp_path)
    man = gen.generate(
        out, get_preset("tiny", **MINI), seed=0, workers=1, quiet=True, job_fn=_crash_job.error_then_drop
    )
    (key,) = [k for k, s in man["scenes"].items() if not s.get("resumed")]
    assert man["scenes"][key]["status"] == "dropped" and man["scenes"][key]["retired"] == victim["scene_id"]
    assert victim["scene_id"] not in {s["scene_id"] for s in ff.iter_scenes(out)}
    assert (out / victim["benchmark"] / ff.RETIRED / victim["scene_id"] / ff.SCENE_JSON).is_file()


def test_an_interrupted_rerun_does_not_leave_a_stale_scene_readable(mini_run, tmp_path):
    """A rerun that must regenerate a slot rewrote the manifest without the slot's scene id before any job ran; when
    it was interrupted, the next rerun no longer knew the old scene and left it for the readers. The slot's scenes
    are now found by its seeds' folders."""
    sys.path.insert(0, str(Path(__file__).parent))
    import _crash_job

    out, victim = _copy_with_an_old_scene(mini_run, tmp_path)
    with pytest.raises(KeyboardInterrupt):
        gen.generate(out, get_preset("tiny", **MINI), seed=0, workers=0, quiet=True, job_fn=_crash_job.interrupted)
    man = gen.generate(
        out, get_preset("tiny", **MINI), seed=0, workers=0, quiet=True, job_fn=_crash_job.error_then_drop
    )
    assert victim["scene_id"] not in {s["scene_id"] for s in ff.iter_scenes(out)}
    assert victim["scene_id"] in [s.get("retired") for s in man["scenes"].values()]


def test_a_resumed_slot_leaves_no_earlier_scene_of_it_readable(mini_run, tmp_path):
    """A rerun killed after committing a slot's new scene but before moving the slot's earlier scene (another seed's,
    by an older generator) aside left both; the next rerun resumed the new one and left the old one for the readers,
    one slot read twice and two generators in one dataset. The resume now retires it as a regeneration does."""
    from floaff_zoo.sim.kitchen import LAYOUTS, STYLES

    src, _ = mini_run
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    before = {s["scene_id"] for s in ff.iter_scenes(out)}
    keep = sorted(ff.iter_scenes(out), key=lambda s: s["scene_id"])[0]
    (job,) = [
        j for j in gen.plan_jobs(get_preset("tiny", **MINI), 0, list(LAYOUTS), list(STYLES)) if j.key == keep["slot"]
    ]
    old_id = [sid for sid in (gen._scene_id(gen._spec(job, s)) for s in job.seeds) if sid != keep["scene_id"]][-1]
    shutil.copytree(keep["dir"], ff.scene_dir(out, job.benchmark, old_id))
    path = ff.scene_dir(out, job.benchmark, old_id) / ff.SCENE_JSON
    path.write_text(json.dumps({**json.loads(path.read_text()), "scene_id": old_id, "generator_version": "2.2.0"}))
    man = gen.generate(out, get_preset("tiny", **MINI), seed=0, workers=0, quiet=True)
    assert all(s.get("resumed") for s in man["scenes"].values())
    assert {s["scene_id"] for s in ff.iter_scenes(out)} == before
    assert man["scenes"][job.key]["retired"] == old_id
    assert (out / job.benchmark / ff.RETIRED / old_id / ff.SCENE_JSON).is_file()


def test_a_regenerated_slot_retires_an_earlier_scene_of_another_kitchen(mini_run, tmp_path):
    """An earlier scene of a slot that none of the slot's seeds draws now (the slot had another layout or style when
    it was made) and that no manifest names is found by the slot in its scene.json at the run's start, and retired
    when the slot is regenerated: after each job the run looks only at the slot's scenes it found then and at its
    seeds' ids, not at every scene.json again."""
    sys.path.insert(0, str(Path(__file__).parent))
    import _crash_job

    out, victim = _copy_with_an_old_scene(mini_run, tmp_path)
    old_id = f"L9_S9_s1_{victim['task']}"
    shutil.copytree(victim["dir"], ff.scene_dir(out, victim["benchmark"], old_id))
    path = ff.scene_dir(out, victim["benchmark"], old_id) / ff.SCENE_JSON
    path.write_text(json.dumps({**json.loads(path.read_text()), "scene_id": old_id}))
    man = gen.generate(
        out, get_preset("tiny", **MINI), seed=0, workers=0, quiet=True, job_fn=_crash_job.error_then_drop
    )
    (key,) = [k for k, s in man["scenes"].items() if not s.get("resumed")]
    assert sorted(man["scenes"][key]["retired"]) == sorted([victim["scene_id"], old_id])
    assert not {victim["scene_id"], old_id} & {s["scene_id"] for s in ff.iter_scenes(out)}
    assert (out / victim["benchmark"] / ff.RETIRED / old_id / ff.SCENE_JSON).is_file()


@pytest.mark.parametrize("damage", ["missing", "corrupt", "scenes_list", "entry_not_a_record"])
def test_a_rerun_into_scenes_without_a_readable_manifest_is_refused(mini_run, tmp_path, damage):
    """Without a readable manifest the settings went unchecked: a rerun with another grid cell kept the old scenes
    and wrote a manifest recording settings they were not made with. A manifest.json that parses but whose 'scenes'
    is not a table of slot records (another tool's file, a hand edit) failed with a bare AttributeError naming no
    file."""
    src, _ = mini_run
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    man = json.loads((out / ff.MANIFEST).read_text())
    key = sorted(man["scenes"])[0]
    if damage == "missing":
        (out / ff.MANIFEST).unlink()
        why = "missing"
    elif damage == "corrupt":
        (out / ff.MANIFEST).write_text("{not json")
        why = "unreadable .*corrupt JSON"
    else:
        if damage == "scenes_list":
            man["scenes"] = list(man["scenes"].values())
        else:
            man["scenes"][key] = man["scenes"][key]["scene_id"]
        (out / ff.MANIFEST).write_text(json.dumps(man))
        why = "unreadable .*manifest.json: .*scenes"
    cell = 0.5 if damage in ("missing", "corrupt") else MINI["cell"]  # the others failed even with the same settings
    with pytest.raises(ValueError, match=f"{out}: holds 2 generated scene.*manifest.json is {why}"):
        gen.generate(out, get_preset("tiny", **{**MINI, "cell": cell}), seed=0, workers=0, quiet=True)


def test_a_rerun_with_fewer_slots_keeps_the_others_in_the_manifest(mini_run, tmp_path):
    """A rerun with --n-test 0 (or fewer tasks) dropped the other slots from the manifest while their scenes stayed
    and were read: the manifest now lists every scene the readers see, the left-out ones marked in_plan false."""
    src, _ = mini_run
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    man = gen.generate(out, get_preset("tiny", **{**MINI, "n_test": 0}), seed=0, workers=0, quiet=True)
    listed = {s["scene_id"] for s in man["scenes"].values() if s["status"] == "ok"}
    assert listed == {s["scene_id"] for s in ff.iter_scenes(out)} and len(listed) == 2
    assert [s["split"] for s in man["scenes"].values() if s.get("in_plan") is False] == ["test"]
    assert man["counts"]["scenes_ok"] == 2


def _copy_with_an_older_test_scene(mini_run, tmp_path: Path) -> tuple[Path, dict, Path, dict]:
    """A copy of the mini run whose test scene says generator 2.2 -> (copy, the scene, its scene.json path, its
    record as generated)."""
    out = tmp_path / "copy"
    shutil.copytree(mini_run[0], out)
    (test_scene,) = [s for s in ff.iter_scenes(out) if s["split"] == "test"]
    sj = ff.scene_dir(out, test_scene["benchmark"], test_scene["scene_id"]) / ff.SCENE_JSON
    rec = json.loads(sj.read_text())
    sj.write_text(json.dumps({**rec, "generator_version": "2.2.0"}))
    return out, test_scene, sj, rec


def test_a_rerun_leaving_out_a_slot_of_an_older_generator_is_refused(mini_run, tmp_path):
    """A rerun with fewer slots kept the left-out slots' scenes whatever generator made them: a 2.2 test scene stayed
    beside the 2.3 training scenes, one dataset of two generators (docs/data_format.md: resume never mixes them)."""
    out, test_scene, sj, rec = _copy_with_an_older_test_scene(mini_run, tmp_path)
    before = sorted(str(p) for p in out.rglob("*"))
    with pytest.raises(
        ValueError, match=rf"holds 1 scene\(s\) of another generator version .*{test_scene['scene_id']}"
    ):
        gen.generate(out, get_preset("tiny", **{**MINI, "n_test": 0}), seed=0, workers=0, quiet=True)
    assert sorted(str(p) for p in out.rglob("*")) == before  # refused before anything was written
    sj.write_text(json.dumps(rec))  # the same generator's scene: kept, as before
    gen.generate(out, get_preset("tiny", **{**MINI, "n_test": 0}), seed=0, workers=0, quiet=True)


def test_a_left_out_slot_an_interrupted_rerun_did_not_record_is_still_checked_and_listed(mini_run, tmp_path):
    """A rerun that was to regenerate a slot wrote its manifest without the slot's scene id and was interrupted; the
    next rerun leaving that slot out looked for left-out scenes in that manifest only: a 2.2 test scene stayed beside
    the 2.3 training scenes, read but neither refused nor listed. The left-out slots' scenes are now also found by
    the slot their scene.json names."""
    sys.path.insert(0, str(Path(__file__).parent))
    import _crash_job

    out, test_scene, sj, rec = _copy_with_an_older_test_scene(mini_run, tmp_path)
    with pytest.raises(KeyboardInterrupt):  # the rerun that was to regenerate the test slot
        gen.generate(out, get_preset("tiny", **MINI), seed=0, workers=0, quiet=True, job_fn=_crash_job.interrupted)
    assert "scene_id" not in json.loads((out / ff.MANIFEST).read_text())["scenes"][test_scene["slot"]]
    with pytest.raises(
        ValueError, match=rf"holds 1 scene\(s\) of another generator version .*{test_scene['scene_id']}"
    ):
        gen.generate(out, get_preset("tiny", **{**MINI, "n_test": 0}), seed=0, workers=0, quiet=True)
    # a scene of this generator (a run killed after committing it, before recording it) stays, listed as left out
    sj.write_text(json.dumps(rec))
    man = gen.generate(out, get_preset("tiny", **{**MINI, "n_test": 0}), seed=0, workers=0, quiet=True)
    listed = {s["scene_id"] for s in man["scenes"].values() if s["status"] == "ok"}
    assert listed == {s["scene_id"] for s in ff.iter_scenes(out)} and test_scene["scene_id"] in listed
    entry = man["scenes"][test_scene["slot"]]
    assert entry["in_plan"] is False and entry["split"] == "test" and entry["slot"] == 0
    assert entry["n_views"] == rec["n_views"] and man["counts"]["scenes_ok"] == 2


def test_workers_exit_when_the_driver_is_killed(tmp_path):
    """Pool workers outlived a killed `generate`: they finished their queued scenes into --out (beside the rerun the
    docs tell the user to start) and then waited forever."""
    import os
    import signal
    import subprocess
    import time

    out = tmp_path / "o"
    here = str(Path(__file__).parent)
    code = (
        f"import sys; sys.path.insert(0, {here!r}); import _crash_job; from floaff_zoo.sim import generate as g; "
        "from floaff_zoo.sim.presets import get_preset; "
        f"g.generate({str(out)!r}, get_preset('tiny'), seed=0, workers=1, quiet=True, job_fn=_crash_job.slow_marker)"
    )
    driver = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.monotonic() + 120
    while not list(out.glob("pid_*")) and time.monotonic() < deadline:
        time.sleep(0.1)
    driver.send_signal(signal.SIGKILL)
    driver.wait()
    (marker,) = out.glob("pid_*")
    pid = int(marker.read_text())
    deadline = time.monotonic() + 5  # the worker checks on its parent every 0.5 s
    while time.monotonic() < deadline and Path(f"/proc/{pid}").exists():
        time.sleep(0.1)
    alive = Path(f"/proc/{pid}").exists() and Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    if alive:
        os.kill(pid, signal.SIGKILL)  # clean up before failing
    assert not alive, "the generate worker outlived its killed driver"
    assert not list(out.glob("after_*"))


def test_two_runs_into_one_folder_are_refused(tmp_path):
    """A second run deleted the first one's half-built scenes (.staging) at its start and raced it for the slots."""
    from floaff_zoo.atomic import folder_lock

    with folder_lock(tmp_path / gen.GENERATE_LOCK):  # as a running generate holds it
        with pytest.raises(ValueError, match="another `floaff-zoo generate` is writing into this folder"):
            gen.generate(tmp_path, get_preset("tiny", **MINI), seed=0, workers=0, quiet=True)
    assert not (tmp_path / ff.MANIFEST).exists()


def test_rgb_png_refuses_an_image_it_would_draw_wrong():
    """rgb_png cast any image to uint8: a float image in [0, 1] became an all-black picture, 300 wrapped to 44 and
    NaN became 0, all without a word; an empty image failed inside PIL."""
    import io

    from PIL import Image

    from floaff_zoo.sim.pictures import rgb_png

    for bad, named in (
        (np.full((4, 4, 3), 0.8), r"integers 0..255 \(uint8\), got float64 in \[0.8, 0.8\]; scale a \[0, 1\]"),
        (np.full((4, 4, 3), 300), r"got int64 in \[300.0, 300.0\]$"),  # no [0, 1] hint for it
        (np.full((4, 4, 3), np.nan), "got float64 in"),
        (np.zeros((0, 4, 3), np.uint8), r"non-empty \[H,W,3\] image, got \(0, 4, 3\)"),
    ):
        with pytest.raises(ValueError, match=named):
            rgb_png(bad)
    for good in (np.full((4, 4, 3), 200, np.uint8), np.full((4, 4, 3), 200, np.int64), np.full((4, 4, 3), 200.0)):
        img = np.asarray(Image.open(io.BytesIO(rgb_png(good, min_size=8))))
        assert img.shape[:2] == (8, 8) and (img[..., :3] == 200).all()


def test_pictures_refuse_a_size_cell_or_pose_they_would_draw_wrong():
    """rgb_png's NaN min_size failed in math.ceil naming nothing; render_topdown_png drew a NaN or negative cell as
    no cell (or a mirrored one), a NaN or negative size_px as the smallest picture, and [V,3] view poses failed in
    numpy's reshape; a NaN cell centre failed in matplotlib's axis limits naming nothing."""
    from floaff_zoo.sim.pictures import render_topdown_png, rgb_png

    for size in (float("nan"), 0, 2.5, True):
        with pytest.raises(ValueError, match="rgb_png: min_size must be an integer >= 1"):
            rgb_png(np.zeros((2, 2, 3), np.uint8), size)
    args = dict(
        outline_polys=[],
        cells_xy=np.zeros((2, 2)),
        values=np.zeros(2),
        cell=0.1,
        target_xy=np.zeros(2),
        target_yaw=0.0,
        title="t",
    )
    assert render_topdown_png(**args, view_poses=np.zeros((1, 4))).startswith(b"\x89PNG")
    for bad, named in (
        (dict(cell=float("nan")), "plot_floor_map: cell must be a finite number > 0"),
        (dict(cell=-1.0), "plot_floor_map: cell must be a finite number > 0"),
        (dict(size_px=float("nan")), "render_topdown_png: size_px must be an integer >= 1"),
        (dict(size_px=-100), "render_topdown_png: size_px must be an integer >= 1"),
        (dict(view_poses=np.zeros((2, 3))), r"render_topdown_png: view_poses must be \[V,4\]"),
        (dict(cells_xy=np.array([[np.nan, 0.0], [0.0, 0.0]])), "plot_floor_map: cells_xy must be finite"),
    ):
        with pytest.raises(ValueError, match=named):
            render_topdown_png(**{**args, **bad})
