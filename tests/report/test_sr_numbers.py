"""The SR numbers a run reports, against hand-computed values: which episodes each cell averages, what its ± is, under
which logged name each number goes, and where the report's SR table puts it (a fake rollout service, no MuJoCo)."""

import math
import re

import numpy as np
import pytest

from floaff_zoo.callbacks.report import render_markdown
from floaff_zoo.callbacks.rollout import (
    STD_METHOD,
    RolloutSuccessRate,
    bootstrap_std,
    summarize_episodes,
    summary_to_logs,
)
from tests.report._fake_world import ConstantModule, FakeService, LabelModule, loader, make_samples, quiet_trainer


def test_sr_all_averages_the_views_not_the_tasks_and_each_view_its_own_episodes():
    """Three front views of task A succeed, one side view of task B fails: SR_all is 3/4 (a mean over views), not
    the mean of the task SRs (1/2); the front cell's ± is over its own episodes (all 1: 0), not over all of them."""
    eps = [{"task": "A", "view": "front", "success": True}] * 3 + [{"task": "B", "view": "side", "success": False}]
    s = summarize_episodes(eps, n_bootstrap=200)
    model = s["model"]
    assert model["all"]["mean"] == 0.75 and model["all"]["n"] == 4
    assert model["front"] == {"mean": 1.0, "std": 0.0, "n": 3}
    assert model["side"] == {"mean": 0.0, "std": 0.0, "n": 1}
    assert model["tasks"] == {"A": {"mean": 1.0, "std": 0.0, "n": 3}, "B": {"mean": 0.0, "std": 0.0, "n": 1}}
    assert s["oracle"] is None  # no episode has an Oracle outcome


def test_bootstrap_std_is_the_sample_std_of_means_of_full_size_resamples():
    """Two outcomes 0 and 1: a resample of both has mean 0, 1/2 or 1, so two resamples' sample std (ddof 1) is
    0, (1/2)/sqrt(2) or 1/sqrt(2); over many resamples the std of the mean tends to sqrt(0.25 / 2) (a resample of one
    outcome, or ddof 0, gives other values)."""
    allowed = (0.0, 0.5 / math.sqrt(2), 1 / math.sqrt(2))
    values = [bootstrap_std([0, 1], 2, seed) for seed in range(40)]
    assert all(min(abs(v - a) for a in allowed) < 1e-12 for v in values), sorted(set(values))
    assert max(values) > 0
    assert bootstrap_std([0, 1], 20000) == pytest.approx(math.sqrt(0.125), abs=0.005)


def _cell(mean: float, std: float, n: int) -> dict:
    return {"mean": mean, "std": std, "n": n}


SUMMARY = {
    "available": True,
    "n_evaluated": 15,
    "n_skipped": 2,
    "std_method": STD_METHOD,
    "n_bootstrap": 1000,
    "top_k": 10,
    "free_space": "full_cloud",
    "pose_source": "map",
    "seconds": 3.25,
    "model": {
        "front": _cell(0.9, 0.03, 10),
        "side": _cell(0.4, 0.05, 5),
        "all": _cell(0.7333, 0.04, 15),
        "tasks": {"A": _cell(0.6, 0.07, 5), "B": _cell(0.8, 0.06, 10)},
    },
    "oracle": {
        "front": _cell(1.0, 0.0, 10),
        "side": _cell(0.8, 0.06, 5),
        "all": _cell(0.9333, 0.02, 15),
        "tasks": {"A": _cell(0.2, 0.09, 5), "B": _cell(1.0, 0.0, 10)},
    },
}


def test_summary_to_logs_puts_every_number_under_its_own_name():
    assert summary_to_logs("test", SUMMARY) == {
        "test_sr_front": 0.9,
        "test_sr_front_std": 0.03,
        "test_sr_side": 0.4,
        "test_sr_side_std": 0.05,
        "test_sr_all": 0.7333,
        "test_sr_all_std": 0.04,
        "test_sr_A": 0.6,
        "test_sr_B": 0.8,
        "test_oracle_sr_front": 1.0,
        "test_oracle_sr_side": 0.8,
        "test_oracle_sr_all": 0.9333,
        "test_oracle_sr_A": 0.2,
        "test_oracle_sr_B": 1.0,
        "test_rollout_seconds": 3.25,
    }
    assert summary_to_logs("val", SUMMARY) == {
        "val_rollout_success": 0.7333,
        "val_sr_front": 0.9,
        "val_sr_side": 0.4,
        "val_oracle_rollout_success": 0.9333,
        "val_rollout_seconds": 3.25,
    }


def test_report_sr_tables_put_each_cell_in_its_column_and_row():
    md = render_markdown({"label": "run", "model": {"class_path": "m.M"}, "metrics": {}, "sr": SUMMARY})
    lines = md.splitlines()
    start = lines.index("| | SR_front | SR_side | SR_all |")
    assert lines[start + 2 : start + 4] == [
        "| model | 0.90 ± 0.03 (n=10) | 0.40 ± 0.05 (n=5) | 0.73 ± 0.04 (n=15) |",
        "| Oracle | 1.00 ± 0.00 (n=10) | 0.80 ± 0.06 (n=5) | 0.93 ± 0.02 (n=15) |",
    ]
    start = lines.index("| | A | B |")
    assert lines[start + 2 : start + 4] == [
        "| model | 0.60 ± 0.07 (n=5) | 0.80 ± 0.06 (n=10) |",
        "| Oracle | 0.20 ± 0.09 (n=5) | 1.00 ± 0.00 (n=10) |",
    ]
    assert (
        f"± = {STD_METHOD}; 15 evaluated, 2 skipped (no sim metadata); pose from the map's best cell;"
        " top_k = 10 (free space: full_cloud); rollouts took 3.2 s." in lines
    )
    no_oracle = render_markdown({"label": "run", "model": {"class_path": "m.M"}, "sr": dict(SUMMARY, oracle=None)})
    assert not re.search(r"^\| Oracle \|", no_oracle, re.M)


def test_n_bootstrap_reaches_the_summary():
    """n_bootstrap 0 means no ± (0.0 in every cell), so the callback's own n_bootstrap, not the default 1000, is what
    its summary resamples with."""
    cb = RolloutSuccessRate(service=FakeService, progress=False, n_bootstrap=0)
    quiet_trainer([cb]).test(ConstantModule(), dataloaders=loader(make_samples(8)), verbose=False)
    s = cb.summaries["test"]
    assert 0 < s["model"]["all"]["mean"] < 1  # outcomes differ, so any resampling would give a std > 0
    cells = [s[who][v] for who in ("model", "oracle") for v in ("front", "side", "all") if v in s[who]]
    assert all(c["std"] == 0.0 for c in cells)


class SimFreeService(FakeService):
    """A service whose scene check (free_space 'sim') blocks the first pose asked for each scene."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.asked: dict[int, int] = {}

    def footprint_free(self, spec, x: float, y: float, yaw: float) -> bool:
        n = self.asked[id(spec)] = self.asked.get(id(spec), 0) + 1
        return n > 1


def test_top_k_with_sim_free_space_asks_the_scene_and_skips_its_blocked_pose():
    """free_space 'sim' reads the rebuilt scene's footprint check: the top-1 it calls blocked is passed over for the
    next candidate (rank 1); the Oracle stays on the label's argmax."""
    samples = make_samples(6)
    cb = RolloutSuccessRate(service=SimFreeService, progress=False, top_k=5, free_space="sim")
    quiet_trainer([cb]).test(LabelModule(), dataloaders=loader(samples), verbose=False)
    eps = cb.episodes["test"]
    assert [e["rank"] for e in eps] == [1] * 6
    assert all(not np.allclose(e["pose"], e["oracle_pose"]) for e in eps)
