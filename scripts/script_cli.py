"""How the research scripts end on bad input: one line naming the file or the argument, exit code 2."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

#: the package's errors for bad input (a missing or corrupt file, an unknown name, data a module refuses), by module:
#: looked up only in modules already imported, so a light script does not import torch to catch them
_USER_ERRORS = (
    ("floaff_zoo.sim.fileformat", "FormatError"),
    ("lightning.fabric.utilities.exceptions", "MisconfigurationException"),
    ("floaff_zoo.hub.registry", "HubError"),
    ("floaff_zoo.runs", "RunError"),
    ("floaff_zoo.data.readers", "DataError"),
    ("floaff_zoo.contract", "SampleError"),
)


def user_error_types() -> tuple[type[BaseException], ...]:
    """OSError and the package's bad-input errors of the modules imported so far."""
    found = [getattr(sys.modules[m], name, None) for m, name in _USER_ERRORS if m in sys.modules]
    return (OSError, *(t for t in found if isinstance(t, type)))


def run(main: Callable[[], int | None], prog: str) -> int:
    """``main()``'s exit code; a bad-input error becomes ``<prog>: error: <one line>`` on stderr and exit code 2 (a
    bug's traceback is kept)."""
    try:
        return int(main() or 0)
    except SystemExit as exc:
        if not isinstance(exc.code, str):  # argparse's usage error (2), a status the script chose
            raise
        # a script's own `raise SystemExit("<prog>: why")` on bad input: it exited 1, with no "error:"
        return _user_error(prog, exc.code)
    except Exception as exc:  # noqa: BLE001 - narrowed to the bad-input types below
        if not isinstance(exc, user_error_types()):
            raise
        return _user_error(prog, str(exc))


def _user_error(prog: str, why: str) -> int:
    """Print ``<prog>: error: <why on one line>`` on stderr and return exit code 2; a message that already starts
    with the script's name (its own SystemExit, ``load_axisnet(..., owner=prog)``) is not prefixed twice."""
    print(f"{prog}: error: {' '.join(why.split()).removeprefix(f'{prog}: ')}", file=sys.stderr)
    return 2


def refuse_folders(parser: argparse.ArgumentParser, **files: str | Path | None) -> None:
    """A usage error (``parser.error``) for the first of ``files`` (option name with ``_`` for ``-`` -> path) that
    names an existing folder, or lies under a file: a script writes its files after the work, so either lost the run
    at its end (a missing folder is fine: the writers make it)."""
    for option, path in files.items():
        if path is None:
            continue
        flag = f"--{option.replace('_', '-')}"
        if Path(path).is_dir():
            parser.error(f"{flag} names a file to write, got the folder {str(path)!r}")
        # atomic.existing_ancestor spelled out: reset_drift may run with a src older than floaff_zoo.atomic
        above = next((q for q in Path(path).parents if q.exists() or q.is_symlink()), None)
        if above is not None and not above.is_dir():
            parser.error(f"{flag} {str(path)!r}: {str(above)!r} exists and is not a folder")


def floor_model(model: str, where: str) -> torch.nn.Module:
    """The module of a MODEL argument (a hub name or a checkpoint path), in eval mode; exits with ``<where>: <why>``
    when it predicts no floor map (an AxisNet checkpoint: its output was read as floor scores and failed later).

    Imports the predict API on call, so that the scripts that never load a model keep this module light.
    """
    from floaff_zoo.predict import check_floor_model, resolve_model

    net = resolve_model(model)
    try:
        check_floor_model(net)
    except TypeError as exc:
        raise SystemExit(f"{where}: {exc}") from exc
    return net.eval()


def add_parking_noise(parser: argparse.ArgumentParser) -> None:
    """``--sigma-xy``, ``--sigma-yaw-deg`` and ``--seed``: the parking noise of the fresh-episode scripts."""
    parser.add_argument("--sigma-xy", type=float, default=0.02, help="parking noise per axis (m)")
    parser.add_argument("--sigma-yaw-deg", type=float, default=2.0, help="parking heading noise (deg)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the parking noise")


def check_parking_noise(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """A usage error for a sigma that is not a finite number >= 0 (a NaN passed ``< 0`` and ended in a rollout's
    error about a NaN pose, naming no option) or a negative seed."""
    for flag, value in (("--sigma-xy", args.sigma_xy), ("--sigma-yaw-deg", args.sigma_yaw_deg)):
        if not 0 <= value < math.inf:
            parser.error(f"{flag} must be a finite number >= 0, got {value}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")


def refuse_repeats(parser: argparse.ArgumentParser, what: str, values: list[str]) -> None:
    """A usage error naming the ``values`` given more than once (``what``: "model", "benchmark"): each names one row
    of the script's table, and a repeat printed its rows twice or merged them with their counts doubled."""
    repeated = sorted({v for v in values if values.count(v) > 1})
    if repeated:
        parser.error(f"a {what} is given twice: {', '.join(repeated)}")
