"""Training labels from repeated episodes: every feasible cell of the train scenes rolled out again.

    python scripts/fresh_labels.py --root data/floaff_dense --benchmark layouts \
        --probs runs/fresh/p_train_layouts.npz --out runs/fresh/labels_train_layouts.npz

A generated label is one rollout per cell with the annotation's task seed, smoothed. Whether that rollout succeeds
is partly luck (a door opened a little more, a grasp that slips): for CloseDoubleDoor only about half of the
annotated successes succeed again. This script rolls every feasible cell of every train scene (the validation
scenes included: they are train scenes on disk) out ``--episodes`` more times with fresh task seeds and parking
noise (``floaff_zoo.sim.repeat``, as ``scripts/fresh_sr.py`` does on test scenes), takes each cell's success rate
over those episodes and the annotated one, and smooths it as the generator smooths its binary labels
(``floaff_zoo.sim.annotate.probability_label``). The result is a scene-label file for
``FloAffKitchenDataModule(train_labels=...)`` (configs/experiments/recipe/fresh_labels_<benchmark>.yaml), which
uses it for the train split only. Test scenes are never touched.

``--zero-failures`` keeps the smoothed map only on cells that succeeded at least once and sets every other cell to 0.
The generated map is smoothed over all cells, so a cell whose rollout failed keeps the value of its successful
neighbours; where failures form holes inside a successful region (the arm without an IK solution at cells next
to ones with a solution, OpenSingleDoor) the map's peak can lie on a failure. With ``--episodes 0`` nothing is
rolled out (the annotated outcome alone, seconds):

    python scripts/fresh_labels.py --root data/floaff_dense --benchmark layouts --episodes 0 --zero-failures \
        --out runs/labels/success_train_layouts.npz
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from floaff_zoo.contract import TASKS
from floaff_zoo.sim.fileformat import BENCHMARKS

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import add_parking_noise, check_parking_noise, refuse_folders  # noqa: E402


def scene_label(scene: dict, fresh: np.ndarray, episodes: int, zero_failures: bool = False) -> np.ndarray:
    """A scene record's label from its fresh probabilities [M] (``episodes`` each) and its annotated outcome: [M].

    ``zero_failures``: 0 on every cell whose success rate is 0 (the smoothed map kept on the others).
    """
    from floaff_zoo.sim.annotate import probability_label

    cand = scene["candidates"]
    annotated = np.asarray(scene["labels"]["success"], float)
    rate = (annotated + episodes * np.asarray(fresh, float)) / (episodes + 1)
    label = probability_label(rate, np.asarray(cand["status"]), tuple(cand["grid_shape"]), float(scene["sigma"]))
    return np.where(rate > 0, label, 0.0).astype(label.dtype) if zero_failures else label


def generated_label(scene: dict) -> np.ndarray:
    """The label the generator gave each cell of a scene record: ``labels.cell_label`` (format 2: filtered cells 0,
    what the views train on), else ``labels.label``. The summary compares peaks with it: ``labels.label`` is the
    smoothed map before filtered cells are zeroed, whose peak can lie on a filtered cell that no label ever has."""
    labels = scene["labels"]
    return np.asarray(labels["cell_label"] if "cell_label" in labels else labels["label"], float)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmark", default="layouts", choices=BENCHMARKS)
    p.add_argument("--episodes", type=int, default=4, help="fresh episodes per cell (0: the annotated outcome only)")
    add_parking_noise(p)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument(
        "--probs",
        default=None,
        help="cache of the fresh probabilities (.npz; read if it exists; unused with --episodes 0)",
    )
    p.add_argument("--zero-failures", action="store_true", help="label 0 on cells that never succeeded (module doc)")
    p.add_argument("--out", required=True, help="the scene-label file to write (.npz)")
    a = p.parse_args(argv)
    check_parking_noise(p, a)
    if a.episodes < 0 or a.workers < 1:
        p.error("--episodes must be >= 0 and --workers >= 1")
    for name in ("probs", "out"):
        v = getattr(a, name)
        if v is not None and not v.endswith(".npz"):
            p.error(f"--{name} must name a .npz file, got {v!r}")
    refuse_folders(p, probs=a.probs, out=a.out)

    from floaff_zoo.data.scene_labels import MADE_FROM, write_scene_labels
    from floaff_zoo.sim import fileformat as ff
    from floaff_zoo.sim.repeat import scene_probabilities

    scenes = {s["scene_id"]: s for s in ff.iter_scenes(a.root, benchmark=a.benchmark, split="train")}
    if not scenes:
        raise SystemExit(f"fresh_labels: no finished train scene of {a.benchmark} under {a.root}")
    setting = dict(episodes=a.episodes, sigma_xy=a.sigma_xy, sigma_yaw_deg=a.sigma_yaw_deg, seed=a.seed)
    if a.episodes == 0:  # the annotated outcome only: nothing to roll out
        probs = {sid: np.asarray(s["labels"]["success"], float) for sid, s in scenes.items()}
    else:
        try:
            probs = scene_probabilities(scenes, setting, Path(a.probs) if a.probs else None, a.workers)
        except ValueError as exc:
            raise SystemExit(f"fresh_labels: {exc}") from exc

    labels = {}
    for sid, scene in scenes.items():
        label = scene_label(scene, probs[sid], a.episodes, a.zero_failures)
        labels[sid] = (np.asarray(scene["candidates"]["xy"], float), label, float(scene["candidates"]["cell"]))
    source = "annotated + fresh episodes" if a.episodes else "annotated"
    setting = {**setting, "zero_failures": a.zero_failures}
    made_from = {sid: ff.labels_digest(scene) for sid, scene in scenes.items()}  # the data module checks it
    write_scene_labels(a.out, labels, {**setting, "benchmark": a.benchmark, "source": source, MADE_FROM: made_from})
    print(f"{a.out}: labels of {len(labels)} train scenes of {a.benchmark} ({setting})")
    for t in TASKS:
        ids = [s for s in scenes if scenes[s]["task"] == t]
        if ids:
            old = np.mean([np.argmax(generated_label(scenes[s])) == np.argmax(labels[s][1]) for s in ids])
            succ = [np.asarray(scenes[s]["labels"]["success"]) > 0 for s in ids]
            again = ""
            if a.episodes:
                hold = np.mean(np.concatenate([probs[s][m] for s, m in zip(ids, succ)]))
                again = f", annotated successes succeed again {hold:.2f}"
            print(f"  {t}: {len(ids)} scenes{again}, same peak cell {old:.2f}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "fresh_labels"))
