"""Simulator benchmark: rollout cost per task, labelling throughput, IK pre-filter agreement.

Usage: OMP_NUM_THREADS=1 python benchmarks/bench_sim.py [--quick] [--cell 0.1] [--layout 0] [--style 0] [--agree 20]
(--quick: cell 0.2 m and 5 agreement checks, ~1-2 min on one core)
Prints, per task: mean wall time of full rollouts (targets: close/open <= 0.3 s, pick-and-place <= 1 s) and
their ratio to bare MuJoCo stepping of the same simulated time on the same scene, measured in the same run (the
cost of the controllers, IK and checks on top of the physics), candidates labelled per second including filtering
(target >= 10/s/core), the speed-up over the robosuite env stack's published 0.8 s per 4 s rollout (a figure
from docs/background.md §5, not measured here), and the agreement of the IK pre-filter with full rollouts run
without the pre-check on up to --agree candidates the pre-filter refused.
"""

from __future__ import annotations

import argparse
import math
import time

import mujoco
import numpy as np

from floaff_zoo.sim.annotate import FILTERED, annotate_scene
from floaff_zoo.sim.controllers import CTRL_DT, default_policy
from floaff_zoo.sim.kitchen import TASKS, SceneSpec, build_scene
from floaff_zoo.sim.rollout import rollout

ROBOSUITE_ROLLOUT_S = 0.8
ROBOSUITE_SIM_S = 4.0  # the simulated length of the rollout that figure times


def physics_seconds(spec: SceneSpec, sim_seconds: float) -> float:
    """Wall time of bare ``mj_step`` for ``sim_seconds`` of simulated time (control ticks of ``CTRL_DT``, as a
    rollout steps) on a freshly built copy of the scene: no controller, IK or checks."""
    sc = build_scene(spec)
    m, d = sc.model, sc.data
    nsub = max(1, int(round(CTRL_DT / m.opt.timestep)))
    ticks = max(1, int(round(sim_seconds / (nsub * m.opt.timestep))))
    t0 = time.perf_counter()
    for _ in range(ticks):
        mujoco.mj_step(m, d, nsub)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cell", type=float, default=None, help="grid cell (m); default 0.1, or 0.2 with --quick")
    ap.add_argument("--layout", type=int, default=0)
    ap.add_argument("--style", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--agree", type=int, default=None, help="agreement checks per task; default 20, 5 with --quick")
    ap.add_argument("--quick", action="store_true", help="coarse grid (cell 0.2) and 5 agreement checks")
    ap.add_argument(
        "--growth-cells",
        type=float,
        nargs="*",
        default=[0.3, 0.2, 0.14, 0.1],
        help="grid cells (m) of the growth-with-candidates measurement on CloseDrawer (none: skip)",
    )
    args = ap.parse_args(argv)
    # --quick sets only what is not given (it overwrote an explicit --cell / --agree)
    args.cell = args.cell if args.cell is not None else (0.2 if args.quick else 0.1)
    args.agree = args.agree if args.agree is not None else (5 if args.quick else 20)
    if not 0 < args.cell < math.inf:  # inf failed in the first annotation, after the scene was built
        ap.error(f"--cell must be a finite number > 0, got {args.cell}")
    if args.agree < 0:
        ap.error(f"--agree must be >= 0, got {args.agree}")
    if any(not 0 < c < math.inf for c in args.growth_cells):
        ap.error(f"--growth-cells must be finite numbers > 0, got {args.growth_cells}")
    try:  # an unknown layout or style, a negative seed: a ValueError traceback from SceneSpec
        SceneSpec(args.layout, args.style, args.seed, TASKS[0])
    except ValueError as exc:
        ap.error(f"--layout {args.layout} --style {args.style} --seed {args.seed}: {exc}")
    t0 = time.perf_counter()
    build_scene(SceneSpec(args.layout, args.style, args.seed, TASKS[0]))
    print(f"build_scene (first, incl. robot model) {time.perf_counter() - t0:.2f}s")
    rates = []
    for task in TASKS:
        spec = SceneSpec(args.layout, args.style, args.seed, task)
        sc = build_scene(spec)
        a = annotate_scene(sc, cell=args.cell)
        full, simulated = [], 0.0
        for i, r in enumerate(a.reasons):
            if r in ("success", "not_closed", "not_open", "not_placed", "timeout"):
                res = rollout(sc, (a.grid_xy[i, 0], a.grid_xy[i, 1], a.yaw[i]))
                full.append(res.wall_seconds)
                simulated += res.sim_seconds
        rate = a.counts["candidates"] / a.wall_seconds
        rates.append(rate)
        mean_full = float(np.mean(full)) if full else float("nan")
        print(f"{task:16s} grid {a.grid_shape} {a.counts}")
        # robosuite's figure is the wall time of a 4 s rollout, ours simulate 2.5-7 s: compare per simulated second
        per_sim_s = sum(full) / simulated if full and simulated > 0 else float("nan")
        print(
            f"{'':16s} annotate {a.wall_seconds:.1f}s -> {rate:.1f} candidates/s; full rollout mean {mean_full:.3f}s "
            f"(n={len(full)}, {simulated / max(len(full), 1):.1f} s simulated each), speed-up per simulated second vs "
            f"robosuite's published {ROBOSUITE_ROLLOUT_S}s per {ROBOSUITE_SIM_S:.0f} s: "
            f"{ROBOSUITE_ROLLOUT_S / ROBOSUITE_SIM_S / per_sim_s:.1f}x"
        )
        if full and simulated > 0:
            bare = physics_seconds(spec, simulated)
            print(
                f"{'':16s} the same {simulated:.1f} s simulated by bare mj_step: {bare:.2f}s -> rollouts cost "
                f"{sum(full) / bare:.1f}x the physics alone"
            )
        # candidates the IK pre-filter refused (a rolled-out cell can end as ik_unreachable too: not these)
        pre = [i for i, r in enumerate(a.reasons) if r == "ik_unreachable" and a.status[i] == FILTERED][: args.agree]
        agree = 0
        for i in pre:
            res = rollout(sc, (a.grid_xy[i, 0], a.grid_xy[i, 1], a.yaw[i]), default_policy(task, precheck=False))
            agree += int(not res.success)
        if pre:
            print(f"{'':16s} IK pre-filter agreement with full rollouts (no pre-check): {agree}/{len(pre)}")
    print(f"mean candidates labelled per second (one core): {float(np.mean(rates)):.1f}")
    growth(args, args.growth_cells)


def growth(args: argparse.Namespace, cells: list[float]) -> None:
    """How labelling time grows with the number of candidates: one CloseDrawer scene at finer and finer grids."""
    if not cells:
        return
    sc = build_scene(SceneSpec(args.layout, args.style, args.seed, "CloseDrawer"))
    rows = []
    for cell in cells:
        a = annotate_scene(sc, cell=cell)
        c = a.counts
        rows.append((c["candidates"], a.wall_seconds))
        print(
            f"[growth] CloseDrawer cell {cell:.2f} m: {c['candidates']:5d} candidates, "
            f"{c['rolled_out']:4d} rolled out, "
            f"annotate {a.wall_seconds:6.2f} s ({1e3 * a.wall_seconds / c['candidates']:.1f} ms/candidate)"
        )
    if len(rows) >= 2:
        (n0, w0), (n1, w1) = rows[0], rows[-1]
        print(f"[growth] {n1 / max(1, n0):.1f}x the candidates -> {w1 / max(1e-9, w0):.1f}x the time")


if __name__ == "__main__":
    main()
