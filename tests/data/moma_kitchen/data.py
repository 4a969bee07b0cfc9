"""Seeded generator of a tiny MoMa-Kitchen dataset in EXACTLY the official layout (PLY via open3d).

Usage: ``python tests/data/moma_kitchen/data.py <out_dir>`` or ``make_dataset(tmp_path)`` in tests.

It writes ``<out>/rgbd/RGBD-<scene6>-target_<k>_<obj>_barrier_<NN>/position_..._orientation_.../``
with ``point_cloud_transformed/*.ply`` and the label CSV, ``<out>/info/<config>/trial_info.json`` and
``<out>/data_split/kitchen_{train,test}.txt``, including the problems of the real release: a missing
global cloud, a missing floor cloud, a directory listed but absent, a barrier pair, an unknown robot,
a label CSV of the wrong length, a corrupt PLY and a PLY with NaN coordinates.
Returns the expected outcome (kept sample ids per split, skip counts by kind, the test order).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

PCD = "point_cloud_transformed"
LABEL = "filtered_transformed_results_with_gaussian_success_rate.txt"
ORIENT = "orientation_0.0_0.0_1.0_6.123233995736766e-17"
TARGET = np.array([1.6, 0.3, 0.9])


def _write_ply(path: Path, xyz: np.ndarray) -> None:
    import open3d as o3d

    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(np.asarray(xyz, dtype=np.float64))
    path.parent.mkdir(parents=True, exist_ok=True)
    if not o3d.io.write_point_cloud(str(path), pcd, write_ascii=False):
        raise OSError(f"open3d could not write {path}")


def _write_ascii_ply(path: Path, xyz: np.ndarray) -> None:
    """Plain ASCII PLY (used for the NaN case, which binary writers may sanitise)."""
    head = (
        f"ply\nformat ascii 1.0\nelement vertex {len(xyz)}\n"
        "property double x\nproperty double y\nproperty double z\nend_header\n"
    )
    body = "\n".join(" ".join(repr(float(v)) for v in p) for p in xyz)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(head + body + "\n")


def _sample_clouds(rng: np.random.Generator, barrier: int) -> dict[str, np.ndarray]:
    """Global / floor / target / barrier clouds and floor labels of one view (base frame, metres)."""
    fx, fy = np.meshgrid(np.linspace(0.2, 1.3, 12), np.linspace(-0.8, 1.4, 12))
    floor = np.c_[fx.ravel(), fy.ravel(), rng.uniform(0.0, 0.015, fx.size)]
    rel = floor[:, :2] - TARGET[:2]
    label = np.exp(-((np.linalg.norm(rel, axis=1) - 0.8) ** 2) / (2 * 0.2**2)) * (rel[:, 0] < -0.1)
    front = np.c_[np.full(120, 1.4), rng.uniform(-1.0, 1.5, 120), rng.uniform(0.0, 0.85, 120)]
    top = np.c_[rng.uniform(1.4, 2.0, 120), rng.uniform(-1.0, 1.5, 120), np.full(120, 0.85)]
    target = TARGET + rng.normal(scale=0.03, size=(40, 3))
    barriers = [np.array([1.7, -0.4 + 0.5 * b, 0.9]) + rng.normal(scale=0.03, size=(30, 3)) for b in range(barrier)]
    world = np.concatenate([floor, front, top, target, *barriers])
    return {"world": world, "floor": floor, "target": target, "barriers": barriers, "label": label}


def make_dataset(root: str | Path, seed: int = 0) -> dict:
    """Write the dataset under ``root``; return the expected reader outcome."""
    root = Path(root)
    rng = np.random.default_rng(seed)
    # (split, scene, obj, barrier count, robot, [(x, y, problem)])
    configs = [
        ("train", "100001", "bottle#1", 0, "panda", [(3.1, 5.7, None), (3.2, 5.6, "missing_global"), (3.3, 5.5, None)]),
        (
            "train",
            "100002",
            "veggieartichoke",
            2,
            "xarm",
            [(2.5, 1.0, None), (2.6, 1.1, "label_count"), (2.7, 1.2, None)],
        ),
        ("train", "100003", "medicine#2", 0, "elephant", [(4.0, 2.0, None)]),  # unknown robot
        (
            "train",
            "100003",
            "veggietomato#1",
            1,
            "ur5e",
            [(4.1, 2.1, None), (4.2, 2.2, "corrupt_ply"), (4.3, 2.3, "nan_coordinates"), (4.4, 2.4, "missing_floor")],
        ),
        ("test", "200001", "minifridge_handle0", 0, "flexiv", [(3.0, 3.0, None), (2.9, 3.1, None), (2.8, 3.2, None)]),
    ]
    lines: dict[str, list[str]] = {"train": [], "test": []}
    kept: dict[str, list[str]] = {"train": [], "test": []}
    skips: dict[str, int] = {}
    for split, scene, obj, nb, robot, views in configs:
        cfg = f"RGBD-{scene}-target_1_{obj}_barrier_{nb:02d}"
        info = root / "info" / cfg[5:] / "trial_info.json"
        info.parent.mkdir(parents=True, exist_ok=True)
        info.write_text(json.dumps({"robot_name": robot, "scene": scene}))
        for x, y, problem in views:
            rel = f"{cfg}/position_{x}_{y}_0_{ORIENT}"
            d = root / "rgbd" / rel
            c = _sample_clouds(rng, nb)
            if problem == "nan_coordinates":
                c["world"][5] = np.nan
                _write_ascii_ply(d / PCD / "world_pcd_transformed.ply", c["world"])
            elif problem != "missing_global":
                _write_ply(d / PCD / "world_pcd_transformed.ply", c["world"])
            if problem == "corrupt_ply":
                (d / PCD / "filtered_pcd_z_less_than_0_02.ply").write_bytes(b"ply\nformat binary_garbage\n\x00\x01\x02")
            elif problem != "missing_floor":
                _write_ply(d / PCD / "filtered_pcd_z_less_than_0_02.ply", c["floor"])
            _write_ply(d / PCD / "target_pcd_transformed.ply", c["target"])
            for b, pts in enumerate(c["barriers"]):
                _write_ply(d / PCD / f"barrier_{b}_pcd_transformed.ply", pts)
            rows = np.c_[c["floor"], c["label"]]
            if problem == "label_count":
                rows = rows[:-7]
            np.savetxt(d / LABEL, rows, delimiter=",", fmt="%.6f")
            lines[split].append(rel)
            kind = "unknown_robot" if robot == "elephant" else problem
            if kind is None:
                kept[split].append(rel)
            else:
                skips[kind] = skips.get(kind, 0) + 1
    lines["train"].append("RGBD-100009-target_1_bottle#1_barrier_00/position_1.0_1.0_0_" + ORIENT)
    skips["missing_dir"] = 1
    lines["test"] = lines["test"][::-1]  # split-file order is not sorted order
    kept["test"] = kept["test"][::-1]
    (root / "data_split").mkdir(parents=True, exist_ok=True)
    for split in ("train", "test"):
        (root / "data_split" / f"kitchen_{split}.txt").write_text("\n".join(lines[split]) + "\n")
    return {
        "kept": kept,
        "skips": skips,
        "floor_points": 144,
        "target": TARGET.tolist(),
        "barrier_sample": f"RGBD-100002-target_1_veggieartichoke_barrier_02/position_2.5_1.0_0_{ORIENT}",
    }


if __name__ == "__main__":
    out = make_dataset(sys.argv[1] if len(sys.argv) > 1 else "moma_kitchen_fixture")
    print(json.dumps(out, indent=1))
