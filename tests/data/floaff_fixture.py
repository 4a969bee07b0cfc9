"""Seeded tiny FloAff-Kitchen dataset in the generator's on-disk format (docs/data_format.md).

Written with ``floaff_zoo.sim.fileformat``'s own atomic writers. Contents (benchmark ``styles``):
CloseDrawer 3 train scenes + 1 test scene, PnPCounterToCab 1 train scene (view-level val) + 1 test
scene, each scene 2 front + 2 side views; plus a ``layouts`` benchmark with OpenSingleDoor 2 train +
1 test scene. Problems: a scene directory without scene.json, a corrupt scene.json, a corrupt view
npz, a view with NaN coordinates and a view file listed but missing.

``version`` 2 (default, the current format) stores ``floor_known`` (the last floor cell of every view
is marked not known) and ``floor_index``; ``version`` 1 writes the generator-1.x layout without them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.sim import fileformat as ff

PLAN = {
    "styles": [
        ("CloseDrawer", "train", 3),
        ("CloseDrawer", "test", 1),
        ("PnPCounterToCab", "train", 1),
        ("PnPCounterToCab", "test", 1),
    ],
    "layouts": [("OpenSingleDoor", "train", 2), ("OpenSingleDoor", "test", 1)],
}
VIEWS = [("front_0000", "front"), ("front_0001", "front"), ("side_0000", "side"), ("side_0001", "side")]


def _view_arrays(seed: int, task: str, rng: np.random.Generator, version: int = 2) -> dict[str, np.ndarray]:
    s = make_synthetic_sample(seed, num_points=160, floor_cells=6, task=task)
    n = s["scene_xyz"].shape[0]
    feat = np.c_[s["scene_feat"].numpy(), rng.uniform(0, 1, (n, 3))].astype(np.float32)
    out = {
        "scene_xyz": s["scene_xyz"].numpy(),
        "scene_feat": feat,
        "floor_xyz": s["floor_xyz"].numpy(),
        "floor_label": s["floor_label"].numpy(),
        "robot": s["robot"].numpy(),
        "target_xyz": s["target_xyz"].numpy(),
        "target_yaw": np.float32(s["target_yaw"]),
        "base_pose_world": rng.uniform(-1, 1, 3).astype(np.float32),
    }
    if version >= 2:
        m = len(out["floor_xyz"])
        out["floor_known"] = np.arange(m) < m - 1
        out["floor_index"] = np.arange(m, dtype=np.int32)
    return out


def make_floaff_dataset(
    root: str | Path, seed: int = 0, problems: bool = True, version: int = ff.FORMAT_VERSION
) -> dict:
    """Write the dataset in format ``version``; return {benchmark: {split: [scene_id]}} and the expected skip kinds."""
    root = Path(root)
    rng = np.random.default_rng(seed)
    scenes: dict[str, dict[str, list[str]]] = {}
    k = 0
    for bench, plan in PLAN.items():
        for task, split, count in plan:
            for i in range(count):
                k += 1
                sid = f"{task}-{split}{i}-s{k:03d}"
                d = ff.scene_dir(root, bench, sid)
                views = []
                for vid, kind in VIEWS:
                    arr = _view_arrays(seed * 1000 + k * 10 + len(views), task, rng, version)
                    ff.atomic_save_npz(d / "views" / f"{vid}.npz", arr)
                    views.append(
                        {
                            "view_id": vid,
                            "view": kind,
                            "file": f"views/{vid}.npz",
                            "base_pose_world": arr["base_pose_world"].tolist(),
                            "n_points": int(arr["scene_xyz"].shape[0]),
                            "n_target_points": 1,
                        }
                    )
                m = 36
                rec = {
                    "format_version": version,
                    "benchmark": bench,
                    "split": split,
                    "scene_id": sid,
                    "slot": f"{bench}/{task}/{split}{i}",
                    "spec": {"layout_id": k % 3, "style_id": k % 5, "seed": 1000 + k, "task": task},
                    "task": task,
                    "target": {"pos": [1.0, 2.0, 0.9], "yaw": 0.5},
                    "candidates": {
                        "xy": np.zeros((m, 2)).tolist(),
                        "yaw": [0.0] * m,
                        "valid": [1] * m,
                        "grid_shape": [6, 6],
                        "cell": 0.05,
                    },
                    "labels": {"success": [0] * m, "label": [0.0] * m, "reasons": [""] * m},
                    "robot": [0.85, 1.03],
                    "views": views,
                    "n_views": {"front": 2, "side": 2},
                    "status": "ok",
                }
                ff.atomic_write_json(d / ff.SCENE_JSON, rec)
                scenes.setdefault(bench, {}).setdefault(split, []).append(sid)
    ff.atomic_write_json(root / ff.MANIFEST, {"format_version": version, "scenes": {}, "status": "done"})
    expected_skips: dict[str, int] = {}
    if problems:
        (root / "styles" / "zz-no-scene-json" / "views").mkdir(parents=True)
        expected_skips["missing_scene_json"] = 1
        bad = root / "styles" / "zz-corrupt-json"
        bad.mkdir(parents=True)
        (bad / ff.SCENE_JSON).write_text("{not json")
        expected_skips["corrupt_scene_json"] = 1
        cd_train = scenes["styles"]["train"][0]  # a CloseDrawer train scene
        (root / "styles" / cd_train / "views" / "front_0001.npz").write_bytes(b"PK\x03\x04 truncated")
        arr = dict(np.load(root / "styles" / cd_train / "views" / "side_0000.npz"))
        arr["scene_xyz"][3, 1] = np.nan
        ff.atomic_save_npz(root / "styles" / cd_train / "views" / "side_0000.npz", arr)
        expected_skips["corrupt_view"] = 1  # found when loading
        expected_skips["nan_values"] = 1
        (root / "styles" / cd_train / "views" / "side_0001.npz").unlink()
        expected_skips["missing_view"] = 1
    return {"scenes": scenes, "skips": expected_skips}
