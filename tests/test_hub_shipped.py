"""The checkpoints shipped in the package: each loads offline from the packaged files and predicts, and no shipped
or pushed entry records a path of the machine that exported it."""

from __future__ import annotations

import json
import re

import pytest
import torch
import yaml

from floaff_zoo.contract import collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.hub import RetiredEntryError, UnknownWeightsError, hub_dir, load_model, load_registry
from floaff_zoo.hub.export import export_checkpoint
from floaff_zoo.hub.registry import SHIPPED_INDEX, RegistryFormatError, read_index, read_retired
from floaff_zoo.models.cfar import CFARModule

SHIPPED = sorted(e.name for e in read_index(SHIPPED_INDEX))
HUB_FILES = sorted(p for p in SHIPPED_INDEX.parent.rglob("*") if p.suffix in (".json", ".md"))
#: "runs/...", "data/...", "/abs/...", "~/..." or a Windows drive inside a JSON string / Markdown code span
LOCAL_PATH = re.compile(r"""["'`](?:runs/|data/|/|~/|[A-Za-z]:\\)[^"'`]*["'`]""")


@pytest.fixture(scope="module")
def batch():
    return collate_samples([make_synthetic_sample(i, num_points=512, floor_cells=8) for i in range(2)])


def test_the_package_ships_checkpoints():
    assert len(SHIPPED) >= 4 and "cfar-pfal.floaff-small-layouts.v2" in SHIPPED


def test_a_retired_name_names_its_successor_and_where_it_is_kept():
    retired = read_retired()
    assert retired and not set(retired) & set(SHIPPED)  # retired names are gone from the index ...
    assert {r.successor for r in retired.values()} <= set(SHIPPED)  # ... and each successor ships
    packaged = {p.name for p in SHIPPED_INDEX.parent.iterdir() if p.is_dir()}
    assert not set(retired) & packaged  # no retired weights left in the package
    assert len({r.commit for r in retired.values()}) >= 2  # retired in two batches, each kept at its own commit
    for name in ("cfar-pfal.floaff-dense-layouts.v4", "cfar-pfal.floaff-dense-layouts.v8"):
        with pytest.raises(RetiredEntryError, match=r"superseded by 'cfar-pfal\.floaff-dense-layouts\.v12'") as err:
            load_model(name, allow_download=False)
        assert f"git archive {retired[name].commit} src/floaff_zoo/hub/{name}" in str(err.value)
    assert retired["cfar-pfal.floaff-dense-layouts.v4"].commit != retired["cfar-pfal.floaff-dense-layouts.v8"].commit
    with pytest.raises(UnknownWeightsError, match="did you mean") as err:  # a typo is not reported as retired
        load_model("cfar-pfal.floaff-dense-layuots.v9", allow_download=False)
    assert not isinstance(err.value, RetiredEntryError)


@pytest.mark.parametrize(
    "text, field",
    [
        ("{not json", "not a readable JSON file"),
        ('{"commit": "' + "a" * 40 + '", "entries": {}}', "batches"),  # the one-batch form of before
        ('{"batches": [{"commit": "abc", "entries": {}}]}', r"batches\[0\]"),
        ('{"batches": [{"commit": "' + "a" * 40 + '", "entries": {"m.d.v1": 3}}]}', r"entries\['m.d.v1'\]"),
        (
            '{"batches": [{"commit": "' + "a" * 40 + '", "entries": {"m.d.v1": "m.d.v2"}}, '
            '{"commit": "' + "b" * 40 + '", "entries": {"m.d.v1": "m.d.v3"}}]}',
            r"batches\[1\]: 'm.d.v1' is retired in an earlier batch",
        ),
    ],
)
def test_a_malformed_retired_file_is_named(tmp_path, text, field):
    bad = tmp_path / "retired.json"
    bad.write_text(text)
    with pytest.raises(RegistryFormatError, match=rf"retired\.json: .*{field}"):
        read_retired(bad)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_entry_loads_offline_and_predicts(name, batch, monkeypatch):
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "1")
    assert not any(hub_dir().rglob("*.safetensors"))  # nothing cached: the packaged file is what loads
    model = load_model(name, allow_download=False)
    assert type(model).__name__ in load_registry()[name].class_path and not model.training
    with torch.no_grad():
        scores = model(batch)
    assert scores.shape == batch["floor_mask"].shape
    valid = scores[batch["floor_mask"]]
    assert torch.isfinite(valid).all() and (valid >= 0).all() and (valid <= 1).all()


#: an entry's model card names the committed test report its metrics came from ("metrics: <folder>" or "test metrics
#: and SR: <folder>" at the end of its description)
REPORT_REF = re.compile(r"metrics(?: and SR)?: (docs/results/\S+?)[.,;]?$")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_metrics_are_those_of_the_report_they_name(name, root):
    """A push given the wrong ``--report`` (another seed's, another benchmark's) would ship numbers that no committed
    report backs; each entry's metrics must equal the report its description points at, and every entry names one."""
    entry = load_registry()[name]
    ref = REPORT_REF.search(entry.meta.get("description", ""))
    assert ref, f"{name}: the description names no committed report ('... metrics: docs/results/<folder>')"
    folder = root / ref.group(1)
    report = json.loads((folder / "report.json").read_text())
    metrics = report.get("metrics", report)
    assert entry.meta["metrics"] and entry.meta["metrics"] == {k: metrics[k] for k in entry.meta["metrics"]}
    # the report is of the entry's own benchmark (the demo trains on Layouts and keeps no benchmark folder)
    assert entry.meta["benchmark"] in folder.parts or "demo" in entry.name


@pytest.mark.parametrize("path", HUB_FILES, ids=lambda p: str(p.relative_to(SHIPPED_INDEX.parent)))
def test_shipped_files_hold_no_local_paths(path):
    hits = LOCAL_PATH.findall(path.read_text(encoding="utf-8"))
    assert not hits, f"{path}: local paths of the exporting machine: {hits[:5]}"


def test_push_records_no_local_paths(tmp_path, root):
    """A CFAR trained with an AxisNet file: the export keeps the AxisNet (architecture, weights, sha256), not
    where the file was."""
    args = yaml.safe_load((root / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
    axis_file = str(tmp_path / "runs/axisnet/version_0/checkpoints/epoch001.ckpt")
    arch = {"crop_radius": 1.3, "widths": [8, 16], "head": [8], "source": axis_file, "sha256": "0" * 64}
    model = CFARModule(**args, axisnet_arch=arch)
    hp = {**dict(model.hparams), "axisnet": axis_file, "_class_path": "floaff_zoo.models.cfar.CFARModule"}
    ckpt = tmp_path / "runs/cfar/version_0/checkpoints/epoch003.ckpt"
    ckpt.parent.mkdir(parents=True)
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": hp}, ckpt)

    entry, out = export_checkpoint(ckpt, "cfar.tiny-paths.v1")
    texts = {p.name: p.read_text() for p in (out / "config.json", out / "README.md", hub_dir() / "index.json")}
    for name, text in texts.items():
        assert str(tmp_path) not in text and "runs/" not in text, name
    assert entry.init_args["axisnet"] is None and entry.init_args["axisnet_arch"]["source"] is None
    assert entry.init_args["axisnet_arch"]["sha256"] == "0" * 64  # the lineage stays
    assert json.loads(texts["config.json"])["init_args"]["axisnet_arch"]["widths"] == [8, 16]
    back = CFARModule.from_pretrained(entry.name)
    own = {k: v for k, v in model.state_dict().items() if k.startswith("axisnet.")}
    got = {k: v for k, v in back.state_dict().items() if k.startswith("axisnet.")}
    assert own and own.keys() == got.keys() and all(torch.equal(own[k], got[k]) for k in own)


def test_every_entry_is_listed_by_the_cli(capsys):
    from floaff_zoo.cli import main

    assert main(["hub", "list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in SHIPPED)
    # a user picks by benchmark and test score; versions in numeric order
    entry = load_registry()["cfar-pfal.floaff-dense-layouts.v12"]
    line = next(x for x in out.splitlines() if x.startswith(entry.name + " "))
    sr, pcc = entry.meta["metrics"]["test_sr_all"], entry.meta["metrics"]["test_pcc"]
    assert line.split()[2:5] == ["layouts", f"{sr:.3f}", f"{pcc:.3f}"]
    assert out.index("cfar-pfal.floaff-dense-layouts.v9 ") < out.index("cfar-pfal.floaff-dense-layouts.v10 ")
    assert f"({len(read_retired())} earlier versions retired from the package" in out
