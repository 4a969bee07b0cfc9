"""``floaff-zoo hub push`` over a registered name: a refused push leaves the registered entry as it was."""

from pathlib import Path

import pytest
import torch

from floaff_zoo.cli import main as zoo_main
from floaff_zoo.hub import HubError, hub_dir, load_model, load_registry
from floaff_zoo.hub import export as hub_export
from floaff_zoo.models.tiny import TinyPointNetModule

NAME = "tiny-pointnet.synthetic.v1"
TINY = "floaff_zoo.models.tiny.TinyPointNetModule"


def _ckpt(path: Path, seed: int, width: int = 8, extra_state: dict | None = None) -> Path:
    """A Lightning-shaped checkpoint of a tiny model (hparams carry ``_class_path``)."""
    torch.manual_seed(seed)
    model = TinyPointNetModule(width=width)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {**model.state_dict(), **(extra_state or {})}
    torch.save({"state_dict": state, "hyper_parameters": {**dict(model.hparams), "_class_path": TINY}}, path)
    return path


def _push(ckpt: Path, name: str = NAME, *extra: str) -> int:
    return zoo_main(["hub", "push", str(ckpt), "--name", name, *extra])


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def registered(tmp_path):
    """``NAME`` pushed once; returns (the hub files after it, the entry)."""
    assert _push(_ckpt(tmp_path / "first.ckpt", seed=1)) == 0
    return _snapshot(hub_dir()), load_registry()[NAME]


def test_push_that_does_not_load_back_leaves_the_entry(registered, tmp_path, capsys):
    before, entry = registered
    bad = _ckpt(tmp_path / "extra.ckpt", seed=2, width=16, extra_state={"net.extra_buffer": torch.ones(2)})
    assert _push(bad, NAME, "--replace") == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "net.extra_buffer" in err and ".push-" not in err
    assert _snapshot(hub_dir()) == before  # weights, config.json, model card and index untouched; no temp left
    assert load_registry()[NAME].sha256 == entry.sha256
    assert load_model(NAME).hparams.width == 8


def test_push_refused_by_the_index_leaves_the_entry(registered, tmp_path, monkeypatch):
    before, _entry = registered

    def refuse(*args, **kwargs):
        raise HubError("index refused")

    monkeypatch.setattr(hub_export, "register", refuse)
    assert _push(_ckpt(tmp_path / "second.ckpt", seed=2, width=16), NAME, "--replace") == 2
    assert _snapshot(hub_dir()) == before  # the new weights file was taken back


def test_invalid_name_writes_nothing(tmp_path):
    assert _push(_ckpt(tmp_path / "a.ckpt", seed=1), name="Bad Name") == 2
    assert not hub_dir().exists() or not any(hub_dir().iterdir())


def test_a_taken_name_is_pushed_over_only_with_replace(registered, tmp_path, capsys):
    """A push under a registered name deleted its earlier weights, and one under a shipped name hid the shipped
    checkpoint from every load by that name, without a word: both are refused unless --replace."""
    before, _old = registered
    second = _ckpt(tmp_path / "second.ckpt", seed=2, width=16)
    assert _push(second) == 2
    assert "is registered already" in capsys.readouterr().err and _snapshot(hub_dir()) == before
    shipped = "cfar-pfal.floaff-small-layouts.v2"
    assert _push(second, shipped) == 2
    assert "shipped with the package" in capsys.readouterr().err and _snapshot(hub_dir()) == before
    retired = "cfar-pfal.floaff-dense-layouts.v1"
    assert _push(second, retired) == 2 and _snapshot(hub_dir()) == before
    assert _push(second, shipped, "--replace") == 0 and load_model(shipped).hparams.width == 16


def test_a_name_registered_while_a_push_ran_is_not_pushed_over(registered, tmp_path, monkeypatch, capsys):
    """The name check ran before the seconds of loading and staging, without the index lock, and the index then took
    the entry with overwrite on: a second push of one new name deleted the first's weights. The index now refuses it
    under its lock (here the early check is skipped, as a push that passed it before the other one registered)."""
    before, _entry = registered
    monkeypatch.setattr(hub_export, "check_name_free", lambda *args, **kwargs: None)
    assert _push(_ckpt(tmp_path / "second.ckpt", seed=2, width=16)) == 2
    assert "exists already" in capsys.readouterr().err
    assert _snapshot(hub_dir()) == before


def test_push_over_a_name_replaces_it(registered, tmp_path):
    _before, old = registered
    assert _push(_ckpt(tmp_path / "second.ckpt", seed=2, width=16), NAME, "--replace") == 0
    new = load_registry()[NAME]
    folder = hub_dir() / NAME
    assert new.sha256 != old.sha256
    assert sorted(p.name for p in folder.iterdir()) == sorted(["README.md", "config.json", new.filename])
    assert load_model(NAME).hparams.width == 16 and load_model(folder).hparams.width == 16
    assert not [p for p in hub_dir().iterdir() if p.name.startswith(".push-")]


def _register_many(directory: str, prefix: str, n: int) -> None:
    from floaff_zoo.hub.registry import HubEntry, register

    for i in range(n):
        name = f"tiny.{prefix}{i}.v1"
        entry = HubEntry(name, TINY, f"{name}-{'0' * 8}.safetensors", "0" * 64, {}, {"kind": "local"}, {})
        register(entry, directory)


def test_pushes_at_once_keep_every_entry(tmp_path):
    """Each register read the index, added its entry and wrote it back: of two processes' 60 pushes each, some
    vanished from the index."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    procs = [ctx.Process(target=_register_many, args=(str(tmp_path), p, 60)) for p in "ab"]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [0, 0]
    assert len(load_registry(tmp_path)) - len(load_registry(tmp_path / "empty")) == 120


def test_a_name_that_ends_like_a_weights_file_is_refused(tmp_path, capsys):
    """`tiny.syn.pt` was pushed, then `hub info tiny.syn.pt` took it for a path."""
    assert _push(_ckpt(tmp_path / "a.ckpt", seed=1), "tiny.syn.pt") == 2
    assert "ends like a weights file" in capsys.readouterr().err and "tiny.syn.pt" not in load_registry()


def test_a_name_of_the_hubs_own_files_is_refused(tmp_path, capsys):
    """`hub push --name index.json` made the entry folder <hub>/index.json/, the index's own path: the push failed with
    a bare Errno 21, every later push failed the same way, and list/load read the folder as an empty user index."""
    from floaff_zoo.hub import RegistryFormatError

    ckpt = _ckpt(tmp_path / "a.ckpt", seed=1)
    for name in ("index.json", "retired.json", "io.py"):
        assert _push(ckpt, name) == 2
        assert "ends like one of the hub's own files" in capsys.readouterr().err
    assert not (hub_dir() / "index.json").exists()
    assert _push(ckpt) == 0 and NAME in load_registry()  # the hub still takes pushes
    broken = tmp_path / "broken_hub"
    (broken / "index.json").mkdir(parents=True)  # as the old push left it
    with pytest.raises(RegistryFormatError, match=r"broken_hub/index\.json: not a file"):
        load_registry(broken)
