"""Where the canonical prior's cell edges lie, measured from the generated labels alone (no model, no rollout).

    python scripts/prior_cells.py --root data/floaff_dense --benchmarks layouts styles [--json out.json]

The generator's label grid is target-aligned with the target on a lattice point, so in the canonical frame every
labelled floor point lies at a multiple of the grid spacing. This script fills a ``CanonicalLabelGrid`` (5 cm cells,
one cell of smoothing: the prior's defaults) from the training views with the simulator's yaw, once with cell edges
at multiples of the cell (the old binning) and once with cell centres there (``centred``), and scores each on the
validation scenes (the DataModule's seeded pick, one per task) and the test scenes: every view stands on the
prior's argmax among the cells it observes, and its outcome is that cell's annotated rollout. The query yaw is
the simulator's, or that yaw turned by ``--noise-deg`` (Gaussian, one draw per view: about the error of AxisNet
snapped to the kitchen's axes). The canonical frame comes from the simulator's target pose (analysis of the
benchmark, not a model input).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

from floaff_zoo.atomic import atomic_write_text
from floaff_zoo.contract import TASKS
from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule, view_sample_id
from floaff_zoo.nn.prior import CanonicalLabelGrid
from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.views import candidates_in_target_frame

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders, refuse_repeats  # noqa: E402

# per view: (task index, split, canonical xy [M, 2], smoothed label [M], rollout success [M])
View = tuple[int, str, np.ndarray, np.ndarray, np.ndarray]


def validation_views(root: Path, benchmark: str) -> set[str]:
    """Sample ids (``<benchmark>/<scene>/<view>``) the DataModule holds out for validation (its default seeded pick,
    one scene per task; a task with one training scene gives some of its views, which its split_scenes lists as
    "<scene> (views)": a scene id test missed them, so they filled the grid and scored nothing)."""
    dm = FloAffKitchenDataModule(root=str(root), benchmark=benchmark, tasks=list(TASKS), val_scenes=1)
    dm.setup("fit")
    return {r.key for r in dm.datasets["val"].records}


def read_views(root: Path, benchmark: str) -> list[View]:
    """Every view of the benchmark with its observed cells in the canonical frame (splits: train/val/test)."""
    val = validation_views(root, benchmark)
    out: list[View] = []
    for scene in ff.iter_scenes(root, benchmark=benchmark):
        success = np.asarray(scene["labels"]["success"]) > 0
        can = candidates_in_target_frame(scene)
        for view in scene["views"]:
            held_out = view_sample_id(benchmark, scene["scene_id"], view["view_id"]) in val
            split = "val" if scene["split"] == "train" and held_out else scene["split"]
            arrays = ff.read_view(Path(scene["dir"]) / view["file"], scene["format_version"], len(success))
            if "floor_index" not in arrays:
                raise SystemExit(f"prior_cells: {scene['dir']}/{view['file']} has no floor_index (format 2 needed)")
            idx = arrays["floor_index"]
            out.append((TASKS.index(scene["task"]), split, can[idx], np.asarray(arrays["floor_label"]), success[idx]))
    if not out:
        raise SystemExit(f"prior_cells: no finished scene under {root / benchmark}")
    return out


def turn(xy: np.ndarray, rad: float) -> np.ndarray:
    """xy [M, 2] rotated by ``rad`` about the target."""
    c, s = np.cos(rad), np.sin(rad)
    return xy @ np.array([[c, s], [-s, c]])


def fit_grid(views: list[View], centred: bool) -> CanonicalLabelGrid:
    grid = CanonicalLabelGrid(list(TASKS), centred=centred)
    for t, split, xy, label, _ in views:
        if split == "train":
            mask = torch.ones(1, len(xy), dtype=torch.bool)
            grid.add(torch.tensor([t]), torch.as_tensor(xy[None]), torch.as_tensor(label[None]), mask)
    return grid


def success_rates(grid: CanonicalLabelGrid, views: list[View], split: str, noise_deg: float, seed: int) -> dict:
    """SR per task and over all views of ``split`` when every view stands on the grid's argmax."""
    rng = np.random.default_rng(seed)
    ok, task = [], []
    for t, s, xy, _, success in views:
        if s != split:
            continue
        query = turn(xy, np.deg2rad(noise_deg) * rng.standard_normal()) if noise_deg else xy
        scores = grid.read(torch.tensor([t]), torch.as_tensor(query[None]))[0].numpy()
        ok.append(bool(success[int(np.argmax(np.round(scores, 6)))]))
        task.append(t)
    ok_a, task_a = np.array(ok), np.array(task)
    row = {TASKS[i]: float(ok_a[task_a == i].mean()) for i in range(len(TASKS)) if (task_a == i).any()}
    row["all"] = float(ok_a.mean()) if len(ok_a) else float("nan")  # a split without views: no rate
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmarks", nargs="+", default=sorted(ff.BENCHMARKS), choices=ff.BENCHMARKS)  # layouts first
    p.add_argument("--noise-deg", type=float, default=0.3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    refuse_repeats(p, "benchmark", a.benchmarks)  # printed its rows twice, or merged them
    if a.seed < 0:  # numpy's generator takes no negative seed: a traceback after the table's header
        p.error(f"--seed must be >= 0, got {a.seed}")
    if not 0 <= a.noise_deg < math.inf:  # NaN or Inf turned every query into NaN: an SR of 0 printed as a result
        p.error(f"--noise-deg must be a finite standard deviation >= 0 (deg), got {a.noise_deg}")
    rows = []
    print("| Benchmark | cells | query yaw | split | " + " | ".join(TASKS) + " | all |")
    print("|---|---|---|---|" + "---:|" * (len(TASKS) + 1))
    for bench in a.benchmarks:
        views = read_views(Path(a.root), bench)
        for centred in (False, True):
            grid = fit_grid(views, centred)
            for noise in (0.0, a.noise_deg):
                for split in ("val", "test"):
                    sr = success_rates(grid, views, split, noise, a.seed)
                    rows.append({"benchmark": bench, "centred": centred, "noise_deg": noise, "split": split, "sr": sr})
                    yaw = "simulator" if noise == 0 else f"simulator + N(0, {noise:g} deg)"
                    cells = "centred" if centred else "edges on the lattice"
                    vals = " | ".join(f"{sr[t]:.2f}" if t in sr else "n/a" for t in TASKS)  # a task without views
                    print(f"| {bench} | {cells} | {yaw} | {split} | {vals} | {sr['all']:.3f} |")
    if a.json:
        atomic_write_text(a.json, json.dumps(rows, indent=1) + "\n")  # makes a missing folder, as the others do
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "prior_cells"))
