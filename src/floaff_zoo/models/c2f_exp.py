"""C2FExpModule: C2F-Exp-style training-free coarse-to-fine base placement (docs/background.md §3)."""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import torch
from torch import Tensor

from floaff_zoo.checks import check_numbers
from floaff_zoo.contract import Batch
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig
from floaff_zoo.models.pointnet2 import floor_inputs, scene_inputs
from floaff_zoo.models.yaw import estimate_yaw
from floaff_zoo.nn.c2f import C2FConfig, C2FPlanner, resolve_scorer


class C2FExpModule(FloAffModule):
    """C2F-Exp-style placement (training-free; no checkpoint needed for ``test``/``predict``).

    Keeps C2F-Exp's geometry and schedule: affordance point g, ring prior of radius ``r_star`` =
    0.7 m (``sigma_dist`` 0.1), semantic Gaussian (``sigma_bias`` 0.2, x ``sigma_decay`` 0.8 per
    round, drift <= 1.2 m), weight w = p_geo^alpha * p_sem^(1-alpha) with
    alpha_t = ``max_alpha`` * sigmoid(12/T (t - 0.35 T)), T = 3 rounds of 20 candidates sampled
    0.4-1.2 m from g on free cells (occupancy of points above ``z_min`` on a ``cell`` grid, with a
    ``clearance`` margin), top-3 picks move the mean. Final pose: 20 candidates -> 5 -> drop the 2
    farthest -> average 3 (nearest pick if that collides), yaw facing g.

    **What replaces the VLM**: C2F-Exp asks GPT-4o (with SAM/DINOv2 affordance points) to choose
    the affordance point, the approach arrow and the best candidates. Here g is the target centre
    from the sample, the initial semantic mean is ``r_star`` along the target's front normal
    (``yaw_source``: ``manhattan`` (default) = the training-free estimate of ``floaff_zoo.models.yaw``,
    ``heading`` = towards the robot, ``gt`` = the simulator's ``target_yaw``, privileged: label such runs
    "C2F-Exp, simulator yaw"), and the candidate choice is a pluggable ``scorer``: by default
    ``"geometric"``, deterministic and purely geometric (it ranks by w itself); ``"clearance"``
    adds an obstacle-distance bonus; any ``"package.module:function"`` with the signature
    ``(candidates [n,2], weights [n], context) -> scores [n]`` can stand in for a VLM. Random draws
    use a generator seeded with ``seed``, so outputs are deterministic.

    The floor map for the metrics is the final w at every floor point, zeroed off the sampling band
    and on occupied cells, divided by its max ([0, 1]).

    ``feat_channels`` and ``robot_dim`` are the zoo's shared input schema: the data is checked against them as
    for every model, but the planner reads neither the scene features nor the robot descriptor (C2F-Exp's
    geometry uses the cloud's xyz and the target only).
    """

    trainable: ClassVar[bool] = False

    def __init__(
        self,
        r_star: float = 0.7,
        sigma_dist: float = 0.1,
        sigma_bias: float = 0.2,
        sigma_decay: float = 0.8,
        rounds: int = 3,
        candidates: int = 20,
        top_k: int = 3,
        r_min: float = 0.4,
        r_max: float = 1.2,
        max_alpha: float = 0.5,
        max_drift: float = 1.2,
        cell: float = 0.05,
        z_min: float = 0.05,
        clearance: float = 0.25,
        scorer: str = "geometric",
        seed: int = 0,
        yaw_source: Literal["gt", "manhattan", "heading"] = "manhattan",
        manhattan_radius: float = 1.2,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(),  # noqa: B008 - frozen
    ) -> None:
        # training-free: ``train`` only sets the logged loss and the metrics; there are no weights
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=None)

    def configure_models(self) -> None:
        h = self.hparams
        if h["rounds"] < 1 or h["candidates"] < 1 or h["top_k"] < 1:
            raise ValueError(
                "C2FExpModule: rounds, candidates, top_k must be >= 1 "
                f"(got {h['rounds']}, {h['candidates']}, {h['top_k']})"
            )
        if not 0 <= h["r_min"] < h["r_max"] < math.inf:
            raise ValueError(f"C2FExpModule: need 0 <= r_min < r_max (finite), got {h['r_min']}, {h['r_max']}")
        # sizes that passed unchecked and silently broke the search: a zero sigma_dist, sigma_bias or sigma_decay gave
        # an all-zero map, a zero cell an occupancy grid of overflowed indices (every candidate free), a max_alpha
        # above 1 a negative exponent on the semantic term, a NaN anywhere NaN weights
        owner = type(self).__name__
        sizes = ("sigma_dist", "sigma_bias", "sigma_decay", "cell", "manhattan_radius")
        check_numbers({k: h[k] for k in sizes}, strict=True, owner=owner)
        check_numbers({k: h[k] for k in ("r_star", "clearance")}, owner=owner)
        check_numbers({"max_alpha": h["max_alpha"]}, high=1.0, owner=owner)
        check_numbers({"z_min": h["z_min"]}, low=-math.inf, owner=owner)
        if not h["max_drift"] >= 0:  # inf: no cap
            raise ValueError(f"{owner}: max_drift must be >= 0, got {h['max_drift']}")
        fields = C2FConfig.__dataclass_fields__
        cfg = C2FConfig(**{k: h[k] for k in fields})
        self.net = C2FPlanner(cfg, resolve_scorer(h["scorer"]))

    def _searches(self, batch: Batch) -> list[dict[str, Any]]:
        xyz, _, mask = scene_inputs(batch, 1)
        yaw = estimate_yaw(
            batch, self.hparams["yaw_source"], None, 0.0, self.hparams["manhattan_radius"], type(self).__name__
        ).float()
        return [
            self.net.search(xyz[i].cpu(), mask[i].cpu(), batch["target_xyz"][i].float().cpu(), yaw[i].cpu())
            for i in range(xyz.shape[0])
        ]

    def forward(self, batch: Batch) -> Tensor:
        fxyz, fmask = floor_inputs(batch)
        states = self._searches(batch)
        maps = [self.net.score_floor(s, fxyz[i].cpu(), fmask[i].cpu()) for i, s in enumerate(states)]
        return torch.stack(maps).to(fxyz.device)

    def propose_pose(self, batch_item: Batch) -> tuple[float, float, float]:
        """Base pose (x, y, yaw) for one sample (a sample dict or a one-sample batch)."""
        from floaff_zoo.models.n2m import _unbatch

        item = _unbatch(batch_item)
        return self.net.final_pose(self._searches(item)[0])

    def predict_step(self, batch: Batch, batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        self.check_inputs(batch)
        fxyz, fmask = floor_inputs(batch)
        states = self._searches(batch)
        scores = torch.stack([self.net.score_floor(s, fxyz[i].cpu(), fmask[i].cpu()) for i, s in enumerate(states)])
        # a tensor: the prediction writer keeps tensors only (a list of tuples was dropped from predictions.npz)
        poses = torch.tensor([self.net.final_pose(s) for s in states], dtype=torch.float32).reshape(len(states), 3)
        return {**self.prediction(batch, scores), "poses": poses}
