"""Time to train each model of the reproduction recipe, through the real CLI, to plan a run.

Every job is a real ``floaff-zoo fit`` (LightningCLI, DataModule, loader, optimizer, callbacks) on the
analytic synthetic DataModule at the input sizes of the recipe it stands for: the ``small`` preset
recipe (``scripts/reproduce_small.sh``: demo-size models, 1,024 points, batch 4) and the paper-size
configs (``configs/models``: 4,096 points, batch 8). Each job runs ``--warmup`` + ``--steps``
optimizer steps without validation or checkpoints; a callback (``StepTimer``) takes the wall time
from the end of the last warm-up step to the end of the last step, loading of the next batch
included, so process start-up, imports and the first steps are left out. Validation, testing and
the rollout callback are not timed.

    python benchmarks/bench_train_time.py                # every job (about 15 minutes on 2 cores)
    python benchmarks/bench_train_time.py --jobs cfar_pfal_stage2 pointnet2 --steps 20
    python benchmarks/bench_train_time.py --accelerators gpu cpu --threads 16 --jobs paper_cfar   # GPU vs CPU

With several ``--accelerators`` every job runs on each in turn, and the last column gives its samples/s as a
multiple of the first accelerator's in the same run. The table's other columns extrapolate to the recipe's
sample counts: ``--recipe-samples`` (default: 20 epochs x 173 training views, the Layouts split of the small
preset) and 10,000 samples.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from lightning.pytorch.callbacks import Callback

ROOT = Path(__file__).resolve().parents[1]
SMALL = {"points": 1024, "batch": 4, "floor_cells": 24}
PAPER = {"points": 4096, "batch": 8, "floor_cells": 32}
#: job -> (model configs, input sizes, what it stands for)
JOBS: dict[str, tuple[list[str], dict[str, int], str]] = {
    "pointnet2": (["configs/demo/pointnet2_demo.yaml"], SMALL, "small recipe: PointNet++"),
    "votenet": (["configs/demo/votenet_demo.yaml"], SMALL, "small recipe: VoteNet-style"),
    "h3dnet": (["configs/demo/h3dnet_demo.yaml"], SMALL, "small recipe: H3DNet-style"),
    "navaff": (["configs/demo/navaff_demo.yaml"], SMALL, "small recipe: NavAff"),
    "n2m": (["configs/demo/n2m_demo.yaml"], SMALL, "small recipe: N2M-style"),
    "axisnet": (["configs/models/axisnet.yaml"], {**SMALL, "batch": 8}, "small recipe: AxisNet stage"),
    "cfar_pfal_stage1": (
        ["configs/demo/cfar_demo.yaml", "configs/experiments/recipe/cfar_recipe.yaml"],
        SMALL,
        "small recipe: CFAR stage 1 (no teacher)",
    ),
    "cfar_pfal_stage2": (
        ["configs/demo/cfar_demo.yaml", "configs/experiments/recipe/cfar_recipe.yaml"],
        SMALL,
        "small recipe: CFAR stage 2 (+ frozen teacher, FD)",
    ),
    "paper_pointnet2_ssg": (["configs/models/pointnet2_ssg.yaml"], PAPER, "paper size: PointNet++ SSG"),
    "paper_navaff": (["configs/models/navaff.yaml"], PAPER, "paper size: NavAff (official sizes)"),
    "paper_cfar": (["configs/models/cfar.yaml"], PAPER, "paper size: CFAR"),
}


class StepTimer(Callback):
    """Writes ``{"seconds", "steps"}`` of the training steps after ``warmup`` to ``out`` (JSON) when fit ends."""

    def __init__(self, out: str, warmup: int = 2) -> None:
        self.out, self.warmup, self.ends = out, warmup, []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if pl_module.device.type == "cuda":  # kernels run asynchronously: a step ends when its last one does
            torch.cuda.synchronize(pl_module.device)
        self.ends.append(time.perf_counter())

    def on_train_end(self, trainer, pl_module) -> None:
        timed = self.ends[self.warmup - 1 :] if self.warmup > 0 else self.ends
        Path(self.out).write_text(json.dumps({"seconds": timed[-1] - timed[0], "steps": len(timed) - 1}))


def fit_args(configs: list[str], sizes: dict[str, int], steps: int, root: Path, accelerator: str = "cpu") -> list[str]:
    """The ``floaff-zoo fit`` command line of one run of ``steps`` optimizer steps on ``accelerator``."""
    n_train = sizes["batch"] * steps
    args = [sys.executable, "-m", "floaff_zoo.cli", "fit", "--config", "configs/data/synthetic_tiny.yaml"]
    for c in configs:
        args += ["--config", c]
    args += [
        "--data.init_args.num_train",
        str(n_train),
        "--data.init_args.points_per_sample",
        str(sizes["points"]),
        "--data.init_args.num_points",
        str(sizes["points"]),
        "--data.init_args.floor_cells",
        str(sizes["floor_cells"]),
        "--data.init_args.batch_size",
        str(sizes["batch"]),
        "--trainer.max_epochs",
        "1",
        "--trainer.limit_val_batches",
        "0",
        "--trainer.num_sanity_val_steps",
        "0",
        "--trainer.enable_checkpointing",
        "false",
        "--trainer.logger",
        "false",
        "--trainer.enable_progress_bar",
        "false",
        "--trainer.enable_model_summary",
        "false",
        "--trainer.accelerator",
        accelerator,
        "--trainer.devices",
        "1",
        "--trainer.default_root_dir",
        str(root),
    ]
    return args


def run(args: list[str], env: dict[str, str]) -> float:
    """Wall seconds of one CLI run; raises with its output when it fails."""
    t = time.perf_counter()
    proc = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")
    return time.perf_counter() - t


def teacher_checkpoint(
    configs: list[str], sizes: dict[str, int], root: Path, env: dict[str, str], extra: list[str]
) -> Path:
    """A stage-1 CFAR checkpoint (one step, on the CPU) to serve as the frozen PFAL teacher of stage 2."""
    args = fit_args(configs, sizes, 1, root) + extra
    args[args.index("--trainer.enable_checkpointing") + 1] = "true"
    run(args, env)
    ckpts = sorted(root.rglob("*.ckpt"))
    if not ckpts:
        raise RuntimeError(f"no teacher checkpoint written under {root}")
    return ckpts[-1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--jobs", nargs="*", default=list(JOBS), choices=list(JOBS))
    p.add_argument("--steps", type=int, default=12, help="timed optimizer steps")
    p.add_argument("--warmup", type=int, default=3, help="untimed first steps")
    p.add_argument("--recipe-samples", type=int, default=20 * 173, help="samples of one recipe job")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--accelerators", nargs="+", default=["cpu"], choices=["cpu", "gpu"],
                   help="run every job on each; the last column compares with the first")  # fmt: skip
    a = p.parse_args(argv)
    if a.steps < 1 or a.warmup < 1:  # the step timer starts at the end of the last warm-up step
        p.error("--steps and --warmup must be >= 1")
    if not a.jobs:  # an empty table and exit 0
        p.error(f"--jobs: name at least one of {list(JOBS)}")
    if a.threads < 1 or a.recipe_samples < 1:
        p.error("--threads and --recipe-samples must be >= 1")
    if "gpu" in a.accelerators and not torch.cuda.is_available():
        p.error("--accelerators gpu: torch sees no CUDA device here")
    env = {**os.environ, "OMP_NUM_THREADS": str(a.threads), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT / "benchmarks"), env.get("PYTHONPATH", "")])
    print(
        f"real `floaff-zoo fit` on synthetic data, {a.threads} threads; per-sample cost = wall time of {a.steps} "
        f"steps after {a.warmup} warm-up steps / ({a.steps} x batch); recipe job = {a.recipe_samples} samples"
    )
    if "gpu" in a.accelerators:
        from floaff_zoo.nn.ops import fps_backend

        fps = fps_backend("cuda", max(SMALL["points"], PAPER["points"]))
        print(f"gpu: {torch.cuda.get_device_name(0)}, torch {torch.__version__}, FPS {fps}")
    print(
        f"{'job':<22} {'acc':>4} {'points':>6} {'batch':>5} {'samples/s':>9} {'s/1k samples':>12} "
        f"{'recipe job':>10} {'10k samples':>11} {'x ' + a.accelerators[0]:>8}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.jobs:
            configs, sizes, what = JOBS[name]
            extra: list[str] = []
            if name.startswith("cfar_pfal"):
                # training uses the simulator's yaw (the recipe); AxisNet only serves evaluation, not timed
                extra += ["--model.init_args.eval_yaw_source", "manhattan"]
            if name.endswith("stage2"):
                teacher = teacher_checkpoint(configs, sizes, Path(tmp) / name / "teacher", env, extra)
                extra += ["--model.init_args.teacher", str(teacher)]
            first: float | None = None
            for acc in a.accelerators:
                root = Path(tmp) / name / acc
                timing = root / "timing.json"
                timer = ["--trainer.callbacks+=bench_train_time.StepTimer", f"--trainer.callbacks.out={timing}",
                         f"--trainer.callbacks.warmup={a.warmup}"]  # fmt: skip
                run(fit_args(configs, sizes, a.warmup + a.steps, root / "run", acc) + extra + timer, env)
                t = json.loads(timing.read_text())
                per_sample = t["seconds"] / (t["steps"] * sizes["batch"])
                first = per_sample if first is None else first
                recipe_min = per_sample * a.recipe_samples / 60
                print(
                    f"{name:<22} {acc:>4} {sizes['points']:>6} {sizes['batch']:>5} {1 / per_sample:>9.2f} "
                    f"{1000 * per_sample:>12.0f} {recipe_min:>8.1f} m {per_sample * 10_000 / 3600:>9.2f} h "
                    f"{first / per_sample:>7.2f}x   ({what})",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
