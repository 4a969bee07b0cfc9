"""floaff-zoo montage: the test figures of several runs side by side (paper Figures 4/6)."""

import json

import numpy as np
import pytest

from floaff_zoo.cli import main as zoo_main


def _run(tmp_path, name, value, cases=("CloseDrawer_front_0", "OpenSingleDoor_side_0"), copy_figures=False):
    """A fake test run: figures under <run_dir>/figures, report.json copied elsewhere (like docs/results)."""
    import matplotlib.pyplot as plt

    run_dir = tmp_path / "runs" / name / "version_1"
    (run_dir / "figures").mkdir(parents=True)
    for i, case in enumerate(cases):  # each later case darker: rows can be told apart
        img = np.full((40, 60, 3), value / (1 + i), dtype=np.float32)
        plt.imsave(run_dir / "figures" / f"{case}.png", img)
    report = {"label": name, "run_dir": str(run_dir), "figures": [f"figures/{c}.png" for c in cases]}
    out = tmp_path / "docs" / name
    out.mkdir(parents=True)
    (out / "report.json").write_text(json.dumps(report))
    return out


def test_montage_puts_runs_in_columns_and_cases_in_rows(tmp_path, capsys):
    import matplotlib.pyplot as plt

    a, b = _run(tmp_path, "CFAR+PFAL", 0.1), _run(tmp_path, "PointNet++", 0.9)
    out = tmp_path / "fig4.png"
    assert (
        zoo_main(
            [
                "montage",
                "--runs",
                str(a),
                str(b / "report.json"),
                "--cases",
                "CloseDrawer_front_0",
                "OpenSingleDoor_side_0",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert str(out) in capsys.readouterr().out
    img = plt.imread(out)[..., :3]
    h, w = img.shape[:2]
    # the dark run is on the left, the light one on the right, in both rows; the second case (darker) below
    means = [[img[row, : w // 2].mean(), img[row, w // 2 :].mean()] for row in (h // 4, 3 * h // 4)]
    for left, right in means:
        assert left < right
    assert means[1][1] < means[0][1] - 0.05, means


def test_montage_names_the_missing_case_and_report(tmp_path, capsys):
    a = _run(tmp_path, "CFAR+PFAL", 0.1)
    with pytest.raises(SystemExit) as ex:
        zoo_main(["montage", "--runs", str(a), "--cases", "CloseDrawer_side_3", "--out", str(tmp_path / "x.png")])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert "CloseDrawer_side_3" in err and "CloseDrawer_front_0" in err and "report.json" in err
    with pytest.raises(SystemExit):
        zoo_main(["montage", "--runs", str(tmp_path / "nope"), "--cases", "a_b_0", "--out", str(tmp_path / "x.png")])
    assert "nope: no report.json" in capsys.readouterr().err


def test_montage_refuses_runs_of_different_benchmarks(tmp_path, capsys):
    """The k-th figure of a case is the same view only within one test split: a Styles run beside a Layouts run put
    two different kitchens side by side as if one method had drawn each, without a word."""
    runs = {}
    for name, bench in (("styles_a", "styles"), ("styles_b", "styles"), ("layouts_a", "layouts"), ("old", None)):
        runs[name] = _run(tmp_path, name, 0.5)
        report = json.loads((runs[name] / "report.json").read_text())
        if bench is not None:  # a report of before the field names no benchmark: not compared
            report["data"] = {"benchmark": bench}
        (runs[name] / "report.json").write_text(json.dumps(report))
    args = ["--cases", "CloseDrawer_front_0", "--out", str(tmp_path / "x.png")]
    with pytest.raises(SystemExit) as ex:
        zoo_main(["montage", "--runs", str(runs["styles_a"]), str(runs["layouts_a"]), *args])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert "tested on different benchmarks (styles: " in err
    assert f"; layouts: {runs['layouts_a'] / 'report.json'}" in err
    assert not (tmp_path / "x.png").exists()
    assert zoo_main(["montage", "--runs", *(str(runs[n]) for n in ("styles_a", "styles_b", "old")), *args]) == 0


def test_montage_out_names_the_file_it_writes(tmp_path, capsys):
    """--out without a suffix wrote <out>.png and printed <out>; a folder wrote <folder>.png beside it; an unknown
    suffix gave matplotlib's traceback; a run's own figure was overwritten."""
    a = _run(tmp_path, "CFAR+PFAL", 0.1)
    args = ["montage", "--runs", str(a), "--cases", "CloseDrawer_front_0", "--out"]
    assert zoo_main([*args, str(tmp_path / "fig")]) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "fig.png") and (tmp_path / "fig.png").is_file()
    for out, message in ((tmp_path, "is a folder"), (tmp_path / "fig.jpgx", "cannot write '.jpgx' pictures")):
        with pytest.raises(SystemExit) as ex:
            zoo_main([*args, str(out)])
        assert ex.value.code == 2 and message in capsys.readouterr().err
    figure = tmp_path / "runs" / "CFAR+PFAL" / "version_1" / "figures" / "CloseDrawer_front_0.png"
    before = figure.read_bytes()
    with pytest.raises(SystemExit) as ex:  # the montage was written over the run's own figure, exit 0
        zoo_main([*args, str(figure)])
    assert ex.value.code == 2 and f"--out {figure}: is the figure {figure} of a run" in capsys.readouterr().err
    assert figure.read_bytes() == before


@pytest.mark.parametrize(
    "report, named",
    [
        ([], "not a report (a JSON list, not an object)"),
        ({"figures": "figures/CloseDrawer_front_0.png"}, "field 'figures' is str"),
        ({"figures": [1]}, "field 'figures' holds 1"),
        ({"figures": [], "model": "CFAR"}, "field 'model' is str"),
        ({"figures": [], "run_dir": 3}, "field 'run_dir' is int"),
    ],
)
def test_montage_names_a_malformed_report_and_field(tmp_path, capsys, report, named):
    """A report.json holding [] ended in a traceback (AttributeError); a string 'figures' was read character by
    character."""
    (tmp_path / "report.json").write_text(json.dumps(report))
    with pytest.raises(SystemExit) as ex:
        zoo_main(["montage", "--runs", str(tmp_path), "--cases", "CloseDrawer_front_0", "--out", str(tmp_path / "x")])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert f"floaff-zoo montage: error: {tmp_path / 'report.json'}: {named}" in err and len(err.splitlines()) == 1


def test_a_report_whose_model_is_null_is_titled_by_its_folder(tmp_path, capsys):
    """check_report lets every field be null, yet the title read rep['model'].get(...) and raised AttributeError."""
    a = _run(tmp_path, "CFAR+PFAL", 0.1)
    rep = json.loads((a / "report.json").read_text())
    (a / "report.json").write_text(json.dumps({**rep, "label": None, "model": None}))
    out = tmp_path / "m.png"
    assert zoo_main(["montage", "--runs", str(a), "--cases", "CloseDrawer_front_0", "--out", str(out)]) == 0
    assert out.is_file()
