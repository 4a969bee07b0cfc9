"""FloAffKitchenDataModule on a fixture in the generator's format (tests/data/floaff_fixture.py)."""

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.data import transforms
from floaff_zoo.data.base import DataConfigError
from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
from floaff_zoo.data.readers import READERS, DataError, GeneratedReader, get_reader, register_reader
from floaff_zoo.sim import fileformat as ff


def _dm(root, **kw):
    args = dict(root=str(root), batch_size=2, num_points=128, cache=False)
    args.update(kw)
    return FloAffKitchenDataModule(**args)


def test_scene_level_splits_meta_and_skips(floaff_root, capsys):
    root, exp = floaff_root
    dm = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"])
    dm.setup("fit")
    assert dict(dm.skips.counts) == exp["skips"]
    assert "skipped 5 sample(s)" in capsys.readouterr().out
    scenes = {s: {r.meta["scene_id"] for r in dm.datasets[s].records} for s in ("train", "val", "test")}
    assert scenes["test"] == set(exp["scenes"]["styles"]["test"])
    cd = {s: {x for x in v if x.startswith("CloseDrawer")} for s, v in scenes.items()}
    assert len(cd["val"]) == 1 and len(cd["train"]) == 2 and not cd["val"] & cd["train"]  # scene-level
    # PnP has one train scene: its views are split (seeded) between train and val
    pnp_tr = [r.key for r in dm.datasets["train"].records if r.meta["task"] == "PnPCounterToCab"]
    pnp_va = [r.key for r in dm.datasets["val"].records if r.meta["task"] == "PnPCounterToCab"]
    assert len(pnp_va) == 1 and len(pnp_tr) == 3 and not set(pnp_tr) & set(pnp_va)
    s = dm.datasets["test"][0]
    m = s["meta"]
    for k in ("dataset", "task", "view", "scene_id", "layout_id", "style_id", "sample_id", "index"):
        assert k in m
    assert m["dataset"] == "floaff_kitchen_styles" and m["index"] == 0
    assert set(m["sim"]) >= {"layout_id", "style_id", "seed", "task", "base_pose_world", "scene_dir"}
    assert len(m["sim"]["base_pose_world"]) == 3 and m["sim"]["scene_dir"].endswith(m["scene_id"])
    assert m["sim"]["target_world"] == [1.0, 2.0]  # scene.json's target.pos: the rollout faces it exactly
    assert s["scene_feat"].shape[1] == 4
    b = next(iter(dm.val_dataloader()))
    assert b["scene_xyz"].shape == (2, 128, 3) and isinstance(b["meta"][0]["sim"], dict)


def test_labels_digests_cover_the_tasks_scenes_and_follow_their_labels(floaff_root):
    root, exp = floaff_root
    dm = _dm(root, tasks=["CloseDrawer"])
    dm.setup("test")
    before = dict(dm.labels_digests)
    assert before and all(s.startswith("CloseDrawer") for s in before)
    assert set(exp["scenes"]["styles"]["test"]) & set(before)
    # one rollout outcome flipped in one scene (another CPU's copy): only that scene's hash moves
    sid = sorted(before)[0]
    path = ff.scene_dir(root, "styles", sid) / ff.SCENE_JSON
    rec = json.loads(path.read_text())
    rec["labels"]["success"][0] = 1 - int(rec["labels"]["success"][0])
    path.write_text(json.dumps(rec))
    again = _dm(root, tasks=["CloseDrawer"])
    again.setup("test")
    assert {k for k in before if before[k] != again.labels_digests[k]} == {sid}


def test_val_scene_ids_pin_the_validation_scenes(floaff_root):
    root, _ = floaff_root
    drawn = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"])
    drawn.setup("fit")
    other = sorted(s for s in drawn.split_scenes["train"] if s.startswith("CloseDrawer"))[0]
    dm = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"], val_scene_ids=[other])
    dm.setup("fit")
    assert dm.split_scenes["val"] == [other]
    val_scenes = {r.meta["scene_id"] for r in dm.datasets["val"].records}
    assert val_scenes == {other} and other not in {r.meta["scene_id"] for r in dm.datasets["train"].records}
    # a task with no listed scene keeps all of its train views in train (no seeded view split)
    assert not [r for r in dm.datasets["val"].records if r.meta["task"] == "PnPCounterToCab"]
    with pytest.raises(DataConfigError, match="val_scene_ids.*nope"):  # one line from the CLI and the scripts
        _dm(root, val_scene_ids=["nope"]).setup("fit")
    # a pinned hold-out may take every train scene of a task: said, since the fit then never trains it
    drawer = sorted({*drawn.split_scenes["train"], *drawn.split_scenes["val"]})
    drawer = [sid for sid in drawer if sid.startswith("CloseDrawer")]
    with pytest.warns(UserWarning, match="every train scene of CloseDrawer is held out .*val_scene_ids") as said:
        _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"], val_scene_ids=drawer).setup("fit")
    assert not [w for w in said if "split holds no sample" in str(w.message)]  # said once, not again as a gap


def test_val_layout_holds_out_every_train_scene_of_one_layout(floaff_root):
    root, _ = floaff_root
    ref = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"])
    ref.setup("fit")
    layout = {r.meta["scene_id"]: str(r.meta["layout_id"]) for r in ref.datasets["train"].records}
    layout |= {r.meta["scene_id"]: str(r.meta["layout_id"]) for r in ref.datasets["val"].records}
    assert len(set(layout.values())) >= 2  # the fixture has train scenes in more than one layout
    fold = sorted(set(layout.values()))[0]
    dm = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"], val_layout=int(fold))
    dm.setup("fit")
    val = {r.meta["scene_id"] for r in dm.datasets["val"].records}
    train = {r.meta["scene_id"] for r in dm.datasets["train"].records}
    assert val == {sid for sid, lay in layout.items() if lay == fold} and val
    assert train and all(layout[sid] != fold for sid in train) and not val & train
    with pytest.raises(DataConfigError, match="val_layout 99 has no train scene"):  # a traceback in every script
        _dm(root, val_layout=99).setup("fit")
    with pytest.raises(DataConfigError, match="val_scene_ids or data.val_layout, not both"):
        _dm(root, val_layout=0, val_scene_ids=["x"])
    for bad in (True, 1.5, -1):  # each matched no layout id and was refused only at setup
        with pytest.raises(DataConfigError, match=r"data.val_layout must be an integer >= 0"):
            _dm(root, val_layout=bad)


def test_val_scenes_0_trains_every_train_scene_and_view_without_validation(floaff_root):
    root, _ = floaff_root
    ref = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"])
    ref.setup("fit")
    pool = {r.key for s in ("train", "val") for r in ref.datasets[s].records}
    assert len(ref.datasets["val"]) > 0  # the default holds some out, scenes and (one-scene PnP) views
    dm = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"], val_scenes=0)
    dm.setup("fit")
    assert not dm.validates and len(dm.datasets["val"]) == 0
    assert {r.key for r in dm.datasets["train"].records} == pool
    assert dm.val_dataloader() == []  # Lightning runs no validation loop
    with pytest.raises(MisconfigurationException, match=r"'val' split is empty \(val_scenes 0: no validation split\)"):
        _dm(root, tasks=["CloseDrawer"], val_scenes=0).setup("validate")
    # val_scenes 0 beside pinned scenes or a fold still validates on those
    assert _dm(root, val_scenes=0, val_layout=0).validates and _dm(root, val_scenes=0, val_scene_ids=["x"]).validates


def _held_out(dm, task):
    """(validation scene ids, validation sample keys) of one task after setup."""
    recs = [r for r in dm.datasets["val"].records if r.meta["task"] == task]
    return sorted({r.meta["scene_id"] for r in recs}), sorted(r.key for r in recs)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_tasks_validation_draw_does_not_depend_on_the_other_tasks_loaded(floaff_root, seed):
    """A PFAL stage that loads some tasks, in its own order, holds out what an all-task run holds out."""
    root, _ = floaff_root
    runs = {}
    for tasks in (None, ["CloseDrawer", "PnPCounterToCab"], ["PnPCounterToCab", "CloseDrawer"], ["CloseDrawer"]):
        dm = _dm(root, tasks=tasks, seed=seed)
        dm.setup("fit")
        runs[str(tasks)] = dm
    ref = runs["None"]
    for name, dm in runs.items():
        assert _held_out(dm, "CloseDrawer") == _held_out(ref, "CloseDrawer"), name
        if "PnPCounterToCab" in dm.tasks:  # one train scene: the seeded view split
            assert _held_out(dm, "PnPCounterToCab") == _held_out(ref, "PnPCounterToCab"), name
    assert len(_held_out(ref, "CloseDrawer")[0]) == 1


def test_single_task_views_filter_and_layouts(floaff_root):
    root, exp = floaff_root
    dm = _dm(root, benchmark="layouts", tasks=["OpenSingleDoor"], views=["front"])
    dm.setup("fit")
    views = {r.meta["view"] for s in ("train", "val", "test") for r in dm.datasets[s].records}
    assert views == {"front"}
    assert len(dm.datasets["train"]) == 2 and len(dm.datasets["val"]) == 2 and len(dm.datasets["test"]) == 2
    assert all(r.meta["task"] == "OpenSingleDoor" for r in dm.datasets["train"].records)
    # a task without scenes -> empty split at fit is a clear error
    with pytest.raises(MisconfigurationException, match="split is empty"):
        _dm(root, benchmark="layouts", tasks=["CloseDoubleDoor"]).setup("fit")


def test_unknown_names_list_valid_ones(floaff_root):
    root, _ = floaff_root
    with pytest.raises(ValueError, match="valid tasks.*CloseDrawer"):
        _dm(root, tasks=["CloseDrawr"])
    with pytest.raises(ValueError, match="valid views.*front"):
        _dm(root, views=["top"])
    with pytest.raises(ValueError, match="valid benchmark.*styles"):
        _dm(root, benchmark="kitchens")
    with pytest.raises(ValueError, match="registered.*generated"):
        _dm(root, reader="nope")
    with pytest.raises(MisconfigurationException, match="does not exist"):
        _dm(root / "missing").setup("fit")
    # the preset it suggests has the benchmark and the tasks asked for (it said `tiny`, Styles and two tasks only)
    with pytest.raises(MisconfigurationException, match="generate --preset demo --out"):
        _dm(root / "missing", benchmark="layouts", tasks=["PnPCounterToCab"]).setup("fit")
    with pytest.raises(MisconfigurationException, match="generate --preset tiny --out"):
        _dm(root / "missing", benchmark="styles", tasks=["CloseDrawer"]).setup("fit")


def test_strict_raises_naming_file(floaff_root):
    root, _ = floaff_root
    with pytest.raises(DataError, match="scene.json"):
        _dm(root, strict=True).setup("fit")


class _RenamedReader(GeneratedReader):
    """A user reader: the generated format, with every scene's views restricted to the first one."""

    def scenes(self, benchmark):
        out = super().scenes(benchmark)
        for s in out:
            s.views = s.views[:1]
        return out


def test_custom_reader_by_registry_and_import_path(floaff_root):
    root, _ = floaff_root
    register_reader("first_view_only")(_RenamedReader)
    try:
        assert get_reader("first_view_only") is _RenamedReader
        dm = _dm(root, reader="first_view_only", tasks=["CloseDrawer"])
        dm.setup("test")
        assert len(dm.datasets["test"]) == 1
        dm2 = _dm(root, reader="tests.data.test_floaff_kitchen:_RenamedReader", tasks=["CloseDrawer"])
        dm2.setup("test")
        assert len(dm2.datasets["test"]) == 1
    finally:
        READERS.pop("first_view_only", None)
    with pytest.raises(TypeError):
        register_reader("bad")(dict)


def test_cache_and_workers(floaff_root):
    root, exp = floaff_root
    dm = _dm(root, cache=True, num_workers=2, tasks=["CloseDrawer"])
    dm.setup("fit")
    n = sum(len(dm.datasets[s]) for s in ("train", "val", "test"))
    assert len(list((root / ".cache").rglob("*.pt"))) == n
    assert len(list((root / ".cache").rglob("*.skip"))) == 2  # bad views are remembered
    dm2 = _dm(root, cache=True, tasks=["CloseDrawer"])
    dm2.setup("fit")
    assert dict(dm2.skips.counts) == {k: v for k, v in exp["skips"].items()}


def test_training_seeds_share_the_cache_unless_a_pre_transform_draws_from_it(floaff_root):
    """Without pre-transforms the seed changes nothing that is cached, so a second training seed reads the first
    one's entries instead of parsing every view again; with one, each seed keeps its own entries."""
    root, _ = floaff_root

    def cache_dirs(**kw):
        for seed in (0, 1):
            _dm(root, tasks=["CloseDrawer"], cache=True, seed=seed, **kw).setup("test")
        return sorted(p.name for p in (root / ".cache").iterdir() if p.is_dir())

    assert len(cache_dirs()) == 1
    shutil.rmtree(root / ".cache")
    assert len(cache_dirs(pre_transforms=[_Shift()])) == 2


def test_full_cloud_carries_every_stored_point_past_crop_cache_and_resampling(floaff_root):
    """full_cloud: the batch's full_xyz is the view file's whole cloud (as fileformat reads it), while scene_xyz is
    the cropped, resampled sample; the cache keeps it under its own key, and without the flag batches have none.
    The train split never carries it and shares the cache of full_cloud false."""
    import torch

    from floaff_zoo.data.transforms import TargetCrop

    root, _ = floaff_root
    kw = dict(
        tasks=["CloseDrawer"], eval_batch_size=1, cache=True, eval_transforms=[TargetCrop(radius=0.5, min_points=1)]
    )
    plain = _dm(root, **kw)
    plain.setup("test")
    assert "full_xyz" not in next(iter(plain.test_dataloader()))
    (plain_dir,) = {p.parent for p in (root / ".cache").rglob("*.pt")}
    n_plain = len(list(plain_dir.glob("*.pt")))
    dm = _dm(root, full_cloud=True, **kw)
    dm.setup("test")
    (full_dir,) = {p.parent for p in (root / ".cache").rglob("*.pt")} - {plain_dir}  # its own cache directory
    assert len(list(full_dir.glob("*.pt"))) == len(dm.datasets["val"]) + len(dm.datasets["test"])
    assert len(list(plain_dir.glob("*.pt"))) == n_plain  # the train split's entries are the plain ones
    assert "full_xyz" not in dm.datasets["train"][0] and "full_xyz" in dm.datasets["val"][0]
    for _ in range(2):  # the second pass reads the cache
        batch = next(iter(dm.test_dataloader()))
        stored = torch.as_tensor(ff.read_view(dm.datasets["test"].records[0].payload["view"]["file"])["scene_xyz"])
        assert batch["scene_xyz"].shape == (1, 128, 3)
        assert batch["full_xyz"].shape == (1, len(stored), 3) and batch["full_mask"].all()
        assert torch.equal(batch["full_xyz"][0], stored)
        crop = (batch["scene_xyz"][0] - batch["target_xyz"][0]).norm(dim=1)
        assert crop.max() <= 0.5 + 1e-5 < (stored - batch["target_xyz"][0]).norm(dim=1).max()


def test_eval_resampling_repeats_across_epochs_and_worker_counts():
    """Val / test batches resample each sample from its own seeded stream: the same points in every epoch, with
    any number of workers and any batch size (a fit's checkpoint choice must not depend on them)."""
    import torch

    from floaff_zoo.data.synthetic import SyntheticDataModule

    def val_points(**kw):
        dm = SyntheticDataModule(num_train=4, num_val=6, num_test=2, points_per_sample=200, num_points=256, **kw)
        dm.setup("fit")
        loader = dm.val_dataloader()
        epochs = [torch.cat([b["scene_xyz"] for b in loader]) for _ in range(2)]
        assert torch.equal(epochs[0], epochs[1])
        return epochs[0]

    ref = val_points(eval_batch_size=2)
    assert torch.equal(ref, val_points(eval_batch_size=2, num_workers=2))
    assert torch.equal(ref, val_points(eval_batch_size=3))
    assert not torch.equal(ref, val_points(eval_batch_size=2, seed=1))


def test_the_views_a_run_loads_never_move_another_tasks_validation_scenes(floaff_root):
    """PnP has a single train scene (its views are drawn); CloseDrawer's held-out scene must not depend on how many
    PnP views the run loads."""
    root, _ = floaff_root

    def cd_val(**kw):
        dm = _dm(root, tasks=["PnPCounterToCab", "CloseDrawer"], **kw)
        dm.setup("fit")
        return {r.meta["scene_id"] for r in dm.datasets["val"].records if r.meta["task"] == "CloseDrawer"}

    ref = cd_val()
    for seed in range(6):
        assert cd_val(seed=seed, views=["front"]) == cd_val(seed=seed)
        assert cd_val(seed=seed, max_views_per_scene=1) == cd_val(seed=seed)
    assert len(ref) == 1


class _Shift(transforms.SampleTransform):
    """A custom pre-transform whose setting is a tuple (part of the cache key)."""

    def __init__(self, offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        self.offset = offset

    def __call__(self, sample, rng):
        import torch

        return {**sample, "scene_xyz": sample["scene_xyz"] + torch.tensor(self.offset)}


def test_every_setting_of_a_pre_transform_keys_the_cache(floaff_root):
    """A tuple, a numpy number or a dict setting changes the cache key; an attribute that cannot be keyed is an
    error naming it (dropping it would serve samples cached under other settings)."""
    import numpy as np

    root, _ = floaff_root

    def first_x(t):
        dm = _dm(root, tasks=["CloseDrawer"], cache=True, pre_transforms=[t])
        dm.setup("test")
        return float(dm.datasets["test"][0]["scene_xyz"][0, 0])

    assert first_x(_Shift((5.0, 0.0, 0.0))) == pytest.approx(first_x(_Shift()) + 5.0)
    assert transforms.ResamplePoints(np.int64(64)).config()["num_points"] == 64
    bad = _Shift()
    bad.offset = lambda: None
    with pytest.raises(TypeError, match=r"_Shift\.offset: a function cannot be part of a sample-cache key"):
        _dm(root, tasks=["CloseDrawer"], cache=True, pre_transforms=[bad]).setup("test")


def test_a_pre_transform_keeps_its_meta_changes_through_the_cache(floaff_root):
    """YawPerturb turns the base pose in meta.sim and LateralMirror drops meta.sim and flags the sample: as
    pre-transforms (applied once, then cached) both keep those changes, read fresh or from the cache."""
    root, _ = floaff_root
    plain = _dm(root, tasks=["CloseDrawer"])
    plain.setup("test")
    pose = plain.datasets["test"][0]["meta"]["sim"]["base_pose_world"]
    for _ in range(2):  # the second setup reads the cache
        dm = _dm(root, tasks=["CloseDrawer"], cache=True, pre_transforms=[transforms.YawPerturb(max_deg=30.0)])
        dm.setup("test")
        turned = dm.datasets["test"][0]["meta"]
        assert turned["sim"]["base_pose_world"] != pose and turned["index"] == 0
        assert turned["sim"]["scene_dir"] == plain.datasets["test"][0]["meta"]["sim"]["scene_dir"]
        dm = _dm(root, tasks=["CloseDrawer"], cache=True, pre_transforms=[transforms.LateralMirror(p=1.0)])
        dm.setup("test")
        mirrored = dm.datasets["test"][0]["meta"]
        assert mirrored["mirrored"] is True and "sim" not in mirrored


@pytest.mark.parametrize(
    "edit",
    [
        lambda r: r["views"][0].pop("file"),
        lambda r: r["labels"].pop("success"),
        lambda r: r.update(candidates=[]),
        lambda r: r.update(split="Train"),
        lambda r: r.update(task="CloseDrawerr"),
        lambda r: r["views"][0].update(base_pose_world=[0.5, float("nan"), 0.0]),  # the SR rollout starts there
        lambda r: r["views"][0].update(base_pose_world=[0.5, 0.0]),
        lambda r: r["views"][0].update(view="Front"),  # was filtered out by `views` without a count
        lambda r: r["target"].update(pos=[float("nan"), 2.0, 0.9]),  # the rollout's yaw faces it
        lambda r: r["target"].update(pos=[1.0]),
        lambda r: r["target"].update(pos=1.0),
        lambda r: r.update(target=[1.0, 2.0]),
    ],
    ids=[
        "view_without_file",
        "labels_without_success",
        "candidates_a_list",
        "split_typo",
        "task_typo",
        "pose_nan",
        "pose_short",
        "view_kind_typo",
        "target_nan",
        "target_short",
        "target_scalar",
        "target_not_a_record",
    ],
)
def test_a_malformed_scene_json_is_a_counted_skip_naming_the_file(floaff_root, tmp_path, edit):
    """A field missing or of the wrong kind, or an unknown split / task / view kind: the scene is skipped as
    corrupt_scene_json with its file named, never a bare exception or a scene that silently vanishes."""
    root, exp = floaff_root
    copy, sj = _edit_first_train_scene(root, tmp_path, edit)
    dm = _dm(copy, tasks=["CloseDrawer"])
    dm.setup("fit")
    assert dm.skips.counts["corrupt_scene_json"] == exp["skips"].get("corrupt_scene_json", 0) + 1
    assert str(sj) in dm.skips.summary()
    assert all(sj.parent.name not in s for split in dm.split_scenes.values() for s in split)


def test_strict_raises_for_a_file_that_breaks_after_setup(tmp_path):
    """strict=True promises an error on the first missing or corrupt file; a file that broke after setup (or any
    file, with validate=False) was quietly replaced by the next sample."""
    from tests.data.floaff_fixture import make_floaff_dataset

    root = tmp_path / "fx"
    make_floaff_dataset(root, problems=False)
    sid = sorted(p.name for p in (root / "styles").iterdir() if p.name.startswith("CloseDrawer-train"))[0]
    (root / "styles" / sid / "views" / "front_0000.npz").write_bytes(b"PK\x03\x04 truncated")
    for strict in (True, False):
        dm = FloAffKitchenDataModule(
            root=str(root), benchmark="styles", strict=strict, validate=False, cache=False, val_scenes=0
        )
        dm.setup("fit")
        ds = dm.datasets["train"]
        i = next(k for k, r in enumerate(ds.records) if r.key.endswith(f"{sid}/front_0000"))
        if strict:
            with pytest.raises(DataError, match=rf"{sid}/front_0000 failed at load time .*strict=True"):
                ds[i]
        else:
            assert ds[i]["meta"]["replaces"].endswith(f"{sid}/front_0000")


class _MaskingReader(GeneratedReader):
    """A user reader that marks every point of the view file ``masked`` invalid (a mask of its own)."""

    masked = ""

    def load_view(self, scene, view):
        s = super().load_view(scene, view)
        if view.file == self.masked:
            s["scene_mask"] = np.zeros(len(s["scene_xyz"]), dtype=bool)
        return s


def _first_view(tmp_path: Path) -> Path:
    """The front_0000 view file of the first CloseDrawer train scene of a clean fixture."""
    from tests.data.floaff_fixture import make_floaff_dataset

    root = tmp_path / "fx"
    make_floaff_dataset(root, problems=False)
    sid = sorted(p.name for p in (root / "styles").iterdir() if p.name.startswith("CloseDrawer-train"))[0]
    return root / "styles" / sid / "views" / "front_0000.npz"


@pytest.mark.parametrize("empty", ["no_point", "all_masked"])
def test_a_view_without_a_valid_point_is_named_by_its_file(tmp_path, monkeypatch, empty):
    """A view with no point was named by its sample id twice (``sample <id> (<id>): scene_xyz is empty``), not by
    the file to look at; one whose reader masked every point invalid passed the setup check and failed in the first
    batch's resampling, naming no sample at all."""
    view = _first_view(tmp_path)
    root = view.parents[3]
    reader = "generated" if empty == "no_point" else "tests.data.test_floaff_kitchen:_MaskingReader"
    if empty == "no_point":
        with np.load(view) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["scene_xyz"], arrays["scene_feat"] = arrays["scene_xyz"][:0], arrays["scene_feat"][:0]
        ff.atomic_save_npz(view, arrays)
    else:
        monkeypatch.setattr(_MaskingReader, "masked", str(view))
    args = dict(root=str(root), benchmark="styles", tasks=["CloseDrawer"], reader=reader, cache=False, val_scenes=0)
    dm = FloAffKitchenDataModule(**args)
    dm.setup("fit")
    assert dm.skips.total == 1 and str(view) in dm.skips.summary(), dm.skips.summary()
    if empty != "no_point":  # its own kind, not the contract's generic one
        assert dict(dm.skips.counts) == {"empty_cloud": 1}, dm.skips.counts
    assert all(r.file != str(view) for split in ("train", "test") for r in dm.datasets[split].records)
    with pytest.raises(DataError, match=re.escape(str(view))):
        FloAffKitchenDataModule(**args, strict=True).setup("fit")


def test_a_copied_scene_folder_is_skipped_not_read_twice(tmp_path, capsys):
    """A copy of a scene folder (X.bak) was read again under the same scene id: its views counted twice in
    training and in the test metrics, under the same sample ids."""
    import shutil

    from tests.data.floaff_fixture import make_floaff_dataset

    root = tmp_path / "fx"
    make_floaff_dataset(root, problems=False)
    sid = sorted(p.name for p in (root / "styles").iterdir() if p.name.startswith("CloseDrawer-test"))[0]
    shutil.copytree(root / "styles" / sid, root / "styles" / f"{sid}.bak")
    dm = FloAffKitchenDataModule(root=str(root), benchmark="styles", cache=False, val_scenes=0)
    dm.setup("test")
    ids = [r.meta["sample_id"] for r in dm.datasets["test"].records]
    assert len(ids) == len(set(ids)) > 0
    out = capsys.readouterr().out
    assert "duplicate_scene" in out and f"{sid}.bak" in out


def test_a_transient_read_error_is_not_remembered(tmp_path, monkeypatch):
    """One I/O error while reading a view (EIO) wrote a skip marker into the cache, keyed by the file's size and
    mtime: the readable file stayed out of every later run until it changed, reported as a "corrupt npz"."""
    import numpy as np

    import floaff_zoo.sim.fileformat as ff
    from tests.data.floaff_fixture import make_floaff_dataset

    root = tmp_path / "fx"
    make_floaff_dataset(root, problems=False)
    real, calls = np.load, []

    def flaky(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 1:
            raise OSError(5, "Input/output error")
        return real(path, *args, **kwargs)

    def train_size() -> int:
        dm = FloAffKitchenDataModule(root=str(root), benchmark="styles", val_scenes=0, cache_dir=str(tmp_path / "c"))
        dm.setup("fit")
        return len(dm.datasets["train"])

    monkeypatch.setattr(ff.np, "load", flaky)
    first = train_size()
    monkeypatch.setattr(ff.np, "load", real)
    assert train_size() == first + 1  # the view is back once the disk reads it
    assert not list((tmp_path / "c").rglob("*.skip"))


def test_a_root_that_is_a_file_is_named_as_such(tmp_path):
    """It was reported as missing, with the advice to generate data into it."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    (tmp_path / "data.zip").write_bytes(b"x")
    with pytest.raises(MisconfigurationException, match=r"data\.zip is a file, not a data folder"):
        _dm(tmp_path / "data.zip").setup("fit")


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("max_views_per_scene", 0, "data.max_views_per_scene must be an integer >= 1 or null"),
        ("max_views_per_scene", -1, "data.max_views_per_scene must be an integer >= 1 or null"),
        ("val_scenes", 1.5, "data.val_scenes must be an integer >= 0"),
        ("val_scenes", -1, "data.val_scenes must be an integer >= 0"),
        ("val_view_fraction", 1.0, r"data.val_view_fraction must be in \[0, 1\)"),
    ],
)
def test_a_bad_split_size_is_named_before_setup(field, value, message):
    """max_views_per_scene 0 failed at setup as 'the train split is empty' and val_scenes 1.5 as a bare TypeError
    (a slice index), naming neither field."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    with pytest.raises(ValueError, match=message) as err:
        _dm("unused", **{field: value})
    assert isinstance(err.value, MisconfigurationException)


def test_skip_kinds_do_not_depend_on_the_dataset_path(floaff_src, tmp_path):
    """The kind of a view that failed to load was found by searching the error text, which holds the path: under a
    folder named 'corrupted_copy' every bad view counted as corrupt."""
    src, expected = floaff_src
    counts = []
    for name in ("plain", "corrupted_copy_with_NaN"):
        root = tmp_path / name / "floaff"
        shutil.copytree(src, root)
        dm = _dm(root, tasks=["CloseDrawer", "PnPCounterToCab"])
        dm.setup("fit")
        counts.append(dict(dm.skips.counts))
    assert counts[0] == counts[1] == expected["skips"]


def test_strict_names_a_missing_view_file_once_and_as_missing(tmp_path):
    """strict=True raised for a missing view file inside the scene.json handler, which took it for a field problem:
    the message said the scene.json was corrupt and carried the view's message inside it."""
    from tests.data.floaff_fixture import make_floaff_dataset

    root = tmp_path / "floaff"
    make_floaff_dataset(root, problems=False)
    view = sorted(root.glob("styles/*/views/side_0001.npz"))[0]
    view.unlink()
    with pytest.raises(DataError) as err:
        _dm(root, strict=True).setup("fit")
    message = str(err.value)
    assert str(view) in message and "view file listed in scene.json is missing" in message
    assert message.count("strict=True") == 1 and "scene.json:" not in message.split(str(view))[0]


_SCALED_READER = """
from floaff_zoo.data.readers import GeneratedReader


class ScaledReader(GeneratedReader):
    def load_view(self, scene, view):
        s = super().load_view(scene, view)
        s["floor_label"] = s["floor_label"] * {scale}
        return s
"""


def test_an_edited_user_reader_reaches_the_cached_samples(floaff_root, tmp_path, monkeypatch):
    """The cache key held the package's parsing code and the reader's class name, not a user reader's code: after
    an edit to ``reader: my_module:MyReader`` the cache kept serving what the old code had read."""
    import importlib
    import sys

    root, _ = floaff_root
    module = tmp_path / "user_reader_mod.py"
    monkeypatch.syspath_prepend(str(tmp_path))

    def labels(scale: float) -> float:
        module.write_text(_SCALED_READER.format(scale=scale))
        sys.modules.pop("user_reader_mod", None)  # a new process would import the edited file
        importlib.invalidate_caches()
        dm = _dm(root, reader="user_reader_mod:ScaledReader", tasks=["CloseDrawer"], cache=True)
        dm.setup("test")
        return max(float(dm.datasets["test"][i]["floor_label"].max()) for i in range(len(dm.datasets["test"])))

    half = labels(0.5)
    assert half > 0
    assert labels(1.0) == pytest.approx(2 * half)
    assert labels(0.5) == pytest.approx(half)  # the first code's entries are found again


def _edit_first_train_scene(root, tmp_path, edit):
    """A copy of the fixture whose first CloseDrawer training scene.json is changed by edit(rec); (copy, path)."""
    copy = tmp_path / "data"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns(".cache"))
    sj = sorted((copy / "styles").glob("CloseDrawer-train*/scene.json"))[0]
    rec = json.loads(sj.read_text())
    edit(rec)
    sj.write_text(json.dumps(rec))
    return copy, sj


def test_a_view_listed_twice_is_read_once(floaff_root, tmp_path):
    """A view listed twice in scene.json (by id, or two ids naming one file) was loaded twice without a word: twice
    in the metrics, and one more view of its kind against max_views_per_scene."""
    root, _ = floaff_root

    def twice(rec):
        v = rec["views"][0]
        rec["views"] += [dict(v), dict(v, view_id=v["view_id"] + "_again")]

    copy, sj = _edit_first_train_scene(root, tmp_path, twice)
    dm = _dm(copy, tasks=["CloseDrawer"])
    dm.setup("fit")
    keys = [r.key for s in ("train", "val") for r in dm.datasets[s].records if sj.parent.name in r.key]
    first = json.loads(sj.read_text())["views"][0]["view_id"]
    assert len(keys) == len(set(keys)) and sum(k.endswith(f"/{first}") for k in keys) == 1
    assert not any(k.endswith("_again") for k in keys)
    assert dm.skips.counts["duplicate_view"] == 2 and str(sj) in dm.skips.summary()


def test_a_view_whose_npz_pose_disagrees_with_scene_json_is_skipped(floaff_root, tmp_path):
    """scene.json's base_pose_world was taken on trust: edited, the rollout parked the robot there while the view's
    points were taken at the npz's pose, and SR was scored at the wrong place without a word."""
    root, exp = floaff_root

    def moved(rec):
        rec["views"][0]["base_pose_world"] = [9.0, 9.0, 0.0]

    copy, sj = _edit_first_train_scene(root, tmp_path, moved)
    dm = _dm(copy, tasks=["CloseDrawer"])
    dm.setup("fit")
    assert dm.skips.counts["bad_view"] == exp["skips"].get("bad_view", 0) + 1
    assert "disagrees with" in dm.skips.summary() and str(sj) in dm.skips.summary()
    rec = ff.read_scene(sj)  # the scripts' reader (predict_sr.py) checks the same, one place for both
    with pytest.raises(ff.FormatError, match="disagrees with"):
        ff.read_sample(rec, rec["views"][0])
    view = json.loads(sj.read_text())["views"][0]["view_id"]
    assert all(not r.key.endswith(f"{sj.parent.name}/{view}") for s in ("train", "val") for r in dm.datasets[s].records)


def test_a_scene_without_views_is_a_counted_skip_naming_it(floaff_root, tmp_path):
    """A committed scene.json listing no view (generators up to 2.2.0 wrote such scenes) was read silently: a scene
    holding no sample took a place in the validation draw, so a split shrank (or emptied) without a word."""
    root, exp = floaff_root

    def no_views(rec):
        rec["views"] = []

    copy, sj = _edit_first_train_scene(root, tmp_path, no_views)
    dm = _dm(copy, tasks=["CloseDrawer"])
    dm.setup("fit")
    assert dm.skips.counts["scene_without_views"] == 1
    assert str(sj) in dm.skips.summary() and sj.parent.name in dm.skips.summary()
    assert all(sj.parent.name not in s for split in dm.split_scenes.values() for s in split)
    assert len(dm.datasets["val"]) > 0  # the remaining train scenes give the draw its validation scene
    with pytest.raises(DataError, match=rf"{sj.parent.name} lists no view.*strict=True"):
        _dm(copy, tasks=["CloseDrawer"], strict=True).setup("fit")


def _copy_damaging_the_held_drawer_scene(
    root: Path, tmp_path: Path, tasks: list[str], damage: Callable[[Path], object]
) -> tuple[Path, str]:
    """A copy of the fixture (without its cache) in which ``damage`` was applied to every view file of the CloseDrawer
    scene the seeded draw holds out for validation -> (the copy, that scene's id)."""
    ref = _dm(root, tasks=tasks)
    ref.setup("fit")
    (held,) = [s for s in ref.split_scenes["val"] if s.startswith("CloseDrawer")]
    copy = tmp_path / "data"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns(".cache"))
    for view in (copy / "styles" / held / "views").glob("*.npz"):
        damage(view)
    return copy, held


def test_a_scene_whose_view_files_are_all_missing_takes_no_validation_place(floaff_root, tmp_path):
    """A scene.json whose every listed view file is missing (a copy cut short) holds no sample, yet it stayed in the
    validation draw: held out, it left its task without a validation sample in a run of several tasks, silently (its
    views were counted as missing, not the emptied split)."""
    root, exp = floaff_root
    tasks = ["CloseDrawer", "PnPCounterToCab"]
    copy, held = _copy_damaging_the_held_drawer_scene(root, tmp_path, tasks, Path.unlink)
    dm = _dm(copy, tasks=tasks)
    dm.setup("fit")
    assert dm.skips.counts["scene_without_views"] == 1 and f"scene {held}" in dm.skips.summary()
    assert dm.skips.counts["missing_view"] == exp["skips"]["missing_view"] + 4  # its views are still named
    assert all(held not in s for split in dm.split_scenes.values() for s in split)
    assert any(r.meta["task"] == "CloseDrawer" for r in dm.datasets["val"].records)


def test_a_split_without_any_sample_of_a_loaded_task_is_said(floaff_root, tmp_path):
    """A task the data has scenes of but a split the stage uses has no sample of (its train scenes all failed or were
    skipped, the scene the seeded draw held out has only corrupt views) was left out of training or of the
    validation that chooses the checkpoint without a word; a task without any scene was printed."""
    import warnings

    root, _ = floaff_root
    tasks = ["CloseDrawer", "PnPCounterToCab"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # the fixture's splits hold every task: nothing to say
        _dm(root, tasks=tasks).setup("fit")
        _dm(root, tasks=tasks, val_scene_ids=["CloseDrawer-train1-s002"]).setup("fit")  # pinned: PnP not validated
    # corrupt views: skipped when the split is built, after the draw
    copy, _ = _copy_damaging_the_held_drawer_scene(root, tmp_path, tasks, lambda v: v.write_bytes(b"not an npz"))
    dm = _dm(copy, tasks=tasks)
    with pytest.warns(UserWarning, match=r"'val' split holds no sample of task\(s\) \['CloseDrawer'\]"):
        dm.setup("fit")
    other = tmp_path / "other"
    shutil.copytree(root, other, ignore=shutil.ignore_patterns(".cache"))
    for d in (other / "styles").glob("PnPCounterToCab-train*"):
        shutil.rmtree(d)  # PnP keeps its test scene only
    dm = _dm(other, tasks=tasks)
    with pytest.warns(
        UserWarning, match=r"'train' split holds no sample of task\(s\) \['PnPCounterToCab'\].*trains"
    ) as got:
        dm.setup("fit")
    assert len([w for w in got if "holds no sample" in str(w.message)]) == 1  # not again for its validation
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        dm.setup("test")  # the test split holds both tasks
    no_test = tmp_path / "no_test"
    shutil.copytree(root, no_test, ignore=shutil.ignore_patterns(".cache"))
    for d in (no_test / "styles").glob("PnPCounterToCab-test*"):
        shutil.rmtree(d)  # PnP keeps its train scenes only
    for stage in ("test", "predict"):
        with pytest.warns(UserWarning, match=r"'test' split holds no sample of task\(s\) \['PnPCounterToCab'\]"):
            _dm(no_test, tasks=tasks).setup(stage)


def test_a_pre_transform_that_is_no_transform_is_named_at_construction():
    """A dict in pre_transforms failed at setup, inside the cache key (no config()) or the first parse."""
    with pytest.raises(DataConfigError, match=r"data\.pre_transforms\[0\] must be a SampleTransform"):
        _dm("unused", pre_transforms=[{"class_path": "floaff_zoo.data.transforms.OfficialNormalize"}])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("strict", "false", r"data\.strict must be true or false, got 'false'"),  # a true text: strict mode
        ("validate", 0, r"data\.validate must be true or false, got 0"),
        ("cache", "no", r"data\.cache must be true or false, got 'no'"),
        ("full_cloud", 1, r"data\.full_cloud must be true or false, got 1"),
        ("cache_hash", "sha", r"data\.cache_hash must be one of 'stat', 'content', got 'sha'"),  # ignored with no cache
        ("val_view_fraction", "0.2", r"data\.val_view_fraction must be in \[0, 1\), got '0\.2'"),  # a bare TypeError
        ("val_view_fraction", False, r"data\.val_view_fraction must be in \[0, 1\), got False"),  # taken as 0
        ("val_view_fraction", float("nan"), r"data\.val_view_fraction must be in \[0, 1\), got nan"),
    ],
)
def test_a_flag_a_choice_or_a_fraction_of_the_wrong_kind_is_named(field, value, message):
    """A text where a flag is asked for was true ("false" set strict mode), a cache_hash typo passed unseen while the
    cache was off, and a text fraction failed in a bare comparison naming nothing."""
    with pytest.raises(DataConfigError, match=message):
        _dm("unused", **{field: value})


@pytest.mark.parametrize("ids", [[], "CloseDrawer-train0-s001"])
def test_an_empty_or_text_val_scene_ids_is_named_at_construction(ids):
    """[] held out no scene, so a fit failed at setup with "the 'val' split is empty", naming no argument; a text
    was read letter by letter as scene ids."""
    with pytest.raises(DataConfigError, match=r"data\.val_scene_ids must be a non-empty list of train scene ids"):
        _dm("unused", val_scene_ids=ids)


@pytest.mark.parametrize(("field", "value"), [("tasks", "CloseDrawer"), ("views", "front"), ("tasks", 5)])
def test_a_single_name_for_a_name_list_is_named(field, value):
    """A text was read letter by letter ("unknown tasks ['C', 'l', 'o', ...]"), a number failed as "not iterable"."""
    with pytest.raises(ValueError, match=rf"{field} must be a list of names \(valid {field}: .*got {value!r}"):
        _dm("unused", **{field: value})


@pytest.mark.parametrize("reader", [5, None, GeneratedReader])
def test_a_reader_that_is_no_name_is_named(reader):
    """A number or None failed as "argument of type 'int' is not iterable", a class as "'type' is not iterable"."""
    with pytest.raises(
        ValueError, match=r"reader must be a registered name \[.*'generated'.*\] or 'pkg\.module:Class'"
    ):
        _dm("unused", reader=reader)
