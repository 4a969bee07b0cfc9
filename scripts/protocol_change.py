"""How much each model's SR moves between two evaluation protocols, with scene-bootstrap intervals.

    python scripts/protocol_change.py A.json B.json [--draws 2000] [--seed 0]

A.json and B.json are ``scripts/scene_sr.py --json`` outputs of the same models (NAMEs) on the same scenes under
two protocols (e.g. the benchmark's floor queries, and ``--deploy-queries``). For every NAME the script prints SR_all
under both and the change B - A; for every pair of NAMEs the difference of their changes, (B - A) of the first minus
(B - A) of the second. Each interval is the 90 % interval over ``--draws`` scene bootstraps: the test scenes of each
task resampled with replacement, the same draw for both protocols and every NAME (paired), as ``scene_sr.py`` does.
A model whose scores do not depend on the query set shows what the protocol change does by itself; a larger change
of another model is what it drew from the part of the protocol that changed.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from floaff_zoo.atomic import atomic_write_text

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders  # noqa: E402
from sr_json import checked_scenes, sr_all  # noqa: E402


def load(path: str) -> dict:
    """A scene_sr JSON: {scene id: {task, views, sr: {name: SR}}} under ``scenes``; exits naming a bad file."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"protocol_change: {path} is not a scene_sr.py --json output ({exc})") from exc
    return checked_scenes(data, path, "protocol_change")


def matched(a: dict, b: dict) -> tuple[list[str], list[str]]:
    """(scene ids, names) both files share; exits when the scenes or their view counts differ."""
    if set(a) != set(b):
        raise SystemExit(f"protocol_change: the files hold different scenes ({sorted(set(a) ^ set(b))[:3]} ...)")
    for sid in a:
        if a[sid]["views"] != b[sid]["views"] or a[sid]["task"] != b[sid]["task"]:
            raise SystemExit(f"protocol_change: scene {sid} has other views or another task in the two files")
    names = [n for n in next(iter(a.values()))["sr"] if all(n in s["sr"] for s in (*a.values(), *b.values()))]
    if not names:
        raise SystemExit("protocol_change: the files share no model NAME")
    return sorted(a), names


def bootstrap_ids(scenes: dict, ids: list[str], draws: int, seed: int) -> list[list[str]]:
    """``draws`` resamples of the scene ids, each task's scenes drawn with replacement."""
    by_task: dict[str, list[str]] = defaultdict(list)
    for sid in ids:
        by_task[scenes[sid]["task"]].append(sid)
    rng = np.random.default_rng(seed)
    return [[s for t in sorted(by_task) for s in rng.choice(by_task[t], size=len(by_task[t]))] for _ in range(draws)]


def changes(a: dict, b: dict, draws: int, seed: int) -> dict:
    """{"models": {name: {a, b, change, p05, p95}}, "differences": {"x - y": {diff, p05, p95}}}."""
    ids, names = matched(a, b)
    samples = bootstrap_ids(a, ids, draws, seed)
    boot = np.array([[sr_all(b, d, n) - sr_all(a, d, n) for n in names] for d in samples])  # [draws, names]
    every = {n for s in (*a.values(), *b.values()) for n in s["sr"]}
    # a NAME of one file only, or not scored on every scene, is left out of the table: said, not dropped silently
    out: dict = {"models": {}, "differences": {}, "left_out": sorted(every - set(names))}
    for k, n in enumerate(names):
        lo, hi = np.quantile(boot[:, k], [0.05, 0.95])
        base, new = sr_all(a, ids, n), sr_all(b, ids, n)
        out["models"][n] = {"a": base, "b": new, "change": new - base, "p05": float(lo), "p95": float(hi)}
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            d = boot[:, i] - boot[:, j]
            diff = out["models"][names[i]]["change"] - out["models"][names[j]]["change"]
            lo, hi = np.quantile(d, [0.05, 0.95])
            out["differences"][f"{names[i]} - {names[j]}"] = {"diff": diff, "p05": float(lo), "p95": float(hi)}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("a", help="scene_sr.py --json output under the first protocol")
    p.add_argument("b", help="the same models under the second protocol")
    p.add_argument("--draws", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    refuse_folders(p, json=args.json)
    if args.draws < 1:
        p.error("--draws must be >= 1")
    if args.seed < 0:  # numpy's generator takes no negative seed
        p.error(f"--seed must be >= 0, got {args.seed}")
    res = changes(load(args.a), load(args.b), args.draws, args.seed)
    print("| name | SR_all A | SR_all B | B - A | 90 % scene bootstrap |")
    print("|---|---:|---:|---:|---|")
    for n, m in res["models"].items():
        print(f"| {n} | {m['a']:.3f} | {m['b']:.3f} | {m['change']:+.3f} | {m['p05']:+.3f} to {m['p95']:+.3f} |")
    if res["left_out"]:
        print(f"left out (not scored on every scene of both files): {', '.join(res['left_out'])}")
    for pair, d in res["differences"].items():
        print(f"change of {pair}: {d['diff']:+.3f} (90 %: {d['p05']:+.3f} to {d['p95']:+.3f})")
    if args.json:
        atomic_write_text(
            args.json, json.dumps({"a": args.a, "b": args.b, "draws": args.draws, **res}, indent=1) + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "protocol_change"))
