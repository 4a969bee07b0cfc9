"""scripts/pfal_retention.sh: the rows come from the curriculum's last two stages, only of a finished curriculum."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: a stand-in for `floaff-zoo validate`, as Lightning's plain results table prints: val_pcc by the stage its
#: checkpoint comes from (AxisNet 0.9, stage 1 0.5, stage 2 0.4), val_sim 0.6
FAKE_FZ = """#!/usr/bin/env bash
for a in "$@"; do case "$a" in *axisnet*) p=0.9 ;; *stage1*) p=0.5 ;; *stage2*) p=0.4 ;; esac; done
printf '      val_pcc      %s\n      val_sim      0.6\n' "$p"
"""


def _run(tmp_path: Path, lineage: dict) -> subprocess.CompletedProcess:
    root = tmp_path / "recipe_s0"
    root.mkdir()
    (root / "lineage.json").write_text(json.dumps(lineage))
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "floaff-zoo").write_text(FAKE_FZ)
    (bin_dir / "floaff-zoo").chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    return subprocess.run(
        ["bash", str(ROOT / "scripts" / "pfal_retention.sh"), str(root)], capture_output=True, text=True, env=env
    )


def _stage(name: str) -> dict:
    return {"stage": name, "checkpoint": f"/runs/{name}/version_0/checkpoints/best.ckpt"}


@pytest.mark.parametrize("first", [["axisnet"], [], ["axisnet", "warmup"]])
def test_a_finished_curriculum_gets_a_row(tmp_path, first):
    """Stages 1 and 2 are the lineage's last two, however many stages come before them (no AxisNet stage when its
    weights are given; a further warm-up stage)."""
    stages = [*map(_stage, first), _stage("stage1_pnp"), _stage("stage2_door_drawer")]
    proc = _run(tmp_path, {"stages": stages, "complete": True})
    assert proc.returncode == 0, proc.stderr
    # stage 1's and stage 2's scores and the change between them, not the AxisNet stage's
    assert proc.stdout.splitlines()[-1] == "| recipe_s0 | 0.500 / 0.600 | 0.400 / 0.600 | -0.100 |"


def test_an_unfinished_curriculum_is_refused(tmp_path):
    """A curriculum killed in stage 2 keeps its AxisNet stage and stage 1 in lineage.json (complete: false): those
    were printed as "stage 1" and "stage 2"."""
    proc = _run(tmp_path, {"stages": [_stage("axisnet"), _stage("stage1_pnp")], "complete": False})
    assert proc.returncode != 0
    assert "the curriculum did not finish" in proc.stderr and "| recipe_s0 |" not in proc.stdout
