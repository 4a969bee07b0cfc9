"""How far scene-independent rules go: fixed cells, and fixed rankings of cells, of the canonical frame per task.

    python scripts/fixed_cell_ceiling.py --root data/floaff_dense --benchmarks layouts styles [--json out.json]

Cells are those of the target-centred, front-aligned label grid. Per task the script reports, from the generated
labels alone (no model, no rollout):

- how many candidate cells of a scene succeed (the rollout outcome, not the smoothed label);
- a **fixed ranking** of cells, fitted on the training scenes (cells by their success rate over the training views
  that observe them), standing in each test view on the best-ranked cell the view observes (none = failure): what
  the canonical prior does with a view's floor; and the same rule with the ranking taken from the test outcomes
  **in hindsight**. Ranking by success rate is not the best ranking for this rule, so the hindsight figure is no
  upper bound (a few hundredths may lie above it);
- a **single fixed cell**: the one cell stood on in every view of a task, a view that does not observe it counting
  as a failure, fitted on training (the cell that succeeds in most training views) and in hindsight on the test
  views (the best one: an upper bound for any single-cell rule).

The exact outcome of a cell comes from ``scene.json`` (``labels.success``) and the cells a view observes from its
``floor_index``; the canonical frame is the generator's target frame (``sim.views.world_to_target``, from the
simulator's target pose: analysis of the benchmark, not a model input). Scenes are read with the format's own
readers, so a missing or corrupt file is an error that names it.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from floaff_zoo.atomic import atomic_write_text
from floaff_zoo.contract import TASKS
from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.views import candidates_in_target_frame

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders, refuse_repeats  # noqa: E402

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


def best_single_cell(views: list[dict[tuple[int, int], bool]]) -> tuple[int, int] | None:
    """The cell that succeeds in most of ``views`` (a view that does not observe it fails), ties to the lowest."""
    wins: dict[tuple[int, int], int] = defaultdict(int)
    for v in views:
        for c, ok in v.items():
            wins[c] += ok
    return min(wins, key=lambda c: (-wins[c], c)) if wins else None


def single_cell_sr(cell: tuple[int, int] | None, views: list[dict[tuple[int, int], bool]]) -> float:
    """SR of standing on ``cell`` in every view (a view that does not observe it fails)."""
    return float(np.mean([bool(cell is not None and v.get(cell, False)) for v in views]))


#: the view-weighted SR columns of a task row
SR_KEYS = ("train_ranking_test_sr", "hindsight_test_sr", "train_cell_test_sr", "hindsight_cell_test_sr")


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
                "train_cell_test_sr": single_cell_sr(best_single_cell(train), test),
                "hindsight_cell_test_sr": single_cell_sr(best_single_cell(test), test),
                "test_views": len(test),
            }
        )
    n = sum(r["test_views"] for r in rows)
    if n:
        rows.append(
            {
                "task": "all",
                **{
                    key: sum(r[key] * r["test_views"] for r in rows) / n
                    for key in (
                        "train_ranking_test_sr",
                        "hindsight_test_sr",
                        "train_cell_test_sr",
                        "hindsight_cell_test_sr",
                    )
                },
                "test_views": n,
            }
        )
    return rows


def benchmark_rows(root: Path, benchmark: str) -> list[dict]:
    """``ceiling``'s rows of one benchmark; a task with no train or no test scene is left out, said on stderr, and a
    benchmark with no row exits naming it (its table was empty, exit 0)."""
    views, counts = read_views(root, benchmark)
    rows = ceiling(views, counts)
    left = sorted({t for t, _ in counts} - {r["task"] for r in rows})
    if not rows:
        raise SystemExit(f"fixed_cell_ceiling: no task under {root / benchmark} has both train and test scenes")
    if left:
        print(
            f"fixed_cell_ceiling: {benchmark}: left out {', '.join(left)} (no train or no test scene)", file=sys.stderr
        )
    return rows


def markdown(bench_rows: dict[str, list[dict]]) -> str:
    lines = [
        "| Benchmark | Task | success cells per scene (train; test) | ranking fitted on train: test SR "
        "| ranking by test outcomes (hindsight): test SR | one cell fitted on train: test SR "
        "| best single cell (hindsight): test SR | test views |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for bench, rows in bench_rows.items():
        for r in rows:
            cells = f"{r['success_cells_train']}; {r['success_cells_test']}" if "success_cells_train" in r else ""
            lines.append(
                f"| {bench} | {r['task']} | {cells} | {r['train_ranking_test_sr']:.2f} | {r['hindsight_test_sr']:.2f} "
                f"| {r['train_cell_test_sr']:.2f} | {r['hindsight_cell_test_sr']:.2f} | {r['test_views']} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmarks", nargs="+", default=sorted(ff.BENCHMARKS), choices=ff.BENCHMARKS)  # layouts first
    p.add_argument("--json", default=None, help="also write the rows here")
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    refuse_repeats(p, "benchmark", a.benchmarks)  # printed its rows twice, or merged them
    out = {b: benchmark_rows(Path(a.root), b) for b in a.benchmarks}
    print(markdown(out))
    if a.json:
        atomic_write_text(a.json, json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "fixed_cell_ceiling"))
