"""Whole-file writes: readable by others as a plain open would make them, and never half written."""

import os
import stat

import numpy as np
import pytest

from floaff_zoo.atomic import atomic_write, existing_ancestor
from floaff_zoo.sim import fileformat as ff


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_generated_files_get_the_mode_of_the_umask(tmp_path, umask_022):
    """mkstemp makes owner-only files: a dataset generated into a shared folder was unreadable by anyone else."""
    ff.atomic_write_json(tmp_path / "scene.json", {"a": 1})
    ff.atomic_save_npz(tmp_path / "views" / "front_0000.npz", {"x": np.zeros(3)})
    assert _mode(tmp_path / "scene.json") == 0o644
    assert _mode(tmp_path / "views" / "front_0000.npz") == 0o644
    np.testing.assert_array_equal(np.load(tmp_path / "views" / "front_0000.npz")["x"], np.zeros(3))
    os.umask(0o027)  # another umask, another mode (a fixed 0o644 passed the lines above); the fixture restores it
    ff.atomic_write_json(tmp_path / "private.json", {"a": 1})
    assert _mode(tmp_path / "private.json") == 0o640


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    path = tmp_path / "index.json"
    path.write_bytes(b"old")

    def half(f):
        f.write(b"new but")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(path, half)
    assert path.read_bytes() == b"old" and os.listdir(tmp_path) == ["index.json"]


def test_the_umask_is_read_without_changing_it(umask_022, monkeypatch):
    """Reading it by os.umask(0) set it to 0 for a moment: a file another thread made then was world-writable."""
    from floaff_zoo import atomic

    calls: list[int] = []
    real = os.umask
    monkeypatch.setattr(os, "umask", lambda m: calls.append(m) or real(m))
    assert atomic._umask() == 0o022 and calls == []


def test_each_json_kind_keeps_its_layout(tmp_path):
    """One JSON writer for the benchmark's files and the curriculum's records: each keeps the bytes it wrote before
    (``runs.data_fingerprint`` hashes scene records; old run folders are read back as they are)."""
    from floaff_zoo import curriculum

    rec = {"b": np.float32(0.5), "a": np.arange(2)}
    ff.atomic_write_json(tmp_path / "scene.json", rec)
    assert (tmp_path / "scene.json").read_bytes() == b'{\n "a": [\n  0,\n  1\n ],\n "b": 0.5\n}'
    curriculum._write_json(tmp_path / "stage.json", {"status": "done", "args": ["a"]})
    assert (tmp_path / "stage.json").read_bytes() == b'{\n  "status": "done",\n  "args": [\n    "a"\n  ]\n}'


def test_a_failed_curriculum_record_write_leaves_no_temp(tmp_path):
    """The curriculum's own writer left ``stage.<pid>.tmp`` behind when the rename failed."""
    from floaff_zoo import curriculum

    (tmp_path / "stage.json" / "x").mkdir(parents=True)  # a folder in the record's place: the rename fails
    with pytest.raises(OSError):
        curriculum._write_json(tmp_path / "stage.json", {"status": "done"})
    assert os.listdir(tmp_path) == ["stage.json"]


def test_a_failed_finished_marker_or_metrics_write_leaves_no_temp(tmp_path):
    """``runs.mark_finished`` and the curriculum's kept-metrics writer had temp files of their own (a fixed
    ``<name>.tmp`` for the metrics, shared by two runners), left behind when the rename failed."""
    from floaff_zoo import curriculum
    from floaff_zoo.runs import FINISHED_FILE, mark_finished

    (tmp_path / FINISHED_FILE / "x").mkdir(parents=True)  # a folder in each file's place: the rename fails
    (tmp_path / "kept.csv" / "x").mkdir(parents=True)
    with pytest.raises(OSError):
        mark_finished(tmp_path, tmp_path / "last.ckpt")
    with pytest.raises(OSError):
        curriculum._write_rows(tmp_path / "kept.csv", [{"epoch": "0", "val_loss": "1.0"}])
    assert sorted(os.listdir(tmp_path)) == ["finished.json", "kept.csv"]


def test_the_kept_metrics_keep_their_csv_bytes(tmp_path):
    """Rows deduplicated, columns sorted, CSV's own line ends: what the curriculum's ``open(newline="")`` wrote."""
    from floaff_zoo import curriculum

    rows = [{"val_loss": "1.0", "epoch": "0"}, {"epoch": "0", "val_loss": "1.0"}, {"epoch": "1", "step": "9"}]
    curriculum._write_rows(tmp_path / "kept.csv", rows)
    assert (tmp_path / "kept.csv").read_bytes() == b"epoch,step,val_loss\r\n0,,1.0\r\n1,9,\r\n"


def test_existing_ancestor_is_the_first_existing_path_a_dangling_link_included(tmp_path, monkeypatch):
    (tmp_path / "file").write_text("x")
    (tmp_path / "dangling").symlink_to(tmp_path / "gone")
    assert existing_ancestor(tmp_path / "a" / "b") == tmp_path
    assert existing_ancestor(tmp_path / "file" / "sub") == tmp_path / "file"
    assert existing_ancestor(tmp_path / "dangling" / "sub") == tmp_path / "dangling"
    monkeypatch.chdir(tmp_path)
    assert existing_ancestor("new/runs") == tmp_path  # relative paths are taken from the working folder


def test_a_symlink_is_written_through_not_replaced(tmp_path):
    """The rename replaced the link with a file and left its target holding the old bytes; a plain open writes the
    target. A dangling link gets its target made, as open would."""
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "index.json"
    target.write_text("old")
    link = tmp_path / "index.json"
    link.symlink_to(target)
    atomic_write(link, lambda f: f.write(b"new"))
    assert link.is_symlink() and target.read_text() == "new"
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(tmp_path / "real" / "made.json")
    atomic_write(dangling, lambda f: f.write(b"x"))
    assert dangling.is_symlink() and (tmp_path / "real" / "made.json").read_text() == "x"
