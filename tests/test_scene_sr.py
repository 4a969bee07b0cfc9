"""scripts/scene_sr.py: runs pooled per name, SR per scene, and the scene bootstrap's paired differences."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

_SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
sys.path.insert(0, str(_SCRIPTS))  # scene_sr imports its neighbour fresh_sr
_SPEC = importlib.util.spec_from_file_location("scene_sr", _SCRIPTS / "scene_sr.py")
ssr = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(ssr)


def test_parse_models_pools_runs_under_one_name():
    assert ssr.parse_models(["a=x.ckpt", "b=y", "a=z.ckpt", "hub.name.v1"]) == {
        "a": ["x.ckpt", "z.ckpt"],
        "b": ["y"],
        "hub.name.v1": ["hub.name.v1"],
    }
    with pytest.raises(SystemExit, match="bad model argument"):
        ssr.parse_models(["=x.ckpt"])


def _rows():
    """Two tasks x two scenes; model a wins every view of one scene per task, b half of every scene."""
    rows = []
    for task, scenes in (("PnPCounterToCab", ("p0", "p1")), ("CloseDrawer", ("d0", "d1"))):
        for k, sid in enumerate(scenes):
            for v in range(4 if k == 0 else 2):  # scenes of different sizes
                rows.append((task, sid, {"a": [k == 0, k == 0], "b": [v % 2 == 0, True]}))
    return rows


def test_per_scene_averages_runs_and_weights_views():
    table = ssr.per_scene(_rows(), ["a", "b"])
    assert table["p0"] == {"task": "PnPCounterToCab", "views": 4, "sr": {"a": 1.0, "b": 0.75}}
    assert table["p1"]["sr"] == {"a": 0.0, "b": 0.75} and table["p1"]["views"] == 2
    # SR over views, not over scenes: 8 of 12 views for a
    assert ssr.sr_all(table, list(table), "a") == pytest.approx(8 / 12)
    assert ssr.sr_all(table, ["p0", "p0"], "a") == 1.0


def test_scene_bootstrap_spreads_only_when_scenes_differ():
    table = ssr.per_scene(_rows(), ["a", "b"])
    res = ssr.summarize(table, ["a", "b"], draws=400, seed=0)
    assert res["models"]["b"]["scene_bootstrap_std"] == pytest.approx(0.0, abs=1e-12)  # b: 0.75 in every scene
    assert res["models"]["a"]["scene_bootstrap_std"] > 0.1  # a: all or nothing per scene
    d = res["differences"]["a - b"]
    assert d["diff"] == pytest.approx(8 / 12 - 0.75)
    assert d["p05"] < 0 < d["p95"]  # which scenes are drawn decides who is ahead
    assert res["models"]["a"]["PnPCounterToCab"] == pytest.approx(4 / 6)


def test_paired_difference_of_a_constant_shift_has_no_spread():
    rows = [(t, f"{t}{k}", {"a": [v < k + 1], "b": [v < k]}) for t in ("x", "y") for k in range(3) for v in range(4)]
    table = ssr.per_scene(rows, ["a", "b"])
    d = ssr.summarize(table, ["a", "b"], draws=200, seed=1)["differences"]["a - b"]
    assert d["diff"] == pytest.approx(0.25) and d["p05"] == pytest.approx(0.25) and d["p95"] == pytest.approx(0.25)
    boot = ssr.scene_bootstrap(table, ["a"], draws=50, seed=2)
    assert boot.shape == (50, 1) and np.all((boot >= 0) & (boot <= 1))


def test_bad_arguments_exit_with_a_message(tmp_path, capsys):
    with pytest.raises(SystemExit):
        ssr.main(["--draws", "0", "a=x"])
    assert "--draws must be >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ssr.main(["--top-k", "0", "a=x"])
    assert "--top-k must be >= 1" in capsys.readouterr().err
    # an unknown model ends the script with a message naming it, not a traceback
    with pytest.raises(SystemExit, match="scene_sr: .*no-such-model.ckpt"):
        ssr.main(["--root", str(tmp_path), "a=no-such-model.ckpt"])


def test_residual_scales_parse_and_copy_only_prior_residual_runs():
    assert ssr.parse_scales(None) == [] and ssr.parse_scales("0,0.5,2") == [0.0, 0.5, 2.0]
    for bad in ("a,1", "-1", "nan"):
        with pytest.raises(SystemExit, match="--residual-scales"):
            ssr.parse_scales(bad)

    class Run:
        def __init__(self, prior):
            self.prior, self.hparams = prior, {"residual_scale": 1.0}

    nets = {"recipe": [Run(object()), Run(object())], "plain": [Run(None)]}
    out = ssr.with_residual_scales(nets, [0.0, 0.5])
    assert list(out) == ["recipe", "plain", "recipe@0", "recipe@0.5"]
    assert [r.hparams["residual_scale"] for r in out["recipe@0.5"]] == [0.5, 0.5]
    assert nets["recipe"][0].hparams["residual_scale"] == 1.0  # the originals are untouched
