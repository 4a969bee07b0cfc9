"""N2MModule: an N2M-style GMM over SE(2) base poses (docs/background.md §3)."""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from floaff_zoo.checks import check_numbers
from floaff_zoo.contract import Batch, batch_item
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig, check_dropout
from floaff_zoo.models.pointnet2 import floor_inputs, maybe_bf16, maybe_compile, scene_inputs
from floaff_zoo.nn.nets import N2MNet, gmm_log_prob
from floaff_zoo.nn.placement import footprint_collides, heading_to, occupied_cells


def floor_poses(floor_xyz: Tensor, target_xyz: Tensor) -> Tensor:
    """SE(2) poses at the floor points facing the target: [B,M,3], [B,3] -> [B,M,3] (x, y, yaw)."""
    yaw = heading_to(floor_xyz[..., :2], target_xyz[:, None, :2])
    return torch.cat([floor_xyz[..., :2], yaw[..., None]], dim=-1)


def positive_poses(batch: Batch, threshold: float) -> tuple[Tensor, Tensor]:
    """Successful poses drawn from the labels: floor points with label >= ``threshold``.

    A sample with no such point contributes its best-labelled point, if its label is > 0; a sample whose labels are
    all 0 contributes none (its first stored point would stand for a success).

    Returns:
        (poses [B,M,3], weights [B,M] float with 1 for positives, 0 elsewhere).
    """
    label = batch["floor_label"].float()
    mask = batch["floor_mask"].bool()
    pos = (label >= threshold) & mask
    masked = label.masked_fill(~mask, -1.0)
    best = masked.argmax(dim=1, keepdim=True)
    fallback = torch.zeros_like(pos).scatter_(1, best, True) & (masked.amax(dim=1, keepdim=True) > 0)
    pos = torch.where(pos.any(dim=1, keepdim=True), pos, fallback)
    return floor_poses(batch["floor_xyz"].float(), batch["target_xyz"].float()), pos.float()


def _unbatch(item: Batch) -> Batch:
    """Accept a sample (no batch dim) or a one-sample batch; return a one-sample batch."""
    if item["scene_xyz"].ndim == 2:
        out = {k: (v[None] if torch.is_tensor(v) else v) for k, v in item.items() if k != "meta"}
        out["meta"] = [item.get("meta", {})]
        return out
    if item["scene_xyz"].shape[0] != 1:
        raise ValueError(f"propose_pose takes one sample, got a batch of {item['scene_xyz'].shape[0]}")
    return item


class N2MModule(FloAffModule):
    """N2M-style base-pose distribution: a GMM over (x, y, theta) from the egocentric cloud.

    A PointNet++ SSG encoder (N2M uses PointBERT; see ``N2MNet``) pools the observation (max ⊕
    mean), an MLP decoder with dropout outputs K components: means, covariances
    ``matrix_exp(sym) + 1e-6 I`` and softmax weights. Training minimises the NLL of successful
    poses drawn from the labels (floor points with label >= ``positive_threshold``, theta = heading
    to the target; the best point when none passes), minus N2M's optional entropy terms
    (``lambda_weights`` on the mixture weights, ``lambda_components`` on the Gaussians; N2M's main
    config uses 0.1/0.1). The angle is wrapped (density summed over theta + 2 pi k).

    For the map metrics the density is evaluated at each floor point (theta facing the target)
    and divided by its max over the valid floor points -> [0, 1]. For placement,
    :meth:`propose_pose` follows N2M's inference: try the highest-weight mean, else sample
    ``num_pose_samples`` poses, sort by density and return the first collision-free one
    (footprint ``footprint_length`` x ``footprint_width`` m, ``footprint_back`` of the length behind
    the base origin, occupancy grid of ``occupancy_cell`` m from points with z > ``occupancy_z``).

    Args:
        npoints, radii, nsamples, mlps: SSG encoder; decoder: MLP widths; num_components: K (1-2);
        dropout; positive_threshold; lambda_weights, lambda_components: entropy terms;
        num_pose_samples, footprint_*, occupancy_*: placement; seed: sampling seed;
        compile, bf16: opt-in speed modes. ``train.loss`` (and ``sdl_beta``) only shape the logged affordance
        loss; ``train.rank_weight`` > 0 is refused (the NLL is the whole training loss).
        (the rest: see :class:`FloAffModule`)
    """

    def __init__(
        self,
        npoints: list[int] = [512, 128, 32],  # noqa: B006
        radii: list[list[float]] = [[0.2], [0.4], [0.8]],  # noqa: B006
        nsamples: list[list[int]] = [[32], [32], [32]],  # noqa: B006
        mlps: list[list[list[int]]] = [[[64, 64, 128]], [[128, 128, 256]], [[256, 256, 384]]],  # noqa: B006
        decoder: list[int] = [512, 256],  # noqa: B006
        num_components: int = 2,
        dropout: float = 0.1,
        positive_threshold: float = 0.5,
        lambda_weights: float = 0.0,
        lambda_components: float = 0.0,
        num_pose_samples: int = 100,
        footprint_length: float = 0.63,
        footprint_width: float = 0.5,
        footprint_back: float = 0.83,
        occupancy_cell: float = 0.02,
        occupancy_z: float = 0.05,
        seed: int = 0,
        compile: bool = False,
        bf16: bool = False,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(lr=1e-4),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=weights)
        if self.train_cfg.rank_weight:  # it would only move the logged aff_loss: a run that set it learned nothing
            raise ValueError(
                f"N2MModule trains its GMM's negative log-likelihood only: train.rank_weight has no effect on it "
                f"(got {self.train_cfg.rank_weight}); leave it 0"
            )

    def configure_models(self) -> None:
        h = self.hparams
        owner = type(self).__name__
        check_dropout(h["dropout"], owner)
        check_numbers({k: h[k] for k in ("lambda_weights", "lambda_components")}, owner=owner)
        check_numbers({k: h[k] for k in ("positive_threshold", "footprint_back")}, high=1.0, owner=owner)
        check_numbers(
            {k: h[k] for k in ("footprint_length", "footprint_width", "occupancy_cell")}, strict=True, owner=owner
        )
        check_numbers({"occupancy_z": h["occupancy_z"]}, low=-math.inf, owner=owner)
        if h["num_pose_samples"] < 1:
            raise ValueError(f"{owner}: num_pose_samples must be >= 1, got {h['num_pose_samples']}")
        self.net = N2MNet(
            h["feat_channels"],
            h["npoints"],
            h["radii"],
            h["nsamples"],
            h["mlps"],
            h["decoder"],
            h["num_components"],
            h["dropout"],
        )
        maybe_compile(self.net, h["compile"])

    def gmm(self, batch: Batch) -> tuple[Tensor, Tensor, Tensor]:
        """(means [B,K,3], covariances [B,K,3,3], log-weights [B,K]) for a batch."""
        xyz, feat, mask = scene_inputs(batch, self.hparams["feat_channels"])
        fps = self.net.sample(xyz, mask)
        with maybe_bf16(self.hparams["bf16"], xyz.device):
            means, cov, logw = self.net(xyz, feat, mask, fps=fps)
        return means.float(), cov.float(), logw.float()

    @staticmethod
    def density_map(gmm: tuple[Tensor, Tensor, Tensor], batch: Batch) -> Tensor:
        """GMM density at the floor points (facing the target), divided by its max: [B, M] in [0, 1]."""
        fxyz, fmask = floor_inputs(batch)
        logp = gmm_log_prob(floor_poses(fxyz, batch["target_xyz"].float()), *gmm)
        logp = logp.masked_fill(~fmask, float("-inf"))
        top = logp.amax(dim=1, keepdim=True)
        return torch.exp(logp - top).masked_fill(~fmask, 0.0)

    def forward(self, batch: Batch) -> Tensor:
        return self.density_map(self.gmm(batch), batch)

    def nll(self, gmm: tuple[Tensor, Tensor, Tensor], batch: Batch) -> Tensor:
        """Weighted NLL of the positive poses (+ optional entropy terms, means over every sample).

        Training: the mean over the samples with a positive pose (0 with a graph when none has one). Evaluation: the
        mean over every sample, 0 for one without a positive pose, so that Lightning's sample-weighted epoch mean of
        ``val_loss``/``test_loss`` does not depend on the eval batch size.
        """
        poses, w = positive_poses(batch, self.hparams["positive_threshold"])
        logp = gmm_log_prob(poses, *gmm)
        keep = w.sum(1) > 0
        per_sample = -(torch.where(w > 0, logp, 0.0) * w).sum(1) / w.sum(1).clamp_min(1.0)  # [B], 0 where not keep
        if self.training:
            nll = per_sample[keep].mean() if bool(keep.any()) else gmm[0].sum() * 0.0
        else:
            nll = per_sample.mean()
        means, cov, logw = gmm
        h = self.hparams
        if h["lambda_weights"]:
            nll = nll + h["lambda_weights"] * (torch.exp(logw) * logw).sum(-1).mean()  # - H(weights)
        if h["lambda_components"]:
            ent = 0.5 * torch.logdet(2 * math.pi * math.e * cov)  # [B, K]
            nll = nll - h["lambda_components"] * (torch.exp(logw) * ent).sum(-1).mean()
        return nll

    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        gmm = self.gmm(batch)
        nll = self.nll(gmm, batch)
        scores = self.density_map(tuple(g.detach() for g in gmm), batch)
        return nll, scores, {"aff_loss": self.affordance_loss(scores, batch).detach()}

    @torch.no_grad()
    def propose_pose(self, batch_item: Batch) -> tuple[float, float, float]:
        """Best collision-free base pose (x, y, yaw) for one sample (N2M's inference procedure).

        Falls back to the highest-density candidate when every candidate collides.
        """
        item = _unbatch(batch_item)
        was_training = self.training
        self.eval()
        try:
            means, cov, logw = self.gmm(item)
        finally:
            self.train(was_training)
        h = self.hparams
        g = torch.Generator(device="cpu").manual_seed(int(h["seed"]))
        k = int(logw[0].argmax())
        comp = torch.multinomial(logw[0].exp().cpu(), h["num_pose_samples"], replacement=True, generator=g)
        chol = torch.linalg.cholesky(cov[0].cpu())
        z = torch.randn(h["num_pose_samples"], 3, generator=g)
        samples = means[0].cpu()[comp] + (chol[comp] @ z[..., None]).squeeze(-1)
        dens = gmm_log_prob(samples[None], means.cpu(), cov.cpu(), logw.cpu())[0]
        cand = torch.cat([means[0, k].cpu()[None], samples[dens.argsort(descending=True)]], dim=0)
        mask = item.get("scene_mask")
        cells = occupied_cells(
            item["scene_xyz"][0].cpu().float(),
            None if mask is None else mask[0].cpu(),
            h["occupancy_cell"],
            h["occupancy_z"],
        )
        hits = footprint_collides(cells, cand, h["footprint_length"], h["footprint_width"], h["footprint_back"])
        free = torch.nonzero(~hits).flatten()
        if free.numel():
            best = cand[int(free[0])]
        else:  # the densest candidate: the mean (tried first, as N2M does) or the densest sample, cand[1]
            mean_dens = gmm_log_prob(cand[None, :1], means.cpu(), cov.cpu(), logw.cpu())[0, 0]
            best = cand[0] if len(cand) == 1 or mean_dens >= dens.max() else cand[1]
        yaw = math.atan2(math.sin(float(best[2])), math.cos(float(best[2])))
        return float(best[0]), float(best[1]), yaw

    def predict_step(self, batch: Batch, batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        out = super().predict_step(batch, batch_idx, dataloader_idx)
        b = batch["scene_xyz"].shape[0]
        # a tensor: the prediction writer keeps tensors only (a list of tuples was dropped from predictions.npz)
        poses = [self.propose_pose(batch_item(batch, i)) for i in range(b)]
        out["poses"] = torch.tensor(poses, dtype=torch.float32).reshape(b, 3)
        return out
