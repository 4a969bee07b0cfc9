"""scripts/script_cli.py: the research scripts end on bad input with one line and exit code 2, on a bug with its
traceback."""

import subprocess
import sys

import pytest

from tests._scripts import ROOT, load_script

sc = load_script("script_cli")


def test_bad_input_is_one_line_and_a_bug_keeps_its_traceback(capsys):
    def missing():
        raise FileNotFoundError("/nowhere/x.json: no such file")

    assert sc.run(missing, "demo_script") == 2
    assert capsys.readouterr().err == "demo_script: error: /nowhere/x.json: no such file\n"
    with pytest.raises(KeyError):
        sc.run(lambda: {}["task"], "demo_script")
    assert sc.run(lambda: 0, "demo_script") == 0


def test_a_scripts_own_exit_message_is_a_bad_input_line_with_exit_code_2(capsys):
    """A script's `raise SystemExit("<prog>: why")` (40 of them) exited 1 with no "error:", unlike the other errors."""

    def no_scene():
        raise SystemExit("demo_script: no finished scene under /data\n(generate it first)")

    assert sc.run(no_scene, "demo_script") == 2
    assert capsys.readouterr().err == "demo_script: error: no finished scene under /data (generate it first)\n"
    with pytest.raises(SystemExit) as done:  # argparse's usage error keeps its own code
        sc.run(lambda: sys.exit(2), "demo_script")
    assert done.value.code == 2


def test_a_script_names_a_missing_data_root(tmp_path):
    """fixed_cell_ceiling (and five others) ended in a FormatError / MisconfigurationException traceback."""
    out = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "fixed_cell_ceiling.py"), "--root", str(tmp_path / "none")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    assert out.stderr.strip() == f"fixed_cell_ceiling: error: {tmp_path / 'none'}: dataset root not found"


def test_a_package_error_naming_the_script_is_not_prefixed_twice(capsys):
    """load_axisnet(..., owner="yaw_errors") names its owner: the line read 'yaw_errors: error: yaw_errors: axisnet'."""
    from floaff_zoo.hub.registry import HubError

    def bad_axisnet():
        raise HubError("yaw_errors: axisnet 'x.ckpt': no such file")

    assert sc.run(bad_axisnet, "yaw_errors") == 2
    assert capsys.readouterr().err == "yaw_errors: error: axisnet 'x.ckpt': no such file\n"


#: the scripts with a --json output, each with the arguments it needs to parse
JSON_SCRIPTS = [
    ("cv_sr", ["x.json"]),
    ("episodes_sr", ["a=x.json"]),
    ("predict_sr", ["--root", "r", "--model", "m"]),
    ("protocol_change", ["a.json", "b.json"]),
    ("scene_sr", ["a=m"]),
    ("val_sr", ["m"]),
    ("coverage_reasons", []),
    ("fixed_cell_ceiling", []),
    ("prior_cells", []),
    ("target_inputs", []),
    ("reset_drift", ["--root", "r"]),
    ("yaw_errors", ["--root", "r"]),
]


@pytest.mark.parametrize(("script", "args"), JSON_SCRIPTS)
def test_a_json_output_that_is_a_folder_is_refused_before_the_work(script, args, tmp_path, capsys):
    """The scripts write --json after the work: a folder there was an IsADirectoryError at the very end of the run."""
    with pytest.raises(SystemExit) as done:
        load_script(script).main([*args, "--json", str(tmp_path)])
    assert done.value.code == 2 and "--json names a file to write, got the folder" in capsys.readouterr().err


@pytest.mark.parametrize(("script", "args"), JSON_SCRIPTS)
def test_a_json_output_under_a_file_is_refused_before_the_work(script, args, tmp_path, capsys):
    """A --json under a file passed the folder check: the write failed with a NotADirectoryError (or a
    FileExistsError naming only the file) at the very end of the run."""
    (tmp_path / "notes.txt").write_text("")
    out = tmp_path / "notes.txt" / "sub" / "x.json"
    with pytest.raises(SystemExit) as done:
        load_script(script).main([*args, "--json", str(out)])
    err = capsys.readouterr().err
    assert (
        done.value.code == 2
        and f"--json {str(out)!r}: {str(tmp_path / 'notes.txt')!r} exists and is not a folder" in err
    )


@pytest.mark.parametrize(
    ("bad", "named"),
    [
        (["--sigma-xy", "nan"], "--sigma-xy must be a finite number >= 0, got nan"),
        (["--sigma-yaw-deg", "inf"], "--sigma-yaw-deg must be a finite number >= 0, got inf"),
        (["--sigma-xy", "-0.1"], "--sigma-xy must be a finite number >= 0, got -0.1"),
        (["--seed", "-1"], "--seed must be >= 0, got -1"),
    ],
)
def test_parking_noise_that_is_no_noise_is_a_usage_error(bad, named, capsys):
    import argparse

    p = argparse.ArgumentParser(prog="fresh")
    sc.add_parking_noise(p)
    sc.check_parking_noise(p, p.parse_args([]))  # the defaults pass
    with pytest.raises(SystemExit) as done:
        sc.check_parking_noise(p, p.parse_args(bad))
    assert done.value.code == 2 and named in capsys.readouterr().err
