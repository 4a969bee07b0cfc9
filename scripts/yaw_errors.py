"""Yaw-estimate errors per task and view, for every training-free or AxisNet-based yaw source.

    python scripts/yaw_errors.py --root data/floaff_small --benchmark layouts --split test \
        --axisnet runs/small/layouts/cfar_pfal/axisnet/.../best.ckpt [--json out.json]

Prints a Markdown table (median / mean absolute error in degrees against the simulator's yaw) for the
sources of ``floaff_zoo.models.yaw``: ``axisnet``, ``axisnet_manhattan`` (with an AxisNet), ``manhattan``
and ``heading``. Choose sources on ``--split val``; report ``--split test``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
from floaff_zoo.models.yaw import estimate_yaw, load_axisnet
from floaff_zoo.nn.axisnet import angle_error_deg
from floaff_zoo.sim.fileformat import BENCHMARKS

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders  # noqa: E402

from floaff_zoo.atomic import atomic_write_text  # noqa: E402


def collect(dm: FloAffKitchenDataModule, split: str, sources: list[str], axisnet, radius: float) -> dict:
    """{source: {(task, view): [errors in deg]}} over one split."""
    loader = {"val": dm.val_dataloader, "test": dm.test_dataloader, "train": dm.train_dataloader}[split]()
    out: dict[str, dict[tuple[str, str], list[float]]] = {s: {} for s in sources}
    for batch in loader:
        gt = batch["target_yaw"].reshape(-1)
        for src in sources:
            yaw = estimate_yaw(batch, src, axisnet, radius, 1.2, "yaw_errors")
            err = angle_error_deg(yaw.double(), gt.double())
            for e, meta in zip(err.tolist(), batch["meta"]):
                out[src].setdefault((meta["task"], meta["view"]), []).append(e)
    return out


def table(errors: dict) -> str:
    """Markdown: one row per task (and 'all'), median / mean per source."""
    sources = list(errors)
    keys = sorted({k for d in errors.values() for k in d})
    tasks = sorted({t for t, _ in keys})
    lines = [
        "| task | " + " | ".join(f"{s} median / mean (deg)" for s in sources) + " |",
        "|---|" + "---:|" * len(sources),
    ]
    for task in [*tasks, "all"]:
        cells = []
        for s in sources:
            e = np.array([x for (t, _), v in errors[s].items() if task in ("all", t) for x in v])
            cells.append(f"{np.median(e):.1f} / {e.mean():.1f}" if len(e) else "n/a")
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", required=True)
    p.add_argument("--benchmark", default="layouts", choices=BENCHMARKS)
    p.add_argument("--split", default="val", choices=["train", "val", "test"])
    p.add_argument("--axisnet", default=None, help="AxisNetModule checkpoint or hub name")
    p.add_argument("--points", type=int, default=1024)
    p.add_argument("--json", default=None, help="also write the raw errors here")
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    torch.manual_seed(0)
    dm = FloAffKitchenDataModule(
        root=a.root, benchmark=a.benchmark, batch_size=8, num_points=a.points, collate_mode="resample", validate=False
    )
    dm.setup("fit" if a.split in ("train", "val") else "test")
    sources = ["manhattan", "heading"]
    axisnet, radius = None, 0.0
    if a.axisnet:
        axisnet, radius, _ = load_axisnet(a.axisnet, "yaw_errors")
        sources = ["axisnet", "axisnet_manhattan", *sources]
    errors = collect(dm, a.split, sources, axisnet, radius)
    print(f"{a.benchmark} {a.split}: {sum(len(v) for v in errors[sources[0]].values())} views")
    print(table(errors))
    if a.json:
        atomic_write_text(
            a.json, json.dumps({s: {f"{t}/{v}": e for (t, v), e in d.items()} for s, d in errors.items()}, indent=1)
        )
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "yaw_errors"))
