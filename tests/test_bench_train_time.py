"""benchmarks/bench_train_time.py: the command line each accelerator gets; a GPU asked for where there is none."""

from __future__ import annotations

import pytest
import torch

from tests._scripts import load_benchmark


def _load():
    return load_benchmark("bench_train_time")


def test_fit_args_run_on_the_named_accelerator_with_one_device(tmp_path):
    bt = _load()
    sizes = {"points": 1024, "batch": 4, "floor_cells": 24}
    for acc in ("cpu", "gpu"):
        args = bt.fit_args(["configs/models/cfar.yaml"], sizes, 5, tmp_path, acc)
        assert args[args.index("--trainer.accelerator") + 1] == acc
        assert args[args.index("--trainer.devices") + 1] == "1"
        assert args[args.index("--data.init_args.num_train") + 1] == "20"  # batch x steps


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_a_gpu_is_refused_up_front_where_torch_sees_none(capsys):
    bt = _load()
    with pytest.raises(SystemExit):
        bt.main(["--accelerators", "gpu", "cpu", "--jobs", "paper_cfar"])
    assert "torch sees no CUDA device" in capsys.readouterr().err
