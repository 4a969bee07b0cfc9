"""predict's default floor queries on generated data (issue 17, item 3): a model trained on a generated scene finds,
on the observed floor cells predict builds from the view's cloud alone, the pose the dataset's labels put first."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
gen = pytest.importorskip("floaff_zoo.sim.generate")
from floaff_zoo.contract import collate_samples, validate_sample  # noqa: E402
from floaff_zoo.predict import predict_from_points  # noqa: E402
from floaff_zoo.sim import fileformat as ff  # noqa: E402
from floaff_zoo.sim.presets import get_preset  # noqa: E402

MAX_DIST = 0.15  # m: best pose of the default grid vs the dataset's label argmax


@pytest.fixture(scope="module")
def drawer_views(tmp_path_factory):
    """The 2 front + 2 side views of one generated tiny CloseDrawer training scene (format 2)."""
    out = tmp_path_factory.mktemp("gen_one")
    man = gen.generate(out, get_preset("tiny", tasks=("CloseDrawer",), n_test=0), seed=0, workers=0, quiet=True)
    assert man["counts"]["scenes_ok"] == 1
    scene = next(ff.iter_scenes(out))
    return scene, [ff.read_sample(scene, v) for v in scene["views"]]


def _contract(s: dict) -> dict:
    return validate_sample({k: v for k, v in s.items() if k != "floor_known"})


def _argmax_set(label: np.ndarray) -> np.ndarray:
    return np.flatnonzero(label >= label.max() - 1e-6)


def _fit_prior(samples: list[dict], cell: float):
    """The canonical prior (a pointwise zoo model: the mean training label at a query's canonical position), fitted
    on the views in one pass; its grid puts the dataset's cell centres mid-cell (no float flips at borders)."""
    from floaff_zoo.models.prior import CanonicalPriorModule

    model = CanonicalPriorModule(
        tasks=["CloseDrawer"],
        cell=cell / 2,
        extent=3.0,
        smooth_sigma_cells=0.0,
        yaw_source="gt",
        eval_yaw_source="gt",
    )
    model.train()
    model.training_step(collate_samples([_contract(s) for s in samples]), 0)
    return model.eval()


@pytest.mark.filterwarnings("ignore:You are trying to `self.log")  # the prior is fitted without a Trainer
def test_default_grid_best_pose_is_the_dataset_argmax(drawer_views):
    scene, samples = drawer_views
    cell = scene["candidates"]["cell"]
    model = _fit_prior(samples, cell)
    for v, s in zip(scene["views"], samples):
        label = np.asarray(s["floor_label"])
        # what `floaff-zoo test` sees: the dataset's floor points; the fitted model puts a label argmax first
        with torch.no_grad():
            on_data = model(collate_samples([_contract(s)]))[0].numpy()
        assert np.allclose(on_data, label, atol=1e-6) and int(on_data.argmax()) in _argmax_set(label), v["view_id"]
        # what a robot does: predict with the default floor queries (the cloud's observed floor cells), given the
        # target pose and the cell of the training data, no simulator field
        pred = predict_from_points(
            model,
            s["scene_xyz"],
            s["scene_feat"],
            None,
            s["robot"],
            s["target_xyz"],
            float(s["target_yaw"]),
            cell=cell,
            task="CloseDrawer",
        )
        assert abs(len(pred.floor_xyz) - len(label)) <= max(1, len(label) // 50)
        best = np.asarray(s["floor_xyz"])[_argmax_set(label), :2]
        d = float(np.hypot(*(best - np.asarray(pred.best_pose[:2])).T).min())
        assert d <= MAX_DIST, f"{v['view_id']}: predict's best pose is {d:.2f} m from the dataset argmax"
