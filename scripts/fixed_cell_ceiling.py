"""How far a scene-independent rule can go: the success rate of one fixed cell of the canonical frame per task.

    python scripts/fixed_cell_ceiling.py --root data/floaff_dense --benchmarks layouts styles [--json out.json]

A fixed-cell rule stands at the same target-relative spot (cell of the target-centred, front-aligned label grid)
in every view of a task; a view whose observed floor lacks that cell counts as a failure. Per task the script
reports, from the generated labels alone (no model, no rollout):

- how many candidate cells of a scene succeed (the rollout outcome, not the smoothed label);
- the rule fitted on the training scenes (the cell that succeeds in most training views) and its test SR;
- the best fixed cell **in hindsight** on the test scenes: an upper bound for any rule that ignores the scene
  (the canonical prior is one), not a method. Any SR above it needs what the view shows of this scene.

The exact outcome of a cell comes from ``scene.json`` (``labels.success``) and the cells a view observes from its
``floor_index``; the canonical frame is the generator's target frame (``sim.views.world_to_target``, from the
simulator's target pose: analysis of the benchmark, not a model input). Scenes are read with the format's own
readers, so a missing or corrupt file is an error that names it.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from floaff_zoo.contract import TASKS
from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.views import candidates_in_target_frame

# (task, split) -> per view: {canonical cell (i, j): rollout succeeded}
Views = dict[tuple[str, str], list[dict[tuple[int, int], bool]]]


def canonical_cells(scene: dict) -> list[tuple[int, int]]:
    """Integer cell of every grid candidate in the target frame, [M] (the grid is target-aligned)."""
    can = candidates_in_target_frame(scene)
    return [(int(i), int(j)) for i, j in np.round(can / float(scene["candidates"]["cell"])).astype(int)]


def read_views(root: Path, benchmark: str) -> tuple[Views, dict[tuple[str, str], list[int]]]:
    """Per (task, split): the views' observed cells with outcomes, and the success-cell count of each scene."""
    views: Views = defaultdict(list)
    counts: dict[tuple[str, str], list[int]] = defaultdict(list)
    for scene in ff.iter_scenes(root, benchmark=benchmark):
        key = (scene["task"], scene["split"])
        success = np.asarray(scene["labels"]["success"]) > 0
        cells = canonical_cells(scene)
        counts[key].append(int(success.sum()))
        for view in scene["views"]:
            path = Path(scene["dir"]) / view["file"]
            arrays = ff.read_view(path, scene["format_version"], len(success))
            if "floor_index" not in arrays:  # format 1 stores the same candidate set in every view
                raise SystemExit(f"fixed_cell_ceiling: {path} has no floor_index (format 2 data needed)")
            idx = arrays["floor_index"]
            views[key].append({cells[i]: bool(success[i]) for i in idx})
    if not counts:
        raise SystemExit(f"fixed_cell_ceiling: no finished scene under {root / benchmark}")
    return views, counts


def cell_ranking(views: list[dict[tuple[int, int], bool]]) -> list[tuple[int, int]]:
    """Cells ordered by their success rate over the views that observe them (then by how often they succeed)."""
    seen: dict[tuple[int, int], list[bool]] = defaultdict(list)
    for v in views:
        for c, ok in v.items():
            seen[c].append(ok)
    return sorted(seen, key=lambda c: (-np.mean(seen[c]), -sum(seen[c]), c))


def rule_sr(ranking: list[tuple[int, int]], views: list[dict[tuple[int, int], bool]]) -> float:
    """SR of standing on the first cell of ``ranking`` each view observes (none observed = failure)."""
    order = {c: k for k, c in enumerate(ranking)}
    ok = []
    for v in views:
        ranked = [c for c in v if c in order]
        ok.append(bool(ranked) and v[min(ranked, key=order.__getitem__)])
    return float(np.mean(ok))


def ceiling(views: Views, counts: dict[tuple[str, str], list[int]]) -> list[dict]:
    """One row per task plus an ``all`` row (view-weighted)."""
    rows = []
    for task in TASKS:
        train, test = views.get((task, "train"), []), views.get((task, "test"), [])
        if not train or not test:
            continue
        rows.append(
            {
                "task": task,
                "success_cells_train": sorted(counts[(task, "train")]),
                "success_cells_test": sorted(counts[(task, "test")]),
                "train_ranking_test_sr": rule_sr(cell_ranking(train), test),
                "hindsight_test_sr": rule_sr(cell_ranking(test), test),
                "test_views": len(test),
            }
        )
    n = sum(r["test_views"] for r in rows)
    if n:
        rows.append(
            {
                "task": "all",
                "train_ranking_test_sr": sum(r["train_ranking_test_sr"] * r["test_views"] for r in rows) / n,
                "hindsight_test_sr": sum(r["hindsight_test_sr"] * r["test_views"] for r in rows) / n,
                "test_views": n,
            }
        )
    return rows


def markdown(bench_rows: dict[str, list[dict]]) -> str:
    lines = [
        "| Benchmark | Task | success cells per scene (train; test) | ranking fitted on train: test SR "
        "| ranking by test outcomes (hindsight): test SR | test views |",
        "|---|---|---|---:|---:|---:|",
    ]
    for bench, rows in bench_rows.items():
        for r in rows:
            cells = f"{r['success_cells_train']}; {r['success_cells_test']}" if "success_cells_train" in r else ""
            lines.append(
                f"| {bench} | {r['task']} | {cells} | {r['train_ranking_test_sr']:.2f} | {r['hindsight_test_sr']:.2f} "
                f"| {r['test_views']} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmarks", nargs="+", default=["layouts", "styles"])
    p.add_argument("--json", default=None, help="also write the rows here")
    a = p.parse_args(argv)
    out = {b: ceiling(*read_views(Path(a.root), b)) for b in a.benchmarks}
    print(markdown(out))
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
