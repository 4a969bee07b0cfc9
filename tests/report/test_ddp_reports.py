"""Test reports and SR under DDP on CPU (gloo, 2 processes) match a single-process run.

``DistributedSampler`` pads 5 test samples to 6 by repeating sample 0: the SR callback must count it once (as the
map metrics do), and ``TestReport`` must take part in Lightning's collectives on every rank and write on rank 0.
DDP relaunches the command line in each process, so the DDP runs are real subprocesses: this file is also the
script (``python -m tests.report.test_ddp_reports DEVICES OUT``). The ``floaff-zoo test`` run is slow (about 25 s).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from tests.conftest import quiet_trainer_args
from tests.report._fake_world import ConstantModule, FakeService

N_SAMPLES = 5  # odd: DistributedSampler repeats sample 0 on rank 1
VAL_CAP = 3  # max_val_samples: the first 3 samples of the split (each rank collects its first 3)


class FirstSampleRight(ConstantModule):
    """Predicts the labels of the sample with ``meta['index'] == 0`` and a constant map elsewhere."""

    def forward(self, batch):
        index = torch.tensor([m["index"] for m in batch["meta"]])
        out = torch.full_like(batch["floor_label"], 0.5)
        out[index == 0] = batch["floor_label"][index == 0]
        return out + 0.0 * self.net.weight.sum()


def cases() -> dict[str, list[dict]]:
    """Test sets: every sample simulated (the repeat is a rolled-out success), sample 0 without sim metadata
    (the repeat is a skipped sample), or none simulated, with figures (plain scatters, fast to draw): sample 0 is the
    only (CloseDrawer, side) one, on rank 0, and the first (CloseDrawer, front) one is sample 1, on rank 1."""
    from tests.report._fake_world import make_samples

    unsimulated = make_samples(N_SAMPLES)
    unsimulated[0]["meta"].pop("sim")
    plain = make_samples(N_SAMPLES)
    for i, s in enumerate(plain):
        s["meta"].pop("sim")
        s["meta"]["task"], s["meta"]["view"] = "CloseDrawer", "side" if i == 0 else "front"
    return {"sim": make_samples(N_SAMPLES), "skip": unsimulated, "figures": plain}


def run_cases(devices: int, out: Path) -> dict[str, dict]:
    """Test ``FirstSampleRight`` on every case with the SR callback (fake simulator) and TestReport, then validate it
    with SR capped at ``VAL_CAP`` samples; on rank 0 the SR summary (less its wall time), the rolled-out sample ids,
    the report's data/sr facts per case and which sample each figure drew."""

    from floaff_zoo.callbacks.report import TestReport
    from floaff_zoo.callbacks.rollout import RolloutSuccessRate
    from tests.report._fake_world import FakeService, loader, quiet_trainer

    rollout = RolloutSuccessRate(service=FakeService, progress=False)
    report = TestReport(figures=False, figures_per_group=2)
    trainer = quiet_trainer([rollout, report], devices=devices, root=str(out))
    results: dict[str, dict] = {}
    for name, samples in cases().items():
        report.out_dir, report.figures = str(out / name), name == "figures"
        trainer.test(FirstSampleRight(), dataloaders=loader(samples, batch_size=2), verbose=False)
        if trainer.is_global_zero:
            written = json.loads((out / name / "report.json").read_text())
            results[name] = {
                "summary": {k: v for k, v in rollout.summaries["test"].items() if k != "seconds"},
                "ids": sorted(e["sample_id"] for e in rollout.episodes["test"]),
                "data": {k: written["data"][k] for k in ("num_samples", "tasks", "views", "dataset")},
                "sr": {k: v for k, v in written["sr"].items() if k != "seconds"},
                "figures": dict(zip(written["figures"], [s.meta["sample_id"] for s in report._samples])),
            }
    rollout.every_n_val_epochs, rollout.max_val_samples = 1, VAL_CAP  # the cap is on the split, not on each rank
    trainer.validate(FirstSampleRight(), dataloaders=loader(cases()["sim"], batch_size=2), verbose=False)
    if trainer.is_global_zero:
        results["val"] = {
            "summary": {k: v for k, v in rollout.summaries["val"].items() if k != "seconds"},
            "ids": [e["sample_id"] for e in rollout.episodes["val"]],
        }
    return results


def test_sr_and_report_under_ddp_match_one_process(tmp_path, root):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    cmd = [sys.executable, "-m", "tests.report.test_ddp_reports", "2", str(tmp_path / "ddp")]
    done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "GLOBAL_RANK: 1" in done.stdout + done.stderr  # two processes really ran
    ddp = json.loads((tmp_path / "ddp" / "result.json").read_text())
    single = json.loads(json.dumps(run_cases(1, tmp_path / "single")))
    assert single["sim"]["summary"]["n_evaluated"] == N_SAMPLES and single["skip"]["summary"]["n_skipped"] == 1
    assert single["sim"]["data"]["num_samples"] == N_SAMPLES
    assert single["val"]["ids"] == [f"fake{i}" for i in range(VAL_CAP)]
    # rank 0 alone drew only its own samples: a group went missing and the k-th figure depended on the world size
    figures = {"figures/CloseDrawer_side_0.png": "fake0", "figures/CloseDrawer_front_0.png": "fake1"}
    assert single["figures"]["figures"] == {**figures, "figures/CloseDrawer_front_1.png": "fake2"}
    for name in ("sim", "skip", "figures", "val"):
        assert ddp[name] == single[name], name  # counts, SR means and bootstrap stds, report facts


class _RaisingService(FakeService):
    """A rollout service whose rollouts raise (a scene that cannot be built)."""

    def run(self, jobs, progress=False):
        raise ValueError("no cabinet wall in this layout")


def fail_on_rank_zero(out: Path) -> None:
    """Test with a rollout service that raises: only rank 0 rolls out, while rank 1 waits for its summary."""
    from floaff_zoo.callbacks.rollout import RolloutSuccessRate
    from tests.report._fake_world import loader, make_samples, quiet_trainer

    trainer = quiet_trainer([RolloutSuccessRate(service=_RaisingService, progress=False)], devices=2, root=str(out))
    trainer.test(FirstSampleRight(), dataloaders=loader(make_samples(N_SAMPLES), batch_size=2), verbose=False)


def test_a_rollout_failure_on_rank_zero_ends_every_rank(tmp_path, root):
    """Rank 0 raised out of the rollouts while rank 1 waited in the summary's broadcast: rank 1 then ended with
    gloo's "remote worker crashing" error, which does not say what failed."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    cmd = [sys.executable, "-m", "tests.report.test_ddp_reports", "2", str(tmp_path / "ddp"), "fail"]
    done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode != 0
    assert "GLOBAL_RANK: 1" in done.stdout + done.stderr
    assert "ValueError: no cabinet wall in this layout" in done.stderr
    assert "the test rollouts failed on rank 0: ValueError: no cabinet wall" in done.stderr


@pytest.mark.slow
def test_floaff_zoo_test_under_ddp_writes_the_report(tmp_path, root, monkeypatch):
    """`floaff-zoo test` with 2 processes: every rank resolves the log dir (a broadcast), rank 0 writes the report
    of all 5 samples (the repeat counted once), with the single-process map metrics."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    args = ["test", "--config", "configs/data/synthetic_tiny.yaml",
            "--config", "tests/configs/models/c2f_exp_tiny.yaml",
            "--data.init_args.num_test", str(N_SAMPLES), "--seed_everything", "0"]  # fmt: skip
    ddp_args = [*quiet_trainer_args(tmp_path / "ddp"), "--trainer.strategy", "ddp", "--trainer.devices", "2"]
    done = subprocess.run(
        [sys.executable, "-m", "floaff_zoo", *args, *ddp_args],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "GLOBAL_RANK: 1" in done.stdout + done.stderr
    (path,) = (tmp_path / "ddp").rglob("report.json")
    ddp = json.loads(path.read_text())
    assert ddp["data"]["num_samples"] == N_SAMPLES and ddp["config"]["trainer"]["strategy"] == "ddp"
    from floaff_zoo.cli import run_lightning

    monkeypatch.chdir(root)
    run_lightning([*args, *quiet_trainer_args(tmp_path / "single"), "--trainer.devices", "1"])
    (path,) = (tmp_path / "single").rglob("report.json")
    single = json.loads(path.read_text())
    assert single["data"]["num_samples"] == N_SAMPLES
    maps = [k for k in single["metrics"] if k != "test_loss"]  # the loss is Lightning's mean over rank-batches
    assert maps and {k: ddp["metrics"][k] for k in maps} == pytest.approx({k: single["metrics"][k] for k in maps})


if __name__ == "__main__":  # the DDP script: python -m tests.report.test_ddp_reports DEVICES OUT
    torch.set_num_threads(1)
    out_dir = Path(sys.argv[2])
    if sys.argv[3:] == ["fail"]:
        fail_on_rank_zero(out_dir)
        sys.exit(0)
    found = run_cases(int(sys.argv[1]), out_dir)
    if found:  # rank 0
        (out_dir / "result.json").write_text(json.dumps(found))
