"""``floaff-zoo montage``: one picture comparing methods case by case, like the paper's Figures 4 and 6.

Every ``floaff-zoo test`` draws the ground truth beside its prediction for the first samples of each
(task, view) (``<run>/figures/<task>_<view>_<k>.png``, listed in ``report.json``). The test loader's
order is fixed, so the k-th figure of a (task, view) shows the same scene and view in every run of the
same test split. This command puts those figures side by side: one row per case, one column per run (runs of
different benchmarks are refused: their figures of a case show different kitchens)::

    floaff-zoo montage --runs docs/results/small/layouts/{cfar_pfal_s0,pointnet2_s0,c2f_exp} \\
        --cases CloseDrawer_front_0 OpenSingleDoor_side_0 --out docs/results/small/fig4_layouts.png

A run is a report.json or a directory holding one; its figures are looked up in the report's
``run_dir`` (where the test wrote them), so the runs must still be on disk.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

__all__ = ["MontageError", "check_one_benchmark", "find_figure", "main", "montage"]


def _read_image(path: Path):
    """The pixels of a figure file; MontageError naming it when it is no readable image."""
    import matplotlib.pyplot as plt

    try:
        return plt.imread(path)
    except (OSError, SyntaxError, ValueError) as exc:  # PIL's "not a PNG file" is a SyntaxError
        raise MontageError(f"{path}: not a readable image ({exc})") from exc


class MontageError(ValueError):
    """A missing report or figure (printed without a traceback)."""


def _load_report(run: str | Path) -> tuple[Path, dict[str, Any]]:
    path = Path(run)
    if path.is_dir():
        path = path / "report.json"
    if not path.is_file():
        raise MontageError(f"{run}: no report.json")
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MontageError(f"{path}: unreadable report ({exc})") from exc
    check_report(path, report)
    return path, report


#: the fields montage reads: name -> (JSON kind, Python types); each may be absent or null
FIELDS = {
    "figures": ("a list", list),
    "run_dir": ("a string", str),
    "label": ("a string", str),
    "model": ("an object", dict),
    "data": ("an object", dict),
}


def check_report(path: Path, report: Any) -> None:
    """MontageError naming ``path`` and the field when ``report`` is not a JSON object or a field montage reads
    holds the wrong kind of value (a string ``figures`` was read character by character)."""
    if not isinstance(report, dict):
        raise MontageError(f"{path}: not a report (a JSON {type(report).__name__}, not an object)")
    for name, (kind, types) in FIELDS.items():
        value = report.get(name)
        if value is not None and not isinstance(value, types):
            raise MontageError(f"{path}: field {name!r} is {type(value).__name__} {json.dumps(value)[:40]}, not {kind}")
    bad = next((f for f in report.get("figures") or [] if not isinstance(f, str)), None)
    if bad is not None:
        raise MontageError(f"{path}: field 'figures' holds {json.dumps(bad)[:40]}, not a figure path")


def check_one_benchmark(reports: list[tuple[Path, dict[str, Any]]]) -> None:
    """MontageError naming the reports of each benchmark when the runs were tested on different benchmarks (their
    k-th figure of a case shows another kitchen); a report that records no benchmark is not compared."""
    benches: dict[str, list[str]] = {}
    for path, report in reports:
        bench = (report.get("data") or {}).get("benchmark")
        if bench is not None:
            benches.setdefault(str(bench), []).append(str(path))
    if len(benches) > 1:
        which = "; ".join(f"{bench}: {', '.join(paths)}" for bench, paths in benches.items())
        raise MontageError(
            f"the runs were tested on different benchmarks ({which}): the k-th figure of a case shows another scene "
            "in each; draw one benchmark's runs per montage"
        )


def find_figure(report_path: Path, report: dict[str, Any], case: str) -> Path:
    """The PNG of ``case`` (``<task>_<view>_<k>``) written by the test run of ``report``.

    Looked up beside the report first, then in the report's ``run_dir``.
    """
    names = [f for f in report.get("figures") or [] if Path(f).stem == case]
    if not names:
        listed = sorted(Path(f).stem for f in report.get("figures") or [])
        raise MontageError(f"{report_path}: no figure {case!r} in the report (it has: {', '.join(listed) or 'none'})")
    roots = [report_path.parent]
    if report.get("run_dir"):
        roots.append(Path(report["run_dir"]))
    for root in roots:
        if (root / names[0]).is_file():
            return root / names[0]
    raise MontageError(f"{report_path}: figure {names[0]} not found in {', '.join(str(r) for r in roots)}")


def montage(
    runs: list[str | Path], cases: list[str], out: str | Path, labels: list[str] | None = None, width: float = 3.2
) -> Path:
    """Draw ``len(cases)`` rows x ``len(runs)`` columns of the runs' figures into ``out`` (PNG).

    labels: column titles (default each report's ``label``); width: inches per column.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = montage_path(out)
    reports = [_load_report(r) for r in runs]
    check_one_benchmark(reports)
    if labels is not None and len(labels) != len(runs):
        raise MontageError(f"--labels: {len(labels)} given for {len(runs)} runs")
    titles = labels or [
        str(rep.get("label") or (rep.get("model") or {}).get("name") or p.parent.name) for p, rep in reports
    ]
    figures = [[find_figure(p, rep, case) for p, rep in reports] for case in cases]
    overwritten = next((f for row in figures for f in row if f.resolve() == out.resolve()), None)
    if overwritten is not None:  # the montage was written over a run's own figure, exit 0
        raise MontageError(f"--out {out}: is the figure {overwritten} of a run; name another picture to write")
    images = [[_read_image(f) for f in row] for row in figures]
    h, w = images[0][0].shape[:2]
    size = (width * len(runs), width * h / w * len(cases))  # every panel keeps the figures' aspect ratio
    fig, axes = plt.subplots(len(cases), len(runs), figsize=size, squeeze=False)
    for i, row in enumerate(images):
        for j, img in enumerate(row):
            ax = axes[i][j]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(titles[j], fontsize=10)
            if j == 0:
                ax.set_ylabel(cases[i], fontsize=8)
    fig.tight_layout()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=110)
    except OSError as exc:
        raise MontageError(f"--out {out}: cannot write ({exc})") from exc
    finally:
        plt.close(fig)
    return out


def montage_path(out: str | Path) -> Path:
    """The file ``montage`` writes for ``--out`` (``sim.pictures.picture_path``: ``.png`` added when it has no suffix;
    a folder or a suffix matplotlib cannot write is a MontageError)."""
    from floaff_zoo.sim.pictures import picture_path

    return picture_path(out, "--out ", "montage.png", MontageError)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="floaff-zoo montage", description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", nargs="+", required=True, help="report.json files or directories holding one")
    p.add_argument("--cases", nargs="+", required=True, help="figure names <task>_<view>_<k>, one row each")
    p.add_argument("--labels", nargs="+", default=None, help="column titles (default: each report's label)")
    p.add_argument("--out", required=True, help="PNG to write")
    args = p.parse_args(argv)
    try:
        path = montage(args.runs, args.cases, args.out, args.labels)
    except MontageError as exc:
        p.exit(2, f"floaff-zoo montage: error: {exc}\n")
    print(path)
    return 0
