"""benchmarks/bench_predict.py: rounds rotate the call order; percentiles by nearest rank."""

from __future__ import annotations

import argparse

import pytest
import torch

from tests._scripts import load_benchmark


def _load():
    return load_benchmark("bench_predict")


def test_rounds_call_every_model_once_in_a_rotating_order():
    bp = _load()
    order: list[str] = []
    calls = {n: (lambda n=n: order.append(n)) for n in "abc"}
    times = bp.run_rounds(calls, rounds=3, warmup=1)
    assert order == list("abc") + list("abc") + list("bca") + list("cab")
    assert {n: len(t) for n, t in times.items()} == {"a": 3, "b": 3, "c": 3}


def test_percentile_is_the_nearest_rank():
    bp = _load()
    xs = [5.0, 1.0, 4.0, 2.0, 3.0]
    assert bp.percentile(xs, 0.0) == 1.0 and bp.percentile(xs, 0.5) == 3.0 and bp.percentile(xs, 1.0) == 5.0
    assert bp.percentile(xs, 0.1) == 1.0 and bp.percentile(xs, 0.9) == 5.0


def test_a_bad_or_absent_device_is_refused_by_name(capsys):
    bp = _load()
    with pytest.raises(SystemExit):
        bp.main(["--device", "gpu0"])
    assert "--device 'gpu0': not a torch device" in capsys.readouterr().err
    if not torch.cuda.is_available():
        with pytest.raises(SystemExit):
            bp.main(["--device", "cuda"])
        assert "torch sees no CUDA device" in capsys.readouterr().err


def test_calls_on_the_cpu_device_run_the_model():
    bp = _load()
    calls, ports = bp.callers(["pointnet2_ssg"], points=256, floor_cells=4, device=torch.device("cpu"))
    assert set(calls) == set(ports) == {"pointnet2_ssg"}
    calls["pointnet2_ssg"]()  # a real forward on the moved batch


@pytest.mark.parametrize(
    ("script", "args"),
    [
        ("bench_predict", ["--models"]),
        ("bench_models", ["--iters", "-1"]),
        ("bench_models", ["--warmup", "0"]),
        ("bench_vs_port", ["--rounds", "0"]),
        ("bench_train_time", ["--steps", "0"]),
        ("profile_step", ["--steps", "0"]),
        ("bench_sim", ["--agree", "-1"]),  # sliced [:-1]: checked all but one, no error
        ("bench_sim", ["--cell", "0"]),
        ("bench_models", ["--batch", "0"]),  # SampleError: cannot collate an empty batch
        ("bench_models", ["--threads", "0"]),
        ("bench_predict", ["--points", "0"]),
        ("profile_step", ["--batch", "0"]),
        ("bench_loader", ["--samples", "0"]),
        ("bench_loader", ["--workers", "-1"]),
        ("bench_train_time", ["--jobs"]),  # an empty table, exit 0
    ],
)
def test_benchmark_counts_below_one_are_refused_up_front(script, args, capsys):
    """They ended in ZeroDivisionError / StatisticsError / KeyError (bench_train_time only after a whole fit), or
    timed the reference's cold first step against ours warmed (bench_models --warmup 0)."""
    with pytest.raises(SystemExit) as exc:
        load_benchmark(script).main(args)
    assert exc.value.code == 2 and "error: --" in capsys.readouterr().err


def test_bench_models_says_which_models_cannot_run_in_the_mode():
    """--model-mode bf16|compile dropped the option for CFAR and C2F-Exp (they take neither) and printed their fp32
    rows under the mode's heading."""
    bm = load_benchmark("bench_models")
    assert not bm.runs_in_mode("cfar", "bf16") and not bm.runs_in_mode("cfar_axisnet", "compile")
    assert not bm.runs_in_mode("c2f_exp", "compile_bf16")
    assert bm.runs_in_mode("pointnet2_ssg", "compile_bf16") and bm.runs_in_mode("cfar", "eager")


def test_each_model_is_timed_against_itself_on_the_ports_ops(monkeypatch):
    """The ratio compared every model with the layer-study net on a random cloud (another network, another input):
    the reference is now the same model, same weights and input, on the port's ops."""
    bp = _load()
    ref_mod = bp.bm.load_reference()
    used: list[bool] = []
    real = ref_mod.reference_ops

    def spy():
        used.append(True)
        return real()

    monkeypatch.setattr(ref_mod, "reference_ops", spy)
    monkeypatch.setattr(bp.bm, "load_reference", lambda: ref_mod)
    calls, ports = bp.callers(["pointnet2_ssg"], points=256, floor_cells=4)
    assert list(calls) == list(ports) == ["pointnet2_ssg"]
    calls["pointnet2_ssg"]()
    assert used == []
    ports["pointnet2_ssg"]()
    assert used == [True]


def test_generation_figures_read_from_a_manifest_say_so(tmp_path):
    """They printed like figures of the run (dated by run_all), with a per-slot rate over zero slots."""
    import json

    bg = load_benchmark("bench_generate")
    man = {
        "status": "done",
        "wall_s": 3.0,
        "preset": "demo",
        "workers": 2,
        "counts": {"scenes_ok": 2, "scenes_dropped": 0, "views_total": 24},
        "config": {"benchmarks": ["layouts"], "max_candidates": 60},
        "scenes": {"a": {"resumed": True}, "b": {"resumed": True}},
    }
    (tmp_path / "floaff_demo").mkdir()
    (tmp_path / "floaff_demo" / "manifest.json").write_text(json.dumps(man))
    (line,) = bg.manifest_walls(tmp_path)
    assert "not timed here" in line and str(tmp_path / "floaff_demo" / "manifest.json") in line
    assert "s/slot n/a: every slot was resumed" in line and "0.0 s/slot" not in line


@pytest.mark.parametrize(
    ("args", "said"),
    [  # a SampleError after the models' rows; a heading over no row, exit 0
        (["--points-sweep", "1024", "0"], "--points-sweep sizes must be >= 1, got [1024, 0]"),
        (["--points-sweep", "1024", "--sweep-models"], "--sweep-models: name at least one of"),
        (["--vs-reference", "cfar", "--sweep-models", "cfar"], "give --points-sweep too"),  # ignored without a word
    ],
)
def test_bench_models_refuses_a_bad_points_sweep_up_front(args, said, capsys):
    with pytest.raises(SystemExit) as exc:
        load_benchmark("bench_models").main(["--skip-models", "--skip-reference", *args])
    assert exc.value.code == 2 and said in capsys.readouterr().err


def test_bench_models_refuses_to_time_nothing(capsys):
    """--skip-models --skip-reference alone printed the torch version line and exited 0, a report of no figure."""
    with pytest.raises(SystemExit) as exc:
        load_benchmark("bench_models").main(["--skip-models", "--skip-reference"])
    assert exc.value.code == 2 and "nothing to time: --skip-models and --skip-reference" in capsys.readouterr().err


def test_a_device_the_benchmarks_cannot_time_is_refused_by_name(monkeypatch, capsys):
    """meta and mps were taken as devices and failed deep in the first model call (meta: Tensor.item() on a meta
    tensor; mps: not linked); a CUDA index past the last device was taken too."""
    bp = _load()
    for device in ("meta", "mps"):
        with pytest.raises(SystemExit) as exc:
            bp.main(["--device", device, "--models", "pointnet2_ssg", "--points", "256", "--floor-cells", "4"])
        assert (
            exc.value.code == 2 and f"--device {device!r}: the benchmarks run on cpu or cuda" in capsys.readouterr().err
        )
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    parser = argparse.ArgumentParser()
    assert bp.bm.parse_device(parser, "cuda:0") == torch.device("cuda:0")
    with pytest.raises(SystemExit):
        bp.bm.parse_device(parser, "cuda:1")
    assert "--device 'cuda:1': torch sees 1 CUDA device(s) here" in capsys.readouterr().err


@pytest.mark.parametrize("threads", ["0", "-1"])
def test_bench_vs_port_refuses_threads_below_one(threads, monkeypatch, capsys):
    """--threads 0 ran every child on torch's default thread count without a word; -1 failed in each child."""
    bv = load_benchmark("bench_vs_port")
    monkeypatch.setattr(bv, "run_config", lambda *a: pytest.fail("a child ran"))
    with pytest.raises(SystemExit) as exc:
        bv.main(["--threads", threads, "--models", "pointnet2_ssg"])
    assert exc.value.code == 2 and f"--threads must be >= 1, got {threads}" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--cell", "inf"], "--cell must be a finite number > 0, got inf"),  # ValueError in the first annotation
        (["--growth-cells", "0.2", "inf", "--layout", "99"], "--growth-cells must be finite numbers > 0"),
        (["--layout", "99"], "--layout 99 --style 0 --seed 0: unknown layout_id 99"),  # a SceneSpec traceback
        (["--style", "-1"], "--layout 0 --style -1 --seed 0: unknown style_id -1"),
        (["--seed", "-1"], "--layout 0 --style 0 --seed -1: seed must be >= 0"),
    ],
)
def test_bench_sim_refuses_a_bad_grid_or_scene_by_name(args, said, capsys):
    with pytest.raises(SystemExit) as exc:
        load_benchmark("bench_sim").main(args)
    assert exc.value.code == 2 and said in capsys.readouterr().err
