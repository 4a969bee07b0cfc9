"""Checkpoint hub: push/list/from_pretrained round trip, sha256 checks, offline errors, downloads (mocked)."""

import io
import json
import re
import sys
import types
from pathlib import Path

import pytest
import torch

from floaff_zoo import atomic
from floaff_zoo.cli import main as zoo_main
from floaff_zoo.contract import collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.hub import (
    ChecksumError,
    HubEntry,
    HubError,
    RegistryFormatError,
    UnknownWeightsError,
    WeightsNotFoundError,
    hub_dir,
    load_model,
    load_registry,
    register,
    resolve_state_dict,
    sha256_file,
)
from floaff_zoo.hub import io as hub_io
from floaff_zoo.hub.registry import unique_filename
from floaff_zoo.models.base import FloAffModule
from floaff_zoo.models.tiny import TinyPointNetModule

TINY = "floaff_zoo.models.tiny.TinyPointNetModule"
NAME = "tiny-pointnet.synthetic.v1"


class OtherTiny(FloAffModule):
    """A different model class, to check that from_pretrained refuses a foreign checkpoint."""

    def configure_models(self) -> None:
        self.net = torch.nn.Linear(2, 1)

    def forward(self, batch):
        return torch.sigmoid(self.net(batch["floor_xyz"][..., :2]).squeeze(-1))


@pytest.fixture(scope="module")
def batch():
    return collate_samples([make_synthetic_sample(i, num_points=128, floor_cells=6) for i in range(2)])


def _model(seed: int, width: int = 8) -> TinyPointNetModule:
    torch.manual_seed(seed)
    return TinyPointNetModule(width=width).eval()


def _lightning_ckpt(model: FloAffModule, path: Path, class_path: str = TINY, extra_state=None, callbacks=None) -> Path:
    """A checkpoint shaped like Lightning + LightningCLI write it (hparams carry _class_path)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {**model.state_dict(), **(extra_state or {})}
    hp = {**dict(model.hparams), "_class_path": class_path, "_instantiator": "lightning.pytorch.cli.instantiate_module"}
    torch.save({"state_dict": state, "hyper_parameters": hp, "callbacks": callbacks or {}, "epoch": 1}, path)
    return path


@pytest.fixture
def run_dir(tmp_path):
    """A run dir whose last.ckpt records a different best checkpoint (with teacher keys in it)."""
    ckdir = tmp_path / "run" / "version_0" / "checkpoints"
    best_model, last_model = _model(1), _model(2)
    teacher = {"teacher.net.head.0.weight": torch.ones(3, 3)}
    best = _lightning_ckpt(best_model, ckdir / "epoch001-val_rmse0.1200.ckpt", extra_state=teacher)
    cb = {
        "ModelCheckpoint{'monitor': 'val_rmse', 'mode': 'min'}": {
            "monitor": "val_rmse",
            "best_model_score": torch.tensor(0.12),
            "best_model_path": str(best),
        }
    }
    _lightning_ckpt(last_model, ckdir / "last.ckpt", callbacks=cb)
    return tmp_path / "run", best_model, last_model


def _push(run, name=NAME, *extra):
    return zoo_main(["hub", "push", str(run), "--name", name, "--dataset", "synthetic", "--license", "MIT", *extra])


def test_push_list_from_pretrained_round_trip(run_dir, batch, capsys):
    run, best_model, last_model = run_dir
    assert _push(run) == 0
    assert zoo_main(["hub", "list"]) == 0
    out = capsys.readouterr().out
    assert NAME in out and "TinyPointNetModule" in out
    assert next(x for x in out.splitlines() if x.startswith(NAME)).split()[2:5] == ["-", "-", "-"]  # no test report
    entry = load_registry()[NAME]
    assert entry.filename == unique_filename(NAME, entry.sha256, ".safetensors")
    assert entry.meta["metrics"] == pytest.approx({"val_rmse": 0.12})  # best score from the checkpoint
    export = hub_dir() / NAME
    cfg = json.loads((export / "config.json").read_text())
    assert cfg["class_path"] == TINY and cfg["init_args"]["width"] == 8 and "weights" not in cfg["init_args"]
    assert "# " + NAME in (export / "README.md").read_text()
    state, _ = resolve_state_dict(str(export / entry.filename))
    assert not any(k.startswith("teacher.") for k in state)  # the student does not carry its teacher

    with torch.no_grad():
        ref = best_model(batch)
        loaded = TinyPointNetModule.from_pretrained(NAME)
        assert torch.equal(loaded(batch), ref)  # the best checkpoint, not last
        assert not torch.allclose(last_model(batch), ref)
        init = TinyPointNetModule(width=8, weights=NAME).eval()
        assert torch.equal(init(batch), ref)
        assert torch.equal(TinyPointNetModule.from_pretrained(str(export))(batch), ref)  # exported dir
        assert torch.equal(FloAffModule.from_pretrained(NAME)(batch), ref)


def test_pushed_files_get_the_umask_mode_not_mkstemp_s(run_dir):
    """Weights and index are written through temp files; they must end up readable as a plain open makes them."""
    import os

    run, _, _ = run_dir
    old = os.umask(0o022)
    try:
        assert _push(run) == 0
    finally:
        os.umask(old)
    entry = load_registry()[NAME]
    for path in (hub_dir() / NAME / entry.filename, hub_dir() / "index.json"):
        assert path.stat().st_mode & 0o777 == 0o644, path


def test_push_uses_report_json_metrics(run_dir, tmp_path):
    run, _, _ = run_dir
    (run / "report.json").write_text(json.dumps({"metrics": {"test_rmse": 0.2, "test_sim": 0.7, "note": "x"}}))
    assert _push(run, "tiny.report.v1") == 0
    assert load_registry()["tiny.report.v1"].meta["metrics"] == {"test_rmse": 0.2, "test_sim": 0.7}
    # an explicit report (e.g. the test run's, which lands beside the fit run) wins over the run's own
    other = tmp_path / "elsewhere" / "report.json"
    other.parent.mkdir()
    other.write_text(json.dumps({"metrics": {"test_sr_all": 0.5, "test_rmse": 0.1}}))
    assert zoo_main(["hub", "push", str(run), "--name", "tiny.report.v2", "--report", str(other)]) == 0
    assert load_registry()["tiny.report.v2"].meta["metrics"] == {"test_sr_all": 0.5, "test_rmse": 0.1}
    assert zoo_main(["hub", "push", str(run), "--name", "tiny.report.v3", "--report", str(tmp_path / "no.json")]) == 2


def _report_of(path: Path, ckpt: str | None, sha: str | None, class_path: str = TINY, **metrics: float) -> Path:
    """A report.json shaped like TestReport writes it: the checkpoint it tested, the model class, test metrics."""
    path.parent.mkdir(parents=True, exist_ok=True)
    checkpoint = None if ckpt is None else {"path": ckpt, "sha256": sha}
    rep = {"schema": "floaff-zoo/report", "model": {"class_path": class_path}, "checkpoint": checkpoint}
    path.write_text(json.dumps({**rep, "metrics": metrics or {"test_rmse": 0.3}}))
    return path


def _best_ckpt(run: Path) -> Path:
    return next(run.rglob("epoch001-*.ckpt"))


def test_push_refuses_a_report_of_another_checkpoint_or_class(run_dir, tmp_path, capsys):
    """A --report of another checkpoint (its sha256) or model class would record that model's test results."""
    run, _, _ = run_dir
    best = _best_ckpt(run)
    sha, other = sha256_file(best), "ab" * 32
    votenet = "floaff_zoo.models.votenet.VoteNetModule"
    malformed = tmp_path / "field" / "report.json"
    malformed.parent.mkdir()
    malformed.write_text(json.dumps({"checkpoint": "best.ckpt", "metrics": {"test_rmse": 0.3}}))
    cases = {  # report -> what the error must name besides the report (both sha256s, both classes, the field)
        _report_of(tmp_path / "sha" / "report.json", "runs/votenet/best.ckpt", other): (other, sha),
        _report_of(tmp_path / "class" / "report.json", str(best), sha, votenet): (votenet, TINY),
        malformed: ("'checkpoint' field is a str",),
    }
    for i, (report, named) in enumerate(cases.items()):
        assert _push(run, f"tiny.bad{i}.v1", "--report", str(report)) == 2, report
        err = capsys.readouterr().err
        assert all(s in err for s in (str(report), "--report", *named)), err
        assert f"tiny.bad{i}.v1" not in load_registry()
    latin = tmp_path / "latin" / "report.json"  # bytes that are no UTF-8: the codec's message named no file
    latin.parent.mkdir()
    latin.write_bytes(b"\xff\xfe{}")
    assert _push(run, "tiny.latin.v1", "--report", str(latin)) == 2
    assert f"{latin}: unreadable report" in capsys.readouterr().err
    assert "tiny.latin.v1" not in load_registry()


def test_push_records_a_report_only_of_its_own_checkpoint(run_dir, tmp_path):
    """A report found in the run but of another checkpoint is left out (the best validation score is recorded);
    reports that cannot be compared are used: no checkpoint, or weights given by hub name or weights file."""
    run, _, _ = run_dir
    best = _best_ckpt(run)
    _report_of(run / "report.json", str(run / "last.ckpt"), "cd" * 32, test_rmse=0.9)
    with pytest.warns(UserWarning, match="left out of the metrics") as caught:
        assert _push(run, "tiny.found.v1") == 0
    assert str(run / "report.json") in str(caught[0].message)
    assert load_registry()["tiny.found.v1"].meta["metrics"] == pytest.approx({"val_rmse": 0.12})
    legit = {
        "own": (str(best), sha256_file(best), "floaff_zoo.models.TinyPointNetModule"),  # a re-export of the class
        "none": (None, None, TINY),
        "hub": ("tiny.synthetic.v0", None, TINY),
        "file": ("exports/tiny/model.safetensors", "ef" * 32, TINY),
    }
    for case, (ckpt, sha, cls) in legit.items():
        report = _report_of(tmp_path / case / "report.json", ckpt, sha, cls, test_rmse=0.25)
        assert _push(run, f"tiny.{case}.v1", "--report", str(report)) == 0, case
        assert load_registry()[f"tiny.{case}.v1"].meta["metrics"] == {"test_rmse": 0.25}, case


def test_info_and_verify_cli(run_dir, capsys):
    run, _, _ = run_dir
    assert _push(run) == 0
    capsys.readouterr()
    assert zoo_main(["hub", "info", NAME]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["name"] == NAME and info["class_path"] == TINY and info["local_file"].endswith(info["filename"])
    assert zoo_main(["hub", "verify", NAME]) == 0
    assert f"OK        {NAME}" in capsys.readouterr().out
    weights = Path(info["local_file"])
    weights.write_bytes(weights.read_bytes()[:-1] + b"\x00")
    assert zoo_main(["hub", "verify"]) == 1
    assert "MISMATCH" in capsys.readouterr().out
    assert zoo_main(["hub", "info", "tiny-pointnet.synthetic.v2"]) == 2
    assert NAME in capsys.readouterr().err  # close match suggested


def test_tampered_file_is_refused(run_dir):
    run, _, _ = run_dir
    assert _push(run) == 0
    entry = load_registry()[NAME]
    weights = hub_dir() / NAME / entry.filename
    data = bytearray(weights.read_bytes())
    data[-5] ^= 0xFF  # flip bits inside a tensor payload: still a valid safetensors file
    weights.write_bytes(bytes(data))
    with pytest.raises(ChecksumError, match=entry.filename):
        TinyPointNetModule.from_pretrained(NAME)
    with pytest.raises(ChecksumError, match=entry.filename):
        TinyPointNetModule(width=8, weights=NAME)
    with pytest.raises(ChecksumError, match="config.json"):  # the exported dir records the hash too
        TinyPointNetModule.from_pretrained(str(hub_dir() / NAME))


def _safetensors(model: FloAffModule, path: Path) -> Path:
    from safetensors.torch import save_file

    path.parent.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(path))
    return path


def _url_entry(name: str, file: Path, url: str, width: int = 8) -> HubEntry:
    sha = sha256_file(file)
    return HubEntry(
        name=name,
        class_path=TINY,
        filename=unique_filename(name, sha, file.suffix),
        sha256=sha,
        init_args={"width": width},
        source={"kind": "url", "url": url},
        meta={},
    )


@pytest.fixture
def transport(monkeypatch):
    """Replace the URL transport by a dict url -> bytes; counts calls."""
    served: dict[str, bytes] = {}
    calls: list[str] = []

    def fake_open(url, timeout=60.0):
        calls.append(url)
        if url not in served:
            raise OSError(f"no route to {url}")
        return io.BytesIO(served[url])

    monkeypatch.setattr(hub_io, "_open_url", fake_open)
    return served, calls


def test_same_basename_does_not_collide(tmp_path, batch, transport, monkeypatch):
    served, calls = transport
    a, b = _model(10), _model(11)
    fa = _safetensors(a, tmp_path / "a" / "model.safetensors")
    fb = _safetensors(b, tmp_path / "b" / "model.safetensors")
    ea = _url_entry("tiny.a.v1", fa, "https://example.org/a/model.safetensors")
    eb = _url_entry("tiny.b.v1", fb, "https://example.org/b/model.safetensors")
    served[ea.source["url"]], served[eb.source["url"]] = fa.read_bytes(), fb.read_bytes()
    register(ea)
    register(eb)
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "0")
    with torch.no_grad():
        out_a = TinyPointNetModule.from_pretrained("tiny.a.v1")(batch)
        out_b = TinyPointNetModule.from_pretrained("tiny.b.v1")(batch)
        assert torch.equal(out_a, a(batch)) and torch.equal(out_b, b(batch))
        assert not torch.allclose(out_a, out_b)
    assert (hub_dir() / ea.filename).is_file() and (hub_dir() / eb.filename).is_file()
    assert ea.filename != eb.filename and len(calls) == 2
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "1")  # cached now: offline works, no transport call
    with torch.no_grad():
        assert torch.equal(TinyPointNetModule.from_pretrained("tiny.a.v1")(batch), out_a)
    assert len(calls) == 2


def test_offline_missing_file_names_file_and_folder(tmp_path, transport, monkeypatch):
    _, calls = transport
    f = _safetensors(_model(3), tmp_path / "m.safetensors")
    e = _url_entry("tiny.offline.v1", f, "https://example.org/m.safetensors")
    register(e)
    with pytest.raises(WeightsNotFoundError) as err:
        TinyPointNetModule.from_pretrained("tiny.offline.v1")
    assert e.filename in str(err.value) and str(hub_dir()) in str(err.value)
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "0")
    with pytest.raises(WeightsNotFoundError, match="allow_download=False"):
        resolve_state_dict("tiny.offline.v1", allow_download=False)
    assert calls == []
    # pre-seeding torch.hub's cache under the unique file name works offline
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "1")
    seeded = Path(torch.hub.get_dir()) / "checkpoints" / e.filename
    seeded.parent.mkdir(parents=True)
    seeded.write_bytes(f.read_bytes())
    _, info = resolve_state_dict("tiny.offline.v1")
    assert info["source"] == str(seeded) and info["sha256"] == e.sha256


def test_download_hash_mismatch_is_rejected_and_not_cached(tmp_path, transport, monkeypatch):
    served, calls = transport
    good = _safetensors(_model(4), tmp_path / "good.safetensors")
    e = _url_entry("tiny.dl.v1", good, "https://example.org/r/0123/good.safetensors")
    register(e)
    served[e.source["url"]] = _safetensors(_model(5), tmp_path / "evil.safetensors").read_bytes()
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "0")
    with pytest.raises(ChecksumError, match=e.filename):
        TinyPointNetModule.from_pretrained("tiny.dl.v1")
    assert len(calls) == 1
    assert not any(hub_dir().glob(f"*{e.filename}*"))  # neither the file nor a .part leftover
    served[e.source["url"]] = good.read_bytes()
    assert zoo_main(["hub", "pull", "tiny.dl.v1"]) == 0
    assert sha256_file(hub_dir() / e.filename) == e.sha256


def test_hf_download_pinned_revision(tmp_path, monkeypatch, batch):
    model = _model(6)
    f = _safetensors(model, tmp_path / "model.safetensors")
    sha = sha256_file(f)
    rev = "a" * 40
    e = HubEntry(
        name="tiny.hf.v1",
        class_path=TINY,
        filename=unique_filename("tiny.hf.v1", sha, ".safetensors"),
        sha256=sha,
        init_args={"width": 8},
        source={"kind": "hf", "repo": "org/tiny", "revision": rev, "path_in_repo": "model.safetensors"},
    )
    register(e)
    seen = []

    def hf_hub_download(repo_id, filename, revision, local_dir):
        seen.append((repo_id, filename, revision))
        dst = Path(local_dir) / filename
        dst.write_bytes(payload)
        dst.chmod(0o600)  # owner-only, as a client's temp file may be
        return str(dst)

    fake = types.ModuleType("huggingface_hub")
    fake.hf_hub_download = hf_hub_download
    monkeypatch.setitem(sys.modules, "huggingface_hub", fake)
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "0")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")  # huggingface_hub's own switch is honoured too
    with pytest.raises(WeightsNotFoundError, match="HF_HUB_OFFLINE"):
        resolve_state_dict("tiny.hf.v1")
    monkeypatch.delenv("HF_HUB_OFFLINE")
    payload = b"not the file"
    with pytest.raises(ChecksumError):
        resolve_state_dict("tiny.hf.v1")
    assert not any(p.name not in ("index.json", ".index.lock") for p in hub_dir().iterdir())  # nothing cached
    payload = f.read_bytes()
    with torch.no_grad():
        assert torch.equal(TinyPointNetModule.from_pretrained("tiny.hf.v1")(batch), model(batch))
    assert seen[-1] == ("org/tiny", "model.safetensors", rev)
    # kept with the mode a plain open gives, as every other file of the hub (others sharing it can read it)
    assert (hub_dir() / e.filename).stat().st_mode & 0o777 == 0o666 & ~atomic._umask()
    (hub_dir() / e.filename).unlink()
    monkeypatch.setitem(sys.modules, "huggingface_hub", None)  # not installed
    with pytest.raises(HubError, match="pip install huggingface_hub"):
        resolve_state_dict("tiny.hf.v1")


def test_other_model_class_is_a_type_error(tmp_path):
    ckpt = _lightning_ckpt(OtherTiny(), tmp_path / "other.ckpt", class_path=f"{OtherTiny.__module__}.OtherTiny")
    with pytest.raises(TypeError, match="OtherTiny"):
        TinyPointNetModule.from_pretrained(str(ckpt))
    assert isinstance(FloAffModule.from_pretrained(str(ckpt)), OtherTiny)


def test_an_error_of_the_model_class_keeps_its_class_and_names_the_file(tmp_path, monkeypatch):
    """A ValueError the model's constructor raises is re-raised naming the checkpoint; a subclass of it (a
    ChecksumError from a weights file the model loads itself, CFAR's AxisNet) was turned into a plain ValueError."""
    from lightning.fabric.utilities.exceptions import MisconfigurationException

    ckpt = _lightning_ckpt(_model(3), tmp_path / "tiny.ckpt")
    for error in (ChecksumError("axisnet.ckpt: sha256 differs"), ValueError("width must be >= 1")):

        def refuse(self, *args, error=error, **kwargs):
            raise error

        monkeypatch.setattr(TinyPointNetModule, "__init__", refuse)
        with pytest.raises(type(error)) as info:
            TinyPointNetModule.from_pretrained(str(ckpt))
        assert type(info.value) is type(error) and str(info.value) == f"{ckpt}: {error}"
        assert info.value.__cause__ is error
    monkeypatch.setattr(TinyPointNetModule, "__init__", lambda self, *a, **k: (_ for _ in ()).throw(KeyError("x")))
    with pytest.raises(KeyError):  # anything else goes through as it is
        TinyPointNetModule.from_pretrained(str(ckpt))

    class Strict(ValueError):  # an exception whose class cannot be rebuilt from its args
        def __init__(self, field: str, value: int) -> None:
            super().__init__(f"{field} refuses {value}")

    monkeypatch.setattr(TinyPointNetModule, "__init__", lambda self, *a, **k: (_ for _ in ()).throw(Strict("w", 0)))
    with pytest.raises(ValueError, match=f"{ckpt}: w refuses 0"):  # not a TypeError from the handler
        TinyPointNetModule.from_pretrained(str(ckpt))
    misconf = MisconfigurationException("no optimizer")
    monkeypatch.setattr(TinyPointNetModule, "__init__", lambda self, *a, **k: (_ for _ in ()).throw(misconf))
    with pytest.raises(MisconfigurationException, match=f"{ckpt}: no optimizer"):
        TinyPointNetModule.from_pretrained(str(ckpt))


def test_untrusted_class_paths_are_not_imported(tmp_path):
    m = _model(7)
    for path in ("untrusted_pkg_floaff_xyz.Model", "os.system"):
        ckpt = _lightning_ckpt(m, tmp_path / f"{path}.ckpt", class_path=path)
        with pytest.raises(HubError, match="outside floaff_zoo|not a model of the zoo"):
            TinyPointNetModule.from_pretrained(str(ckpt))
    assert "untrusted_pkg_floaff_xyz" not in sys.modules


def test_code_in_pickle_is_refused(tmp_path):
    bad = tmp_path / "bad.ckpt"
    torch.save({"state_dict": {}, "hyper_parameters": {"x": OtherTiny}}, bad)
    with pytest.raises(ValueError, match="weights-only"):
        resolve_state_dict(str(bad))


def test_unknown_name_and_missing_path():
    register(
        HubEntry(
            name="cfar-pfal.floaff-sim-layouts.v1",
            class_path=TINY,
            sha256="0" * 64,
            filename="cfar-pfal.floaff-sim-layouts.v1-00000000.safetensors",
        )
    )
    with pytest.raises(UnknownWeightsError, match="cfar-pfal.floaff-sim-layouts.v1"):
        resolve_state_dict("cfar-pfal.floaff-sim-layout.v1")
    with pytest.raises(FileNotFoundError, match="nowhere/model.ckpt"):
        resolve_state_dict("nowhere/model.ckpt")


def test_an_unknown_name_suggests_the_entries_it_begins_newest_version_first(monkeypatch):
    """A model's name alone ('alpha') suggested none of its entries (too short for difflib) but the index's first ten
    names, all of other models; a name without its version listed an old version first (v2 before v10); a name
    typed in capitals ranked another model's entry above the one it spells."""
    from floaff_zoo.hub import get_entry, registry

    monkeypatch.setattr(registry, "SHIPPED_INDEX", hub_dir() / "no-shipped-index.json")
    layouts, styles = "floaff-dense-layouts", "floaff-dense-styles"
    names = [f"aaa-{i}.{layouts}.v1" for i in range(12)] + [f"beta.{layouts}.v1", f"alpha-x.{layouts}.v1"]
    names += [f"alpha.{layouts}.v1", f"alpha.{layouts}.v2", f"alpha.{layouts}.v10", f"alpha.{styles}.v3"]
    for name in names:
        register(HubEntry(name=name, class_path=TINY, sha256="0" * 64, filename=f"{name}-00000000.safetensors"))

    def suggested(name: str) -> list[str]:
        with pytest.raises(UnknownWeightsError) as err:
            get_entry(name)
        message = str(err.value)
        assert repr(name) in message and "did you mean" in message, message
        return re.findall(r"'([a-z0-9.-]+)'", message.split("did you mean", 1)[1].split("?", 1)[0])

    assert suggested("alpha")[:3] == [f"alpha.{layouts}.v10", f"alpha.{styles}.v3", f"alpha-x.{layouts}.v1"]
    assert suggested(f"alpha.{layouts}")[0] == f"alpha.{layouts}.v10"
    assert suggested(f"ALPHA.{layouts}.v2")[0] == f"alpha.{layouts}.v2"
    # a version the entry never had: its versions newest first (difflib ranked v1 and v2 above v10 for v99)
    assert suggested(f"alpha.{layouts}.v99")[:3] == [f"alpha.{layouts}.v{n}" for n in (10, 2, 1)]


@pytest.mark.parametrize(
    "patch, field",
    [
        ({"filename": "x.safetensors"}, "hash prefix"),
        ({"sha256": "abc"}, "64-hex"),
        ({"source": {"kind": "hf", "repo": "org/x", "revision": "main"}}, "pinned 40-hex"),
        ({"source": {"kind": "url", "url": "https://huggingface.co/o/r/resolve/main/x.safetensors"}}, "pin"),
        ({"init_args": {"weights": "other.v1"}}, "weights"),
        ({"meta": {"metrics": [0.5]}}, "'meta.metrics' must be an object"),  # `hub list` died in `.get`
    ],
)
def test_malformed_user_index_names_file_and_field(patch, field):
    sha = "1" * 64
    raw = {"name": "tiny.bad.v1", "class_path": TINY, "filename": f"tiny.bad.v1-{sha[:8]}.safetensors", "sha256": sha}
    path = hub_dir() / "index.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"version": 1, "entries": [{**raw, **patch}]}))
    with pytest.raises(RegistryFormatError, match=field) as err:
        load_registry()
    assert str(path) in str(err.value)


def test_shipped_index_is_valid():
    from floaff_zoo.hub import sha256_file
    from floaff_zoo.hub.registry import SHIPPED_INDEX, read_index

    for e in read_index(SHIPPED_INDEX):
        if e.source["kind"] == "local":  # shipped inside the package, next to the index
            path = Path(SHIPPED_INDEX).parent / e.source["path"]
            assert path.is_file() and sha256_file(path) == e.sha256, e.name
        else:
            assert e.source["kind"] in ("url", "hf")  # otherwise it must be downloadable


@pytest.fixture(scope="module")
def shipped_entries():
    from floaff_zoo.hub.registry import SHIPPED_INDEX, read_index

    return [e for e in read_index(SHIPPED_INDEX) if e.source["kind"] == "local"]


def test_every_shipped_entry_loads(shipped_entries, batch):
    """The shipped entries and export folders were written before the `train` group (training args flat):
    loading moves those into `train`, and the weights load strictly."""
    from floaff_zoo.hub import load_model
    from floaff_zoo.hub.registry import SHIPPED_INDEX

    assert shipped_entries
    for e in shipped_entries:
        recorded = e.init_args.get("train") or e.init_args  # flat (old) or grouped
        by_name = load_model(e.name)
        by_dir = load_model(Path(SHIPPED_INDEX).parent / e.name)
        for m in (by_name, by_dir):
            assert f"{type(m).__module__}.{type(m).__name__}" == e.class_path
            assert "lr" not in m.hparams and m.train_cfg.lr == recorded["lr"], e.name
            assert m.train_cfg.loss == recorded["loss"] and m.train_cfg.scheduler == recorded["scheduler"]
        with torch.no_grad():
            assert torch.equal(by_name(batch), by_dir(batch)), e.name


def test_push_upload_pins_the_commit(run_dir, monkeypatch):
    run, _, _ = run_dir
    uploads = []

    class FakeApi:
        def create_repo(self, repo_id, repo_type, exist_ok, private):
            assert exist_ok

        def upload_folder(self, folder_path, repo_id, repo_type, commit_message):
            uploads.append(sorted(p.name for p in Path(folder_path).iterdir()))
            return types.SimpleNamespace(oid="b" * 40)

    fake = types.ModuleType("huggingface_hub")
    fake.HfApi = FakeApi
    monkeypatch.setitem(sys.modules, "huggingface_hub", fake)
    assert _push(run, NAME, "--upload", "--repo", "org/tiny") == 2  # offline: refused before exporting
    assert uploads == [] and NAME not in load_registry()
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "0")
    assert _push(run, NAME, "--upload", "--repo", "org/tiny") == 0
    entry = load_registry()[NAME]
    assert entry.source == {"kind": "hf", "repo": "org/tiny", "revision": "b" * 40, "path_in_repo": entry.filename}
    assert uploads == [sorted(["README.md", "config.json", entry.filename])]


@pytest.mark.parametrize("flags", [["--repo", "org/tiny"], ["--private"]], ids=["repo", "private"])
def test_push_refuses_upload_options_without_upload(run_dir, capsys, flags):
    """--repo and --private say where and how to upload: without --upload they were ignored without a word, and a push
    meant to publish a checkpoint exported it locally only."""
    run, _, _ = run_dir
    assert _push(run, NAME, *flags) == 2
    err = capsys.readouterr().err
    assert flags[0] in err and "only apply to --upload" in err
    assert NAME not in load_registry() and not (hub_dir() / NAME).exists()  # refused before exporting


def test_a_failed_download_is_one_hub_error_naming_the_file_and_the_folder(tmp_path, monkeypatch, capsys):
    """No network, a refused connection, a 404: the loader says which file to put where (a bare URLError named
    neither), and `hub pull` prints one line (exit 2), not a traceback."""
    import urllib.error

    e = _url_entry("tiny.nonet.v1", _safetensors(_model(0), tmp_path / "m.safetensors"), "https://example.org/m")
    register(e)

    def no_network(url, timeout=60.0):
        raise urllib.error.URLError("[Errno 111] Connection refused")

    monkeypatch.setattr(hub_io, "_open_url", no_network)
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "0")
    with pytest.raises(WeightsNotFoundError) as err:
        hub_io.fetch("tiny.nonet.v1")
    assert e.filename in str(err.value) and str(hub_dir()) in str(err.value) and "Connection refused" in str(err.value)
    assert zoo_main(["hub", "pull", "tiny.nonet.v1"]) == 2
    assert "Connection refused" in capsys.readouterr().err
    assert not list(hub_dir().glob("*.part"))


def test_predict_keeps_the_hub_error_of_a_registered_name_whose_file_is_missing(tmp_path):
    """predict called a registered name whose weights are not here 'neither a checkpoint file nor a known hub name'."""
    from floaff_zoo.predict import resolve_model

    e = _url_entry("tiny.missing.v1", _safetensors(_model(0), tmp_path / "m.safetensors"), "https://example.org/m")
    register(e)  # offline (conftest): a known name, its file not here
    with pytest.raises(WeightsNotFoundError) as err:
        resolve_model("tiny.missing.v1")
    assert "not a known hub name" not in str(err.value) and e.filename in str(err.value)


@pytest.mark.parametrize("cmd", ["info", "pull", "verify"])
def test_hub_commands_given_a_path_say_they_take_a_name(tmp_path, capsys, cmd):
    """They answered that an exported folder 'is not a checkpoint file, an exported directory, nor a registered
    hub name'."""
    folder = tmp_path / "exported"
    _model(0).save_pretrained(folder)
    assert zoo_main(["hub", cmd, str(folder)]) == 2
    err = capsys.readouterr().err
    assert "takes a registered name" in err and "not a checkpoint file, an exported directory" not in err


def test_the_weights_file_of_an_exported_folder_named_directly_is_checked_too(tmp_path):
    """The folder's config.json records the weights' sha256 and loading the folder checks it; naming the weights
    file itself loaded an altered file without a word."""
    from safetensors.torch import load_file, save_file

    folder = tmp_path / "exported"
    _model(0).save_pretrained(folder)
    cfg = json.loads((folder / "config.json").read_text())
    weights = folder / cfg.get("weights", "model.safetensors")
    assert cfg.get("sha256")
    assert load_model(str(weights)) is not None  # intact: loads
    state = load_file(str(weights))
    key = next(iter(state))
    state[key] = torch.zeros_like(state[key])
    save_file(state, str(weights))  # still a valid safetensors file, other numbers
    with pytest.raises(ChecksumError, match="config.json"):
        load_model(str(weights))
    with pytest.raises(ChecksumError):
        load_model(str(folder))


def test_a_checkpoint_beside_an_unrelated_config_json_loads(tmp_path):
    """Any weights file read the config.json of its folder, so a .pt or .ckpt saved beside some other (or broken)
    config.json failed to load with that file's error; only an export's safetensors file is checked against it."""
    state = _model(0).state_dict()
    torch.save(state, tmp_path / "weights.pt")
    (tmp_path / "config.json").write_text("{not json")
    loaded, _ = hub_io.resolve_state_dict(str(tmp_path / "weights.pt"))
    assert loaded.keys() == state.keys()


def test_an_exported_config_with_a_malformed_sha256_is_named(tmp_path):
    folder = tmp_path / "exported"
    _model(0).save_pretrained(folder)
    cfg = json.loads((folder / "config.json").read_text())
    (folder / "config.json").write_text(json.dumps({**cfg, "sha256": 12}))
    with pytest.raises(ValueError, match=r"config.json: 'sha256' must be 64 hex digits, got 12"):
        load_model(str(folder))
