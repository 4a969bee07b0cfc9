"""Hub files a user may hand the loaders or the exporter: every bad one is refused with its file named."""

import json
import os
from pathlib import Path

import pytest
import torch

from floaff_zoo.cli import main as zoo_main
from floaff_zoo.hub import HubError, UnknownWeightsError, get_entry, load_model, load_registry
from floaff_zoo.hub.export import export_checkpoint
from floaff_zoo.models.tiny import TinyPointNetModule

TINY = "floaff_zoo.models.tiny.TinyPointNetModule"


def _ckpt(path: Path, width: int = 8, nan: bool = False, best: tuple[Path, float] | None = None) -> Path:
    torch.manual_seed(0)
    model = TinyPointNetModule(width=width)
    state = model.state_dict()
    if nan:
        state = {k: torch.full_like(v, float("nan")) if v.is_floating_point() else v for k, v in state.items()}
    callbacks = {}
    if best is not None:
        key = "ModelCheckpoint{'monitor': 'val_rmse', 'mode': 'min'}"
        score = torch.tensor(best[1])
        callbacks[key] = {"monitor": "val_rmse", "best_model_score": score, "best_model_path": str(best[0])}
    path.parent.mkdir(parents=True, exist_ok=True)
    hp = {**dict(model.hparams), "_class_path": TINY}
    torch.save({"state_dict": state, "hyper_parameters": hp, "callbacks": callbacks}, path)
    return path


def test_weights_of_another_shape_name_the_file(tmp_path):
    """load_state_dict raised a bare RuntimeError (no file named) and `hub push` died with a traceback."""
    sd = tmp_path / "sd.pt"
    torch.save(TinyPointNetModule(width=8).state_dict(), sd)
    with pytest.raises(ValueError, match=rf"{sd}: weights do not match TinyPointNetModule.*of another shape"):
        TinyPointNetModule.from_pretrained(str(sd))
    exported = tmp_path / "export"
    TinyPointNetModule(width=8).save_pretrained(str(exported))
    cfg = json.loads((exported / "config.json").read_text())
    cfg["init_args"]["width"] = 16
    (exported / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match="of another shape"):
        load_model(exported)


def test_a_config_of_wrong_types_names_its_file(tmp_path):
    exported = tmp_path / "export"
    TinyPointNetModule(width=8).save_pretrained(str(exported))
    cfg = json.loads((exported / "config.json").read_text())
    (exported / "config.json").write_text(json.dumps({**cfg, "class_path": 5}))
    with pytest.raises(ValueError, match=r"config\.json: expected an object with a string 'class_path'"):
        load_model(exported)
    bad = tmp_path / "list.pt"
    torch.save({"state_dict": [1, 2]}, bad)
    with pytest.raises(ValueError, match=rf"{bad}: 'state_dict' and 'hyper_parameters' must be dicts"):
        load_model(bad)


def test_diverged_weights_are_not_pushed(tmp_path, capsys):
    ckpt = _ckpt(tmp_path / "nan.ckpt", nan=True)
    assert zoo_main(["hub", "push", str(ckpt), "--name", "tiny.nan.v1"]) == 2
    assert "hold NaN or inf" in capsys.readouterr().err and "tiny.nan.v1" not in load_registry()


def test_save_pretrained_leaves_no_open_file(tmp_path):
    before = len(os.listdir("/proc/self/fd"))
    for i in range(5):
        TinyPointNetModule(width=8).save_pretrained(str(tmp_path / f"m{i}"))
    assert len(os.listdir("/proc/self/fd")) == before


def test_a_home_relative_run_keeps_its_metrics(tmp_path, monkeypatch):
    """A run given as ~/run was found, but not read as a run: its best validation score was not recorded."""
    monkeypatch.setenv("HOME", str(tmp_path))
    ckdir = tmp_path / "run" / "version_0" / "checkpoints"
    _ckpt(ckdir / "last.ckpt", best=(_ckpt(ckdir / "epoch001.ckpt"), 0.125))
    entry, _ = export_checkpoint("~/run", "tiny.home.v1")
    assert entry.meta["metrics"] == pytest.approx({"val_rmse": 0.125})
    with pytest.raises(HubError, match="registered already"):
        export_checkpoint("~/run", "tiny.home.v1")


def test_a_folder_of_a_registered_name_in_the_working_folder_does_not_hide_it(tmp_path, monkeypatch):
    """An unrelated folder named like a hub entry made every load by that name fail ("not an exported model
    directory"); an exported folder of that name is still what a load by that name reads."""
    monkeypatch.chdir(tmp_path)
    name = "cfar-pfal.floaff-small-layouts.v2"
    (tmp_path / name).mkdir()
    assert type(load_model(name)).__name__ == "CFARModule"
    TinyPointNetModule(width=8).save_pretrained(str(tmp_path / name))
    assert type(load_model(name)).__name__ == "TinyPointNetModule"


def test_a_class_path_other_than_the_recorded_one_is_refused(tmp_path):
    """--class-path was ignored without a word when the checkpoint records its class."""
    ckpt = _ckpt(tmp_path / "a.ckpt")
    with pytest.raises(HubError, match=r"--class-path floaff_zoo\.models\.Nope differs from the class the checkpoint"):
        export_checkpoint(ckpt, "tiny.cls.v1", class_path="floaff_zoo.models.Nope")
    entry, _ = export_checkpoint(ckpt, "tiny.cls.v1", class_path=TINY)  # the same class: fine
    assert entry.class_path == TINY


@pytest.mark.parametrize("field, value", [("meta", ["x"]), ("name", 5)])
def test_an_exported_config_of_a_wrong_meta_or_name_names_its_file(tmp_path, field, value):
    """A `meta` that is no object died in `dict(...)` with "dictionary update sequence element #0 has length 1",
    naming neither the file nor the field."""
    exported = tmp_path / "export"
    TinyPointNetModule(width=8).save_pretrained(str(exported))
    cfg = json.loads((exported / "config.json").read_text())
    (exported / "config.json").write_text(json.dumps({**cfg, field: value}))
    with pytest.raises(ValueError, match=rf"config\.json: '{field}' must be an? "):
        load_model(exported)


def test_an_index_or_config_of_bytes_that_are_not_utf8_names_its_file(tmp_path, monkeypatch):
    """A UnicodeDecodeError escaped the JSON checks: `hub list` printed only "'utf-8' codec can't decode byte"."""
    hub = tmp_path / "hub"
    hub.mkdir()
    (hub / "index.json").write_bytes(b"\xff\xfe\x00")
    monkeypatch.setenv("FLOAFF_ZOO_HUB", str(hub))
    with pytest.raises(HubError, match=rf"{hub / 'index.json'}: not a readable JSON index"):
        load_registry()
    exported = tmp_path / "export"
    TinyPointNetModule(width=8).save_pretrained(str(exported))
    (exported / "config.json").write_bytes(b"\xff{}")
    with pytest.raises(ValueError, match=rf"{exported / 'config.json'}: unreadable JSON"):
        load_model(exported)


@pytest.mark.parametrize(
    "patch, said",
    [
        ({"hyper_parameters": [1]}, "its 'hyper_parameters' is a list, not a dict"),
        ({"state_dict": [1]}, "its 'state_dict' is a list, not a dict"),
        ({"hyper_parameters": {"_class_path": 5}}, "'_class_path' is a int, not a str"),
    ],
)
def test_a_checkpoint_of_wrong_types_is_named_by_push_and_load(tmp_path, capsys, patch, said):
    """A list of hyper_parameters or a state_dict pushed died in `dict(...)`/`.items()` (a traceback from `hub push`)
    and a `_class_path` of 5 in `import_model_class` ("argument of type 'int' is not iterable"), naming no file."""
    ckpt = _ckpt(tmp_path / "a.ckpt")
    torch.save({**torch.load(ckpt, weights_only=True), **patch}, ckpt)
    assert zoo_main(["hub", "push", str(ckpt), "--name", "tiny.bad.v1", "--class-path", TINY]) == 2
    err = capsys.readouterr().err
    assert f"{ckpt}: " in err and said in err
    if "_class_path" in said:
        with pytest.raises(ValueError, match=rf"{ckpt}: .*{said}"):
            load_model(ckpt)


def test_a_push_of_a_file_that_is_no_checkpoint_says_why_in_one_line(tmp_path, capsys):
    """torch's page of advice about weights_only was printed whole, not the reason."""
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"garbage")
    assert zoo_main(["hub", "push", str(junk), "--name", "tiny.junk.v1"]) == 2
    err = capsys.readouterr().err
    assert f"{junk}: not a readable weights-only checkpoint" in err and "documentation of torch.load" not in err


def test_a_hub_folder_from_the_environment_that_is_a_file_or_a_broken_link_is_named(tmp_path, monkeypatch, capsys):
    """Only --hub-dir was checked: FLOAFF_ZOO_HUB naming a file, or a link to nothing, ended a push in
    "[Errno 17] File exists", and `--hub-dir ''` pushed into the working folder."""
    ckpt = _ckpt(tmp_path / "a.ckpt")
    (tmp_path / "hubfile").write_text("x")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    for hub, said in ((tmp_path / "hubfile", "is a file"), (tmp_path / "loop", "a link to nothing")):
        monkeypatch.setenv("FLOAFF_ZOO_HUB", str(hub))
        assert zoo_main(["hub", "push", str(ckpt), "--name", "tiny.env.v1"]) == 2
        assert f"$FLOAFF_ZOO_HUB {hub}: {said}" in capsys.readouterr().err
    monkeypatch.chdir(tmp_path)
    assert zoo_main(["hub", "push", str(ckpt), "--name", "tiny.env.v1", "--hub-dir", ""]) == 2
    assert "--hub-dir is empty" in capsys.readouterr().err and not (tmp_path / "tiny.env.v1").exists()


def test_an_empty_or_non_string_name_is_refused_as_such(tmp_path, monkeypatch):
    """`load_model('')` read the working folder as an exported directory (Path('') is '.'), `load_model(None)` looked
    up the hub name 'None', and `get_entry(None)` died in close_names with "'NoneType' object has no attribute"."""
    monkeypatch.chdir(tmp_path)
    TinyPointNetModule(width=8).save_pretrained(str(tmp_path))
    with pytest.raises(UnknownWeightsError, match="an empty name"):
        load_model("")
    for bad in (None, 5):
        with pytest.raises(TypeError, match=rf"a str or os\.PathLike\), got {bad}"):
            load_model(bad)
        with pytest.raises(TypeError, match=rf"a hub name must be a str, got {bad}"):
            get_entry(bad)
    assert type(load_model(Path("."))).__name__ == "TinyPointNetModule"  # the working folder, named: still loads


@pytest.mark.parametrize("cmd", ["info", "pull", "verify"])
def test_hub_commands_given_an_empty_name_say_so(capsys, cmd):
    """`hub verify ''` verified every entry and exited 0; `info`/`pull` listed names an empty one 'may mean'."""
    assert zoo_main(["hub", cmd, ""]) == 2
    assert f"hub {cmd}: the name is empty" in capsys.readouterr().err


def test_an_index_nested_too_deep_for_json_names_its_file(tmp_path, monkeypatch, capsys):
    """json's RecursionError escaped the JSON checks: `hub list` printed a traceback from json.decoder."""
    hub = tmp_path / "hub"
    hub.mkdir()
    (hub / "index.json").write_text("[" * 100_000 + "]" * 100_000)
    monkeypatch.setenv("FLOAFF_ZOO_HUB", str(hub))
    with pytest.raises(HubError, match=rf"{hub / 'index.json'}: not a readable JSON index"):
        load_registry()
    exported = tmp_path / "export"
    TinyPointNetModule(width=8).save_pretrained(str(exported))
    (exported / "config.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ValueError, match=rf"{exported / 'config.json'}: unreadable JSON"):
        load_model(exported)


def test_a_checkpoint_of_odd_callbacks_or_an_unreadable_last_still_exports(tmp_path):
    """The best score is looked up in the pushed checkpoint, then in the run's newest last.ckpt: a list of callbacks
    or a text score ended the push in a traceback naming no file, as did a last.ckpt that became unreadable after the
    checkpoint was chosen; the export is sound without the score, and the skip is said."""
    from floaff_zoo.hub.export import _best_score

    ckdir = tmp_path / "run" / "version_0" / "checkpoints"
    best = _ckpt(ckdir / "epoch001.ckpt")
    state = torch.load(best, weights_only=True)
    cb = {"monitor": "val_rmse", "best_model_path": str(best)}
    for i, odd in enumerate(([1, 2], {"ModelCheckpoint{}": {**cb, "best_model_score": "0.1"}})):
        torch.save({**state, "callbacks": odd}, best)
        entry, _ = export_checkpoint(best, f"tiny.odd-callbacks{i}.v1", directory=tmp_path / "hub")
        assert entry.meta["metrics"] == {}
    torch.save({**state, "callbacks": {"ModelCheckpoint{}": {**cb, "best_model_score": 0.25}}}, best)
    entry, _ = export_checkpoint(best, "tiny.good-callbacks.v1", directory=tmp_path / "hub")
    assert entry.meta["metrics"] == pytest.approx({"val_rmse": 0.25})
    (ckdir / "last.ckpt").write_bytes(b"not a checkpoint")
    with pytest.warns(UserWarning, match=r"last.ckpt: not a readable checkpoint .*best validation score is not"):
        assert _best_score(best, {}, tmp_path / "run") == {}
