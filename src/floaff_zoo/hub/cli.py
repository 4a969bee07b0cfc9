"""``floaff-zoo hub list | info NAME | pull NAME | push RUN --name NAME | verify [NAME]``."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from typing import Any

from floaff_zoo.hub.registry import (
    HubEntry,
    HubError,
    get_entry,
    hub_dir,
    is_offline,
    load_registry,
    read_retired,
    sha256_file,
    user_index_path,
)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="floaff-zoo hub",
        description="Named pretrained checkpoints: offline first, sha256-verified, config carried with the weights. "
        "Hub directory: --hub-dir, else $FLOAFF_ZOO_HUB, else ~/.cache/floaff_zoo/hub; "
        "FLOAFF_ZOO_OFFLINE=1 forbids downloads.",
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--hub-dir", default=None, help="hub directory (default: $FLOAFF_ZOO_HUB)")
    ls = sub.add_parser("list", parents=[common], help="list registered checkpoints")
    ls.add_argument("--json", action="store_true", help="print the entries as JSON")
    info = sub.add_parser("info", parents=[common], help="show one entry and where its file is")
    info.add_argument("name")
    pull = sub.add_parser("pull", parents=[common], help="make an entry's file available locally (download if allowed)")
    pull.add_argument("name")
    push = sub.add_parser("push", parents=[common], help="export a run's best checkpoint and register it")
    push.add_argument("run", help="run directory (best checkpoint, like --ckpt_path best) or a .ckpt file")
    push.add_argument("--name", required=True, help="hub name, model.dataset.vN")
    push.add_argument("--class-path", default=None, help="model class if the checkpoint does not record it")
    push.add_argument("--dataset", default=None)
    push.add_argument("--benchmark", default=None)
    push.add_argument("--license", default=None)
    push.add_argument("--description", default=None)
    push.add_argument(
        "--report",
        default=None,
        help="report.json of `floaff-zoo test` on this checkpoint: its metrics go into the index "
        "(default: a report.json in the run directory, else the best validation score)",
    )
    push.add_argument(
        "--replace",
        action="store_true",
        help="push over a name that is taken: a registered one (its weights are deleted) or a shipped one (hidden)",
    )
    push.add_argument("--upload", action="store_true", help="also upload to Hugging Face (needs network)")
    push.add_argument("--repo", default=None, help="Hugging Face repo org/name for --upload")
    push.add_argument("--private", action="store_true", help="create the Hugging Face repo as private")
    ver = sub.add_parser("verify", parents=[common], help="re-hash local files against the index")
    ver.add_argument("name", nargs="?", default=None)
    return p


def _where(entry: HubEntry, directory: str | None) -> str:
    from floaff_zoo.hub.io import find_local

    p = find_local(entry, directory)
    return str(p) if p is not None else "-"


def _source_text(entry: HubEntry) -> str:
    s = entry.source
    if s.get("kind") == "url":
        return s["url"]
    if s.get("kind") == "hf":
        return f"hf://{s['repo']}@{s['revision'][:12]}"
    return "local"


def _version_order(entry: HubEntry) -> tuple[str, int, str]:
    """Sort key: by name, versions in numeric order (``.v9`` before ``.v10``)."""
    m = re.fullmatch(r"(.*)\.v(\d+)", entry.name)
    return (m[1], int(m[2]), "") if m else (entry.name, -1, entry.name)


def _metric_text(entry: HubEntry, key: str) -> str:
    """``key`` of the entry's recorded metrics to 3 decimals, or '-' (a push without a test report has none)."""
    value = (entry.meta.get("metrics") or {}).get(key)
    return f"{value:.3f}" if isinstance(value, (int, float)) and not isinstance(value, bool) else "-"


def cmd_list(args: argparse.Namespace) -> int:
    reg = load_registry(args.hub_dir)
    if args.json:
        print(json.dumps([e.to_json() for e in reg.values()], indent=2))
        return 0
    if not reg:
        print(f"no checkpoints registered (shipped index empty; user index {user_index_path(args.hub_dir)})")
        return 0
    # what a user picks a checkpoint by: its benchmark and test scores (the file name is in `hub info`)
    rows = [
        (
            e.name,
            e.class_path.rsplit(".", 1)[-1],
            str(e.meta.get("benchmark") or "-"),
            _metric_text(e, "test_sr_all"),
            _metric_text(e, "test_pcc"),
            _source_text(e),
            "yes" if _where(e, args.hub_dir) != "-" else "no",
        )
        for e in sorted(reg.values(), key=_version_order)
    ]
    head = ("name", "class", "benchmark", "test SR_all", "test PCC", "source", "local")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    for r in [head, *rows]:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    print("(test scores are each entry's own, on the data copy its model card names: `floaff-zoo hub info NAME`)")
    retired = [n for n in read_retired() if n not in reg]
    if retired:
        print(f"({len(retired)} earlier versions retired from the package; `floaff-zoo hub info NAME` says where)")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    e = get_entry(args.name, args.hub_dir)
    out: dict[str, Any] = {**e.to_json(), "index": str(e.index_path), "local_file": _where(e, args.hub_dir)}
    print(json.dumps(out, indent=2))
    return 0


def cmd_pull(args: argparse.Namespace) -> int:
    from floaff_zoo.hub.io import fetch

    print(fetch(args.name, args.hub_dir, allow_download=True))
    return 0


def cmd_push(args: argparse.Namespace) -> int:
    from floaff_zoo.hub.export import export_checkpoint, upload_export

    if args.upload and not args.repo:
        raise HubError("--upload needs --repo org/name")
    given = [flag for flag, value in (("--repo", args.repo), ("--private", args.private)) if value]
    if given and not args.upload:  # they were ignored: a push meant to publish exported locally only
        raise HubError(
            f"{' and '.join(given)} only apply to --upload; add --upload to upload the export, or leave them out"
        )
    if args.upload and is_offline():  # fail before exporting anything
        raise HubError("refusing to --upload: FLOAFF_ZOO_OFFLINE is set (unset it or set it to 0)")
    meta = {k: getattr(args, k) for k in ("dataset", "benchmark", "license", "description") if getattr(args, k)}
    from floaff_zoo._version import __version__

    meta["zoo_version"] = __version__
    entry, out = export_checkpoint(
        args.run,
        args.name,
        args.hub_dir,
        class_path=args.class_path,
        meta=meta,
        report=args.report,
        replace=args.replace,
    )
    print(f"exported {entry.name} -> {out / entry.filename} (sha256 {entry.sha256})")
    print(f"registered in {user_index_path(args.hub_dir)}")
    if args.upload:
        entry = upload_export(entry, out, args.repo, args.hub_dir, private=args.private)
        print(f"uploaded to {args.repo} at revision {entry.source['revision']}")
    return 0


def cmd_verify(args: argparse.Namespace) -> int:
    from floaff_zoo.hub.io import local_candidates

    reg = load_registry(args.hub_dir)
    entries = [get_entry(args.name, args.hub_dir)] if args.name else sorted(reg.values(), key=lambda e: e.name)
    bad = missing = 0
    for e in entries:
        paths = [p for p in local_candidates(e, args.hub_dir) if p.is_file()]
        if not paths:
            missing += 1
            print(f"MISSING   {e.name}: {e.filename} not in {hub_dir(args.hub_dir)}")
        for p in paths:  # every copy: a stale duplicate in another cache would be loaded otherwise
            ok = sha256_file(p) == e.sha256
            bad += not ok
            print(f"{'OK' if ok else 'MISMATCH':<9} {e.name}: {p}")
    print(f"{len(entries)} entr{'y' if len(entries) == 1 else 'ies'}: {bad} mismatch(es), {missing} missing")
    return 1 if bad or (args.name and missing) else 0


def _looks_like_path(name: str) -> bool:
    from floaff_zoo.hub.io import looks_like_path  # imports torch: only for the commands that take a name

    return looks_like_path(name)


def _check_hub_folder(option: str | None) -> None:
    """HubError unless the hub folder (``--hub-dir``, else ``$FLOAFF_ZOO_HUB``, else the default) is a folder or
    is still to be made: a file or a broken link ended a push in "[Errno 17] File exists", and an empty
    ``--hub-dir`` made the working folder the hub."""
    if option is not None and not option.strip():
        raise HubError("--hub-dir is empty: give a hub folder, or leave the option out to use $FLOAFF_ZOO_HUB")
    hub = hub_dir(option)
    given = "--hub-dir" if option is not None else "$FLOAFF_ZOO_HUB" if os.environ.get("FLOAFF_ZOO_HUB") else "hub"
    if hub.is_symlink() and not hub.exists():
        raise HubError(f"{given} {hub}: a link to nothing (or a loop of links), not a hub folder")
    if hub.exists() and not hub.is_dir():
        raise HubError(f"{given} {hub}: is a file, not a hub folder")


COMMANDS = {"list": cmd_list, "info": cmd_info, "pull": cmd_pull, "push": cmd_push, "verify": cmd_verify}


def main(argv: list[str] | None = None) -> int:
    """Entry point for ``floaff-zoo hub ...``; returns the exit code (2 on a hub error)."""
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        _check_hub_folder(args.hub_dir)
        name = getattr(args, "name", None)
        if args.cmd in ("info", "pull", "verify") and name is not None and not name.strip():
            # `hub verify ''` checked every entry and passed: a script's empty variable verified nothing it meant
            raise HubError(f"hub {args.cmd}: the name is empty; `floaff-zoo hub list` shows the registered names")
        if args.cmd in ("info", "pull", "verify") and name and _looks_like_path(name):
            raise HubError(
                f"hub {args.cmd} takes a registered name (`floaff-zoo hub list`), not a path: {name!r}; a file or an "
                "exported folder loads with floaff_zoo.hub.load_model or a model class's from_pretrained"
            )
        return COMMANDS[args.cmd](args)
    except (HubError, OSError, ValueError, TypeError) as exc:  # OSError: a file or folder that cannot be read / written
        print(f"floaff-zoo hub: error: {exc}", file=sys.stderr)
        return 2
