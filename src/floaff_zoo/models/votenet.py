"""VoteNetModule: a VoteNet-style adaptation to floor affordance (MoMa-Kitchen baseline)."""

from __future__ import annotations

import abc

import torch
from torch import Tensor

from floaff_zoo.checks import check_number, check_numbers
from floaff_zoo.contract import Batch
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig, check_dropout, check_sizes
from floaff_zoo.models.pointnet2 import maybe_compile, run_scene_floor_net
from floaff_zoo.nn.nets import VoteNetNet


def good_floor_points(batch: Batch, rel_threshold: float) -> tuple[Tensor, Tensor]:
    """Floor points whose label is positive and at least ``rel_threshold`` x the sample's best label.

    Returns:
        (floor_xyz [B,M,3], selected [B,M] bool); a sample with a positive label always has its argmax point
        selected, a sample without one (every label 0: no good position to vote for) has none.
    """
    label = batch["floor_label"].float().masked_fill(~batch["floor_mask"].bool(), -1.0)
    best = label.amax(dim=1, keepdim=True)
    sel = (label >= rel_threshold * best) & batch["floor_mask"].bool()
    sel = sel | (torch.arange(label.shape[1], device=label.device)[None] == label.argmax(dim=1, keepdim=True))
    return batch["floor_xyz"].float(), sel & (best > 0)


def vote_distances(votes: Tensor, gt_xyz: Tensor, gt_sel: Tensor) -> Tensor:
    """L1 distance of every vote to its nearest selected GT position: [B,S,3], [B,M,3], [B,M] bool -> [B, S]
    (inf in a sample with no selected position)."""
    d = (votes[:, :, None, :] - gt_xyz[:, None, :, :]).abs().sum(-1)  # [B, S, M]
    return d.masked_fill(~gt_sel[:, None, :], float("inf")).amin(dim=-1)


def vote_loss(votes: Tensor, gt_xyz: Tensor, gt_sel: Tensor, seed_mask: Tensor | None = None) -> Tensor:
    """Min-over-GT L1 distance of every vote (VoteNet's vote loss with a set of GT positions).

    Args:
        votes: [B, S, 3]; gt_xyz: [B, M, 3]; gt_sel: [B, M] bool (samples with no True have no target: left out);
        seed_mask: [B, S] bool, False on repeated seeds (their votes copy the first seed's: each counts once);
        None when no seed repeats (the plain mean).
    Returns:
        scalar mean over the distinct seeds' votes of the samples with a target (0, with a graph, when no sample
        has one).
    """
    has = gt_sel.any(dim=1)  # [B]
    if not bool(has.any()):
        return votes.sum() * 0.0
    d = vote_distances(votes[has], gt_xyz[has], gt_sel[has])  # [B', S]
    return d.mean() if seed_mask is None else d[seed_mask[has]].mean()


def vote_loss_per_sample(votes: Tensor, gt_xyz: Tensor, gt_sel: Tensor, seed_mask: Tensor | None = None) -> Tensor:
    """Each sample's mean vote distance (as :func:`vote_loss`): [B,S,3], [B,M,3], [B,M] bool, [B,S] bool -> [B].

    A sample with no target gets 0 (it has no vote term), so the mean over a batch of these is a mean over samples,
    which Lightning's sample-weighted epoch average keeps whatever the batch size.
    """
    has = gt_sel.any(dim=1)  # [B]
    per_sample = votes.new_zeros(len(votes))
    d = vote_distances(votes[has], gt_xyz[has], gt_sel[has])  # [B', S]
    if seed_mask is None:
        per_sample[has] = d.mean(dim=-1)
    else:  # d * 0 is finite: every sample left here has a target
        w = seed_mask[has].to(d.dtype)
        per_sample[has] = (d * w).sum(dim=-1) / w.sum(dim=-1)
    return per_sample


class SeedVotingModule(FloAffModule, abc.ABC):
    """What the VoteNet- and H3DNet-style modules share: the net gives scores and vote geometry; the
    loss is the affordance loss + ``vote_weight`` x :meth:`vote_loss`. Subclasses build the net."""

    def forward_with_aux(self, batch: Batch) -> tuple[Tensor, dict[str, Tensor]]:
        """Scores [B, M] and the vote geometry (``seed_xyz`` [B,S,3], ``seed_mask`` [B,S] when a seed repeats, + the
        net's own, see its ``decode``)."""
        scores, aux = run_scene_floor_net(self.net, batch, self.hparams["feat_channels"], self.hparams["bf16"])
        return scores.float(), aux

    def forward(self, batch: Batch) -> Tensor:
        return self.forward_with_aux(batch)[0]

    @abc.abstractmethod
    def vote_loss(self, batch: Batch, aux: dict[str, Tensor]) -> Tensor:
        """Scalar vote loss from the vote geometry (each subclass supervises its own votes).

        In evaluation it must be the mean over the batch's samples of each sample's own vote loss: Lightning weighs
        each batch's ``val_loss``/``test_loss`` by its sample count, so only then is the epoch value independent of
        the eval batch size (as the per-map affordance loss is, ``FloAffModule.affordance_loss``).
        """

    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        scores, aux = self.forward_with_aux(batch)
        vl = self.vote_loss(batch, aux)
        aff = self.affordance_loss(scores, batch)
        return aff + self.hparams["vote_weight"] * vl, scores, {"vote_loss": vl.detach(), "aff_loss": aff.detach()}


class VoteNetModule(SeedVotingModule):
    """VoteNet-style floor affordance.

    How VoteNet maps onto this task: VoteNet's seeds (PointNet++ backbone points) vote for object
    centres; here the seeds (PointNet++ SSG over the observation, robot code fused, FP back to
    the second SA level) vote for **good base positions**: each vote is the seed plus a predicted
    offset, supervised by the vote loss = L1 distance to the nearest floor point whose label is at
    least ``vote_label_threshold`` x the sample's best label (VoteNet's min-over-GT vote loss; a view whose labels
    are all 0 has no good position and adds no vote loss).
    VoteNet's proposal module becomes the aggregation: FPS over the votes, ball grouping and a
    PointNet give proposal features and an objectness-like score; instead of boxes, the floor
    map is read out of the proposals by 3-NN feature propagation (plus the distance to the nearest
    proposal) and a per-point sigmoid head. Loss = affordance loss + ``vote_weight`` x vote loss.

    Args:
        npoints, radii, nsamples, mlps: SSG backbone; seed_fp: FP widths from the deepest level
            to the seed level (one entry per FP).
        num_proposals, proposal_radius, proposal_nsample, proposal_width: vote aggregation.
        floor_fp: widths of the FP onto the floor points; robot_width, head_width, dropout.
        vote_weight, vote_label_threshold: vote loss weight and GT selection.
        compile, bf16: opt-in speed modes.
        (the rest: see :class:`FloAffModule`)
    """

    def __init__(
        self,
        npoints: list[int] = [1024, 256, 64],  # noqa: B006
        radii: list[list[float]] = [[0.2], [0.4], [0.8]],  # noqa: B006
        nsamples: list[list[int]] = [[32], [32], [32]],  # noqa: B006
        mlps: list[list[list[int]]] = [[[64, 64, 128]], [[128, 128, 256]], [[256, 256, 256]]],  # noqa: B006
        seed_fp: list[list[int]] = [[256, 256]],  # noqa: B006
        num_proposals: int = 64,
        proposal_radius: float = 0.3,
        proposal_nsample: int = 16,
        proposal_width: int = 128,
        floor_fp: list[int] = [128, 128],  # noqa: B006
        robot_width: int = 64,
        head_width: int = 64,
        dropout: float = 0.1,
        vote_weight: float = 1.0,
        vote_label_threshold: float = 0.8,
        compile: bool = False,
        bf16: bool = False,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=weights)

    def configure_models(self) -> None:
        h = self.hparams
        check_dropout(h["dropout"], type(self).__name__)
        check_numbers({"vote_weight": h["vote_weight"]}, owner=type(self).__name__)
        check_numbers({"vote_label_threshold": h["vote_label_threshold"]}, high=1.0, owner=type(self).__name__)
        sizes = ("num_proposals", "proposal_nsample", "proposal_width", "robot_width", "head_width")
        check_sizes(h, sizes, type(self).__name__)
        check_number("proposal_radius", h["proposal_radius"], strict=True, owner=type(self).__name__)
        self.net = VoteNetNet(
            h["feat_channels"],
            h["robot_dim"],
            h["npoints"],
            h["radii"],
            h["nsamples"],
            h["mlps"],
            h["seed_fp"],
            num_proposals=h["num_proposals"],
            proposal_radius=h["proposal_radius"],
            proposal_nsample=h["proposal_nsample"],
            proposal_width=h["proposal_width"],
            floor_fp=h["floor_fp"],
            robot_width=h["robot_width"],
            head_width=h["head_width"],
            dropout=h["dropout"],
        )
        maybe_compile(self.net, h["compile"])

    def vote_loss(self, batch: Batch, aux: dict[str, Tensor]) -> Tensor:
        """Min-over-GT L1 distance of the votes to the good floor points: training, the mean over the votes of the
        samples with a target; evaluation, the mean over samples (0 for one without a target). A repeated seed
        (``aux["seed_mask"]`` False, the mask given when a seed repeats) is left out: each distinct seed's vote counts
        once."""
        gt_xyz, gt_sel = good_floor_points(batch, self.hparams["vote_label_threshold"])
        votes = aux["vote_xyz"].float()
        if self.training:
            return vote_loss(votes, gt_xyz, gt_sel, aux.get("seed_mask"))
        return vote_loss_per_sample(votes, gt_xyz, gt_sel, aux.get("seed_mask")).mean()
