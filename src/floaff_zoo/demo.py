"""``floaff-zoo demo``: the whole pipeline on a small generated benchmark, end to end.

1. generate (or reuse) a FloAff-Kitchen-style benchmark in MuJoCo (``--preset demo`` by default);
2. run a short PFAL curriculum: AxisNet, CFAR stage 1 on PnPCounterToCab, stage 2 on the three
   door/drawer tasks, initialised from and distilled from stage 1;
3. train one baseline (PointNet++ SSG) on all four tasks;
4. test both with the rollout success-rate callback (report.json, report.md, figures);
5. print the comparison tables and the paths of the reports and pictures.

Everything goes through the same commands a user runs (``generate``, ``curriculum``, ``fit``,
``test``, ``table``); a rerun reuses finished steps (generation resumes, the curriculum skips
finished stages, a baseline run that wrote ``finished.json`` with the same ``--data`` and ``--epochs`` is not
retrained; one killed before that, or fitted with other arguments, is fitted again).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from floaff_zoo.atomic import existing_ancestor
from floaff_zoo.names import TASKS as ALL_TASKS  # the final model and the baseline are tested on every task

EXPERIMENT = "configs/demo/pfal_demo.yaml"
DATA_CONFIG = "configs/demo/data_demo.yaml"
BASELINE_CONFIG = "configs/demo/pointnet2_demo.yaml"
EVAL_CONFIG = "configs/trainer/eval_sr.yaml"


def _step(i: int, n: int, text: str) -> None:
    print(f"\n[{i}/{n}] {text}", flush=True)


def _check_configs() -> None:
    """Raise RunError (one line on the console, no traceback) when the demo's configs are not below the working
    directory."""
    from floaff_zoo.runs import RunError

    missing = [p for p in (EXPERIMENT, DATA_CONFIG, BASELINE_CONFIG, EVAL_CONFIG) if not Path(p).is_file()]
    if missing:
        raise RunError(f"demo configs not found: {missing}; run the demo from the repository root")


def baseline_args(data: str, epochs: int) -> dict[str, Any]:
    """What a baseline fit was asked for, recorded in its ``finished.json``: a run reused must match it. The data
    folder's fingerprint (``runs.data_fingerprint``) is part of it: data generated again into the same folder gave a
    baseline trained on the old data beside a curriculum re-fit on the new."""
    from floaff_zoo.runs import data_fingerprint

    folder = Path(data).resolve()
    return {"data": str(folder), "data_fingerprint": data_fingerprint(folder), "max_epochs": int(epochs)}


def _fit_baseline(data: str, root: Path, epochs: int) -> Path:
    """The newest finished baseline run under ``root`` fitted on ``data`` for ``epochs``, fitting one first when
    none did.

    A run counts as finished only with its ``finished.json`` (written below after ``fit`` returns): a
    killed fit leaves a ``last.ckpt`` too, and reusing it would test a half-trained model. One fitted with other
    ``--data`` or ``--epochs`` (or before they were recorded) is not this demo's baseline either.
    """
    from floaff_zoo.cli import run_lightning
    from floaff_zoo.runs import finished_runs, mark_finished

    wanted = baseline_args(data, epochs)
    done = finished_runs(root)
    matching = [(run, rec) for run, rec in done if rec.get("args") == wanted]
    if matching:
        print(f"  reusing {matching[-1][0]} (finished {matching[-1][1]['finished']})")
        return matching[-1][0]
    if done:
        got = done[-1][1].get("args")
        same = isinstance(got, dict) and {k: v for k, v in got.items() if k != "data_fingerprint"} == {
            k: v for k, v in wanted.items() if k != "data_fingerprint"
        }
        why = (
            f"the data in {data} changed since (or its run predates the data record)"
            if same
            else f"was fitted with {got or 'unrecorded arguments'}, not {wanted}"
        )
        print(f"  {done[-1][0]} {why}; fitting")
    unfinished = sorted({p.parents[1] for p in root.rglob("last*.ckpt")} - {run for run, _ in done})
    if unfinished:
        print(f"  {', '.join(map(str, unfinished))}: fit did not finish (no finished.json); fitting again")
    cli = run_lightning(
        [
            "fit",
            "--config",
            DATA_CONFIG,
            "--config",
            BASELINE_CONFIG,
            "--data.init_args.root",
            data,
            "--trainer.default_root_dir",
            str(root),
            "--trainer.max_epochs",
            str(epochs),
        ]
    )
    cb = cli.trainer.checkpoint_callback
    ckpt = (cb.best_model_path or cb.last_model_path) if cb is not None else ""
    run = Path(cli.trainer.log_dir or "")
    if not ckpt or not Path(ckpt).is_file() or not (run / "config.yaml").is_file():
        raise RuntimeError(f"baseline fit under {root} wrote no checkpoint or config.yaml")
    mark_finished(run, ckpt, {"epochs": int(cli.trainer.current_epoch), "args": wanted})
    return run


def _test(run_dir: Path, data: str, ckpt: str | None = None) -> Path:
    """Test a fit run on every task with the rollout callback; returns its report.json.

    ``best`` resolves inside ``run_dir`` (the run the ``--config`` came from); the report lands in the
    next ``version_<n>`` directory beside the fit run (the saved config carries its logger).
    """
    from floaff_zoo.cli import run_lightning

    cli = run_lightning(
        [
            "test",
            "--config",
            str(run_dir / "config.yaml"),
            "--config",
            EVAL_CONFIG,
            "--data.init_args.root",
            data,
            "--data.init_args.tasks",
            json.dumps(list(ALL_TASKS)),
            "--ckpt_path",
            ckpt or "best",
        ]
    )
    report = Path(cli.trainer.log_dir) / "report.json"
    if not report.is_file():
        raise RuntimeError(f"test of {run_dir} wrote no report.json")
    return report


def main(argv: list[str] | None = None, *, raise_errors: bool | None = None) -> int:
    """``floaff-zoo demo``. A damaged run record is printed in one line; then it is raised when ``raise_errors``
    (default: when ``argv`` is given, i.e. a Python caller), else exit code 2 is returned (the console)."""
    from floaff_zoo.curriculum import CurriculumError
    from floaff_zoo.runs import RunError

    raise_errors = argv is not None if raise_errors is None else raise_errors
    try:
        return _run(argv, raise_errors)
    except (CurriculumError, RunError) as exc:  # damaged run records: name the file, no traceback
        print(f"floaff-zoo demo: error: {exc}", file=sys.stderr)
        if raise_errors:
            raise
        return 2


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The demo's arguments; ``--data`` and ``--runs`` default per preset (data/floaff_<preset>, runs/demo or
    runs/demo_<preset>): the generator refuses to resume a folder made with another preset's settings."""
    p = argparse.ArgumentParser(prog="floaff-zoo demo", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--preset", default="demo", help="generation preset (default: demo; see `floaff-zoo generate --help`)"
    )
    p.add_argument(
        "--data", default=None, help="where the benchmark is generated / reused (default: data/floaff_<preset>)"
    )
    p.add_argument(
        "--runs",
        default=None,
        help="where the runs, reports and pictures go (default: runs/demo, or runs/demo_<preset> for another preset)",
    )
    p.add_argument(
        "--epochs",
        type=int,
        default=None,
        help="epochs of every stage and of the baseline (default: the demo experiment's, 20 per CFAR "
        "stage, 30 for the small AxisNet, 20 for the baseline; paper: 30)",
    )
    p.add_argument("--workers", type=int, default=2, help="generation worker processes")
    args = p.parse_args(argv)
    if args.epochs is not None and args.epochs < 1:  # 0 trains nothing; -1 is Lightning's "never stop"
        p.error(f"--epochs must be >= 1, got {args.epochs}")
    if args.workers < 0:
        p.error(f"--workers must be >= 0, got {args.workers}")
    from floaff_zoo.sim.presets import PRESETS

    preset = PRESETS.get(args.preset)
    if preset is None:
        p.error(f"--preset {args.preset!r}: choose from {sorted(PRESETS)}")
    if "layouts" not in preset.benchmarks or set(preset.tasks) != set(ALL_TASKS):  # found only after generating
        p.error(f"--preset {args.preset}: the demo's experiment needs the Layouts benchmark with all four tasks")
    if args.data is None:
        args.data = f"data/floaff_{args.preset}"
    if args.runs is None:
        args.runs = "runs/demo" if args.preset == "demo" else f"runs/demo_{args.preset}"
    if not (found := existing_ancestor(args.runs)).is_dir():  # the curriculum found it only after generating
        p.error(f"--runs {args.runs}: {found} exists and is not a folder")
    return args


def _run(argv: list[str] | None, raise_errors: bool) -> int:
    args = parse_args(argv)
    _check_configs()
    t0 = time.time()
    runs = Path(args.runs)
    n = 5

    from floaff_zoo.sim import generate

    _step(1, n, f"generate the '{args.preset}' benchmark into {args.data} (resumes if present)")
    rc = generate.main(["--preset", args.preset, "--out", args.data, "--workers", str(args.workers)])
    if rc:
        return rc

    from floaff_zoo import curriculum

    _step(2, n, "PFAL curriculum: AxisNet -> CFAR stage 1 (PnPCounterToCab) -> stage 2 (doors + drawer, distilled)")
    sets = ["--set", f"data.init_args.root={args.data}"]
    if args.epochs is not None:
        sets += ["--set", f"trainer.max_epochs={args.epochs}"]
    # the curriculum prints its own error line; at the console it returns 2 instead of raising (no second line)
    rc = curriculum.main(["--config", EXPERIMENT, "--root", str(runs / "cfar_pfal"), *sets], raise_errors=raise_errors)
    if rc:
        return rc
    last_stage = curriculum.read_lineage(runs / "cfar_pfal")["stages"][-1]

    _step(3, n, "baseline: PointNet++ SSG on all four tasks")
    baseline = _fit_baseline(args.data, runs / "pointnet2", args.epochs or 20)

    _step(4, n, "test both with the rollout success-rate callback (and the Oracle)")
    stage_dir = Path(last_stage["checkpoint"]).parents[1]  # <run>/checkpoints/<file>.ckpt
    reports = [_test(stage_dir, args.data, last_stage["checkpoint"]), _test(baseline, args.data)]

    _step(5, n, "comparison")
    from floaff_zoo.report import table

    dirs = [str(r.parent) for r in reports]
    failed = [
        p for p in ("map", "sr_views", "sr_tasks") if table.main(["--runs", *dirs, "--preset", p, "--format", "md"])
    ]
    print("\nreports:")
    for r in reports:
        figs = sorted((r.parent / "figures").glob("*.png"))
        print(f"  {r}  ({r.parent / 'report.md'}; {len(figs)} figures in {r.parent / 'figures'})")
    if failed:  # the table printed why; the demo did not finish what it promises
        print(f"floaff-zoo demo: error: the {', '.join(failed)} table(s) failed (named above)", file=sys.stderr)
        return 2
    print(f"\ndemo finished in {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
