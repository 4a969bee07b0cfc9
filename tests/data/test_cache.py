"""The per-sample cache and RecordDataset (floaff_zoo.data.cache): write failures, content hashing, run-time errors."""

import errno
import os
import warnings

import pytest
import torch

import floaff_zoo.data.cache as cache_mod
from floaff_zoo.data.cache import RecordDataset
from floaff_zoo.data.moma_kitchen import LABEL_TXT, MoMaKitchenDataModule
from floaff_zoo.data.readers import DataError, SampleRecord, SkipLog
from floaff_zoo.data.synthetic import make_synthetic_sample


def _dm(root, **kw):
    args = dict(root=str(root), val_fraction=0.34, batch_size=2, num_points=256, cache=False)
    args.update(kw)
    return MoMaKitchenDataModule(**args)


def _cache_warnings(caught) -> list[str]:
    return [str(w.message) for w in caught if "sample cache" in str(w.message)]


def _full_disk(monkeypatch):
    """Every cache write fails as on a full disk (the folder itself can be made)."""

    def full(path, write, durable=False):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(cache_mod, "atomic_write", full)


@pytest.mark.parametrize("why", ["under_a_file", "disk_full"])
def test_an_unwritable_cache_serves_every_sample_from_its_sources(moma_root, tmp_path, monkeypatch, why):
    """A cache write's OSError made the setup check skip a good sample as an OSError and a failing ``.skip`` marker
    crashed ``build``; with validate false every access failed. Now one warning names the folder, nothing is
    written, and the splits are those of an uncached run."""
    root, _ = moma_root
    ref = _dm(root)
    ref.setup("fit")
    ref.setup("test")
    cache_dir = tmp_path / "afile" / "cache"
    if why == "under_a_file":
        (tmp_path / "afile").write_text("not a folder")
    else:
        _full_disk(monkeypatch)
    dm = _dm(root, cache=True, cache_dir=str(cache_dir))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dm.setup("fit")
        dm.setup("test")
    msgs = _cache_warnings(caught)
    assert len(msgs) == 3  # once per split's dataset, not once per sample
    assert all(str(cache_dir) in m and "cannot be written" in m and "\n" not in m for m in msgs)
    for split in ("train", "val", "test"):
        assert [r.key for r in dm.datasets[split].records] == [r.key for r in ref.datasets[split].records]
        assert dict(dm.skips[split].counts) == dict(ref.skips[split].counts)
    assert not list(tmp_path.rglob("*.pt")) and not list(tmp_path.rglob("*.skip"))
    # validate false: every access reads the sources (no sample is replaced), with one warning
    lazy = _dm(root, cache=True, cache_dir=str(cache_dir), validate=False)
    lazy.setup("test")
    ds, good = lazy.datasets["test"], ref.datasets["test"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = {ds.records[i].key: ds[i] for i in range(len(ds))}
    assert len(_cache_warnings(caught)) == 1 and ds.runtime_failures == 0
    for i in range(len(good)):
        s = got[good.records[i].key]
        assert "replaces" not in s["meta"] and torch.equal(s["scene_xyz"], good[i]["scene_xyz"])


@pytest.mark.parametrize("workers", [0, 2])
def test_content_hash_reads_the_sources_once_at_setup(moma_root, monkeypatch, workers):
    """``cache_hash: content`` hashed every source file's bytes again at every access (a cache hit read as much as a
    parse). Now setup reads them once per record (in its worker processes too) and accesses reuse the name; an
    edit that keeps the file's size and mtime still misses the cache at the next setup."""
    root, exp = moma_root
    real, calls = cache_mod.source_signature, []

    def spy(paths, mode="stat"):
        calls.append(mode)
        return real(paths, mode)

    monkeypatch.setattr(cache_mod, "source_signature", spy)
    dm = _dm(root, cache=True, cache_hash="content", num_workers=workers)
    dm.setup("test")
    ds = dm.datasets["test"]
    assert calls == ([] if workers else ["content"] * len(ds))  # one read per record (workers: in their processes)
    first = [ds[i]["floor_label"] for i in range(len(ds))]
    assert calls == ([] if workers else ["content"] * len(ds))  # cache hits read no source file
    # an edit keeping size and mtime: the next setup reads the bytes again and misses the cache for that sample
    csv = root / "rgbd" / exp["kept"]["test"][0] / LABEL_TXT
    st, lines = csv.stat(), csv.read_text().splitlines(keepends=True)
    *xyz, label = lines[0].rstrip("\n").split(",")
    lines[0] = ",".join([*xyz, "0.5".ljust(len(label), "0")]) + "\n"  # the first floor point's label, same length
    csv.write_text("".join(lines))
    assert csv.stat().st_size == st.st_size
    os.utime(csv, ns=(st.st_atime_ns, st.st_mtime_ns))
    dm2 = _dm(root, cache=True, cache_hash="content", num_workers=workers)
    dm2.setup("test")
    i = [r.key for r in dm2.datasets["test"].records].index(exp["kept"]["test"][0])
    assert dm2.datasets["test"][i]["floor_label"][0] == 0.5 and first[i][0] != 0.5


@pytest.mark.parametrize("error", [IndexError, TypeError])
def test_a_sample_breaking_after_setup_with_any_load_error_is_replaced(error, capsys):
    """Run time caught fewer errors than the setup check: a sample whose loader raised IndexError or TypeError after
    setup crashed the epoch instead of being replaced by the next one. The setup check counts the same errors."""
    good = make_synthetic_sample(0, num_points=64, floor_cells=4)
    broken: set[str] = set()

    def load(rec):
        if rec.key in broken:
            raise error(f"{rec.key}: truncated table")
        return {k: v.clone() if isinstance(v, torch.Tensor) else dict(v) for k, v in good.items()}

    records = [SampleRecord(f"s{i}", [], {}) for i in range(3)]
    ds = RecordDataset(records, load, name="tiny").build(SkipLog("tiny"))
    strict = RecordDataset(records, load, name="tiny", strict=True).build(SkipLog("tiny"))
    broken.add("s0")
    s = ds[0]
    assert s["meta"]["replaces"] == "s0" and ds.runtime_failures == 1
    assert "s0 failed at load time" in capsys.readouterr().out
    with pytest.raises(DataError, match="s0 failed at load time"):  # strict still names it
        strict[0]
    skips = SkipLog("tiny")
    assert len(RecordDataset(records, load, name="tiny").build(skips)) == 2
    assert dict(skips.counts) == {error.__name__: 1}


def test_a_parsing_fix_reaches_samples_cached_before_it(moma_root, monkeypatch):
    """The cache key held the reader's settings and the source files' signatures, never the parsing code: what an
    older reader decided stayed cached after a fix (here a sound PLY an older check refused, as the ASCII-row check
    once did: its skip marker outlived the fix)."""
    import floaff_zoo.data.moma_kitchen as mk

    root, _ = moma_root
    rel = (root / "data_split/kitchen_test.txt").read_text().split()[0]

    def kept() -> tuple[bool, dict]:
        dm = _dm(root, cache=True)
        dm.setup("test")
        return rel in [r.key for r in dm.datasets["test"].records], dict(dm.skips["test"].counts)

    def refuse(path, kind="corrupt_ply"):  # the older reader: refuses this sample's sound PLY
        if rel in str(path):
            raise mk.LoadError(kind, f"{path}: refused")

    check = mk.check_ply_complete
    monkeypatch.setattr(mk, "check_ply_complete", refuse)
    monkeypatch.setattr(cache_mod, "parser_digest", lambda: "older parser", raising=False)
    assert kept() == (False, {"corrupt_ply": 1})
    monkeypatch.setattr(mk, "check_ply_complete", check)
    assert kept() == (False, {"corrupt_ply": 1})  # the same code version reads its own markers back
    monkeypatch.undo()  # the fixed reader, the installed code's digest
    assert kept() == (True, {})


#: package modules a parsing module may import without being one: they never touch a sample's tensors or its skip
NOT_PARSING = {
    "floaff_zoo.names": "constant names",
    "floaff_zoo.atomic": "writes files",
    "floaff_zoo.checks": "constructor argument checks",
    "floaff_zoo.data.base": "the DataModule's plumbing",
    "floaff_zoo.data.scene_labels": "a pre-transform: its class's file is in the cache key (code_digest)",
    "floaff_zoo.sim": "the package, for fileformat",
    "floaff_zoo.sim.presets": "a hint's preset names",
}


def test_every_package_module_the_parsers_call_is_in_the_cache_key():
    """floor (the readers' pose check) and frames (SceneLabels' frame change) were not hashed: an edit to either
    kept serving samples and skip markers cached before it."""
    import ast
    import importlib
    import inspect

    modules = [*cache_mod.PARSER_MODULES, "floaff_zoo.data.scene_labels"]
    missing = set()
    for name in modules:
        for node in ast.walk(ast.parse(inspect.getsource(importlib.import_module(name)))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("floaff_zoo"):
                found = {node.module} if node.module != "floaff_zoo" else {f"floaff_zoo.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                found = {a.name for a in node.names if a.name.startswith("floaff_zoo")}
            else:
                continue
            missing |= found - set(cache_mod.PARSER_MODULES) - set(NOT_PARSING)
    assert not missing, f"imported by the parsing code but not in PARSER_MODULES: {sorted(missing)}"
