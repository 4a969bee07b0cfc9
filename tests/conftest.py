"""Shared test set-up: headless rendering, no network, quiet matplotlib, small thread pools."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
# a local Ray cluster binds to loopback only (tests never use the network)
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# ``make test`` runs the suite in pytest-xdist workers (2 by default, one per core of the CI machine): one torch thread
# each, two in a single process
torch.set_num_threads(1 if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1 else 2)


@pytest.fixture(autouse=True)
def _isolated_caches(tmp_path_factory, monkeypatch):
    """Keep torch.hub and the floaff hub inside a temp dir so tests never touch the user's hubs. The compiled point
    kernels are the exception, on purpose: their build folder (``TORCH_EXTENSIONS_DIR``, torch's default
    ``~/.cache/torch_extensions``) is shared with the user's runs, as torch rebuilds a kernel whose sources changed and
    a build per test session would add its 40-60 s compile to every run (``tests/nn/test_ops.py`` checks the folder
    rule under a temp dir)."""
    hub = tmp_path_factory.mktemp("hub")
    torch.hub.set_dir(str(hub / "torch"))
    monkeypatch.setenv("FLOAFF_ZOO_HUB", str(hub / "floaff"))
    monkeypatch.setenv("FLOAFF_ZOO_OFFLINE", "1")


@pytest.fixture
def root() -> Path:
    return ROOT


def quiet_trainer_args(tmp_path) -> list[str]:
    """Trainer flags for fast, quiet CLI runs under tmp_path."""
    return [
        "--trainer.accelerator",
        "cpu",
        "--trainer.default_root_dir",
        str(tmp_path),
        "--trainer.enable_progress_bar",
        "false",
        "--trainer.enable_model_summary",
        "false",
    ]


def console(monkeypatch, capsys, args: list[str]) -> tuple[int, str, list[str]]:
    """Run ``floaff-zoo <args>`` in this process as the console does (argv from ``sys.argv``: a user error is printed,
    not raised): (exit code, stdout, non-blank stderr lines). A subprocess would test the same ``cli.main`` after
    ``python -m floaff_zoo``'s two lines, at ~7 s of imports each; a few subprocess tests keep that path covered, and
    what a logging handler bound to the real stderr prints (``test_corrupt_weights_file_is_one_line_on_stderr``)."""
    import sys
    import warnings

    from floaff_zoo import cli

    capsys.readouterr()  # what earlier steps of the test printed is not this command's
    monkeypatch.setattr(sys, "argv", ["floaff-zoo", *args])
    # a warning the console would print (the filters ``quiet`` installs apply) is counted as a stderr line, after
    # the printed ones: pytest would keep it off stderr
    with warnings.catch_warnings(record=True) as caught:
        rc = cli.main()
    out = capsys.readouterr()
    lines = [line for line in out.err.splitlines() if line.strip()]
    return rc, out.out, lines + [f"warning: {w.message}" for w in caught]


def block_first_footprint(batch: dict, n: int = 10) -> dict:
    """A copy of ``batch`` whose sample 0 has ``n`` valid cloud points 0.2 m tall just behind floor point 0, inside the
    base footprint parked there facing the target (what the occupancy inputs must see)."""
    floor0, target0 = batch["floor_xyz"][0, 0], batch["target_xyz"][0]
    heading = torch.atan2(target0[1] - floor0[1], target0[0] - floor0[0])
    behind = floor0[:2] - 0.2 * torch.stack([torch.cos(heading), torch.sin(heading)])
    blocked = dict(batch)
    blocked["scene_xyz"] = batch["scene_xyz"].clone()
    blocked["scene_xyz"][0, :n] = torch.cat([behind, torch.tensor([0.2])])
    blocked["scene_mask"] = batch["scene_mask"].clone()
    blocked["scene_mask"][0, :n] = True
    return blocked
