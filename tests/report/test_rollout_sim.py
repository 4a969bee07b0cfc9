"""RolloutSuccessRate + TestReport with the real simulator on freshly generated tiny data (~35 s: 2 scenes)."""

import json

import numpy as np
import pytest

from floaff_zoo.callbacks import RolloutSuccessRate, TestReport
from floaff_zoo.contract import validate_sample
from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim import generate as gen
from tests.report._fake_world import ConstantModule, LabelModule, loader, quiet_trainer


@pytest.fixture(scope="module")
def sim_samples(tmp_path_factory):
    out = tmp_path_factory.mktemp("gen")
    rc = gen.main(
        [
            "--preset",
            "tiny",
            "--out",
            str(out),
            "--tasks",
            "CloseDrawer",
            "OpenSingleDoor",
            "--n-train",
            "0",
            "--n-test",
            "1",
            "--workers",
            "0",
            "--quiet",
        ]
    )
    assert rc == 0
    samples = [validate_sample(ff.read_sample(sc, v, out)) for sc in ff.iter_scenes(out) for v in sc["views"]]
    assert samples and all("sim" in s["meta"] for s in samples)
    return samples


def _test(module, samples, callbacks):
    return quiet_trainer(callbacks).test(module, dataloaders=loader(samples, 4), verbose=False)[0]


def test_oracle_succeeds_and_constant_map_is_no_better_than_chance(sim_samples, tmp_path):
    cb = RolloutSuccessRate(progress=False)
    res = _test(LabelModule(), sim_samples, [cb, TestReport(out_dir=str(tmp_path), figures_per_group=1)])
    assert res["test_oracle_sr_all"] >= 0.9 and res["test_sr_all"] >= 0.9
    assert {"test_sr_front", "test_sr_side", "test_sr_CloseDrawer", "test_sr_OpenSingleDoor"} <= set(res)
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["sr"]["available"] and rep["sr"]["oracle"]["all"]["n"] == len(sim_samples)
    assert len(rep["figures"]) == 4 and all((tmp_path / f).stat().st_size > 5000 for f in rep["figures"])
    # base rate: the fraction of candidates whose label says success
    base = float(np.mean([(s["floor_label"][s["floor_mask"]] > 0.5).float().mean() for s in sim_samples]))
    res_c = _test(ConstantModule(), sim_samples, [RolloutSuccessRate(progress=False)])
    assert res_c["test_oracle_sr_all"] >= 0.9
    assert res_c["test_sr_all"] <= base + 0.25, (res_c["test_sr_all"], base)
