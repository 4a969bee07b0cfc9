"""scripts/reproduce_small.sh copies the report of the job it ran: two jobs testing one run at once each get theirs."""

from __future__ import annotations

import json
import os
import subprocess
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: a stand-in for `floaff-zoo test`: the report (its label and residual scale) in a new version folder beside the
#: run, after the delay $DELAY_<scale> seconds
FAKE_FZ = textwrap.dedent(
    """\
    #!/usr/bin/env bash
    cfg=$3; scale=none; label=
    while [ $# -gt 0 ]; do
      case $1 in
        --model.init_args.residual_scale) scale=$2 ;;
        --trainer.callbacks.init_args.label) label=$2 ;;
      esac
      shift
    done
    d=$(dirname "$cfg")/../version_scale$scale; mkdir -p "$d"
    delay=DELAY_$scale; sleep "${!delay}"
    printf '{"label": "%s", "residual_scale": "%s"}' "$label" "$scale" > "$d/report.json"; echo x > "$d/report.md"
    """
)


@pytest.mark.parametrize("slow", ["0", "2"])
def test_two_jobs_testing_one_run_at_once_copy_their_own_reports(tmp_path, slow):
    """Each test found its report as the first report.json written beside the run since it started: the slower of
    two jobs testing one run (occ_recipe_rs0_s0 and occ_recipe_rs2_s0) could copy the faster one's report."""
    run = tmp_path / "runs" / "layouts" / "occ_recipe_s0" / "stage2" / "cfarmodule" / "version_0"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.yaml").write_text("")
    ckpt = run / "checkpoints" / "last.ckpt"
    ckpt.write_text("")
    lineage = {"complete": True, "stages": [{"checkpoint": str(ckpt)}]}
    (tmp_path / "runs" / "layouts" / "occ_recipe_s0" / "lineage.json").write_text(json.dumps(lineage))
    fz = tmp_path / "fakefz"
    fz.write_text(FAKE_FZ)
    fz.chmod(0o755)
    env = {
        **os.environ,
        "FZ": str(fz),
        "PRESET": "dense",
        "RUNS": str(tmp_path / "runs"),
        "OUT": str(tmp_path / "out"),
        "PAR": "2",
        "DELAY_0": "2" if slow == "0" else "0.2",
        "DELAY_2": "2" if slow == "2" else "0.2",
    }
    jobs = ["occ_recipe_rs0_s0", "occ_recipe_rs2_s0"]
    done = subprocess.run(
        [str(ROOT / "scripts" / "reproduce_small.sh"), *jobs], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr
    for scale in ("0", "2"):
        report = json.loads((tmp_path / "out" / "layouts" / f"occ_recipe_rs{scale}_s0" / "report.json").read_text())
        assert report["residual_scale"] == scale, (slow, report)
