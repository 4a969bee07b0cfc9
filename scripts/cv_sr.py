"""Pool the folds of a leave-one-layout-out cross-validation into one validation table.

    python scripts/cv_sr.py docs/results/v21/cv/layouts [--json out.json]      # a folder of fold JSONs, or files
    python scripts/cv_sr.py runs/a/cv/layouts@old runs/b/cv/layouts@new   # the same jobs of two runs, paired

Each input is a ``scripts/scene_sr.py --split val --val-layout F --json ...`` output (written per fold and model by
the ``cv<f>_*`` jobs of ``scripts/reproduce_small.sh``): one model NAME scored on the validation scenes of one fold,
the models of that fold trained without them. Pooled, every train scene of the benchmark is a validation scene once,
so a hypothesis is decided on 19-20 kitchens instead of the 4 of the default split. The script merges the per-scene
success rates by NAME, checks that every NAME covers the same scenes (a fold missing for one NAME is an error that
names it: a comparison on different kitchens is not paired), and prints SR per scene, per task and over all views,
SR per fold, and the paired scene-bootstrap differences of ``scene_sr.py``. An input written ``PATH@TAG`` reads every
model NAME of PATH as ``NAME@TAG``, so the same job run twice (e.g. before and after a code change) is compared paired.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scene_sr import print_scenes, print_summary, summarize  # noqa: E402
from script_cli import refuse_folders  # noqa: E402
from sr_json import checked_scenes  # noqa: E402

from floaff_zoo.atomic import atomic_write_text  # noqa: E402


def fold_files(paths: list[str]) -> list[tuple[Path, str]]:
    """Files and folders (their ``*.json``), each optionally ``PATH@TAG`` -> [(fold JSON, tag or "")], sorted per input;
    an empty or missing input exits."""
    out: list[tuple[Path, str]] = []
    for item in paths:
        # the tag follows the last @ (a folder of the path may hold one); an existing path is never split
        split = "@" in item and not Path(item).exists()
        path, _, tag = item.rpartition("@") if split else (item, "", "")
        if split and not tag:  # `x.json@` read untagged would pool it with x.json's own names
            raise SystemExit(f"cv_sr: {item}: the tag after @ is empty")
        p = Path(path)
        if p.is_dir():
            found = sorted(p.glob("*.json"))
            if not found:  # one run's folder empty (its jobs not run): the others were pooled without it
                raise SystemExit(f"cv_sr: no fold JSON in {p}")
            out += [(f, tag) for f in found]
        elif p.is_file():
            out.append((p, tag))
        else:
            raise SystemExit(f"cv_sr: {p}: no such file or folder")
    if not out:
        raise SystemExit(f"cv_sr: no fold JSON in {paths}")
    return out


def tagged(doc: dict, tag: str, where: str) -> dict:
    """A scene_sr JSON with every model NAME read as ``NAME@tag`` (unchanged without a tag); exits naming ``where``
    when its scene table is malformed (a list for a file or a scene was an AttributeError here)."""
    if not tag:
        return doc  # merge_folds names a malformed file
    scenes = {
        sid: {**s, "sr": {f"{n}@{tag}": v for n, v in s["sr"].items()}}
        for sid, s in checked_scenes(doc, where, "cv_sr").items()
    }
    return {**doc, "scenes": scenes}


def merge_folds(docs: list[tuple[str, dict]]) -> tuple[dict[str, dict], dict[str, dict[str, float]], str]:
    """[(file, scene_sr JSON)] -> (scene id -> {task, views, fold, sr: {name: SR}}, fold -> {name: SR_all}, benchmark).

    Every JSON must be a validation fold (``split`` val, ``val_layout`` set) of one benchmark; a scene scored twice
    for one NAME, or scored with different view counts, exits with the files named.
    """
    scenes: dict[str, dict] = {}
    seen: dict[tuple[str, str], str] = {}
    first: dict[str, str] = {}  # scene id -> the file that first scored it
    benchmarks = set()
    for f, d in docs:
        layout = d.get("val_layout") if isinstance(d, dict) else None
        # a fold is a layout number: another value (a list, a string beside numbers) was a TypeError when sorted
        # ... and of a named benchmark (a fold without one pooled as benchmark None)
        bad = not isinstance(layout, int) or isinstance(layout, bool) or not isinstance(d.get("benchmark"), str)
        if layout is None or d.get("split") != "val" or bad:
            raise SystemExit(
                f"cv_sr: {f} is not a fold (scene_sr.py --split val --val-layout F: a benchmark, F a layout number)"
            )
        benchmarks.add(d.get("benchmark"))
        for sid, s in checked_scenes(d, f, "cv_sr").items():
            row = scenes.setdefault(sid, {"task": s["task"], "views": s["views"], "fold": d["val_layout"], "sr": {}})
            first.setdefault(sid, f)
            if row["views"] != s["views"] or row["fold"] != d["val_layout"]:
                raise SystemExit(f"cv_sr: scene {sid} has other views or another fold in {f} than in {first[sid]}")
            for name, v in s["sr"].items():
                if (sid, name) in seen:
                    raise SystemExit(f"cv_sr: {name} scored twice on {sid} ({seen[sid, name]} and {f})")
                seen[sid, name] = f
                row["sr"][name] = v
    if len(benchmarks) != 1:
        raise SystemExit(f"cv_sr: the folds mix benchmarks {sorted(map(str, benchmarks))}")
    names = sorted({n for s in scenes.values() for n in s["sr"]})
    for sid, s in sorted(scenes.items()):
        missing = [n for n in names if n not in s["sr"]]
        if missing:
            raise SystemExit(f"cv_sr: {sid} (fold {s['fold']}) is not scored for {missing}; run those folds first")
    per_fold: dict[str, dict[str, float]] = defaultdict(dict)
    for fold in sorted({s["fold"] for s in scenes.values()}):
        ids = [sid for sid, s in scenes.items() if s["fold"] == fold]
        views = sum(scenes[i]["views"] for i in ids)
        for n in names:
            per_fold[str(fold)][n] = sum(scenes[i]["views"] * scenes[i]["sr"][n] for i in ids) / views
    return dict(sorted(scenes.items())), dict(per_fold), benchmarks.pop()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("inputs", nargs="+", help="fold JSONs of scene_sr.py, or folders of them")
    p.add_argument("--draws", type=int, default=2000, help="scene-bootstrap draws")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    if a.draws < 1:
        p.error("--draws must be >= 1")
    if a.seed < 0:  # numpy's generator takes no negative seed: a traceback after every file had been read
        p.error(f"--seed must be >= 0, got {a.seed}")
    files = fold_files(a.inputs)
    docs = []
    for f, tag in files:
        try:
            docs.append((str(f), tagged(json.loads(f.read_text()), tag, str(f))))
        except (OSError, ValueError) as exc:
            raise SystemExit(f"cv_sr: {f}: {exc}") from exc
    scenes, per_fold, bench = merge_folds(docs)
    names = sorted({n for s in scenes.values() for n in s["sr"]})
    res = summarize(scenes, names, a.draws, a.seed)

    print(f"{bench} cross-validation: {len(per_fold)} folds, {len(scenes)} validation scenes, {len(files)} files")
    print_scenes(scenes, names, extra="fold")
    print()
    print("| fold (layout held out) | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for fold, by_name in per_fold.items():
        print(f"| {fold} | " + " | ".join(f"{by_name[n]:.3f}" for n in names) + " |")
    print()
    print_summary(res)
    if a.json:
        listed = [f"{f}@{tag}" if tag else str(f) for f, tag in files]
        out = {"benchmark": bench, "files": listed, "draws": a.draws, "seed": a.seed}
        out |= {"scenes": scenes, "folds": per_fold, **res}
        atomic_write_text(a.json, json.dumps(out, indent=1) + "\n")
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "cv_sr"))
