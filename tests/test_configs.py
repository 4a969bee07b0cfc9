"""Every YAML file under configs/ parses with the real CLI (`--print_config`), in the combination it is used in.

A data config goes with a model config and vice versa (the demo's files with each other, the others with the tiny
synthetic data / tiny PointNet), a model-override file (ablation, sweep point) with the CFAR config it modifies,
a data-override file (transforms) and a trainer preset with the tiny pair, and a curriculum experiment stage by
stage. A file that fits none of these kinds fails the test, so a new config cannot go untested.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from floaff_zoo.cli import run_lightning
from floaff_zoo.curriculum import build_stage_args, load_experiment

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "configs").rglob("*.y*ml"))
TINY_DATA, TINY_MODEL = "configs/data/synthetic_tiny.yaml", "configs/models/tiny_pointnet.yaml"
DEMO_DATA, DEMO_MODEL = "configs/demo/data_demo.yaml", "configs/demo/pointnet2_demo.yaml"


def _class_path(section: object) -> str | None:
    return section.get("class_path") if isinstance(section, dict) else None


def _contains(printed: object, given: object) -> bool:
    """The printed config holds every value the file gives (the printed one adds defaults)."""
    if isinstance(given, dict):
        return isinstance(printed, dict) and all(k in printed and _contains(printed[k], v) for k, v in given.items())
    if isinstance(given, list):
        return isinstance(printed, list) and len(printed) == len(given) and all(map(_contains, printed, given))
    return printed == pytest.approx(given) if isinstance(given, float) else printed == given


def plan(cfg: str) -> tuple[str, list[list[str]]]:
    """(kind, CLI argument lists to check) for one config file."""
    raw = yaml.safe_load((ROOT / cfg).read_text()) or {}
    demo = cfg.startswith("configs/demo/")
    if "stages" in raw or "extends" in raw:
        exp = load_experiment(ROOT / cfg)
        best = {s["name"]: "some/best.ckpt" for s in exp["stages"]}
        return "experiment", [build_stage_args(exp, s, Path("runs/x"), best) for s in exp["stages"]]
    if _class_path(raw.get("data")):
        return "data", [["fit", "--config", cfg, "--config", DEMO_MODEL if demo else TINY_MODEL]]
    if _class_path(raw.get("model")):
        return "model", [["fit", "--config", DEMO_DATA if demo else TINY_DATA, "--config", cfg]]
    if isinstance(raw.get("model"), dict):  # init_args only: an ablation / sweep override of CFAR
        return "override", [["fit", "--config", TINY_DATA, "--config", "configs/models/cfar.yaml", "--config", cfg]]
    if isinstance(raw.get("data"), dict):  # init_args only: e.g. transforms added to any DataModule
        # FloAff-Kitchen's own options (train_labels, full_cloud) go over a FloAff-Kitchen data config
        own = {"train_labels", "full_cloud"} & set(raw["data"].get("init_args") or {})
        base = "configs/data/floaff_tiny.yaml" if own else TINY_DATA
        # with evaluation callbacks (eval_sr_top10_full.yaml) it is a `test` preset
        command = "test" if "callbacks" in (raw.get("trainer") or {}) else "fit"
        return "data_override", [[command, "--config", base, "--config", TINY_MODEL, "--config", cfg]]
    if set(raw) == {"trainer"}:
        command = "test" if "callbacks" in (raw["trainer"] or {}) else "fit"
        return "trainer", [[command, "--config", TINY_DATA, "--config", TINY_MODEL, "--config", cfg]]
    raise AssertionError(
        f"{cfg}: not a data, model, override, trainer or experiment config; teach tests/test_configs.py"
    )


@pytest.mark.parametrize("cfg", CONFIGS)
def test_config_parses(cfg, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    kind, runs = plan(cfg)
    raw = yaml.safe_load((root / cfg).read_text()) or {}
    for args in runs:
        with pytest.raises(SystemExit) as ex:
            run_lightning([*args, "--print_config"])
        assert ex.value.code in (0, None), (cfg, args, capsys.readouterr().err[-2000:])
        printed = yaml.safe_load(capsys.readouterr().out)
        assert _class_path(printed["model"]) and _class_path(printed["data"]), (cfg, args)
        if kind in ("data", "model"):
            assert printed[kind]["class_path"] == raw[kind]["class_path"], cfg
        if kind == "override":
            for key, value in raw["model"]["init_args"].items():
                assert _contains(printed["model"]["init_args"][key], value), (cfg, key)
        if kind == "data_override":
            assert _contains(printed["data"]["init_args"], raw["data"]["init_args"]), cfg


def test_every_config_kind_is_present():
    kinds = {plan(c)[0] for c in CONFIGS}
    assert kinds == {"experiment", "data", "model", "override", "data_override", "trainer"}
