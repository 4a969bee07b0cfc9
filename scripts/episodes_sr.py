"""Per-scene SR from ``floaff-zoo test`` episode files, in the scene table ``scripts/scene_sr.py --json`` writes.

    python scripts/episodes_sr.py NAME=<run>/sr_episodes.json [NAME=...] --json out.json

Each ``sr_episodes.json`` (written next to ``report.json`` by ``TestReport(write_episodes=true)``) lists one episode per
test view: its scene, task and whether the rolled-out pose succeeded. The output holds, per scene, its task, its number
of views and every NAME's SR there, so ``scripts/protocol_change.py A.json B.json`` can compare two evaluations of the
same views with its scene bootstrap (e.g. a model's map argmax against its own placement procedure,
``RolloutSuccessRate(pose_source: model)``). Every file must hold the same views (by ``sample_id``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from floaff_zoo.atomic import atomic_write_text

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders  # noqa: E402
from sr_json import sr_all  # noqa: E402

#: the fields an episode needs here
FIELDS = ("sample_id", "scene_id", "task", "success")


def read_episodes(path: str) -> list[dict[str, Any]]:
    """The episodes of one ``sr_episodes.json``; exits naming the file when it is no such list."""
    try:
        episodes = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"episodes_sr: {path} is not a readable sr_episodes.json ({exc})") from exc
    if not isinstance(episodes, list) or not episodes:
        raise SystemExit(f"episodes_sr: {path} holds no episode list")
    for i, e in enumerate(episodes):
        # ids and task strings: a list there was unhashable (a TypeError), a number a table protocol_change refuses
        ok = isinstance(e, dict) and all(k in e for k in FIELDS) and isinstance(e["success"], bool)
        if not ok or not all(isinstance(e[k], str) for k in ("sample_id", "scene_id", "task")):
            raise SystemExit(
                f"episodes_sr: {path}: episode {i} lacks one of {list(FIELDS)} "
                "(ids and task strings, success a boolean)"
            )
    ids = [e["sample_id"] for e in episodes]
    if len(set(ids)) != len(ids):
        raise SystemExit(f"episodes_sr: {path} lists a view twice")
    return episodes


def scene_table(runs: dict[str, list[dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """{scene id: {task, views, sr: {NAME: SR}}} of runs that hold the same views; exits naming the first that
    differs from the first run."""
    names = list(runs)
    first = {e["sample_id"]: e for e in runs[names[0]]}
    for n in names[1:]:
        if {e["sample_id"] for e in runs[n]} != set(first):
            raise SystemExit(f"episodes_sr: {n} holds other views than {names[0]}")
        # a view under another scene or task was counted there: a silently wrong SR of both scenes
        for e in runs[n]:
            if (e["scene_id"], e["task"]) != (first[e["sample_id"]]["scene_id"], first[e["sample_id"]]["task"]):
                raise SystemExit(
                    f"episodes_sr: {n} puts view {e['sample_id']} in another scene or task than {names[0]}"
                )
    table: dict[str, dict[str, Any]] = {}
    wins: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(names, 0))
    for n in names:
        for e in runs[n]:
            wins[e["scene_id"]][n] += int(e["success"])
    for e in first.values():
        row = table.setdefault(e["scene_id"], {"task": e["task"], "views": 0})
        if row["task"] != e["task"]:  # the table kept the first view's task for the whole scene
            raise SystemExit(f"episodes_sr: scene {e['scene_id']} has views of two tasks ({row['task']}, {e['task']})")
        row["views"] += 1
    for sid, row in table.items():
        row["sr"] = {n: wins[sid][n] / row["views"] for n in names}
    return dict(sorted(table.items()))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", metavar="NAME=PATH", help="a name and its sr_episodes.json")
    p.add_argument("--json", required=True, help="where the scene table goes")
    args = p.parse_args(argv)
    refuse_folders(p, json=args.json)
    runs: dict[str, list[dict[str, Any]]] = {}
    paths: dict[str, str] = {}
    for item in args.runs:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            p.error(f"{item!r} is not NAME=PATH")
        if name in runs:
            p.error(f"the name {name!r} is given twice")
        runs[name], paths[name] = read_episodes(path), path
    table = scene_table(runs)
    out = {"runs": dict(paths), "scenes": table}
    atomic_write_text(args.json, json.dumps(out, indent=1) + "\n")
    views = sum(r["views"] for r in table.values())
    for n in runs:
        print(f"{n}: SR_all {sr_all(table, list(table), n):.3f} over {views} views of {len(table)} scenes")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "episodes_sr"))
