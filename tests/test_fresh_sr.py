"""scripts/fresh_sr.py: fresh-episode success probabilities of the candidate cells, and the SR of chosen cells."""

import json

import numpy as np
import pytest

pytest.importorskip("mujoco")
gen = pytest.importorskip("floaff_zoo.sim.generate")
from floaff_zoo.sim import fileformat as ff  # noqa: E402
from floaff_zoo.sim.presets import get_preset  # noqa: E402
from tests._scripts import load_script  # noqa: E402

fs = load_script("fresh_sr")


@pytest.fixture(scope="module")
def drawer_root(tmp_path_factory):
    """One generated tiny CloseDrawer test scene (and its training scene), format 2."""
    out = tmp_path_factory.mktemp("fresh_sr")
    man = gen.generate(out, get_preset("tiny", tasks=("CloseDrawer",), n_test=1), seed=0, workers=0, quiet=True)
    assert man["counts"]["scenes_ok"] >= 2
    return out


def test_perturbed_poses_are_seeded_and_scaled():
    xy, yaw = np.zeros((500, 2)), np.zeros(500)
    a = fs.perturbed_poses(xy, yaw, 0, 0.02, 0.03, seed=7)
    assert np.array_equal(a, fs.perturbed_poses(xy, yaw, 0, 0.02, 0.03, seed=7))
    assert not np.array_equal(a, fs.perturbed_poses(xy, yaw, 1, 0.02, 0.03, seed=7))  # another episode
    assert np.std(a[:, :2]) == pytest.approx(0.02, rel=0.15) and np.std(a[:, 2]) == pytest.approx(0.03, rel=0.15)
    assert np.array_equal(fs.perturbed_poses(xy, yaw, 0, 0.0, 0.0, seed=7), np.zeros((500, 3)))


def test_annotation_seed_without_noise_gives_back_the_labels(drawer_root):
    scene = next(ff.iter_scenes(drawer_root, split="test"))
    p = fs.fresh_probability(scene, fs.service_runner(1), 1, 0.0, 0.0, seed=0, seeds=[gen.ANNOTATE_SEED])
    success = np.asarray(scene["labels"]["success"]) > 0
    assert success.any()
    assert np.array_equal(p > 0.5, success)
    assert not p[~np.asarray(scene["candidates"]["valid"], bool)].any()  # filtered cells: never rolled out, 0


def test_nearest_cells_names_an_off_grid_point():
    cand = np.array([[0.0, 0.0], [0.1, 0.0]])
    assert fs.nearest_cells(cand, np.array([[0.09, 0.01], [0.0, 0.0]]), 0.1, "v").tolist() == [1, 0]
    with pytest.raises(ValueError, match="view7: 1 floor point"):
        fs.nearest_cells(cand, np.array([[0.5, 0.0]]), 0.1, "view7")


def test_cli_scores_the_label_oracle_and_caches_probabilities(drawer_root, tmp_path, monkeypatch):
    out, cache = tmp_path / "j" / "fresh.json", tmp_path / "new_dir" / "p.npz"  # folders are made
    args = ["--root", str(drawer_root), "--benchmark", "styles", "--episodes", "2", "--probs", str(cache)]
    assert fs.main([*args, "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["views"] > 0 and rep["setting"]["episodes"] == 2
    assert rep["sr"]["label"]["exact"]["all"] == 1.0  # the label argmax is an annotated success
    for kind in ("exact", "fresh"):
        assert 0.0 <= rep["sr"]["label"][kind]["all"] <= 1.0
    # the hindsight scorer stands on the best fresh cell, so no scorer beats it under fresh episodes
    assert rep["sr"]["best"]["fresh"]["all"] >= rep["sr"]["label"]["fresh"]["all"]
    assert cache.is_file()
    # the cache is reused (no rollout) only for the setting it was made with
    import floaff_zoo.sim.repeat as repeat

    def no_rollout(workers):
        raise AssertionError("the cached probabilities were rolled out again")

    monkeypatch.setattr(repeat, "service_runner", no_rollout)
    assert fs.main([*args, "--json", str(out)]) == 0
    assert json.loads(out.read_text())["sr"] == rep["sr"]
    with pytest.raises(SystemExit, match="was made with"):
        fs.main([*args[:-3], "3", "--probs", str(cache)])


def test_cli_annotation_seed_without_noise_is_the_exact_evaluation(drawer_root, tmp_path):
    out = tmp_path / "same.json"
    args = ["--root", str(drawer_root), "--benchmark", "styles", "--episodes", "1", "--annotation-seed"]
    for top_k, cloud in (("1", []), ("3", []), ("3", ["--full-cloud"])):  # the check in the sample or every point
        argv = [*args, "--sigma-xy", "0", "--sigma-yaw-deg", "0", "--top-k", top_k, *cloud, "--json", str(out)]
        assert fs.main(argv) == 0
        rep = json.loads(out.read_text())
        assert rep["setting"]["task_seed"] == "annotation" and rep["top_k"] == int(top_k)
        assert rep["full_cloud"] == bool(cloud)
        # the same seed at the same pose reproduces every annotated outcome, so fresh equals exact for every scorer
        for scorer in ("label", "best"):
            assert rep["sr"][scorer]["fresh"] == rep["sr"][scorer]["exact"]
    assert rep["sr"]["best"]["fresh"]["all"] == 1.0


def test_cli_names_bad_arguments_and_a_corrupt_cache(drawer_root, tmp_path):
    args = ["--root", str(drawer_root), "--benchmark", "styles"]
    bad_args = (["--top-k", "0"], ["--episodes", "0"], ["--seed", "-1"], ["--probs", str(tmp_path / "p.txt")])
    for bad in (*bad_args, ["--full-cloud"]):
        with pytest.raises(SystemExit):
            fs.main([*args, *bad])
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"not an npz")
    with pytest.raises(SystemExit, match="corrupt.npz is not a fresh-probability cache"):
        fs.main([*args, "--probs", str(corrupt)])
    with pytest.raises(FileNotFoundError, match="no_such_model.ckpt"):  # before any rollout
        fs.main([*args, "--probs", str(tmp_path / "never.npz"), str(tmp_path / "no_such_model.ckpt")])
    assert not (tmp_path / "never.npz").exists()


def test_a_model_without_a_floor_map_exits_naming_it(tmp_path):
    """An AxisNet checkpoint was resolved without a check and its output read as floor scores, after the data."""
    import re

    from tests.test_val_sr import axisnet_ckpt

    ckpt = axisnet_ckpt(tmp_path / "axisnet.ckpt")
    with pytest.raises(SystemExit, match=rf"fresh_sr: {re.escape(str(ckpt))}: .*AxisNetModule predicts no floor map"):
        fs.main(["--root", str(tmp_path / "missing"), "--benchmark", "styles", str(ckpt)])


def test_fresh_labels_train_the_datamodule_and_val_split_scores(drawer_root, tmp_path):
    """scripts/fresh_labels.py labels every train scene; the DataModule trains on them; fresh_sr scores val."""
    fl = load_script("fresh_labels")
    from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
    from floaff_zoo.data.scene_labels import read_scene_labels

    out, cache = tmp_path / "labels.npz", tmp_path / "p_train.npz"
    args = ["--root", str(drawer_root), "--benchmark", "styles", "--episodes", "1", "--probs", str(cache)]
    assert fl.main([*args, "--out", str(out)]) == 0
    table, setting = read_scene_labels(out)
    train = {s["scene_id"]: s for s in ff.iter_scenes(drawer_root, benchmark="styles", split="train")}
    assert set(table) == set(train) and setting["episodes"] == 1
    # the data module checks a file against the generated labels it was made from (data.scene_labels)
    assert setting["made_from"] == {sid: ff.labels_digest(scene) for sid, scene in train.items()}
    for sid, scene in train.items():
        xy, label, cell = table[sid]
        assert np.allclose(xy, scene["candidates"]["xy"]) and cell == scene["candidates"]["cell"]
        assert label.max() == pytest.approx(1.0) or not label.any()  # max-normalised as the generated labels
        assert not label[np.asarray(scene["candidates"]["status"]) == 0].any()  # filtered cells stay 0
    with pytest.raises(SystemExit):
        fl.main([*args, "--out", str(tmp_path / "labels.txt")])

    dm = FloAffKitchenDataModule(
        root=str(drawer_root), benchmark="styles", tasks=["CloseDrawer"], train_labels=str(out), num_points=256
    )
    dm.setup("fit")
    s = dm.train_dataloader().dataset[0]
    sid = s["meta"]["scene_id"]
    assert s["floor_label"].max() <= 1.0 and sid in table

    # the cache of the train scenes serves fresh_sr on the validation split (no new rollout for its scenes)
    rep = tmp_path / "val.json"
    assert fs.main(["--root", str(drawer_root), "--benchmark", "styles", "--episodes", "1", "--split", "val",
                    "--probs", str(cache), "--json", str(rep)]) == 0  # fmt: skip
    assert json.loads(rep.read_text())["views"] == len(dm.val_dataloader().dataset)


def test_fresh_labels_without_episodes_zero_the_failed_cells(drawer_root, tmp_path):
    """--episodes 0 gives back the generated labels (no rollout); --zero-failures keeps them on successes only."""
    fl = load_script("fresh_labels")
    from floaff_zoo.data.scene_labels import read_scene_labels

    base = ["--root", str(drawer_root), "--benchmark", "styles", "--episodes", "0", "--probs", str(tmp_path / "p.npz")]
    assert fl.main([*base, "--out", str(tmp_path / "plain.npz")]) == 0
    assert fl.main([*base, "--zero-failures", "--out", str(tmp_path / "zero.npz")]) == 0
    assert not (tmp_path / "p.npz").exists()  # nothing rolled out, nothing cached
    plain, setting = read_scene_labels(tmp_path / "plain.npz")
    zero, zsetting = read_scene_labels(tmp_path / "zero.npz")
    assert setting["source"] == "annotated" and not setting["zero_failures"] and zsetting["zero_failures"]
    failed_with_value = 0
    for scene in ff.iter_scenes(drawer_root, benchmark="styles", split="train"):
        sid, labels = scene["scene_id"], scene["labels"]
        generated = np.asarray(labels["cell_label"], np.float32)
        success = np.asarray(labels["success"], bool)
        assert np.array_equal(plain[sid][1], generated)  # the generator's smoothing, reproduced exactly
        assert np.array_equal(zero[sid][1][success], generated[success])
        assert not zero[sid][1][~success].any()
        failed_with_value += int((generated[~success] > 0).sum())
    assert failed_with_value > 0  # the generated map does give failed cells a value (what the option removes)
    with pytest.raises(SystemExit):
        fl.main([*base[:-2], "--episodes", "-1", "--out", str(tmp_path / "x.npz")])


def test_named_models_pool_their_runs():
    keys, groups = fs.parse_models(["occ=a.ckpt", "prior=p.ckpt", "occ=b.ckpt", "hub.name"])
    assert keys == {"occ/0": "a.ckpt", "prior": "p.ckpt", "occ/1": "b.ckpt", "hub.name": "hub.name"}
    assert groups == {"occ": ["occ/0", "occ/1"], "prior": ["prior"], "hub.name": ["hub.name"]}
    sr = {
        "occ/0": {"exact": {"all": 0.8}, "fresh": {"all": 0.6}},
        "occ/1": {"exact": {"all": 0.6}, "fresh": {"all": 0.6}},
        "prior": {"exact": {"all": 0.7}, "fresh": {"all": 0.5}},
    }
    pooled = fs.pool_runs(sr, {"occ": groups["occ"], "prior": groups["prior"]})
    assert pooled["occ"]["runs"] == 2
    assert pooled["occ"]["exact"]["all"]["mean"] == pytest.approx(0.7)
    assert pooled["occ"]["exact"]["all"]["std"] == pytest.approx(np.std([0.8, 0.6], ddof=1))
    assert pooled["occ"]["fresh"]["all"] == {"mean": pytest.approx(0.6), "std": pytest.approx(0.0)}
    assert pooled["prior"]["exact"]["all"] == {"mean": pytest.approx(0.7), "std": 0.0}
    keys, _ = fs.parse_models(["runs/x/epoch=1-step=9.ckpt"])
    assert keys == {"runs/x/epoch=1-step=9.ckpt": "runs/x/epoch=1-step=9.ckpt"}
    for bad in (["=a.ckpt"], ["occ="], ["label=a.ckpt"]):
        with pytest.raises(SystemExit, match="bad model argument"):
            fs.parse_models(bad)


def test_view_choices_with_full_cloud_check_every_stored_point(drawer_root):
    """``full_cloud`` reads the batch's ``full_xyz`` (every stored point; the DataModule's ``full_cloud``): with the
    batch's sample masked out it chooses as the full sample does, and without it the masked batch chooses otherwise in
    some view (so the comparison can fail)."""
    import torch

    from floaff_zoo.contract import validate_sample
    from floaff_zoo.nn.placement import footprint_counts
    from tests.report._fake_world import loader

    scenes = {s["scene_id"]: s for s in ff.iter_scenes(drawer_root)}
    samples = [validate_sample(ff.read_sample(sc, v, drawer_root)) for sc in scenes.values() for v in sc["views"]]
    samples = [{**s, "full_xyz": s["scene_xyz"].clone()} for s in samples]  # as the DataModule's full_cloud gives it
    probs = {sid: np.arange(len(s["candidates"]["xy"]), dtype=float) for sid, s in scenes.items()}  # tells cells apart
    changed = 0
    for batch in loader(samples, 4):
        m = batch["floor_xyz"].shape[1]
        # the cells whose footprint holds the most obstacle points first: the check must refuse the top ones
        counts = footprint_counts(
            batch["scene_xyz"], batch["scene_mask"], batch["floor_xyz"][..., :2], batch["target_xyz"][..., :2]
        )
        blocked_first = {"m": torch.sigmoid(counts).numpy()}
        blind = {**batch, "scene_mask": torch.zeros_like(batch["scene_mask"])}
        full = fs.view_choices(batch, blocked_first, scenes, probs, top_k=m)
        assert fs.view_choices(blind, blocked_first, scenes, probs, top_k=m, full_cloud=True) == full
        sample_only = fs.view_choices(blind, blocked_first, scenes, probs, top_k=m)
        changed += sum(a["m"] != b["m"] for a, b in zip(sample_only, full))
    assert changed > 0


def test_split_data_ends_bad_data_with_the_scripts_message(tmp_path, drawer_root):
    """Both scripts read their split through ``split_data``: a missing root or a benchmark without a usable scene ends
    with a message naming the script, not a traceback; a good root gives the split's scenes only."""
    with pytest.raises(SystemExit, match="fresh_sr: .*does not exist"):
        fs.split_data("fresh_sr", str(tmp_path / "missing"), "styles", "test", 256, False)
    dm, scenes = fs.split_data("scene_sr", str(drawer_root), "styles", "val", 256, False)
    val = {s.removesuffix(" (views)") for s in dm.split_scenes["val"]}
    assert set(scenes) == val and scenes
    with pytest.raises(SystemExit, match="scene_sr: .*no usable 'layouts' scene"):
        fs.split_data("scene_sr", str(drawer_root), "layouts", "test", 256, False)


def test_the_label_oracle_stands_on_its_argmax_under_top_k(drawer_root):
    """Under --top-k the Oracle row went through the footprint check like the models, and stood elsewhere when the
    view's cloud reached into its argmax cell's footprint; the test's Oracle takes its argmax (top 1, no check)."""
    import torch

    from floaff_zoo.contract import validate_sample
    from tests.report._fake_world import loader

    scenes = {s["scene_id"]: s for s in ff.iter_scenes(drawer_root)}
    samples = [validate_sample(ff.read_sample(sc, v, drawer_root)) for sc in scenes.values() for v in sc["views"]]
    probs = {sid: np.arange(len(s["candidates"]["xy"]), dtype=float) for sid, s in scenes.items()}  # tells cells apart
    for batch in loader(samples, 4):
        label = batch["floor_label"].masked_fill(~batch["floor_mask"], -1.0)
        for i, best in enumerate(label.argmax(dim=1).tolist()):  # an obstacle (two points) over each argmax cell
            for j, dx in enumerate((0.0, 0.02)):
                batch["scene_xyz"][i, j] = batch["floor_xyz"][i, best] + torch.tensor([dx, 0.0, 0.3])
                batch["scene_mask"][i, j] = True
        scores = {"label": batch["floor_label"].numpy()}
        top1 = fs.view_choices(batch, scores, scenes, probs, top_k=1)
        topk = fs.view_choices(batch, scores, scenes, probs, top_k=batch["floor_xyz"].shape[1])
        assert [r["label"] for r in topk] == [r["label"] for r in top1]


def test_top_k_checks_each_footprint_at_the_pose_the_callback_rolls_out():
    """``--top-k`` checked the footprints of poses rebuilt from the view's float32 points, not at the exact pose the
    callback rolls out: a point on a footprint's edge freed a cell the callback refuses (scene_sr's knife edge)."""
    from tests.test_scene_sr import knife_edge_view

    batch, scenes, scores = knife_edge_view(top_k=3)
    probs = {sid: np.asarray(s["labels"]["success"], float) for sid, s in scenes.items()}
    (row,) = fs.view_choices(batch, {"m": scores}, scenes, probs, top_k=3)
    assert row["m"] == (True, 1.0)  # the callback's cell: the only successful one


def _hole_scene(task: str = "CloseDrawer") -> dict:
    """A 3 x 3 scene whose centre the IK pre-filter refused amid 8 successes: the smoothed map (labels.label) peaks
    on that filtered cell, which every per-cell label (labels.cell_label) sets to 0."""
    from floaff_zoo.sim.annotate import FILTERED, ROLLED_OUT, _smooth, cell_labels

    status = np.full(9, ROLLED_OUT)
    status[4] = FILTERED
    success = (status == ROLLED_OUT).astype(float)
    label = _smooth(success, (3, 3), 1.0)
    cell_label, known = cell_labels(label, status)
    xy = np.stack(np.meshgrid(np.arange(3) * 0.1, np.arange(3) * 0.1, indexing="ij"), -1).reshape(-1, 2)
    return {
        "scene_id": "hole",
        "task": task,
        "sigma": 1.0,
        "candidates": {
            "xy": xy.tolist(),
            "status": status.tolist(),
            "grid_shape": [3, 3],
            "cell": 0.1,
            "valid": [True] * 9,
        },
        "labels": {"success": success.tolist(), "label": label.tolist(), "cell_label": cell_label.tolist()},
    }


def test_fresh_labels_summary_compares_peaks_with_the_generated_per_cell_labels(tmp_path, monkeypatch, capsys):
    """The 'same peak cell' summary took the generated peak from labels.label, the map before filtered cells are
    zeroed: with --episodes 0, whose labels equal the generated ones, it printed 0.00 for a scene whose map peaked on
    a filtered cell."""
    fl = load_script("fresh_labels")
    scene = _hole_scene()
    assert int(np.argmax(scene["labels"]["label"])) == 4  # the smoothed map peaks on the filtered centre
    monkeypatch.setattr(ff, "iter_scenes", lambda root, benchmark=None, split=None: iter([scene]))
    out = tmp_path / "labels.npz"
    assert fl.main(["--root", str(tmp_path), "--benchmark", "styles", "--episodes", "0", "--out", str(out)]) == 0
    assert "CloseDrawer: 1 scenes, same peak cell 1.00" in capsys.readouterr().out
    assert np.array_equal(fl.generated_label(scene), np.asarray(scene["labels"]["cell_label"]))


def test_cell_stats_leaves_cells_over_the_budget_out_of_the_annotated_failures():
    """A cell over the rollout budget (SKIPPED) was never rolled out, yet counted as an annotated failure: its fresh
    successes raised fresh_p_of_annotated_failures."""
    from floaff_zoo.sim.annotate import SKIPPED

    scene = _hole_scene()
    scene["candidates"]["status"][0] = SKIPPED
    scene["labels"]["success"][0] = 0.0
    scene["labels"]["success"][1] = 0.0  # a rolled-out failure
    probs = np.zeros(9)
    probs[0], probs[1], probs[2] = 1.0, 0.25, 0.5
    stats = fs.cell_stats({"hole": scene}, {"hole": probs})["CloseDrawer"]
    # failures: cell 1 (rolled out) and the IK-refused centre 4; not the skipped cell 0
    assert stats["fresh_p_of_annotated_failures"] == pytest.approx((0.25 + 0.0) / 2)
    assert fs.annotated_failures(scene).tolist() == [i in (1, 4) for i in range(9)]


@pytest.mark.parametrize("sigma", [["--sigma-xy", "nan"], ["--sigma-yaw-deg", "inf"]])
@pytest.mark.parametrize("script", ["fresh_sr", "fresh_labels"])
def test_a_sigma_that_is_no_number_is_a_usage_error(script, sigma, tmp_path, capsys):
    """NaN passed `sigma < 0` and ended in a rollout's error about a NaN pose, naming no option, after the setup."""
    out = ["--out", str(tmp_path / "l.npz")] if script == "fresh_labels" else []
    with pytest.raises(SystemExit) as done:
        load_script(script).main(["--root", str(tmp_path), *out, *sigma])
    assert done.value.code == 2 and f"{sigma[0]} must be a finite number >= 0" in capsys.readouterr().err


@pytest.mark.parametrize(("script", "option"), [("fresh_sr", "--probs"), ("fresh_sr", "--json"),
                                                ("fresh_labels", "--probs"), ("fresh_labels", "--out")])  # fmt: skip
def test_an_output_file_that_is_a_folder_is_refused_before_any_rollout(script, option, tmp_path, capsys):
    """The cache or the output was written after the first scene's rollouts (or the whole run): an IsADirectoryError."""
    folder = tmp_path / "x.npz"
    folder.mkdir()
    args = {"--out": str(tmp_path / "l.npz"), option: str(folder)}
    if script == "fresh_sr":
        args.pop("--out")
    with pytest.raises(SystemExit) as done:
        load_script(script).main(["--root", str(tmp_path / "none"), *[x for kv in args.items() for x in kv]])
    assert done.value.code == 2 and f"{option} names a file to write, got the folder" in capsys.readouterr().err
