"""``floaff-zoo table``: paper-style tables (mean ± std over seeds) from ``report.json`` files.

Usage::

    floaff-zoo table --runs runs/cfar* runs/navaff --group-by model --format md --preset sr_views --out t.md

Each ``--runs`` entry is a run directory, a glob, or a ``report.json`` file; directories are
searched recursively for ``report.json`` (written by the ``TestReport`` callback). Only
``report.json`` files are read, never logger files. A directory without one, and an unreadable
report or one with a field of the wrong type (``model`` a string, an SR mean a string), is named on
stderr and skipped; the skips are counted.

Presets (shaped like the FloAff-Kitchen paper's tables):

* ``map`` (Table 1): RMSE ↓, logMSE ↓, PCC ↑, SIM ↑; one section per benchmark, one row per group.
* ``sr_views`` (Table 2): SR_front, SR_side, SR_all per benchmark; an Oracle row (ground-truth maps).
* ``sr_tasks`` (Table 3): SR per task (all views); one section per benchmark; an Oracle row. A row may hold one
  model per task (runs each tested on one task, as the paper's Table 3 trains them): each column pools the runs
  tested on its task, which must share their test tasks; the count under the table gives each task's runs.
* ``ablation`` (Tables 4-5): map metrics, rows grouped by the report's ``label`` by default.
* ``sweep`` (crop-radius study): map metrics, rows grouped by ``model.hparams.crop_radius`` by
  default and sorted numerically.

Cells are the mean over the runs of a row ± their sample standard deviation (ddof=1, i.e. over
seeds); a row with a single run shows its SR bootstrap std (see ``RolloutSuccessRate``) and no
± for map metrics. A cell made from fewer runs than its row holds (a run without SR, a NaN metric)
is marked ``(n=1/2)``. The best mean of each column within a section is bold (the Oracle row never).
``--group-by`` takes ``model`` (class name), ``label``, ``benchmark`` or any dotted path into
``report.json`` (``model.hparams.crop_radius``, ``config.data.init_args.crop_radius``, ``seed``).

A row pools runs of one protocol: reports that differ in the SR protocol (``sr.top_k``; ``sr.free_space`` where top_k >
1; ``sr.pose_source``, the map's argmax or the model's own placement), ``sim_variant`` or ``metric_reduction``, or two
reports of one checkpoint (``checkpoint.sha256``), are refused with the row, the setting and the report paths (pass one
protocol's reports, e.g. a narrower ``--runs`` glob); so is an Oracle row over reports of different SR protocols (or
pass ``--no-oracle``). Rows of different SR protocols (without an Oracle row) are allowed, since a top-k ablation
compares them on purpose; the Markdown note and stderr name the setting and the rows of each value. They also name a
row whose runs differ in a model hyper-parameter other than a seed's own files (``teacher``, ``weights``,
``axisnet``) and seed: two variants under one label, or one model class under ``--group-by model``, are no seeds.

A row whose runs read the simulator's target yaw at test time (``eval_yaw_source: gt``; C2F-Exp's ``yaw_source:
gt``), which a robot does not have, is named with `` (simulator yaw)`` unless its name says so already.

Runs whose reports give one scene different label hashes (``data.labels_sha256``: copies of a preset generated on
different CPUs differ in a few rollouts) are not put in one table unless ``--allow-mixed-data`` says so; reports
written before the hash was recorded are not checked.
"""

from __future__ import annotations

import argparse
import difflib
import glob
import json
import math
import statistics
import sys
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from floaff_zoo.frames import PRIVILEGED_YAW

PRESETS = ("map", "sr_views", "sr_tasks", "ablation", "sweep")
FORMATS = ("md", "latex", "csv")
#: (metric key, display name, decimals, lower is better)
MAP_COLUMNS = (
    ("rmse", "RMSE", 3, True),
    ("logmse", "logMSE", 4, True),
    ("pcc", "PCC", 3, False),
    ("sim", "SIM", 3, False),
)
TASK_SHORT = {
    "PnPCounterToCab": "PnPC2C",
    "OpenSingleDoor": "OpenSD",
    "CloseDrawer": "CloseD",
    "CloseDoubleDoor": "CloseDD",
}
VIEWS = ("front", "side", "all")
DEFAULT_GROUP = {
    "map": "model",
    "sr_views": "model",
    "sr_tasks": "model",
    "ablation": "label",
    "sweep": "model.hparams.crop_radius",
}


#: files that mark a Lightning run directory (used only to name run dirs lacking report.json)
RUN_MARKERS = ("config.yaml", "hparams.yaml", "metrics.csv")


class TableError(ValueError):
    """A user-facing error of ``floaff-zoo table`` (bad arguments, no usable report)."""


# ------------------------------------------------------------------------------------------ loading
#: why a folder named report.json is skipped
FOLDER_NAMED = "a folder named report.json, not a report"


def load_reports(runs: list[str]) -> tuple[list[tuple[Path, dict[str, Any]]], list[tuple[str, str]]]:
    """Find and parse report.json files.

    Args:
        runs: run directories, globs or report.json paths.
    Returns:
        ([(path, report)] sorted by path, [(entry, reason)] for every skipped entry).
    """
    found: dict[Path, None] = {}
    skipped: list[tuple[str, str]] = []
    for entry in runs:
        matches = sorted(glob.glob(entry, recursive=True)) if glob.has_magic(entry) else [entry]
        if not matches:
            skipped.append((entry, "no such file or directory"))
        for m in matches:
            p = Path(m)
            if p.is_file():
                if p.name == "report.json":
                    found[p.resolve()] = None
                else:
                    skipped.append((m, "not a run directory or report.json"))
            elif p.is_dir() and p.name == "report.json":
                skipped.append((m, FOLDER_NAMED))
            elif p.is_dir():
                # a folder named report.json is no report: named as one, not as a file that could not be read
                reports = [r for r in sorted(p.rglob("report.json")) if r.is_file()]
                skipped += [(str(r), FOLDER_NAMED) for r in sorted(p.rglob("report.json")) if r.is_dir()]
                if not reports:
                    skipped.append((m, "no report.json (run `floaff-zoo test` with the TestReport callback)"))
                for r in reports:
                    found[r.resolve()] = None
                # run directories (logger/config files) below p that hold no report.json are named too
                have = {r.parent for r in reports}
                for d in sorted({q.parent for marker in RUN_MARKERS for q in p.rglob(marker)}):
                    if d != p and not any(h == d or h.is_relative_to(d) or d.is_relative_to(h) for h in have):
                        skipped.append((str(d), "no report.json (run `floaff-zoo test` with the TestReport callback)"))
            else:
                skipped.append((m, "no such file or directory"))
    loaded: list[tuple[Path, dict[str, Any]]] = []
    for path in sorted(found):
        try:
            rep = json.loads(path.read_text())
        except (OSError, ValueError) as exc:  # ValueError: bad JSON or bytes that are not UTF-8
            skipped.append((str(path), f"unreadable report.json ({exc})"))
            continue
        if not isinstance(rep, dict) or rep.get("schema") != "floaff-zoo/report":
            skipped.append((str(path), "not a floaff-zoo report (schema field missing)"))
            continue
        version = rep.get("version")
        if version is not None and (isinstance(version, bool) or version not in READ_VERSIONS):
            skipped.append(
                (str(path), f"report format version {version!r}; this floaff-zoo reads {list(READ_VERSIONS)}")
            )
            continue
        wrong = malformed_field(rep)
        if wrong is not None:
            skipped.append((str(path), f"malformed report.json ({wrong})"))
            continue
        loaded.append((path, rep))
    return loaded, skipped


#: the kinds of value a report field may hold; null (not recorded) is allowed for every field
OBJECT, TEXT, NUMBER, INTEGER, FLAG = "an object", "a string", "a number", "an integer", "true or false"


def _is_kind(value: Any, kind: str) -> bool:
    """Whether ``value`` is null or of ``kind`` (JSON ``true``/``false`` is neither a number nor an integer)."""
    if value is None:
        return True
    if kind == OBJECT:
        return isinstance(value, dict)
    if kind == TEXT:
        return isinstance(value, str)
    if kind == FLAG:
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    return isinstance(value, int) if kind == INTEGER else isinstance(value, (int, float))


def _typed_fields(rep: dict[str, Any]) -> Iterator[tuple[str, Any, str]]:
    """(dotted name, value, kind) of every report field the table reads, each object before the fields in it."""

    def get(obj: Any, key: str) -> Any:  # a field under a malformed parent reads as absent: the parent is named
        return obj.get(key) if isinstance(obj, dict) else None

    for name in ("model", "data", "metrics", "sr", "checkpoint"):
        yield name, rep.get(name), OBJECT
    for name in ("label", "sim_variant", "metric_reduction"):
        yield name, rep.get(name), TEXT
    model, data, sr = rep.get("model"), rep.get("data"), rep.get("sr")
    yield "model.name", get(model, "name"), TEXT
    yield "model.hparams", get(model, "hparams"), OBJECT
    for source in ("eval_yaw_source", "yaw_source"):  # read for the (simulator yaw) marker
        yield f"model.hparams.{source}", get(get(model, "hparams"), source), TEXT
    yield "data.num_samples", get(data, "num_samples"), INTEGER
    yield "data.benchmark", get(data, "benchmark"), TEXT
    labels = get(data, "labels_sha256")
    yield "data.labels_sha256", labels, OBJECT
    for scene, digest in (labels if isinstance(labels, dict) else {}).items():
        yield f"data.labels_sha256.{scene}", digest, TEXT
    yield "checkpoint.sha256", get(rep.get("checkpoint"), "sha256"), TEXT
    for key, _, _, _ in MAP_COLUMNS:
        yield f"metrics.test_{key}", get(rep.get("metrics"), f"test_{key}"), NUMBER
    yield "sr.available", get(sr, "available"), FLAG
    yield "sr.top_k", get(sr, "top_k"), INTEGER
    yield "sr.free_space", get(sr, "free_space"), TEXT
    yield "sr.pose_source", get(sr, "pose_source"), TEXT
    for who in ("model", "oracle"):
        results = get(sr, who)
        yield f"sr.{who}", results, OBJECT
        tasks = get(results, "tasks")
        yield f"sr.{who}.tasks", tasks, OBJECT
        cells = [(f"sr.{who}.{view}", get(results, view)) for view in VIEWS]
        cells += [(f"sr.{who}.tasks.{task}", cell) for task, cell in (tasks if isinstance(tasks, dict) else {}).items()]
        for name, cell in cells:
            yield name, cell, OBJECT
            yield f"{name}.mean", get(cell, "mean"), NUMBER
            yield f"{name}.std", get(cell, "std"), NUMBER


def malformed_field(rep: dict[str, Any]) -> str | None:
    """The first field the table reads that holds the wrong kind of value (``'sr' is a str, not an object``), or
    None: a report with a string SR mean or a number for ``model`` would crash or mislead a table."""
    for name, value, kind in _typed_fields(rep):
        if not _is_kind(value, kind):
            return f"{name!r} is {type(value).__name__} {json.dumps(value)[:40]}, not {kind}"
    return None


def lookup(report: dict[str, Any], key: str) -> Any:
    """Group value of a report: ``model`` = class name, ``benchmark``, ``label``, or a dotted path."""
    if key == "model":
        return (report.get("model") or {}).get("name")
    if key == "benchmark":
        return (report.get("data") or {}).get("benchmark")
    cur: Any = report
    for part in key.split("."):
        if isinstance(cur, dict) and part in cur:
            cur = cur[part]
        elif isinstance(cur, dict) and part == "hparams" and "init_args" in cur:
            cur = cur["init_args"]
        else:
            return None
    return cur


def benchmark_name(report: dict[str, Any]) -> str:
    """Display name of a report's benchmark (paper names where recognised)."""
    raw = str(lookup(report, "benchmark") or (report.get("data") or {}).get("dataset") or "unknown")
    low = raw.lower()
    if "layout" in low:
        return "FloAff-Kitchen (Layouts)"
    if "style" in low:
        return "FloAff-Kitchen (Styles)"
    if "moma" in low:
        return "MoMa-Kitchen"
    return raw


# ------------------------------------------------------------------------------------------ table model
@dataclass
class Cell:
    mean: float
    std: float | None
    n: int
    of: int = 0  # runs of the cell's row in its section; a cell with n < of is marked (n=1/2) when rendered


@dataclass
class Column:
    name: str
    decimals: int
    lower_better: bool
    group: str = ""  # header group (benchmark in sr_views)
    arrow: bool = False  # show the better direction (map metrics)


@dataclass
class Row:
    name: str
    cells: list[Cell | None]
    runs: int  # reports pooled in the row
    oracle: bool = False
    runs_text: str = ""  # how the footnote counts them when not ``runs`` (sr_views: "Styles 3, Layouts 1")


@dataclass
class Section:
    title: str
    rows: list[Row] = field(default_factory=list)


@dataclass
class Table:
    title: str
    row_header: str
    columns: list[Column]
    sections: list[Section]
    note: str = ""
    # how the rows' protocols differ (``mixed_protocols``) and what settings a row pools (``pooled_settings``), named
    # under the table and on stderr
    mixed: str = ""


#: one run's value in a cell and its own std (an SR's bootstrap std; None for a map metric); value None: n/a
RunValue = tuple[float | None, float | None]
#: reads a report's ``RunValue`` for one column
Getter = Callable[[dict[str, Any]], RunValue]


def aggregate(runs: Sequence[RunValue]) -> Cell | None:
    """Mean ± std over runs (ddof=1); a single run keeps its own std (SR bootstrap) if any. Runs whose value is
    missing or not finite are left out, their own std with them."""
    kept = [(float(v), s) for v, s in runs if v is not None and math.isfinite(float(v))]
    if not kept:
        return None
    if len(kept) == 1:
        return Cell(kept[0][0], kept[0][1], 1)
    vals = [v for v, _ in kept]
    return Cell(statistics.fmean(vals), statistics.stdev(vals), len(vals))


def _metric(report: dict[str, Any], key: str) -> RunValue:
    """(value, None) of a map metric; null (``test_pcc`` where no map has a Pearson r) is n/a and never ranked."""
    v = (report.get("metrics") or {}).get(f"test_{key}")
    return (float(v) if v is not None else None), None


def _sr(report: dict[str, Any], who: str, view: str | None = None, task: str | None = None) -> RunValue:
    sr = report.get("sr") or {}
    if not sr.get("available"):
        return None, None
    t = sr.get(who) or {}
    cell = (t.get("tasks") or {}).get(task) if task else t.get(view)
    return (cell.get("mean"), cell.get("std")) if isinstance(cell, dict) else (None, None)


def _cell(reports: list[dict[str, Any]], getter: Getter) -> Cell | None:
    """The cell of a row's ``reports`` (one section): mean ± std of ``getter``'s (value, std) over the runs that
    have a value, recording how many runs the row holds there (``of``)."""
    cell = aggregate([getter(r) for r in reports])
    if cell is not None:
        cell.of = len(reports)
    return cell


def _oracle_cell(reports: list[dict[str, Any]], getter: Getter) -> Cell | None:
    """The Oracle does not depend on the model: runs on one test split report the same episodes, so identical
    values are shown once with their bootstrap std (a std over runs would read 0); differing ones (several
    test splits) are pooled like a model row. Non-finite values are left out first (as ``aggregate`` leaves them): a
    NaN compared as equal or not by where it stood, and identical values read ± 0."""
    runs = [r for r in map(getter, reports) if r[0] is not None and math.isfinite(float(r[0]))]
    if runs and max(v for v, _ in runs) - min(v for v, _ in runs) < 1e-9:
        runs = runs[:1]
    return aggregate(runs)


def _group_rows(
    reports: list[dict[str, Any]],
    group_by: str,
    numeric: bool,
    section: str = "",
    floats: bool | None = None,
    protocol_keys: tuple[str, ...] | None = None,
) -> list[tuple[str, list[dict]]]:
    """Reports split into rows by their ``group_by`` value (``numeric``: rows sorted by it); each row is checked
    by ``check_row`` (one protocol in ``protocol_keys``, default ``PROTOCOL``; one report per checkpoint).
    ``section`` names the rows' section in errors. ``floats``: read int values as floats (default: when one of
    ``reports`` gives a float)."""
    groups: dict[str, list[dict]] = {}
    keys: dict[str, Any] = {}
    values = [lookup(r, group_by) for r in reports]
    for r, v in zip(reports, values):
        if v is None:
            hint = _field_hint(group_by, reports, values)
            raise TableError(f"--group-by {group_by}: report {_where(r)} has no such field{hint}")
    # where some runs give a float, an int is the same number (crop_radius 1 and 1.0 are one row)
    if floats is None:
        floats = any(isinstance(v, float) for v in values)
    for r, v in zip(reports, values):
        if floats and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        name = _fmt_key(v)
        groups.setdefault(name, []).append(r)
        keys[name] = v
    names = list(groups)
    if numeric:
        try:
            names.sort(key=lambda n: float(keys[n]))
        except (TypeError, ValueError) as exc:
            raise TableError(f"--group-by {group_by}: values {sorted(groups)} are not numeric") from exc
    for n in names:
        check_row(n, groups[n], section, protocol_keys)
    return [(n, groups[n]) for n in names]


#: the ``--group-by`` keys that are no dotted path into a report (``lookup``)
GROUP_NAMES = ("model", "label", "benchmark")


def _dotted_fields(value: Any, prefix: str = "") -> Iterator[str]:
    """The dotted path of every field of a report (objects are walked into, lists are not)."""
    for key, item in value.items() if isinstance(value, dict) else ():
        if key != PATH_KEY:
            yield f"{prefix}{key}"
            yield from _dotted_fields(item, f"{prefix}{key}.")


def _field_hint(group_by: str, reports: list[dict[str, Any]], values: list[Any]) -> str:
    """``"; did you mean 'label'?"`` when no report has the ``--group-by`` field (a typo, not a field some runs lack)
    and the reports have a field close to it (a field beside it whose name is close, else a close dotted path: the
    shared ``model.hparams.`` of two paths made every field of a model close); else ``""``."""
    if any(v is not None for v in values):
        return ""
    # not the field itself: a report without 'model' was told "did you mean 'model'?"
    fields = {*GROUP_NAMES, *(f for r in reports for f in _dotted_fields(r))} - {group_by}
    parent, _, name = group_by.rpartition(".")
    beside = {f.rpartition(".")[2]: f for f in fields if f.rpartition(".")[0] == parent}
    close = [beside[k] for k in difflib.get_close_matches(name, sorted(beside), n=3, cutoff=0.75)]
    close = close or difflib.get_close_matches(group_by, sorted(fields), n=3, cutoff=0.85)
    return f"; did you mean {' or '.join(map(repr, close))}?" if close else ""


def _fmt_key(v: Any) -> str:
    """Row name of a group value: floats with 2 decimals where that is exact (``1.10``, ``1.25``), else the
    shortest text that reads back as the value (``0.0002``), so distinct values never share a row."""
    if isinstance(v, float):
        s = f"{v:.2f}"
        return s if float(s) == v else repr(v)
    return str(v)


#: the ``version`` values of report.json whose fields this table knows (``callbacks.report.SCHEMA_VERSION`` writes
#: one of them): a report of another version, from a newer floaff-zoo, was read as this one
READ_VERSIONS: tuple[int, ...] = (1,)
#: the report path ``main`` attaches to each report (named in errors); ``run_dir`` is used when absent
PATH_KEY = "_report_path"
#: settings every report of a row must share (dotted names as in errors); SR ones only where SR was measured; the
#: test set (a run tested on a task or view subset, or with limit_test_batches, is no seed of the full evaluation)
PROTOCOL = (
    "sr.top_k",
    "sr.free_space",
    "sr.pose_source",
    "sim_variant",
    "metric_reduction",
    "data.tasks",
    "data.views",
    "data.num_samples",
)
SR_PROTOCOL = PROTOCOL[:3]


def _where(report: dict[str, Any]) -> str:
    """Where a report came from: its report.json path, else the run directory it records."""
    return str(report.get(PATH_KEY) or report.get("run_dir") or report.get("label") or "?")


def protocol(report: dict[str, Any]) -> dict[str, Any]:
    """The evaluation settings of a report (None = unknown or irrelevant, never compared).

    SR settings count only where SR was measured; ``free_space`` only with ``top_k > 1`` (the top-1 pose needs no
    footprint check), and reports from before it was recorded used the simulator's footprints (``sim``).
    """
    sr = report.get("sr") or {}
    out = {"sim_variant": report.get("sim_variant"), "metric_reduction": report.get("metric_reduction")}
    top_k = sr.get("top_k") if sr.get("available") else None
    out["sr.top_k"] = top_k
    out["sr.free_space"] = sr.get("free_space", "sim") if top_k is not None and top_k != 1 else None
    # reports from before the choice existed stood on the map's argmax
    out["sr.pose_source"] = sr.get("pose_source", "map") if top_k is not None else None
    data = report.get("data") or {}
    for key in ("tasks", "views", "num_samples"):
        out[f"data.{key}"] = data.get(key)
    return out


def _checkpoint_sha(report: dict[str, Any]) -> str | None:
    """The sha256 of a report's checkpoint (None without one)."""
    digest = (report.get("checkpoint") or {}).get("sha256")
    return str(digest) if digest else None


HINT = "tabulate one protocol's reports per row (e.g. a narrower --runs glob)"


def check_row(name: str, reports: list[dict[str, Any]], section: str = "", keys: tuple[str, ...] | None = None) -> None:
    """Raise TableError unless a row's reports are runs of one protocol (``check_protocol`` over ``keys``, default
    ``PROTOCOL``) and of different checkpoints (``check_checkpoints``): only then is mean ± std over them a spread
    over seeds."""
    check_protocol(name, reports, section, PROTOCOL if keys is None else keys, HINT)
    check_checkpoints(name, reports, section)


#: what a test set's tasks decide: an ``sr_tasks`` row's runs may differ in them, since each column is checked on its
#: own (``task_reports``)
TASK_SET = ("data.tasks", "data.num_samples")
#: the protocol of an ``sr_tasks`` row
TASK_ROW_PROTOCOL = tuple(k for k in PROTOCOL if k not in TASK_SET)


def tested_on(report: dict[str, Any], task: str) -> bool:
    """Whether a report's test set held ``task`` (a report that does not record its tasks counts as holding it)."""
    tasks = protocol(report)["data.tasks"]
    return tasks is None or task in tasks


def task_reports(name: str, reports: list[dict[str, Any]], task: str, section: str = "") -> list[dict[str, Any]]:
    """The reports of an ``sr_tasks`` row tested on ``task``. They must share their test tasks: a row may pool
    single-task runs (one model per task, the paper's Table 3), each column one task's runs, but not a column of
    one-task runs with runs of a multi-task model."""
    on_task = [r for r in reports if tested_on(r, task)]
    check_protocol(f"{name}, {TASK_SHORT.get(task, task)}", on_task, section, TASK_SET, HINT)
    return on_task


def _task_counts(rows: list[tuple[str, list[dict[str, Any]]]]) -> dict[str, str]:
    """Per row of one section, how many tasks each of its runs was tested on (``"1"``, ``"4"``, ``"1, 4"``; rows
    whose runs record no tasks are left out): the ``sr_tasks`` note's stand-in for ``data.tasks``."""
    out = {}
    for name, reports in rows:
        counts = sorted({len(t) for t in (protocol(r)["data.tasks"] for r in reports) if t is not None})
        if counts:
            out[name] = ", ".join(map(str, counts))
    return out


def task_count_note(sections: list[tuple[str, list[tuple[str, list[dict[str, Any]]]]]]) -> str:
    """``"rows differ in tasks per run: 1 (A), 4 (B)"`` when the rows of one section differ in how many tasks their
    runs were tested on (one model per task against one model for all), else ``""``."""
    parts = []
    for title, rows in sections:
        where = f"{_short(title)} " if title and len(sections) > 1 else ""
        seen: dict[str, list[str]] = {}
        for name, count in _task_counts(rows).items():
            seen.setdefault(count, []).append(name)
        if len(seen) > 1:
            parts.append(f"{where}tasks per run: " + ", ".join(f"{c} ({', '.join(n)})" for c, n in seen.items()))
    return f"rows differ in {'; '.join(parts)}" if parts else ""


def check_oracle(reports: list[dict[str, Any]], section: str = "") -> None:
    """Raise TableError when the Oracle row of a section would pool Oracle SR of different SR protocols."""
    with_oracle = [r for r in reports if (r.get("sr") or {}).get("oracle")]
    check_protocol("Oracle", with_oracle, section, SR_PROTOCOL, HINT + ", or pass --no-oracle")


def mixed_protocols(
    sections: list[tuple[str, list[tuple[str, list[dict[str, Any]]]]]], keys: tuple[str, ...] = PROTOCOL
) -> str:
    """``"rows differ in sr.top_k: 1 (A, B), 10 (C)"`` when the rows of one section (benchmark) differ in a setting
    of ``keys`` (each row is one protocol, ``check_row``), else ``""``. A table may compare rows of different
    protocols (a top-k ablation does on purpose; rows tested on other tasks or views, or with another metric
    reduction, do not), and its note then says so; each part names its benchmark when the table has several."""
    parts = []
    for title, rows in sections:
        where = f"{_short(title)} " if title and len(sections) > 1 else ""
        for key in keys:
            seen: dict[str, list[str]] = {}
            for name, reports in rows:
                values = {repr(v) for v in (protocol(r)[key] for r in reports) if v is not None}
                for v in values:
                    if name not in seen.setdefault(v, []):
                        seen[v].append(name)
            if len(seen) > 1:
                parts.append(f"{where}{key}: " + ", ".join(f"{v} ({', '.join(names)})" for v, names in seen.items()))
    return f"rows differ in {'; '.join(parts)}" if parts else ""


#: model hyper-parameters that name a run's own files or seed: the seeds of one row differ in them by design
PER_RUN_HPARAMS = ("seed", "weights", "teacher", "axisnet", "axisnet_arch", "_instantiator")


def _settings(report: dict[str, Any], skip: tuple[str, ...] = ()) -> dict[str, str]:
    """A report's model hyper-parameters as dotted key -> JSON text, without ``PER_RUN_HPARAMS`` and ``skip``."""

    def walk(value: Any, prefix: str) -> Iterator[tuple[str, str]]:
        if isinstance(value, dict) and value:
            for k, v in value.items():
                yield from walk(v, f"{prefix}.{k}" if prefix else str(k))
        else:
            yield prefix, json.dumps(value, sort_keys=True, default=str)

    hparams = (report.get("model") or {}).get("hparams") or {}
    return {k: v for k, v in walk(hparams, "") if k.split(".", 1)[0] not in (*PER_RUN_HPARAMS, *skip)}


def pooled_settings(
    sections: list[tuple[str, list[tuple[str, list[dict[str, Any]]]]]], skip: tuple[str, ...] = ()
) -> str:
    """``"rows pool runs of different model settings: A (crop_radius 0.5 x2, 1.0 x1)"`` when a row's runs differ in
    a model hyper-parameter (``_settings``), else ``""``. A row's mean ± std reads as a spread over seeds: runs of two
    variants grouped under one label (the default ``ablation`` key, which defaults to the logger's name) were pooled
    without a word. ``skip``: settings a row may vary on purpose (``tasks`` for one model per task)."""
    parts = []
    for title, rows in sections:
        where = f"{_short(title)} " if title and len(sections) > 1 else ""
        for name, reports in rows:
            settings = [_settings(r, skip) for r in reports]
            keys = sorted({k for s in settings for k in s})
            differ = []
            for key in keys:
                counts = Counter(s.get(key, "(absent)") for s in settings)
                if len(counts) > 1:
                    differ.append(f"{key} " + ", ".join(f"{v} x{n}" for v, n in counts.items()))
            if differ:
                parts.append(f"{where}{name} ({'; '.join(differ[:3])}{'; ...' if len(differ) > 3 else ''})")
    return f"rows pool runs of different model settings: {', '.join(parts)}" if parts else ""


def _notes(*texts: str) -> str:
    """The non-empty notes under a table, joined."""
    return "; ".join(t for t in texts if t)


#: the report field that names the yaw a model read at test time, per model class (others: ``eval_yaw_source``)
_EVAL_YAW_FIELD = {"C2FExpModule": "yaw_source"}
#: the marker of a row whose runs read the simulator's yaw at test time
SIMULATOR_YAW = "simulator yaw"


def privileged_yaw(report: dict[str, Any]) -> bool:
    """Whether a report's model read the simulator's target yaw at test time (a ``PRIVILEGED_YAW`` source),
    which a robot does not have."""
    model = report.get("model") or {}
    hparams = model.get("hparams") or {}
    return hparams.get(_EVAL_YAW_FIELD.get(str(model.get("name")), "eval_yaw_source")) in PRIVILEGED_YAW


def _marked(name: str, reports: list[dict[str, Any]]) -> str:
    """A row's name, with `` (simulator yaw)`` when one of its runs read the simulator's yaw at test time and the
    name does not say so already: such a row is no fair comparison and must not pass for one."""
    if SIMULATOR_YAW in name.lower() or not any(privileged_yaw(r) for r in reports):
        return name
    return f"{name} ({SIMULATOR_YAW})"


def _row_name(name: str, section: str) -> str:
    """``row 'CFARModule' (FloAff-Kitchen (Styles))``: a row as errors name it."""
    return f"row {name!r}" + (f" ({section})" if section else "")


def check_protocol(name: str, reports: list[dict[str, Any]], section: str, keys: tuple[str, ...], hint: str) -> None:
    """Raise TableError naming the setting and the reports when a row's reports differ in one of ``keys``
    (settings of ``protocol``; unknown values are not compared)."""
    for key in keys:
        seen: dict[str, list[str]] = {}
        for r in reports:
            v = protocol(r)[key]
            if v is not None:
                seen.setdefault(repr(v), []).append(_where(r))
        if len(seen) > 1:
            which = "; ".join(f"{key} = {v} in {', '.join(paths)}" for v, paths in seen.items())
            raise TableError(f"{_row_name(name, section)} mixes reports of different protocols: {which}; {hint}")


def _run_identity(report: dict[str, Any]) -> tuple[str, str]:
    """What makes a run one run, and how errors name it: its checkpoint's sha256, or for a model without one
    (training-free: C2F-Exp, a prior given by weights) its class, hyper-parameters and seed."""
    sha = _checkpoint_sha(report)
    if sha is not None:
        return sha, f"checkpoint (sha256 {sha[:16]}…)"
    model = report.get("model") or {}
    what = [model.get("class_path") or model.get("name"), model.get("hparams"), report.get("seed")]
    shown = f"{str(what[0]).rsplit('.', 1)[-1]} without a checkpoint, with the same hyper-parameters and seed {what[2]}"
    return json.dumps(what, sort_keys=True, default=str), shown


def check_checkpoints(name: str, reports: list[dict[str, Any]], section: str = "") -> None:
    """Raise TableError when two reports of a row are one run (``_run_identity``: the same checkpoint, or the same
    training-free model and seed): one run tested twice is not two seeds (a row holds one protocol, so they are the
    same evaluation)."""
    first: dict[str, dict[str, Any]] = {}
    for r in reports:
        key, shown = _run_identity(r)
        if key in first:
            raise TableError(
                f"{_row_name(name, section)}: {_where(first[key])} and {_where(r)} report the same {shown} under "
                f"the same protocol, which would count one run twice; {HINT}"
            )
        first[key] = r


BENCH_ORDER = ("MoMa-Kitchen", "FloAff-Kitchen (Styles)", "FloAff-Kitchen (Layouts)")


def _sections(reports: list[dict[str, Any]]) -> list[tuple[str, list[dict]]]:
    """Reports split by benchmark, in the paper's order (MoMa-Kitchen, Styles, Layouts, then others A-Z)."""
    out: dict[str, list[dict]] = {}
    for r in reports:
        out.setdefault(benchmark_name(r), []).append(r)
    rank = {b: i for i, b in enumerate(BENCH_ORDER)}
    return sorted(out.items(), key=lambda kv: (rank.get(kv[0], len(rank)), kv[0]))


def _short(bench: str) -> str:
    """Column-group name: ``FloAff-Kitchen (Styles)`` -> ``Styles``."""
    return bench.split("(", 1)[1].rstrip(")") if bench.startswith("FloAff-Kitchen (") else bench


def check_one_copy(reports: list[dict[str, Any]]) -> None:
    """Raise TableError when two reports record different label hashes for one scene of one benchmark."""
    seen: dict[tuple[str, str], tuple[str, str]] = {}  # (benchmark, scene) -> (hash, run)
    for r in reports:
        data = r.get("data") or {}
        run = _where(r)  # the file read here, not the folder of the machine that wrote it
        for scene, digest in sorted((data.get("labels_sha256") or {}).items()):
            key = (benchmark_name(r), scene)
            first = seen.setdefault(key, (digest, run))
            if first[0] != digest:
                raise TableError(
                    f"scene {scene} ({key[0]}) has different labels in {first[1]} ({first[0]}) and {run} ({digest}): "
                    "the runs used different copies of the data (labels depend on the CPU that generated them); "
                    "tabulate runs of one copy, or pass --allow-mixed-data"
                )


def build_table(
    reports: list[dict[str, Any]],
    preset: str = "map",
    group_by: str | None = None,
    oracle: bool = True,
    mixed_data: bool = False,
) -> Table:
    """A Table of one preset from parsed reports (rows = groups; cells = mean ± std over runs).

    ``mixed_data``: allow runs whose reports disagree on a scene's labels (``check_one_copy``).
    """
    if preset not in PRESETS:
        raise TableError(f"unknown preset {preset!r}; choose from {list(PRESETS)}")
    if not reports:
        raise TableError("no report.json to tabulate")
    if not mixed_data:
        check_one_copy(reports)
    group_by = group_by or DEFAULT_GROUP[preset]
    numeric = preset == "sweep"
    note = (
        "mean ± std over the runs of each row (sample std over seeds); a single run shows its SR bootstrap std "
        "and no ± for map metrics; a cell from fewer runs than its row holds says how many (n=1/2); "
        "best mean per column in bold"
    )
    if preset in ("map", "ablation", "sweep"):
        columns = [Column(n, d, lo, arrow=True) for _, n, d, lo in MAP_COLUMNS]
        sections = []
        grouped = []
        for title, reps in _sections(reports):
            sec = Section(title)
            grouped.append((title, _group_rows(reps, group_by, numeric, title)))
            for name, group in grouped[-1][1]:
                cells = [_cell(group, lambda r, k=k: _metric(r, k)) for k, _, _, _ in MAP_COLUMNS]
                sec.rows.append(Row(_marked(name, group), cells, len(group)))
            sections.append(sec)
        header = {"map": "Method", "ablation": "Ablation", "sweep": group_by.rsplit(".", 1)[-1]}[preset]
        # the map columns do not depend on how SR chose a pose: only the other settings make rows incomparable
        map_keys = tuple(k for k in PROTOCOL if not k.startswith("sr."))
        notes = _notes(mixed_protocols(grouped, map_keys), pooled_settings(grouped))
        return Table(preset, header, columns, sections, note, notes)
    if preset == "sr_views":
        benches = _sections(reports)
        columns = [Column(f"SR_{v}", 2, False, group=_short(b)) for b, _ in benches for v in VIEWS]
        # one row name per value over every benchmark (an int read as a float when any report gives a float)
        floats = any(isinstance(lookup(r, group_by), float) for r in reports)
        by_bench = [dict(_group_rows(reps, group_by, False, bench, floats)) for bench, reps in benches]
        names = list(dict.fromkeys(n for groups in by_bench for n in groups))
        sec = Section("")
        for name in names:
            cells: list[Cell | None] = []
            row_reports = []
            for groups in by_bench:
                group = groups.get(name, [])
                row_reports += group
                cells += [_cell(group, lambda r, v=v: _sr(r, "model", view=v)) for v in VIEWS]
            # each cell pools one benchmark's runs: a total over benchmarks read as a spread over that many seeds
            counts = [(_short(b), len(g.get(name, []))) for (b, _), g in zip(benches, by_bench)]
            text = ", ".join(f"{b} {n}" for b, n in counts if n) if len(benches) > 1 else ""
            sec.rows.append(Row(_marked(name, row_reports), cells, len(row_reports), runs_text=text))
        if oracle:
            for bench, reps in benches:
                check_oracle(reps, bench)
            cells = [_oracle_cell(reps, lambda r, v=v: _sr(r, "oracle", view=v)) for _, reps in benches for v in VIEWS]
            if any(c is not None for c in cells):
                sec.rows.append(Row("Oracle", cells, len(reports), oracle=True))
        per_bench = [(b, list(g.items())) for (b, _), g in zip(benches, by_bench)]
        return Table(
            preset, "Method", columns, [sec], note, _notes(mixed_protocols(per_bench), pooled_settings(per_bench))
        )
    # sr_tasks
    tasks = [
        t
        for t in TASK_SHORT
        if any(t in (((r.get("sr") or {}).get("model") or {}).get("tasks") or {}) for r in reports)
    ]
    tasks += sorted(
        {t for r in reports for t in (((r.get("sr") or {}).get("model") or {}).get("tasks") or {})} - set(tasks)
    )
    if not tasks:
        raise TableError(
            "preset sr_tasks: no report has per-task SR (was RolloutSuccessRate active on simulated data?)"
        )
    columns = [Column(TASK_SHORT.get(t, t), 2, False) for t in tasks]
    sections = []
    grouped = []
    for title, reps in _sections(reports):
        sec = Section(title)
        grouped.append((title, _group_rows(reps, group_by, False, title, protocol_keys=TASK_ROW_PROTOCOL)))
        for name, group in grouped[-1][1]:
            # each cell pools the row's runs tested on its task (all of them, unless the row holds one model per task)
            on_task = [task_reports(name, group, t, title) for t in tasks]
            cells = [_cell(runs, lambda r, t=t: _sr(r, "model", task=t)) for runs, t in zip(on_task, tasks)]
            text = ""
            if any(len(runs) != len(group) for runs in on_task):  # a total over tasks is no count of seeds
                per = ", ".join(f"{TASK_SHORT.get(t, t)} {len(runs)}" for runs, t in zip(on_task, tasks) if runs)
                text = f"{len(group)} ({per})"
            sec.rows.append(Row(_marked(name, group), cells, len(group), runs_text=text))
        if oracle:
            check_oracle(reps, title)
            cells = [_oracle_cell(reps, lambda r, t=t: _sr(r, "oracle", task=t)) for t in tasks]
            if any(c is not None for c in cells):
                sec.rows.append(Row("Oracle", cells, len(reps), oracle=True))
        sections.append(sec)
    mixed = "; ".join(
        m.removeprefix("rows differ in ")
        for m in (mixed_protocols(grouped, TASK_ROW_PROTOCOL), task_count_note(grouped))
        if m
    )
    # one model per task (the paper's Table 3) differs in its tasks on purpose; task_count_note says so
    pooled = pooled_settings(grouped, skip=("tasks",))
    return Table(preset, "Method", columns, sections, note, _notes(f"rows differ in {mixed}" if mixed else "", pooled))


# ------------------------------------------------------------------------------------------ rendering
def _best(section: Section, j: int, col: Column) -> float | None:
    vals = [r.cells[j].mean for r in section.rows if not r.oracle and r.cells[j] is not None]
    if len(vals) < 2:
        return None
    return min(vals) if col.lower_better else max(vals)


def _text(cell: Cell | None, col: Column, pm: str) -> str:
    if cell is None:
        return "n/a"
    s = f"{cell.mean:.{col.decimals}f}"
    if cell.std is not None:
        s += f"{pm}{cell.std:.{col.decimals}f}"
    if cell.n < cell.of:  # a single run's ± is its bootstrap std, not a spread over the row's seeds: say so
        s += f" (n={cell.n}/{cell.of})"
    return s


def _is_best(cell: Cell | None, best: float | None, col: Column) -> bool:
    return cell is not None and best is not None and round(cell.mean, col.decimals) == round(best, col.decimals)


def _col_title(col: Column, latex: bool = False) -> str:
    """Header text: ``RMSE ↓`` (map metrics carry their direction), ``Styles SR_front``, ``PnPC2C``."""
    if latex:
        name = f"$SR_{{\\text{{{col.name[3:]}}}}}$" if col.name.startswith("SR_") else f"\\textbf{{{_tex(col.name)}}}"
        return name + ((" $\\downarrow$" if col.lower_better else " $\\uparrow$") if col.arrow else "")
    head = f"{col.group} {col.name}" if col.group else col.name
    return head + ((" ↓" if col.lower_better else " ↑") if col.arrow else "")


def _md(s: str) -> str:
    """Text for a Markdown table cell: a ``|`` in a row label (``--label``, a ``--group-by`` value) split the row
    and moved every value one column to the right."""
    return s.replace("|", "\\|")


def render_markdown(table: Table) -> str:
    cols = table.columns
    lines = [
        "| " + " | ".join([_md(table.row_header)] + [_md(_col_title(c)) for c in cols]) + " |",
        "|" + "---|" + "---:|" * len(cols),
    ]
    for sec in table.sections:
        if sec.title:
            lines.append(f"| **{_md(sec.title)}** |" + " |" * len(cols))
        bests = [_best(sec, j, c) for j, c in enumerate(cols)]
        for row in sec.rows:
            cells = []
            for j, c in enumerate(cols):
                t = _text(row.cells[j], c, " ± ")
                cells.append(f"**{t}**" if _is_best(row.cells[j], bests[j], c) and not row.oracle else t)
            lines.append("| " + " | ".join([_md(row.name)] + cells) + " |")
    runs = "; ".join(
        f"{r.name}{f' ({_short(sec.title)})' if sec.title else ''}: {r.runs_text or r.runs}"
        for sec in table.sections
        for r in sec.rows
        if not r.oracle
    )
    mixed = f"; {table.mixed}" if table.mixed else ""
    lines += ["", f"_{table.note}{mixed}. Runs per row: {runs}._"]
    return "\n".join(lines) + "\n"


#: LaTeX's special characters as text (a row label such as ``r~1.2, top-$k$`` printed verbatim changed the rendering
#: or broke the compile)
_TEX = {
    "\\": "\\textbackslash{}",
    "&": "\\&",
    "%": "\\%",
    "_": "\\_",
    "#": "\\#",
    "$": "\\$",
    "{": "\\{",
    "}": "\\}",
    "~": "\\textasciitilde{}",
    "^": "\\textasciicircum{}",
}


def _tex(s: str) -> str:
    return "".join(_TEX.get(c, c) for c in s)


def render_latex(table: Table) -> str:
    cols = table.columns
    out = ["\\begin{tabular}{l" + "c" * len(cols) + "}", "\\toprule"]
    groups = [c.group for c in cols]
    if any(groups):
        spans, start = [], 0
        for j in range(1, len(cols) + 1):
            if j == len(cols) or groups[j] != groups[start]:
                spans.append((groups[start], start, j))
                start = j
        out.append(
            " & "
            + " & ".join(f"\\multicolumn{{{b - a}}}{{c}}{{\\textbf{{\\emph{{{_tex(g)}}}}}}}" for g, a, b in spans)
            + " \\\\"
        )
        out.append(" ".join(f"\\cmidrule(lr){{{a + 2}-{b + 1}}}" for _, a, b in spans))
    out.append(
        " & ".join([f"\\textbf{{{_tex(table.row_header)}}}"] + [_col_title(c, latex=True) for c in cols]) + " \\\\"
    )
    out.append("\\midrule")
    for k, sec in enumerate(table.sections):
        if k:
            out.append("\\midrule")
        if sec.title:
            out.append(f"\\multicolumn{{{len(cols) + 1}}}{{l}}{{\\textbf{{\\emph{{{_tex(sec.title)}}}}}}} \\\\")
        bests = [_best(sec, j, c) for j, c in enumerate(cols)]
        for row in sec.rows:
            if row.oracle:
                out.append("\\midrule")
            cells = []
            for j, c in enumerate(cols):
                t = _text(row.cells[j], c, " $\\pm$ ")
                cells.append(f"\\textbf{{{t}}}" if _is_best(row.cells[j], bests[j], c) and not row.oracle else t)
            out.append(" & ".join([_tex(row.name)] + cells) + " \\\\")
    out += ["\\bottomrule", "\\end{tabular}"]
    return "\n".join(out) + "\n"


def render_csv(table: Table) -> str:
    import csv
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["section", table.row_header, "runs"]
    for c in table.columns:
        name = f"{c.group} {c.name}".strip()
        head += [f"{name} mean", f"{name} std", f"{name} n"]
    w.writerow(head)
    for sec in table.sections:
        for row in sec.rows:
            line: list[Any] = [sec.title, row.name, row.runs]
            for cell in row.cells:
                line += (
                    ["", "", 0]
                    if cell is None
                    else [f"{cell.mean:.6g}", "" if cell.std is None else f"{cell.std:.6g}", cell.n]
                )
            w.writerow(line)
    return buf.getvalue()


def render(table: Table, fmt: str) -> str:
    if fmt not in FORMATS:
        raise TableError(f"unknown format {fmt!r}; choose from {list(FORMATS)}")
    return {"md": render_markdown, "latex": render_latex, "csv": render_csv}[fmt](table)


# ------------------------------------------------------------------------------------------ CLI
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="floaff-zoo table",
        description="Aggregate report.json files (written by `floaff-zoo test`) into paper-style tables: "
        "mean ± std over seeds, best value in bold.",
    )
    p.add_argument("--runs", nargs="+", required=True, help="run directories, globs or report.json files")
    p.add_argument(
        "--group-by",
        default=None,
        help="row key: model | label | benchmark | a dotted path into report.json "
        "(default per preset: model; ablation: label; sweep: model.hparams.crop_radius)",
    )
    p.add_argument("--format", choices=FORMATS, default="md")
    p.add_argument("--preset", choices=PRESETS, default="map")
    p.add_argument("--no-oracle", action="store_true", help="leave out the Oracle row of SR presets")
    p.add_argument(
        "--allow-mixed-data",
        action="store_true",
        help="tabulate runs whose reports record different labels for a scene (different copies of the data)",
    )
    p.add_argument("--out", default=None, help="write the table here instead of stdout")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``floaff-zoo table``; returns an exit code (0 ok, 2 nothing to tabulate / bad args)."""
    args = build_parser().parse_args(argv)
    reports, skipped = load_reports(args.runs)
    for entry, reason in skipped:
        print(f"floaff-zoo table: skipped {entry}: {reason}", file=sys.stderr)
    if not reports:
        # a report.json that was found but could not be used is named above: "none found" would mislead
        unusable = sum(
            Path(entry).name == "report.json" and (Path(entry).is_file() or why == FOLDER_NAMED)
            for entry, why in skipped
        )
        if unusable:
            why = f"no usable report.json in {args.runs}: {unusable} found and skipped (named above)"
        else:
            why = f"no report.json found in {args.runs}"
        print(f"floaff-zoo table: error: {why}", file=sys.stderr)
        return 2
    try:
        table = build_table(
            [{**r, PATH_KEY: str(path)} for path, r in reports],
            args.preset,
            args.group_by,
            oracle=not args.no_oracle,
            mixed_data=args.allow_mixed_data,
        )
        text = render(table, args.format)
        if table.mixed:  # LaTeX and CSV carry no note: the reader of the terminal is told
            print(f"floaff-zoo table: note: the {table.mixed}", file=sys.stderr)
    except TableError as exc:
        print(f"floaff-zoo table: error: {exc}", file=sys.stderr)
        return 2
    if args.out:
        read = next((path for path, _ in reports if path == Path(args.out).resolve()), None)
        if read is not None:  # the table was written over a report it had just read, exit 0
            print(
                f"floaff-zoo table: error: --out {args.out}: is the report {read}; name another file", file=sys.stderr
            )
            return 2
        try:
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            Path(args.out).write_text(text)
        except OSError as exc:
            print(f"floaff-zoo table: error: --out {args.out}: cannot write ({exc})", file=sys.stderr)
            return 2
        print(f"floaff-zoo table: wrote {args.out} ({len(reports)} report(s), {len(skipped)} skipped)", file=sys.stderr)
    else:
        sys.stdout.write(text)
        if skipped:  # the table is on stdout: the count of what it leaves out goes with the names above
            print(f"floaff-zoo table: {len(reports)} report(s) tabulated, {len(skipped)} skipped", file=sys.stderr)
    return 0
