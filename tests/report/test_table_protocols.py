"""`floaff-zoo table` rows hold runs of one protocol and one report per checkpoint; float group keys stay distinct."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from floaff_zoo.report.table import TableError, _fmt_key, build_table, main, render

FIX = Path(__file__).parent / "fixtures" / "runs"
BASE = json.loads((FIX / "cfar_styles_s0" / "report.json").read_text())


def report(
    seed: int, top_k: int = 1, free_space: str | None = None, pose_source: str | None = None, **top: object
) -> dict:
    """A CFAR Styles report of seed ``seed`` (its own checkpoint hash) under an SR protocol; ``top`` overrides
    top-level fields (``sim_variant``, ``metric_reduction``, ``checkpoint``, ``label``)."""
    rep = copy.deepcopy(BASE)
    rep["seed"] = seed
    rep["checkpoint"] = {"path": f"runs/s{seed}/last.ckpt", "sha256": f"{seed + 1:064x}"}
    rep["sr"]["top_k"] = top_k
    if free_space is not None:
        rep["sr"]["free_space"] = free_space
    if pose_source is not None:
        rep["sr"]["pose_source"] = pose_source
    rep.update(top)
    return rep


def write(tmp_path: Path, reports: dict[str, dict]) -> list[str]:
    """Each report into ``tmp_path/<name>/report.json``; returns the run directories."""
    dirs = []
    for name, rep in reports.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "report.json").write_text(json.dumps(rep))
        dirs.append(str(tmp_path / name))
    return dirs


@pytest.mark.parametrize(
    ("other", "setting"),
    [
        (dict(top_k=10, free_space="cloud"), "sr.top_k"),
        (dict(sim_variant="hist"), "sim_variant"),
        (dict(metric_reduction="official_batchwise"), "metric_reduction"),
        # the model's own placement (N2M, C2F-Exp) is another protocol than the map's argmax (a report without
        # the field stood on the argmax)
        (dict(pose_source="model"), "sr.pose_source"),
    ],
    ids=["top_k", "sim_variant", "metric_reduction", "pose_source"],
)
@pytest.mark.parametrize("preset", ["map", "sr_views", "sr_tasks"])
def test_a_row_refuses_reports_of_different_protocols(tmp_path, capsys, other, setting, preset):
    runs = write(tmp_path, {"p1_s0": report(0), "p1_s1": report(1), "p2_s0": report(2, **other)})
    assert main(["--runs", *runs, "--preset", preset]) == 2
    err = capsys.readouterr().err
    assert "row 'CFARModule' (FloAff-Kitchen (Styles))" in err and setting in err, err
    assert all(f"{name}/report.json" in err for name in ("p1_s0", "p1_s1", "p2_s0")), err
    assert "--runs" in err
    # one protocol's reports (a narrower --runs) make the table
    assert main(["--runs", *runs[:2], "--preset", preset]) == 0


def test_free_space_is_compared_only_where_top_k_uses_it():
    cloud, full = report(0, top_k=10, free_space="cloud"), report(1, top_k=10, free_space="full_cloud")
    with pytest.raises(TableError, match=r"sr\.free_space = 'cloud' in .*sr\.free_space = 'full_cloud'"):
        build_table([cloud, full], "sr_views")
    # reports from before free_space was recorded used the simulator's footprints
    with pytest.raises(TableError, match=r"sr\.free_space = 'sim'"):
        build_table([cloud, report(1, top_k=10)], "sr_views")
    # top-1 needs no footprint check: a missing free_space and 'cloud' are one protocol
    assert build_table([report(0), report(1, free_space="cloud")], "sr_views").sections[0].rows[0].runs == 2


def test_one_checkpoint_counts_once(tmp_path, capsys):
    same = {"path": "runs/x/last.ckpt", "sha256": "ab" * 32}
    runs = write(tmp_path, {"test_a": report(0, checkpoint=same), "test_b": report(0, checkpoint=same)})
    assert main(["--runs", *runs]) == 2
    err = capsys.readouterr().err
    assert "same checkpoint" in err and "abababab" in err and "row 'CFARModule'" in err
    assert "test_a/report.json" in err and "test_b/report.json" in err
    # the same checkpoint under another protocol is refused for the protocol (the differing setting is named)
    other = report(0, top_k=10, free_space="cloud", checkpoint=same)
    with pytest.raises(TableError, match=r"sr\.top_k"):
        build_table([report(0, checkpoint=same), other], "map")
    # ... and may be its own row (another label), as may a report with no checkpoint hash
    rows = build_table([report(0, checkpoint=same), dict(other, label="top-10")], "map", group_by="label")
    assert [r.runs for r in rows.sections[0].rows] == [1, 1]
    assert build_table([report(0, checkpoint=None), report(1, checkpoint=None)], "map").sections[0].rows[0].runs == 2


def test_one_training_free_evaluation_counts_once():
    """A model without a checkpoint (C2F-Exp) tested twice was pooled as two seeds with a std of 0."""
    runs = [report(0, checkpoint=None), report(0, checkpoint=None)]
    with pytest.raises(
        TableError,
        match=r"same CFARModule without a checkpoint, with the same hyper-parameters and seed 0.*one run twice",
    ):
        build_table(runs, "sr_views")
    assert build_table([report(0, checkpoint=None), report(1, checkpoint=None)], "map").sections[0].rows[0].runs == 2


def test_a_row_holds_one_test_set():
    """A run tested on a task or view subset, or on fewer samples, was pooled as a seed of the full evaluation."""
    subset = report(1)
    subset["data"] = {**BASE["data"], "views": ["front"], "num_samples": 20}
    with pytest.raises(TableError, match=r"data\.views = \['front'\]"):
        build_table([report(0), subset], "map")


def test_an_int_and_a_float_group_value_are_one_row_in_every_preset():
    """sr_views grouped crop_radius 1 and 1.0 into one row but filled it from the 1.0 reports only."""
    reps = [report(s, model=dict(BASE["model"], hparams={"crop_radius": r})) for s, r in enumerate((1, 1.0))]
    for preset in ("map", "sr_views", "sr_tasks"):
        table = build_table(reps, preset, group_by="model.hparams.crop_radius", oracle=False)
        assert [(r.name, r.runs) for r in table.sections[0].rows] == [("1.00", 2)], preset


def test_rows_of_different_protocols_share_no_oracle_row():
    top1, top10 = report(0), report(1, top_k=10, free_space="cloud", label="top-10")
    with pytest.raises(TableError, match=r"row 'Oracle'.*sr\.top_k.*--no-oracle"):
        build_table([top1, top10], "sr_views", group_by="label")
    table = build_table([top1, top10], "sr_views", group_by="label", oracle=False)
    assert [r.name for r in table.sections[0].rows] == ["CFARModule", "top-10"]


def test_float_group_keys_stay_distinct():
    reps = [
        report(s, model=dict(BASE["model"], hparams={"train": {"lr": lr}}))
        for s, lr in enumerate((2e-4, 2e-4, 8e-4, 8e-4))
    ]
    table = build_table(reps, "ablation", group_by="model.hparams.train.lr")
    assert [(r.name, r.runs) for r in table.sections[0].rows] == [("0.0002", 2), ("0.0008", 2)]
    assert "| 0.0002 |" in render(table, "md")
    # values that printed distinctly keep their text (crop radii of the committed sweep tables)
    assert [_fmt_key(v) for v in (1.1, 1.25, 1.3, 0.5, 2.0)] == ["1.10", "1.25", "1.30", "0.50", "2.00"]
    assert _fmt_key(1.125) != _fmt_key(1.12) and _fmt_key(1e-5) != _fmt_key(0.0)
    assert [_fmt_key(v) for v in (3, "label", None)] == ["3", "label", "None"]


def test_rows_of_different_sr_protocols_are_named_under_the_table(tmp_path, capsys):
    """Without an Oracle row, rows of different SR protocols shared a column with nothing saying so."""
    top1, top10 = report(0), report(1, top_k=10, free_space="cloud", label="top-10")
    for preset in ("sr_views", "sr_tasks"):
        table = build_table([top1, top10], preset, group_by="label", oracle=False)
        assert table.mixed == "rows differ in sr.top_k: 1 (CFARModule), 10 (top-10)"
        assert "; rows differ in sr.top_k: 1 (CFARModule), 10 (top-10). Runs per row" in render(table, "md")
    runs = write(tmp_path, {"a": top1, "b": top10})
    assert main(["--runs", *runs, "--preset", "sr_views", "--group-by", "label", "--no-oracle", "--format", "csv"]) == 0
    assert "note: the rows differ in sr.top_k: 1 (CFARModule), 10 (top-10)" in capsys.readouterr().err
    assert build_table([top1, report(1)], "sr_views", oracle=False).mixed == ""  # one protocol: no note


def test_map_rows_of_different_test_protocols_are_named_under_the_table():
    """The map, ablation and sweep presets put rows of another metric reduction or test set in one column with no
    word, and one of them in bold as the best."""
    official = report(2, metric_reduction="official_batchwise", label="official")
    fewer = report(3, label="two tasks", data=dict(BASE["data"], tasks=["CloseDrawer", "PnPCounterToCab"]))
    for preset in ("map", "ablation"):
        table = build_table([report(0), report(1), official, fewer], preset, group_by="label")
        assert "metric_reduction: " in table.mixed and "(official)" in table.mixed, table.mixed
        assert "data.tasks: " in table.mixed and "(two tasks)" in table.mixed, table.mixed
        assert f"; {table.mixed}. Runs per row" in render(table, "md")
    assert build_table([report(0), report(1)], "map").mixed == ""
    # how SR chose its pose does not touch the map columns: no note for that
    top10 = report(4, top_k=10, free_space="cloud", label="top-10")
    assert build_table([report(0), report(1), top10], "map", group_by="label").mixed == ""


def test_sr_views_counts_each_benchmarks_runs_apart():
    """A model with one run per benchmark was listed as 2 runs: its cells read as a spread over 2 seeds, each being
    one run's bootstrap std."""
    layouts = report(1, data=dict(BASE["data"], benchmark="layouts", dataset="floaff_sim_layouts"))
    table = build_table([report(0), layouts], "sr_views", oracle=False)
    assert [(r.runs, r.runs_text) for r in table.sections[0].rows] == [(2, "Styles 1, Layouts 1")]  # CSV keeps 2
    assert "Runs per row: CFARModule: Styles 1, Layouts 1." in render(table, "md")
    assert [r.runs for r in build_table([report(0), report(1)], "sr_views", oracle=False).sections[0].rows] == [2]


def single_task(seed: int, task: str, mean: float, label: str = "one model per task") -> dict:
    """A report of a model trained and tested on ``task`` alone (the paper's Table 3 protocol)."""
    rep = report(seed, label=label)
    rep["data"] = {**BASE["data"], "tasks": [task], "num_samples": 200}
    rep["sr"]["model"]["tasks"] = {task: {"mean": mean, "std": 0.02, "n": 200}}
    rep["sr"]["oracle"]["tasks"] = {task: BASE["sr"]["oracle"]["tasks"][task]}
    return rep


def test_an_sr_tasks_row_pools_one_model_per_task(tmp_path, capsys):
    """One model per task (the paper's Table 3) was refused as a row mixing test sets: each column now pools the
    runs tested on its task, and the count under the table says how many runs each task has."""
    reps = [
        single_task(0, "PnPCounterToCab", 0.6),
        single_task(1, "PnPCounterToCab", 0.8),
        single_task(2, "OpenSingleDoor", 0.5),
    ]
    table = build_table(reps, "sr_tasks", group_by="label")
    (row, oracle) = table.sections[0].rows
    assert [c.name for c in table.columns] == ["PnPC2C", "OpenSD"]
    pnp, osd = row.cells
    assert round(pnp.mean, 6) == 0.7 and round(pnp.std, 6) == round(0.02**0.5, 6) and (pnp.n, pnp.of) == (2, 2)
    assert round(osd.mean, 6) == 0.5 and (osd.n, osd.of) == (1, 1)
    assert row.runs_text == "3 (PnPC2C 2, OpenSD 1)" and oracle.oracle
    assert table.mixed == ""
    md = render(table, "md")
    assert "| one model per task | 0.70 ± 0.14 | 0.50 ± 0.02 |" in md, md
    runs = write(tmp_path, {f"r{i}": r for i, r in enumerate(reps)})
    assert main(["--runs", *runs, "--preset", "sr_tasks", "--group-by", "label"]) == 0
    # the map preset has no per-task columns: its rows still hold one test set
    with pytest.raises(TableError, match=r"data\.tasks"):
        build_table(reps, "map", group_by="label")


def test_an_sr_tasks_column_refuses_one_task_runs_beside_a_multi_task_run():
    """A column must not pool a model trained for one task with one trained for all of them."""
    both = report(3, label="one model per task")  # tested on OpenSingleDoor and PnPCounterToCab
    with pytest.raises(TableError, match=r"row 'one model per task, PnPC2C'.*data\.tasks"):
        build_table([single_task(0, "PnPCounterToCab", 0.6), both], "sr_tasks", group_by="label")


def test_sr_tasks_rows_of_one_and_of_several_tasks_per_run_are_named_under_the_table():
    table = build_table([single_task(0, "PnPCounterToCab", 0.6), report(1)], "sr_tasks", group_by="label")
    assert table.mixed == "rows differ in tasks per run: 1 (one model per task), 2 (CFARModule)"
