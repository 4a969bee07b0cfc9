"""`floaff-zoo table` on fixture report.json files (golden Markdown tables, hand-checked)."""

import json
import shutil
from pathlib import Path

import pytest

from floaff_zoo.cli import main as cli_main
from floaff_zoo.report.table import build_table, load_reports, main, render

FIX = Path(__file__).parent / "fixtures"
RUNS = FIX / "runs"


@pytest.mark.parametrize("preset", ["map", "sr_views"])
def test_golden_markdown(preset, tmp_path, capsys):
    out = tmp_path / "t.md"
    assert main(["--runs", str(RUNS), "--preset", preset, "--format", "md", "--out", str(out)]) == 0
    assert out.read_text() == (FIX / f"golden_{preset}.md").read_text()
    err = capsys.readouterr().err
    assert "skipped" in err and "crashed_run" in err and "no report.json" in err


def test_golden_values_by_hand():
    """Cells the golden file must contain: CFAR Styles RMSE (0.030, 0.028, 0.029) -> 0.029 ± 0.001 (ddof=1)."""
    text = (FIX / "golden_map.md").read_text()
    assert "| CFARModule | **0.029 ± 0.001** | **0.0004 ± 0.0000** | **0.860 ± 0.010** | **0.862 ± 0.002** |" in text
    assert "| NavAffModule | 0.065 ± 0.001 | 0.0026 ± 0.0001 | 0.395 ± 0.007 | 0.335 ± 0.007 |" in text
    sr = (FIX / "golden_sr_views.md").read_text()
    # Layouts has one CFAR run: its bootstrap std is shown; NavAff has no Layouts run
    assert (
        "| CFARModule | **0.85 ± 0.01** | **0.85 ± 0.02** | **0.85 ± 0.01** | 0.81 ± 0.02 | 0.77 ± 0.02 | 0.79 ± 0.01 |"
        in sr
    )
    assert "| NavAffModule | 0.29 ± 0.01 | 0.45 ± 0.01 | 0.37 ± 0.00 | n/a | n/a | n/a |" in sr
    assert sr.index("| Oracle |") > sr.index("| NavAffModule |")
    # the Oracle is the same for every run of a test split: its bootstrap std, not a std over runs (0.00)
    assert "| Oracle | 0.87 ± 0.02 |" in sr


def test_globs_dedupe_and_cli_dispatch(tmp_path, capsys):
    assert (
        cli_main(
            [
                "table",
                "--runs",
                str(RUNS / "cfar_*"),
                str(RUNS / "cfar_styles_s0" / "report.json"),
                "--preset",
                "sr_tasks",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "| Method | PnPC2C | OpenSD |"
    assert out.count("| CFARModule |") == 2  # one row per benchmark section, 3 Styles runs merged
    assert "0.83 ± 0.01" in out  # PnP Styles: (0.82, 0.84, 0.83)


def test_latex_and_csv(capsys):
    assert main(["--runs", str(RUNS), "--preset", "sr_views", "--format", "latex"]) == 0
    tex = capsys.readouterr().out
    assert tex.startswith("\\begin{tabular}{lcccccc}") and "\\textbf{0.85 $\\pm$ 0.01}" in tex
    assert "\\multicolumn{3}{c}{\\textbf{\\emph{Styles}}}" in tex and tex.rstrip().endswith("\\end{tabular}")
    assert main(["--runs", str(RUNS), "--preset", "map", "--format", "csv"]) == 0
    rows = [r.split(",") for r in capsys.readouterr().out.strip().splitlines()]
    assert rows[0][:4] == ["section", "Method", "runs", "RMSE mean"]
    cfar = next(r for r in rows if r[1] == "CFARModule" and "Styles" in r[0])
    assert float(cfar[3]) == pytest.approx(0.029) and float(cfar[4]) == pytest.approx(0.001)


def test_latex_row_names_are_text():
    """A label with LaTeX's special characters was printed verbatim: `$` opened math mode, `~` a space."""
    from floaff_zoo.report.table import _tex

    assert _tex("r~1.2, top-$k$ {10} a_b 5% #1 x^2 &\\") == (
        "r\\textasciitilde{}1.2, top-\\$k\\$ \\{10\\} a\\_b 5\\% \\#1 x\\textasciicircum{}2 \\&\\textbackslash{}"
    )


def test_bad_inputs_are_named_and_skipped(tmp_path, capsys):
    bad = tmp_path / "bad_run"
    bad.mkdir()
    (bad / "report.json").write_text("{not json")
    assert main(["--runs", str(bad), str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err
    assert "bad_run" in err and "unreadable" in err and "missing" in err
    assert "no usable report.json" in err and "1 found and skipped" in err  # not "none found": one was unusable
    with pytest.raises(SystemExit):
        main(["--runs", str(RUNS), "--preset", "nope"])
    assert main(["--runs", str(RUNS), "--group-by", "model.hparams.no_such"]) == 2
    assert "no_such" in capsys.readouterr().err


def _set(rep: dict, dotted: str, value: object) -> dict:
    """``rep`` with the field ``dotted`` (``sr.model.all.mean``) set to ``value``."""
    *parents, last = dotted.split(".")
    cur = rep
    for part in parents:
        cur = cur[part]
    cur[last] = value
    return rep


@pytest.mark.parametrize(
    ("field", "value", "preset"),
    [
        ("model", "CFARModule", "map"),
        ("sr", 3, "map"),
        ("checkpoint", "last.ckpt", "map"),
        ("data.labels_sha256", ["aaaa"], "map"),
        ("metrics.test_rmse", "0.03", "map"),
        ("sr.model.all.mean", "0.85", "sr_views"),
        ("sr.model.all.mean", "n/a", "sr_views"),
        ("sr.available", "false", "sr_views"),
        ("sr.oracle.tasks.OpenSingleDoor", 0.9, "sr_tasks"),
        ("model.hparams.eval_yaw_source", ["gt"], "sr_views"),
        ("data.num_samples", "400", "map"),
    ],
)
def test_reports_with_wrong_field_types_are_named_and_skipped(tmp_path, capsys, field, value, preset):
    """A report of the right schema with a field of the wrong type is skipped with its file and field named and
    counted, not a traceback (``'str' object has no attribute 'get'``) nor a silently converted value."""
    good = json.loads((RUNS / "cfar_layouts_s0" / "report.json").read_text())
    bad = _set(json.loads(json.dumps(good)), field, value)
    bad["checkpoint"] = bad["checkpoint"] if field == "checkpoint" else {**good["checkpoint"], "sha256": "b" * 64}
    for name, rep in (("good", good), ("bad", bad)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "report.json").write_text(json.dumps(rep))
    assert main(["--runs", str(tmp_path), "--preset", preset]) == 0
    out, err = capsys.readouterr()
    assert f"skipped {tmp_path / 'bad' / 'report.json'}: malformed report.json ('{field}' is" in err
    assert "1 report(s) tabulated, 1 skipped" in err
    assert out.rstrip().endswith(": 1._")  # the row holds the good run only
    assert main(["--runs", str(tmp_path / "bad"), "--preset", preset]) == 2
    assert "no usable report.json" in capsys.readouterr().err


def test_a_report_of_another_format_version_is_named_and_skipped(tmp_path, capsys):
    """A version 2 report (a newer writer) was tabulated as a version 1 one, its fields read by the old meanings."""
    from floaff_zoo.callbacks.report import SCHEMA_VERSION
    from floaff_zoo.report.table import READ_VERSIONS

    assert SCHEMA_VERSION in READ_VERSIONS  # the table reads what the test callback writes
    rep = json.loads((RUNS / "cfar_layouts_s0" / "report.json").read_text())
    _write_runs(tmp_path, {"v2": {**rep, "version": 2}, "vtrue": {**rep, "version": True}})
    assert main(["--runs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"skipped {tmp_path / 'v2' / 'report.json'}: report format version 2; this floaff-zoo reads [1]" in err
    assert f"skipped {tmp_path / 'vtrue' / 'report.json'}: report format version True" in err


def test_a_report_without_the_group_field_is_not_told_to_mean_that_field(tmp_path, capsys):
    rep = json.loads((RUNS / "cfar_layouts_s0" / "report.json").read_text())
    _write_runs(tmp_path, {"nomodel": {k: v for k, v in rep.items() if k != "model"}})
    assert main(["--runs", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"--group-by model: report {tmp_path / 'nomodel' / 'report.json'} has no such field" in err
    assert "did you mean 'model'" not in err


def _write_runs(root: Path, reports: dict[str, dict]) -> None:
    for name, rep in reports.items():
        (root / name).mkdir()
        (root / name / "report.json").write_text(json.dumps(rep))


def test_odd_but_accepted_report_fields_do_not_crash_the_table(tmp_path, capsys):
    """Fields the validator accepts (an SR cell without mean, "tasks": null) and a file that is not UTF-8 ended in a
    traceback (KeyError, TypeError, UnicodeDecodeError) instead of a table or a named skip."""
    good = json.loads((RUNS / "cfar_layouts_s0" / "report.json").read_text())
    no_mean = _set(json.loads(json.dumps(good)), "sr.model.front", {"std": 0.01, "n": 10})
    no_tasks = _set(json.loads(json.dumps(good)), "sr.model.tasks", None)
    for i, rep in enumerate((no_mean, no_tasks)):
        rep["checkpoint"] = {**good["checkpoint"], "sha256": f"{i + 1}" * 64}
    _write_runs(tmp_path, {"good": good, "no_mean": no_mean, "no_tasks": no_tasks})
    (tmp_path / "latin1").mkdir()
    (tmp_path / "latin1" / "report.json").write_bytes(b'{"schema": "floaff-zoo/report", "label": "\xff\xfe"}\xff')
    for preset in ("sr_views", "sr_tasks"):
        assert main(["--runs", str(tmp_path), "--preset", preset]) == 0
        err = capsys.readouterr().err
        assert f"skipped {tmp_path / 'latin1' / 'report.json'}: unreadable report.json" in err


def test_a_non_finite_value_takes_its_own_std_with_it(tmp_path):
    """aggregate() dropped a NaN run's value but kept its bootstrap std, which the remaining run then showed."""
    from floaff_zoo.report.table import aggregate

    cell = aggregate([(float("nan"), 0.999), (0.458, 0.013)])
    assert cell.n == 1 and cell.mean == 0.458 and cell.std == 0.013
    assert aggregate([(0.4, 0.01), (None, None)]).std == 0.01  # a run without a value is left out


@pytest.mark.parametrize("where", [0, 2])
def test_an_oracle_nan_does_not_turn_identical_runs_into_a_spread(where):
    """The Oracle row shows identical values once with their bootstrap std; a NaN first among them compared unequal
    (max/min of a NaN) and the row read 0.87 ± 0.00, a NaN last did not."""
    reps = [json.loads((RUNS / f"cfar_styles_s{i}" / "report.json").read_text()) for i in range(3)]
    reps[where]["sr"]["oracle"]["front"]["mean"] = float("nan")
    oracle = build_table(reps, "sr_views").sections[0].rows[-1]
    assert oracle.oracle and oracle.cells[0].mean == 0.87 and oracle.cells[0].std == 0.02 and oracle.cells[0].n == 1


def test_equal_group_values_of_different_types_share_a_row(tmp_path):
    """crop_radius 1 (an int) and 1.0 (a float) made two rows, "1" and "1.00"."""
    src = json.loads((RUNS / "cfar_styles_s0" / "report.json").read_text())
    reports = {}
    for i, crop in enumerate((1, 1.0)):
        hp = dict(src["model"]["hparams"], crop_radius=crop)
        reports[f"r{i}"] = dict(
            src, model=dict(src["model"], hparams=hp), checkpoint={**src["checkpoint"], "sha256": f"{i}" * 64}
        )
    _write_runs(tmp_path, reports)
    sweep = render(build_table([r for _, r in load_reports([str(tmp_path)])[0]], "sweep"), "md")
    assert [ln.split("|")[1].strip() for ln in sweep.splitlines() if ln.startswith("| 1")] == ["1.00"]


def test_sweep_sorts_numerically_and_ablation_groups_by_label(tmp_path):
    src = json.loads((RUNS / "cfar_styles_s0" / "report.json").read_text())
    for i, (crop, label) in enumerate([(1.3, "Ours (Full)"), (1.1, "w/o SDL"), (1.25, "w/o Crop")]):
        rep = dict(src, label=label, model=dict(src["model"], hparams=dict(src["model"]["hparams"], crop_radius=crop)))
        rep["metrics"] = dict(src["metrics"], test_rmse=0.02 + 0.01 * i)
        (tmp_path / f"r{i}").mkdir()
        (tmp_path / f"r{i}" / "report.json").write_text(json.dumps(rep))
    reports = [r for _, r in load_reports([str(tmp_path)])[0]]
    sweep = render(build_table(reports, "sweep"), "md")
    rows = [ln.split("|")[1].strip() for ln in sweep.splitlines() if ln.startswith("| 1.")]
    assert rows == ["1.10", "1.25", "1.30"] and sweep.startswith("| crop_radius |")
    assert "**0.020**" in sweep  # lowest RMSE in bold
    abl = render(build_table(reports, "ablation"), "md")
    assert "| w/o SDL |" in abl and "| Ours (Full) |" in abl and abl.startswith("| Ablation |")


def test_reads_only_report_json(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(RUNS / "navaff_styles_s0", run)
    (run / "metrics.csv").write_text("test_rmse\n0.5\n")
    (reports, skipped) = load_reports([str(run)])
    assert len(reports) == 1 and not skipped
    assert reports[0][1]["metrics"]["test_rmse"] == 0.064


def test_runs_on_different_copies_of_the_data_are_not_mixed(tmp_path, capsys):
    """Reports that record different labels for one scene come from different copies of the data."""
    rep = json.loads((RUNS / "cfar_styles_s0" / "report.json").read_text())
    copies = (("a", {"s1": "aaaa", "s2": "cccc"}), ("a2", {"s1": "aaaa"}), ("b", {"s1": "bbbb"}), ("old", None))
    for name, digests in copies:
        d = tmp_path / name
        d.mkdir()
        ckpt = {**rep["checkpoint"], "sha256": name * (64 // len(name))}  # another seed's checkpoint
        r = {**rep, "run_dir": name, "checkpoint": ckpt, "data": {**rep["data"], "labels_sha256": digests}}
        (d / "report.json").write_text(json.dumps(r))
    assert main(["--runs", str(tmp_path / "a"), str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "scene s1" in err and "aaaa" in err and "bbbb" in err and "--allow-mixed-data" in err
    # the files read here, not the run folders recorded on the machine that wrote them
    assert str(tmp_path / "a" / "report.json") in err and str(tmp_path / "b" / "report.json") in err
    assert main(["--runs", str(tmp_path / "a"), "--group-by", "model.hparams.nope"]) == 2
    assert f"report {tmp_path / 'a' / 'report.json'} has no such field" in capsys.readouterr().err
    assert main(["--runs", str(tmp_path / "a"), str(tmp_path / "b"), "--allow-mixed-data"]) == 0
    # the same labels, disjoint scenes, or a report from before the hash was recorded: one table
    assert main(["--runs", str(tmp_path / "a"), str(tmp_path / "a2"), str(tmp_path / "old")]) == 0


@pytest.mark.parametrize(
    ("typed", "meant"), [("lable", "label"), ("model.hparams.feat_channel", "model.hparams.feat_channels")]
)
def test_a_mistyped_group_by_names_the_field_it_may_mean(capsys, typed, meant):
    """A --group-by that no report has said only "has no such field": the dotted path of a field the reports do
    have, a letter away, was left for the reader to find in report.json."""
    assert main(["--runs", str(RUNS / "cfar_styles_s0"), str(RUNS / "cfar_styles_s1"), "--group-by", typed]) == 2
    err = capsys.readouterr().err
    assert f"--group-by {typed}:" in err and "has no such field" in err and f"did you mean {meant!r}?" in err


def test_a_cell_from_fewer_runs_than_its_row_says_so(tmp_path):
    """A two-run row where one run has no SR showed the other run's bootstrap std as if it were a spread over both
    seeds; only the CSV's n column told them apart."""
    src = json.loads((RUNS / "cfar_styles_s0" / "report.json").read_text())
    no_sr = dict(src, sr={"available": False}, checkpoint={**src["checkpoint"], "sha256": "1" * 64})
    _write_runs(tmp_path, {"with_sr": src, "without_sr": no_sr})
    reports = [r for _, r in load_reports([str(tmp_path)])[0]]
    md = render(build_table(reports, "sr_views", oracle=False), "md")
    assert "| CFARModule | 0.84 ± 0.02 (n=1/2) | 0.83 ± 0.02 (n=1/2) | 0.83 ± 0.01 (n=1/2) |" in md
    assert "(n=1/2)" in render(build_table(reports, "sr_views", oracle=False), "latex")
    # both runs carry map metrics: those cells are over both and carry no mark
    assert "(n=" not in render(build_table(reports, "map"), "md").split("\n\n")[0]


def test_rows_that_read_the_simulators_yaw_are_marked(tmp_path):
    """Nothing marked a row whose runs read the simulator's target yaw at test time (a model configured with
    eval_yaw_source: gt, C2F-Exp with yaw_source: gt), which a robot does not have."""
    src = json.loads((RUNS / "cfar_styles_s0" / "report.json").read_text())
    gt = dict(src, model=dict(src["model"], hparams=dict(src["model"]["hparams"], eval_yaw_source="gt")))
    c2f = dict(src, model={"name": "C2FExpModule", "hparams": {"yaw_source": "gt"}}, checkpoint=None)
    c2f_fair = dict(c2f, model={"name": "C2FExpModule", "hparams": {"yaw_source": "manhattan"}}, label="fair")
    names = [r.name for r in build_table([gt, c2f], "sr_views").sections[0].rows if not r.oracle]
    assert sorted(names) == ["C2FExpModule (simulator yaw)", "CFARModule (simulator yaw)"]
    for preset in ("map", "sr_tasks"):
        rows = [r for r in build_table([gt], preset).sections[0].rows if not r.oracle]
        assert rows and all(r.name.endswith("(simulator yaw)") for r in rows)
    labelled = dict(gt, label="CFAR, simulator yaw")
    assert build_table([labelled, c2f_fair], "map", group_by="label").sections[0].rows[0].name == "CFAR, simulator yaw"
    assert build_table([c2f_fair], "map").sections[0].rows[0].name == "C2FExpModule"


def test_a_pipe_in_a_row_label_stays_in_its_markdown_cell(tmp_path):
    """A `|` in a label (``--label``, a ``--group-by`` value) split the Markdown row: every value moved one column to
    the right under the wrong header and the last one fell off the table."""
    src = json.loads((RUNS / "cfar_styles_s0" / "report.json").read_text())
    md = render(build_table([dict(src, label="r=1.2 | top-k")], "map", group_by="label"), "md")
    row = next(line for line in md.splitlines() if line.startswith("| r=1.2"))
    header = md.splitlines()[0]
    cells = [c for c in row.replace("\\|", "\0").split("|")[1:-1]]
    assert len(cells) == len(header.split("|")[1:-1]) == 5  # Method + RMSE, logMSE, PCC, SIM
    assert cells[0].strip() == "r=1.2 \0 top-k" and row.startswith("| r=1.2 \\| top-k |")


def test_out_is_never_a_report_the_table_reads(tmp_path, capsys):
    """``--out`` naming one of the reports read (a run folder's report.json) is refused: the table replaced the
    report, exit 0."""
    run = tmp_path / "cfar_styles_s0"
    shutil.copytree(RUNS / "cfar_styles_s0", run)
    before = (run / "report.json").read_text()
    assert main(["--runs", str(tmp_path), "--out", str(run / "report.json")]) == 2
    assert "is the report" in capsys.readouterr().err
    assert (run / "report.json").read_text() == before


def test_a_folder_named_report_json_is_named_as_one(tmp_path, capsys):
    """A folder named report.json was read as a file ("unreadable report.json ([Errno 21] Is a directory)") and the
    run then said "no report.json found"; given itself, it was searched for a report.json inside."""
    (tmp_path / "run" / "report.json").mkdir(parents=True)
    for entry in (tmp_path / "run", tmp_path / "run" / "report.json", tmp_path / "r*" / "report.json"):
        assert main(["--runs", str(entry)]) == 2
        err = capsys.readouterr().err
        assert f"skipped {tmp_path / 'run' / 'report.json'}: a folder named report.json, not a report" in err
        assert "no usable report.json" in err and "1 found and skipped" in err


def test_a_row_that_pools_runs_of_different_model_settings_says_so(tmp_path, capsys):
    """Runs of two variants under one label (the ablation preset's default key, the logger's name by default) were
    pooled into one row whose mean ± std read as a spread over seeds; the seeds' own files (teacher) differ by
    design and are no such difference."""
    src = json.loads((RUNS / "cfar_styles_s0" / "report.json").read_text())
    reports = {}
    for i, (crop, teacher) in enumerate([(1.2, "a.ckpt"), (1.2, "b.ckpt"), (0.8, "c.ckpt")]):
        hp = dict(src["model"]["hparams"], crop_radius=crop, teacher=teacher)
        reports[f"r{i}"] = dict(
            src, model=dict(src["model"], hparams=hp), checkpoint={**src["checkpoint"], "sha256": f"{i}" * 64}
        )
    _write_runs(tmp_path, reports)
    seeds = [r for p, r in load_reports([str(tmp_path)])[0] if p.parent.name != "r2"]
    for preset in ("map", "sr_views", "sr_tasks", "ablation"):
        assert "model settings" not in build_table(seeds, preset).mixed  # teacher differs per seed
    assert main(["--runs", str(tmp_path), "--preset", "ablation", "--format", "md"]) == 0
    out, err = capsys.readouterr()
    said = "rows pool runs of different model settings: CFARModule (crop_radius 1.2 x2, 0.8 x1)"
    assert said in out and said in err and "teacher" not in out
