"""Floor-query independence: a query's score must not depend on which OTHER floor queries are asked.

A robot asks a model about the floor it sees (``floaff_zoo.floor``), not about the benchmark's candidate set, so
adding or removing queries far from a query point must leave that point's score alone. For every deployable floor
model (every ``FloAffModule`` exported by ``floaff_zoo.models``, built from its tiny test config, eval mode) the test
scores a fixed scene with three query sets that share the NEAR queries (within ``NEAR`` m of a probe point):

* ``base``: a synthetic sample's floor grid (16 x 16 cells over 2.4 m x 1.4 m in front of the target);
* ``removed``: ``base`` without the queries farther than ``FAR`` m from the probe;
* ``added``: ``base`` plus a second grid of queries all farther than ``FAR`` m from the probe;

and measures the sensitivity = the largest change of a near query's score between the sets.

* Pointwise models (``INDEPENDENT``) must stay within ``TOL`` (absolute) and ``REL_TOL`` (relative): their floor
  scores are functions of the scene and of the query point alone (PointNet++ / VoteNet / H3DNet / tiny: scene
  features interpolated at the query; canonical prior: a map read at the query).
* Set encoders over the queries (``SET_ENCODERS``: NavAff's floor branch, as the paper's; CFAR's floor encoder in
  its default ``set`` mode) are measured and recorded (``record_property("sensitivity", ...)`` in the JUnit report,
  and printed); the test asserts that they ARE sensitive (relative > ``REL_TOL``, so the table here stays true) and
  that the model's query-independent mode (CFAR ``floor_encoder="pointwise"``; NavAff has none) satisfies both.
* Map-normalised models (``NORMALISED``: N2M, C2F-Exp) divide a query-independent map by its max over the asked
  set: they are measured, and the test asserts the ratios of near scores stay put (one per-sample factor), i.e.
  the ranking a robot uses is query-independent while the absolute scores are not.

Measured with the tiny configs (seed 0, CPU, untrained; absolute / relative to the spread of the near scores):
tiny, PointNet++ SSG/MSG, H3DNet, canonical prior, CFAR ``floor_encoder="pointwise"`` 0 / 0; VoteNet 6e-8 / 6e-6
(float round-off); NavAff 5e-6 / 0.022; CFAR ``set`` 7e-5 / 0.017; N2M 0.17 / 6.8 (max-normalised); C2F-Exp ~1e-16
(its near scores are ~0 here). The then shipped ``cfar-pfal.floaff-small-layouts.v1`` (set, trained on format-1
data; since retired) gave 4e-3 / 1.06 on the same sets: its near scores move by as much as they differ. Untrained set
encoders give almost flat maps, so their absolute sensitivity understates what a trained one shows (issue 17: every
score <= 0.01 on the API's default disc for the shipped CFAR); the relative number is the one asserted.
"""

from __future__ import annotations

import inspect
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import floaff_zoo.models as zoo
from floaff_zoo.contract import collate_samples, validate_sample
from floaff_zoo.data.synthetic import make_synthetic_sample

ROOT = Path(__file__).resolve().parents[2]
TOL = 1e-4  # absolute score change allowed for a query-independent model (float round-off only)
REL_TOL = 1e-3  # the same, relative to the spread of the near scores (an untrained net's map is almost flat)
NEAR = 0.5  # m: queries this close to the probe are compared
FAR = 1.0  # m: queries added / removed are farther than this from the probe

# class name -> config (tests/configs tiny configs; the canonical prior has no network: its shipped config)
CONFIGS = {
    "TinyPointNetModule": None,
    "PointNet2Module": "tests/configs/models/pointnet2_ssg_tiny.yaml",
    "VoteNetModule": "tests/configs/models/votenet_tiny.yaml",
    "H3DNetModule": "tests/configs/models/h3dnet_tiny.yaml",
    "NavAffModule": "tests/configs/models/navaff_tiny.yaml",
    "N2MModule": "tests/configs/models/n2m_tiny.yaml",
    "C2FExpModule": "tests/configs/models/c2f_exp_tiny.yaml",
    "CFARModule": "tests/configs/cfar_tiny.yaml",
    "CanonicalPriorModule": "configs/models/canonical_prior.yaml",
}
INDEPENDENT = [
    "TinyPointNetModule",
    "PointNet2Module",
    "PointNet2Module:msg",
    "VoteNetModule",
    "H3DNetModule",
    "CanonicalPriorModule",
]
SET_ENCODERS = ["NavAffModule", "CFARModule"]
NORMALISED = ["N2MModule", "C2FExpModule"]
#: CFAR's query-independent mode: the constructor argument and its value (being added to CFARModule)
CFAR_POINTWISE = ("floor_encoder", "pointwise")


def _floor_models() -> list[str]:
    return sorted(
        n
        for n in zoo.__all__
        if n != "FloAffModule" and isinstance(getattr(zoo, n), type) and issubclass(getattr(zoo, n), zoo.FloAffModule)
    )


def build(name: str, **overrides) -> torch.nn.Module:
    """A model from its config (``name`` = class name, ``Class:msg`` for the PointNet++ MSG variant), eval mode."""
    cls_name, _, variant = name.partition(":")
    cls = getattr(zoo, cls_name)
    path = CONFIGS[cls_name]
    if variant:
        path = f"tests/configs/models/pointnet2_{variant}_tiny.yaml"
    args = dict(yaml.safe_load((ROOT / path).read_text())["model"].get("init_args") or {}) if path else {}
    if cls_name == "TinyPointNetModule":
        args = {"width": 16}
    torch.manual_seed(0)
    model = cls(**{**args, **overrides})
    return model.eval()


def _sample(extra: np.ndarray | None = None, keep: np.ndarray | None = None) -> dict:
    s = make_synthetic_sample(3, num_points=256, floor_cells=16)
    floor = s["floor_xyz"].numpy()
    if keep is not None:
        floor = floor[keep]
    if extra is not None:
        floor = np.concatenate([floor, extra.astype(np.float32)])
    return validate_sample(
        {
            **{k: v for k, v in s.items() if k not in ("floor_xyz", "floor_label", "floor_mask")},
            "floor_xyz": floor,
            "floor_label": np.zeros(len(floor), np.float32),
        }
    )


def query_sets() -> tuple[dict[str, dict], np.ndarray]:
    """(name -> one-sample batch, indices of the near queries in every set: they come first and in order)."""
    base = _sample()
    floor = base["floor_xyz"].numpy()
    probe = floor[0, :2]  # a corner of the grid: most of the grid is farther than FAR
    d = np.hypot(*(floor[:, :2] - probe).T)
    near = np.flatnonzero(d <= NEAR)
    far = d > FAR
    assert len(near) >= 4 and far.sum() >= 100 and (d[~far] <= FAR).all()
    t = base["target_xyz"].numpy()
    away = floor[:, :2] - probe
    shift = 2.5 * away.mean(0) / np.linalg.norm(away.mean(0))  # a copy of the grid pushed away from the probe
    extra = floor[far] + np.r_[shift, 0.0].astype(np.float32)
    assert (np.hypot(*(extra[:, :2] - probe).T) > FAR).all() and np.isfinite(t).all()
    sets = {"base": base, "removed": _sample(keep=~far), "added": _sample(extra=extra)}
    kept = sets["removed"]["floor_xyz"][:, :2].numpy()
    near_in = {"base": near, "removed": np.flatnonzero(np.hypot(*(kept - probe).T) <= NEAR), "added": near}
    assert all(len(v) == len(near) for v in near_in.values())
    return {k: collate_samples([v]) for k, v in sets.items()}, near_in


def near_scores(model: torch.nn.Module) -> dict[str, np.ndarray]:
    batches, near = query_sets()
    with torch.no_grad():
        return {k: model(b)[0].double().numpy()[near[k]] for k, b in batches.items()}


def sensitivity(scores: dict[str, np.ndarray]) -> float:
    """Largest change of a near query's score between the query sets (absolute, scores in [0, 1])."""
    ref = scores["base"]
    return float(max(np.abs(s - ref).max() for s in scores.values()))


def relative(scores: dict[str, np.ndarray]) -> float:
    """sensitivity / spread of the near scores: an untrained net's scores all sit near 0.5, so the absolute change
    says little about how much the set matters; relative to the spread it does."""
    return sensitivity(scores) / max(float(np.ptp(scores["base"])), 1e-12)


def _record(record_property, name: str, scores: dict[str, np.ndarray]) -> float:
    s, r = sensitivity(scores), relative(scores)
    record_property("sensitivity", s)
    record_property("relative_sensitivity", r)
    print(f"\nquery sensitivity {name}: {s:.3g} absolute, {r:.3g} of the near scores' spread (tolerance {TOL})")
    return s


def test_every_floor_model_is_classified():
    classified = {n.partition(":")[0] for n in INDEPENDENT + SET_ENCODERS + NORMALISED}
    missing = sorted(set(_floor_models()) - classified)
    assert not missing, f"add {missing} to INDEPENDENT, SET_ENCODERS or NORMALISED (and CONFIGS) in {__file__}"


@pytest.mark.filterwarnings("ignore:You are trying to `self.log")  # the prior is fitted without a Trainer
@pytest.mark.parametrize("name", INDEPENDENT)
def test_pointwise_models_are_query_independent(name, record_property):
    model = build(name)
    if name == "CanonicalPriorModule":  # no network: accumulate one batch of labels, then read the map
        model.train()
        model.training_step(collate_samples([make_synthetic_sample(5, num_points=256, floor_cells=16)]), 0)
        model.eval()
    scores = near_scores(model)
    s = _record(record_property, name, scores)
    assert s <= TOL, f"{name}: a near query's score moved by {s:.3g} when far queries were added or removed"
    assert relative(scores) <= REL_TOL, f"{name}: near scores moved by {relative(scores):.3g} of their spread"


@pytest.mark.parametrize("name", SET_ENCODERS)
def test_set_encoders_are_measured(name, record_property):
    scores = near_scores(build(name))
    _record(record_property, name, scores)
    r = relative(scores)
    assert math.isfinite(r) and r > REL_TOL, f"{name} looks query-independent now ({r:.3g}): move it to INDEPENDENT"


def _has_arg(cls_name: str, arg: str) -> bool:
    return arg in inspect.signature(getattr(zoo, cls_name).__init__).parameters


@pytest.mark.xfail(
    not _has_arg("CFARModule", CFAR_POINTWISE[0]),
    strict=True,
    reason=f"CFARModule has no query-independent mode yet ({CFAR_POINTWISE[0]}={CFAR_POINTWISE[1]!r})",
)
def test_cfar_pointwise_mode_is_query_independent(record_property):
    model = build("CFARModule", **{CFAR_POINTWISE[0]: CFAR_POINTWISE[1]})
    scores = near_scores(model)
    assert _record(record_property, "CFARModule pointwise", scores) <= TOL and relative(scores) <= REL_TOL


def test_navaff_pointwise_mode_is_query_independent(record_property):
    model = build("NavAffModule", floor_encoder="pointwise")
    scores = near_scores(model)
    assert _record(record_property, "NavAffModule pointwise", scores) <= TOL and relative(scores) <= REL_TOL


@pytest.mark.parametrize("name", NORMALISED)
def test_normalised_maps_keep_their_ratios(name, record_property):
    scores = near_scores(build(name))
    _record(record_property, name, scores)
    ref = scores["base"]
    assert ref.max() > 0
    for k, s in scores.items():  # s = ref * c for one factor c > 0 per set: the ranking does not move
        c = s.max() / ref.max()
        assert c > 0 and np.allclose(s, c * ref, atol=1e-6, rtol=1e-4), (name, k)
