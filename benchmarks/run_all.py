"""Run every benchmark script and collect their printed figures into docs/performance.md.

    python benchmarks/run_all.py            # quick modes (about 10-20 minutes on 2 idle cores)
    python benchmarks/run_all.py --full     # longer settings: more rounds or steps, the small preset

Each script prints its own figures and ratios against a reference measured in the same run
(absolute numbers move with machine load; ratios carry over). This runner only executes them one
after another, records the machine and the exact commands, and writes their output verbatim.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from floaff_zoo.atomic import atomic_write_text, existing_ancestor

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: every learned model of the zoo, timed against itself on the reference port's operations
_LEARNED = ["pointnet2_ssg", "pointnet2_msg", "votenet", "h3dnet", "navaff", "n2m", "cfar"]
#: sections written by hand (their title starts with this): kept from the old report on every run
_KEPT = "## Reading"

#: (title, script, quick args, full args)
SUITE: list[tuple[str, str, list[str], list[str]]] = [
    (
        "Simulator: rollouts, candidates labelled per second, IK pre-filter agreement, growth with candidates",
        "bench_sim.py",
        ["--quick"],
        [],
    ),
    ("Generator: render ms per view, wall time per preset, growth with scenes", "bench_generate.py", [], ["--small"]),
    ("Loader: samples/s vs a PointNet++ training step", "bench_loader.py", ["--samples", "16"], []),
    (
        "Loader: a train epoch's start, workers restarted each epoch (as shipped) vs persistent, fork vs spawn",
        "bench_loader.py",
        ["--epoch-start", "--epoch-start-epochs", "4"],
        ["--epoch-start"],
    ),
    (
        "Models: train samples/s, predict latency, growth with points, PointNet++ vs the reference-style port",
        "bench_models.py",
        ["--quick", "--points-sweep", "1024", "2048", "4096", "8192", "--vs-reference", *_LEARNED],
        ["--points-sweep", "1024", "2048", "4096", "8192", "--vs-reference", *_LEARNED],
    ),
    (
        "Predict latency as shipped: PointNet++ and CFAR in interleaved rounds, the port in rounds of its own",
        "bench_predict.py",
        ["--rounds", "60"],
        ["--rounds", "120"],
    ),
    (
        "As shipped: every learned model with the zoo's allocator setting vs the port, four processes each",
        "bench_vs_port.py",
        ["--rounds", "1", "--iters", "2"],
        [],
    ),
    ("Time to train: a real `fit` per model of the reproduction recipe", "bench_train_time.py", ["--steps", "8"], []),
]


def _machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",)
    return f"{cpu}; {os.cpu_count()} logical cores; Python {platform.python_version()}; load average at start {load}"


def _merge_sections(old: str, new: list[str]) -> list[str]:
    """The old report with its ``## `` sections replaced by the new ones of the same title (header: new)."""

    def split(text: str) -> list[str]:
        parts = text.split("\n## ")
        return [parts[0]] + ["## " + p for p in parts[1:]]

    fresh = {s.split("\n", 1)[0]: s for s in new if s.startswith("## ")}
    head = [s for s in new if not s.startswith("## ")]
    old_body = split(old)[1:]
    body = [fresh.get(s.split("\n", 1)[0], s) for s in old_body]
    # a section the old report lacks goes before the hand-written ones (it would be lost otherwise)
    titles = {s.split("\n", 1)[0] for s in old_body}
    added = [s for t, s in fresh.items() if t not in titles]
    at = next((i for i, s in enumerate(body) if s.startswith(_KEPT)), len(body))
    body = body[:at] + added + body[at:]
    return head + [s.rstrip("\n") + "\n" for s in body]


def check_out(ap: argparse.ArgumentParser, out: Path) -> None:
    """``ap.error`` naming ``--out`` where the report could not be written or its old text not read: checked before
    the suite runs (10-20 minutes), whose output was lost when the write failed at its end."""
    if out.is_dir():
        ap.error(f"--out {out}: is a folder, give the report's file name")
    target = Path(os.path.realpath(out)) if out.is_symlink() else out  # the write goes through a link, as open does
    folder = existing_ancestor(target.absolute().parent)  # the write creates the missing folders
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        ap.error(f"--out {out}: cannot write under {folder}")
    if out.exists():
        try:  # its sections are kept, so it must be readable text
            out.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            ap.error(f"--out {out}: cannot read the existing report ({exc})")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="longer settings (more rounds or steps, the small preset)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "performance.md"))
    ap.add_argument(
        "--only",
        nargs="*",
        default=None,
        help="script names to run (default: all); their sections replace those of an existing --out",
    )
    args = ap.parse_args(argv)
    scripts = [script for _, script, _, _ in SUITE]
    if args.only is not None:  # a typo would run nothing and still rewrite the report's header
        args.only = [s if s.endswith(".py") else f"{s}.py" for s in args.only]
        unknown = [s for s in args.only if s not in scripts]
        if not args.only or unknown:
            what = f"unknown script(s) {unknown}" if unknown else "no script named"
            ap.error(f"--only: {what}; choose from {scripts}")
    check_out(ap, Path(args.out))
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    only = f" --only {' '.join(args.only)}" if args.only else ""
    earlier = " (the other sections are from earlier runs, each says how it ran)" if only else ""
    sections = [
        "# Performance\n",
        f"Written by `python benchmarks/run_all.py{' --full' if args.full else ''}{only}` on "
        f"{time.strftime('%Y-%m-%d')}{earlier}.",
        f"Machine: {_machine()}.",
        "Figures are printed by each script with the references it measures in the same run (the simulator: bare "
        "MuJoCo stepping; the time to train: the first accelerator, so times alone on a CPU-only run); the simulator "
        "also compares with robosuite's published rollout time. Compare ratios, not absolute values.\n",
    ]
    failed = 0
    for title, script, quick, full in SUITE:
        if args.only and script not in args.only:
            continue
        cmd = [sys.executable, str(HERE / script), *(full if args.full else quick)]
        print(f"[run_all] {' '.join(cmd[1:])}", flush=True)
        t0 = time.time()
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        wall = time.time() - t0
        status = "ok" if proc.returncode == 0 else f"FAILED (exit {proc.returncode})"
        failed += proc.returncode != 0
        out = proc.stdout.strip() or "(no output)"
        if proc.returncode != 0:
            out += "\n--- stderr (tail) ---\n" + "\n".join(proc.stderr.strip().splitlines()[-20:])
        rel = " ".join(["python", f"benchmarks/{script}", *cmd[2:]])
        sections.append(f"## {title}\n\n`{rel}` — {status}, {wall:.0f} s wall\n\n```\n{out}\n```\n")
        print(out, flush=True)
    out_path = Path(args.out)
    if args.only and out_path.is_file():  # refresh only these sections of an existing report
        sections = _merge_sections(out_path.read_text(), sections)
    elif out_path.is_file():  # a full run keeps the hand-written reading
        old = out_path.read_text().split("\n## ")
        sections += ["## " + part.rstrip("\n") + "\n" for part in old[1:] if ("## " + part).startswith(_KEPT)]
    # whole or not at all: a write that fails (a full disk) or is killed kept nothing of the old report, whose
    # hand-written reading exists nowhere else
    atomic_write_text(out_path, "\n".join(sections))
    print(f"[run_all] wrote {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
