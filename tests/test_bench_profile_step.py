"""benchmarks/profile_step.py: a real training step of a shipped model, timed and profiled; bad devices refused."""

from __future__ import annotations

import pytest
import torch

from tests._scripts import load_benchmark


def _load():
    return load_benchmark("profile_step")


def test_a_step_is_timed_and_its_ops_listed(capsys):
    ps = _load()
    assert ps.main(["--models", "n2m", "--batch", "1", "--points", "512", "--steps", "1", "--warmup", "0"]) == 0
    out = capsys.readouterr().out
    assert "device cpu, FPS " in out
    assert "== n2m: " in out and "ms per step (B=1 x 512 points, mean of 1)" in out
    assert "Self CPU time total" in out  # the profiled step's table


def test_a_step_trains_the_model():
    """The timed step is a real training step: the loss has gradients, and they are cleared after it."""
    ps = _load()
    torch.manual_seed(0)
    model = ps.bm.build("n2m").train()
    batch = ps.bm.make_batch(1, 512, 8)
    seen = []
    original = model.zero_grad

    def record(set_to_none=True):
        seen.append(any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.parameters()))
        original(set_to_none=set_to_none)

    model.zero_grad = record
    ps.make_step(model, batch, torch.device("cpu"))()
    assert seen == [True] and all(p.grad is None for p in model.parameters())


@pytest.mark.parametrize("device", ["cuda:abc", "gpu"])
def test_an_unknown_device_is_named(device, capsys):
    with pytest.raises(SystemExit):
        _load().main(["--device", device])
    assert f"--device {device!r}" in capsys.readouterr().err


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_cuda_without_a_device_is_refused(capsys):
    with pytest.raises(SystemExit):
        _load().main(["--device", "cuda"])
    assert "torch sees no CUDA device here" in capsys.readouterr().err
