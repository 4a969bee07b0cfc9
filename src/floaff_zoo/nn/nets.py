"""Floor-affordance networks built from the PointNet++ blocks (pure torch, no Lightning).

Every net separates neighbour sampling from the differentiable pass: ``sample(...)`` returns the
FPS indices (no grad, fp32, run outside ``torch.compile``/autocast) and ``forward(..., fps=...)``
consumes them.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from floaff_zoo.checks import check_integer
from floaff_zoo.nn.ops import (
    check_finite,
    check_floor_feat,
    farthest_point_sample,
    three_interpolate,
    three_nn,
)
from floaff_zoo.nn.pointnet2 import (
    FeaturePropagation,
    PointNet2Encoder,
    SetAbstraction,
    SharedMLP,
    check_row_mask,
    copy_to_repeats,
    kept_centres,
    on_valid_rows,
    one_row_batch_norm,
    repeat_sources,
)

__all__ = [
    "CrossAttention",
    "H3DNetNet",
    "N2MNet",
    "NavAffNet",
    "PointNet2Net",
    "SeedVotingNet",
    "VoteNetNet",
    "floor_local_features",
    "require_valid",
]


def require_valid(name: str, mask: Tensor) -> None:
    """Raise ``ValueError`` when a sample of the batch has no True entry in ``mask`` [B, N]."""
    empty = ~mask.any(dim=1)
    if empty.any():
        raise ValueError(
            f"{name}: sample(s) {torch.nonzero(empty).flatten().tolist()} of the batch have no valid point"
        )


def check_inputs(**tensors: Tensor) -> None:
    """NaN/Inf check of named inputs (clear ``ValueError`` naming the tensor)."""
    for name, t in tensors.items():
        check_finite(name, t)


def floor_local_features(floor_xyz: Tensor, target_xyz: Tensor) -> Tensor:
    """[B,M,3], [B,3] -> [B,M,6]: floor xyz, xy offset to the target, planar distance to it."""
    rel = floor_xyz[..., :2] - target_xyz[:, None, :2]
    return torch.cat([floor_xyz, rel, rel.norm(dim=-1, keepdim=True)], dim=-1)


def _mlp(sizes: Sequence[int], dropout: float = 0.0) -> nn.Sequential:
    """Linear layers sizes[0] -> ... -> sizes[-1], ReLU (and dropout) between them. Widths are whole numbers >= 0
    (2.5, True or -1 failed inside nn.Linear); a 0 is refused by the models' ``check_layer_sizes``, which names the
    model and the layer."""
    for w in sizes[1:]:
        check_integer("sizes: a layer's width", w, 0, owner="mlp")
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
            if dropout > 0:
                layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)


class PerPointHead(nn.Module):
    """SharedMLP(C -> hidden) -> dropout -> Linear(hidden -> 1): logits [B, M].

    ``forward``'s ``mask`` [B, M] (False = padding) keeps padded points out of the BatchNorm's batch statistics;
    their logits are then 0 in training.
    """

    def __init__(self, in_channels: int, hidden: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.mlp = SharedMLP(in_channels, [hidden])
        self.drop = nn.Dropout(dropout)
        self.out = nn.Linear(hidden, 1)

    def forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
        """x [B, M, C] -> logits [B, M]."""
        if mask is not None:
            check_row_mask("PerPointHead", x, mask)
        if mask is None or self.mlp.rowwise():
            return self._logits(x)
        return on_valid_rows(self._logits, x, mask)

    def _logits(self, x: Tensor) -> Tensor:
        return self.out(self.drop(self.mlp(x))).squeeze(-1)


# ============================================================================ PointNet++
class SceneEncoderDecoder(nn.Module):
    """PointNet++ over the scene + robot code, decoded back to the first SA level's centres.

    Shared by the PointNet++, VoteNet-style and H3DNet-style nets.

    Args:
        feat_channels: scene feature channels; robot_dim/robot_width: robot MLP;
        npoints/radii/nsamples/mlps: SA levels; scene_fp: FP widths from the deepest level down to
        level ``stop_level`` (one entry per FP); xyz_first: SSG (True) or MSG (False) order.
    """

    def __init__(
        self,
        feat_channels: int,
        robot_dim: int,
        robot_width: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        scene_fp: Sequence[Sequence[int]],
        xyz_first: bool,
    ) -> None:
        super().__init__()
        self.encoder = PointNet2Encoder(feat_channels, npoints, radii, nsamples, mlps, xyz_first=xyz_first)
        self.robot = _mlp([robot_dim, robot_width, robot_width])
        ch = self.encoder.level_channels
        n = len(npoints)
        if len(scene_fp) > n - 1:
            raise ValueError(f"scene FP layers: at most {n - 1} for {n} SA levels, got {len(scene_fp)}")
        self.fps_layers = nn.ModuleList()
        cur = ch[-1] + robot_width
        for j, widths in enumerate(scene_fp):
            lvl = n - 1 - j
            fp = FeaturePropagation(ch[lvl] + cur, widths)
            self.fps_layers.append(fp)
            cur = fp.out_channels
        self.stop_level = n - len(scene_fp)
        self.out_channels = cur

    def sample(self, xyz: Tensor, mask: Tensor) -> list[Tensor | None]:
        return self.encoder.sample(xyz, mask)

    def forward(
        self,
        xyz: Tensor,
        feat: Tensor,
        mask: Tensor,
        robot: Tensor,
        fps: list[Tensor | None] | None,
        srcs: list[Tensor | None] | None = None,
    ) -> tuple[Tensor, Tensor, list[tuple[Tensor, Tensor | None]]]:
        """Returns (xyz at stop level [B,S,3], features [B,S,C], all encoder levels).

        ``srcs``: ``PointNet2Encoder.sources(fps)`` when the caller needs them too (found here when None)."""
        if fps is None:
            fps = self.encoder.sample(xyz, mask)
        if srcs is None:
            srcs = self.encoder.sources(fps)
        levels = self.encoder(xyz, feat, mask, fps, srcs)
        kept = [None] + self.encoder.kept_masks(srcs)  # repeated centres (a cloud under npoint), per level
        deep_xyz, deep = levels[-1]
        r = self.robot(robot)[:, None, :].expand(-1, deep.shape[1], -1)
        cur = torch.cat([deep, r.to(deep.dtype)], dim=-1)
        n = len(levels) - 1
        for j, fp in enumerate(self.fps_layers):
            lvl = n - 1 - j
            cur = fp(levels[lvl][0], levels[lvl + 1][0], levels[lvl][1], cur, kept[lvl + 1], kept[lvl])
        stop = self.stop_level
        # the caller reads every stop-level row (FP onto the floor, vote heads): a repeat gets its first occurrence's
        # row, which training left at 0 (kept out of the batch statistics above)
        if stop > 0:
            cur = copy_to_repeats(cur, srcs[stop - 1])
        return levels[stop][0], cur, levels


class PointNet2Net(nn.Module):
    """PointNet++ (SSG or MSG) over the observation, robot MLP fused at the deepest level, FP onto
    the floor points, per-point sigmoid head.

    Args:
        variant: ``ssg`` or ``msg`` (grouped channel order of the classic port);
        fp_mlps: FP widths, deepest first; the last entry is the FP onto the floor points
            (skip = floor xyz, xy offset and distance to the target [, ``floor_feat``]);
        floor_feat_channels: extra per-floor-point input channels appended to that skip (``floor_feat`` of
            :meth:`forward`, e.g. ``nn.placement.footprint_occupancy``); 0 = none.
    """

    def __init__(
        self,
        variant: str,
        feat_channels: int,
        robot_dim: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        fp_mlps: Sequence[Sequence[int]],
        robot_width: int = 64,
        head_width: int = 64,
        dropout: float = 0.1,
        floor_feat_channels: int = 0,
    ) -> None:
        super().__init__()
        if variant not in ("ssg", "msg"):  # anything but "ssg" (e.g. "SSG") silently took the MSG channel order
            raise ValueError(f"PointNet2Net: variant must be 'ssg' or 'msg', got {variant!r}")
        if len(fp_mlps) != len(npoints):
            raise ValueError(f"fp_mlps needs {len(npoints)} entries (one per SA level), got {len(fp_mlps)}")
        # int() cut 2.5 to 2 and read True as 1; NaN or a text failed in the comparison naming no argument
        check_integer("floor_feat_channels", floor_feat_channels, 0, owner="PointNet2Net")
        self.floor_feat_channels = int(floor_feat_channels)
        self.scene = SceneEncoderDecoder(
            feat_channels, robot_dim, robot_width, npoints, radii, nsamples, mlps, fp_mlps[:-1], variant == "ssg"
        )
        self.floor_fp = FeaturePropagation(6 + self.floor_feat_channels + self.scene.out_channels, fp_mlps[-1])
        self.head = PerPointHead(self.floor_fp.out_channels, head_width, dropout)

    def sample(self, scene_xyz: Tensor, scene_mask: Tensor) -> list[Tensor | None]:
        return self.scene.sample(scene_xyz, scene_mask)

    def forward(
        self,
        scene_xyz: Tensor,
        scene_feat: Tensor,
        scene_mask: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        robot: Tensor,
        target_xyz: Tensor,
        fps: list[Tensor | None] | None = None,
        floor_feat: Tensor | None = None,
    ) -> Tensor:
        """Scene [B,N,3]/[B,N,C]/[B,N], floor [B,M,3]/[B,M], robot [B,R], target [B,3],
        floor_feat [B,M,floor_feat_channels] (None when 0 channels) -> scores [B,M] in [0,1]."""
        check_floor_feat("PointNet2Net", floor_feat, floor_xyz, self.floor_feat_channels)
        skip = floor_local_features(floor_xyz, target_xyz)
        if floor_feat is not None:
            skip = torch.cat([skip, floor_feat.to(skip.dtype)], dim=-1)
        if fps is None:
            fps = self.scene.sample(scene_xyz, scene_mask)
        srcs = self.scene.encoder.sources(fps)
        sxyz, sfeat, _ = self.scene(scene_xyz, scene_feat, scene_mask, robot, fps, srcs)
        # a cloud with fewer points than the stop level's centres repeats its first centre: the repeats stay out of the
        # floor points' 3-NN (they would fill two or three of the neighbours with one point)
        kept = kept_centres(srcs[self.scene.stop_level - 1])
        h = self.floor_fp(floor_xyz, sxyz, skip, sfeat, mask_sparse=kept, mask_dense=floor_mask)
        return torch.sigmoid(self.head(h, floor_mask).float())


# ============================================================================ NavAff
class CrossAttention(nn.Module):
    """NavAff's fusion attention: q from the floor tokens, k/v from [robot; global] tokens.

    No residual and no LayerNorm (the output replaces the floor tokens), q/kv without bias,
    output projection with bias, dropout on attention weights and output (docs/background.md §3).
    """

    def __init__(self, dim: int = 512, num_heads: int = 8, dropout: float = 0.1) -> None:
        super().__init__()
        # 0 divided by zero below, a negative count failed at the first batch, 2.0 in a reshape
        check_integer("dim", dim, 1, owner="CrossAttention")  # 0: a ZeroDivisionError, 2.5: "not divisible"
        check_integer("num_heads", num_heads, 1, owner="CrossAttention")
        if dim % num_heads:
            raise ValueError(f"dim {dim} is not divisible by num_heads {num_heads}")
        self.num_heads = num_heads
        self.scale = (dim // num_heads) ** -0.5
        self.q = nn.Linear(dim, dim, bias=False)
        self.kv = nn.Linear(dim, 2 * dim, bias=False)
        self.attn_drop = nn.Dropout(dropout)
        self.proj = nn.Linear(dim, dim)
        self.proj_drop = nn.Dropout(dropout)

    def forward(self, q: Tensor, kv: Tensor) -> Tensor:
        """q [B,Nq,C], kv [B,Nk,C] -> [B,Nq,C]."""
        b, nq, c = q.shape
        nk = kv.shape[1]
        h = self.num_heads
        qh = self.q(q).reshape(b, nq, h, c // h).transpose(1, 2)
        kvh = self.kv(kv).reshape(b, nk, 2, h, c // h).permute(2, 0, 3, 1, 4)
        attn = (qh @ kvh[0].transpose(-2, -1)) * self.scale
        attn = self.attn_drop(attn.softmax(dim=-1))
        x = (attn @ kvh[1]).transpose(1, 2).reshape(b, nq, c)
        return self.proj_drop(self.proj(x))


#: official NavAff MSG levels (MoMaKitchen/MoMaKitchen:model/NaviAff.py@64ca7a4)
NAVAFF_RADII = [[0.1, 0.2, 0.4], [0.4, 0.8], [0.2, 0.4]]
NAVAFF_NSAMPLES = [[32, 64, 128], [64, 128], [16, 32]]
NAVAFF_MLPS = [
    [[32, 32, 64], [64, 64, 128], [64, 96, 128]],
    [[128, 128, 256], [128, 196, 256]],
    [[128, 128, 256], [128, 196, 256]],
]


#: m: NavAff's pointwise floor encoder runs over the cloud's points below this height (MoMa-Kitchen's floor points)
GROUND_Z = 0.02


class NavAffNet(nn.Module):
    """NavAff (MoMa-Kitchen): two PointNet++ MSG encoders, robot token, cross-attention, FP decoder.

    Global encoder input: xyz + target flag (``l0_points = [xyz, flag]``, 7 grouped channels);
    floor encoder input: xyz (``l0_points = xyz``, 6 grouped channels). The scene cloud is
    normalised like the official ``pc_normalize`` (minus the valid-point centroid, divided by the
    max radius) when ``normalize_global``; the floor stays in metres. Unlike the official code,
    padded points are never sampled or grouped (masks respected).

    Args:
        npoints: centres of sa1/sa2/sa3 (official 512, 128, 64 = N_p); radii/nsamples: per level
        (official values by default); feat_channels: scene features used (1 = flag);
        robot_dim: robot descriptor size (official 2); num_heads: 8; dropout: 0.1.
        floor_encoder: ``set`` (official: the floor encoder runs over the queried floor points, so a
            point's score depends on the other points asked) or ``pointwise`` (it runs over the observed
            ground points of the scene cloud, z < ``GROUND_Z``, and the last FP interpolates from them to
            each query with the query's own xyz as skip: scores do not depend on the other queries).
    """

    def __init__(
        self,
        npoints: Sequence[int] = (512, 128, 64),
        radii: Sequence[Sequence[float]] = NAVAFF_RADII,
        nsamples: Sequence[Sequence[int]] = NAVAFF_NSAMPLES,
        feat_channels: int = 1,
        robot_dim: int = 2,
        num_heads: int = 8,
        dropout: float = 0.1,
        normalize_global: bool = True,
        floor_encoder: str = "set",
    ) -> None:
        super().__init__()
        if len(npoints) != 3:
            raise ValueError(f"NavAff has 3 SA levels; npoints={list(npoints)}")
        if floor_encoder not in ("set", "pointwise"):
            raise ValueError(f"NavAff: floor_encoder must be 'set' or 'pointwise', got {floor_encoder!r}")
        self.floor_mode = floor_encoder
        self.normalize_global = normalize_global
        self.encoder_global = PointNet2Encoder(
            feat_channels, npoints, radii, nsamples, NAVAFF_MLPS, xyz_first=False, xyz_as_feat=True
        )
        self.encoder_floor = PointNet2Encoder(
            0, npoints, radii, nsamples, NAVAFF_MLPS, xyz_first=False, xyz_as_feat=True
        )
        self.mlp_robot = nn.Sequential(nn.Linear(robot_dim, 256), nn.ReLU(), nn.Linear(256, 512))
        self.fusion = CrossAttention(512, num_heads, dropout)
        self.fp3 = FeaturePropagation(512 + 512, [768, 512])
        self.fp2 = FeaturePropagation(832, [768, 512])
        self.fp1 = FeaturePropagation(518, [512, 512])
        self.head_fc1 = nn.Linear(512, 64)
        self.head_bn = nn.BatchNorm1d(64)
        self.head_fc2 = nn.Linear(64, 1)

    def _head_logits(self, up: Tensor) -> Tensor:
        """Per-point features [..., 512] -> logits [...]."""
        h = self.head_fc1(up)
        flat = h.reshape(-1, 64)
        if self.head_bn.training and flat.shape[0] == 1:  # one view with one floor point: BatchNorm1d refuses it
            flat = one_row_batch_norm(flat, torch.zeros_like(self.head_bn.bias), self.head_bn)
        else:
            flat = self.head_bn(flat)
        h = F.relu(flat.reshape(h.shape))
        return self.head_fc2(h).squeeze(-1)

    def _normalize(self, xyz: Tensor, mask: Tensor) -> Tensor:
        if not self.normalize_global:
            return xyz
        w = mask.float()[..., None]
        centroid = (xyz * w).sum(1, keepdim=True) / w.sum(1, keepdim=True).clamp_min(1.0)
        c = (xyz - centroid) * w
        m = c.norm(dim=-1).amax(dim=1).clamp_min(1e-6)
        return c / m[:, None, None]

    def floor_anchors(
        self, scene_xyz: Tensor, scene_mask: Tensor, floor_xyz: Tensor, floor_mask: Tensor
    ) -> tuple[Tensor, Tensor]:
        """The points the floor encoder runs over: the queries (``set``) or, ``pointwise``, the cloud's ground
        points flattened onto z = 0 (all its points when a cloud sees no ground). -> (xyz [B, K, 3], mask [B, K])."""
        if self.floor_mode == "set":
            return floor_xyz, floor_mask
        ground = scene_mask & (scene_xyz[..., 2] < GROUND_Z)
        ground = torch.where(ground.any(dim=1, keepdim=True), ground, scene_mask)
        return scene_xyz * torch.tensor([1.0, 1.0, 0.0], device=scene_xyz.device, dtype=scene_xyz.dtype), ground

    def sample(self, scene_xyz: Tensor, scene_mask: Tensor, floor_xyz: Tensor, floor_mask: Tensor) -> tuple[list, list]:
        axyz, amask = self.floor_anchors(scene_xyz, scene_mask, floor_xyz, floor_mask)
        return (
            self.encoder_global.sample(self._normalize(scene_xyz, scene_mask), scene_mask),
            self.encoder_floor.sample(axyz, amask),
        )

    def forward(
        self,
        scene_xyz: Tensor,
        scene_feat: Tensor,
        scene_mask: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        robot: Tensor,
        fps: tuple[list, list] | None = None,
    ) -> Tensor:
        """Returns scores [B, M] in [0, 1] (sigmoid head)."""
        gxyz = self._normalize(scene_xyz, scene_mask)
        fps_g, fps_f = fps if fps is not None else (None, None)
        g = self.encoder_global(gxyz, scene_feat, scene_mask, fps_g)
        axyz, amask = self.floor_anchors(scene_xyz, scene_mask, floor_xyz, floor_mask)
        if fps_f is None:
            fps_f = self.encoder_floor.sample(axyz, amask)
        srcs_f = self.encoder_floor.sources(fps_f)
        f = self.encoder_floor(axyz, None, amask, fps_f, srcs_f)
        # a view's floor holds fewer points than sa1 has centres (median 150 of 256): FPS repeats the first one, and
        # the decoder keeps the repeats out of its interpolation and batch statistics
        k1, k2, k3 = self.encoder_floor.kept_masks(srcs_f)
        token = self.mlp_robot(robot)[:, None, :]
        kv = torch.cat([token.to(g[3][1].dtype), g[3][1]], dim=1)  # [B, 1 + N_p, 512]
        fused = self.fusion(f[3][1], kv)  # replaces the floor sa3 features (no residual)
        up = self.fp3(f[2][0], f[3][0], f[2][1], fused, mask_sparse=k3, mask_dense=k2)
        up = self.fp2(f[1][0], f[2][0], f[1][1], up, mask_sparse=k2, mask_dense=k1)
        # f[0][0] = anchors; padded floor points stay out of fp1's and the head's batch statistics
        up = self.fp1(
            floor_xyz, f[1][0], torch.cat([floor_xyz, floor_xyz], dim=-1), up, mask_sparse=k1, mask_dense=floor_mask
        )
        batch_stats = self.head_bn.training or self.head_bn.running_mean is None
        logits = on_valid_rows(self._head_logits, up, floor_mask) if batch_stats else self._head_logits(up)
        return torch.sigmoid(logits.float())


# ============================================================================ VoteNet-style
class VoteModule(nn.Module):
    """VoteNet vote module: per seed an xyz offset and a feature residual (vote_per_seed = 1).

    Vote features are L2-normalised (seed feature + residual), as VoteNet does.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.mlp = SharedMLP(channels, [channels, channels])
        self.out = nn.Linear(channels, 3 + channels)

    def forward(self, seed_xyz: Tensor, seed_feat: Tensor, seed_src: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """seed_xyz [B,S,3], seed_feat [B,S,C] -> (vote_xyz [B,S,3], vote_feat [B,S,C]).

        ``seed_src`` [B,S] (``repeat_sources`` of the seeds, None when none repeats): a repeated seed stays out of
        the training-mode batch statistics and takes its first occurrence's vote."""
        o = copy_to_repeats(self.out(self.mlp(seed_feat, kept_centres(seed_src))), seed_src)
        vote_xyz = seed_xyz + o[..., :3].float()
        vote_feat = F.normalize(seed_feat + o[..., 3:], dim=-1)
        return vote_xyz, vote_feat


class VoteAggregation(nn.Module):
    """VoteNet proposal module: FPS over votes, ball grouping, PointNet, proposal head.

    Returns proposal centres, features and an objectness-like score per proposal.
    """

    def __init__(self, channels: int, num_proposals: int, radius: float, nsample: int, width: int) -> None:
        super().__init__()
        self.num_proposals = num_proposals
        self.sa = SetAbstraction(num_proposals, [radius], [nsample], channels, [[width, width, width]], xyz_first=True)
        self.head = SharedMLP(width, [width])
        self.score = nn.Linear(width, 1)
        self.out_channels = width + 1

    def sample(self, vote_xyz: Tensor, vote_mask: Tensor | None = None) -> Tensor:
        return farthest_point_sample(vote_xyz.detach().float(), vote_mask, self.num_proposals)

    def forward(
        self, vote_xyz: Tensor, vote_feat: Tensor, fps_idx: Tensor | None = None, vote_mask: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor | None]:
        """-> (proposal_xyz [B,P,3], proposal features [B,P,width+1] incl. the sigmoid score last, proposal mask
        [B,P] bool: False on repeated proposals, None when none repeats).

        ``vote_mask`` [B,S] (False on the votes of repeated seeds) keeps those copies out of the proposals' groups,
        as the encoder keeps repeated centres out of the next level's; fewer distinct votes than proposals repeat
        the first proposal, which then stays out of the head's batch statistics and of the caller's 3-NN."""
        if fps_idx is None:
            fps_idx = self.sample(vote_xyz, vote_mask)
        src = repeat_sources(fps_idx)
        pxyz, pfeat = self.sa(vote_xyz, vote_feat, vote_mask, fps_idx, src)
        kept = kept_centres(src)
        h = copy_to_repeats(self.head(pfeat, kept), src)
        s = torch.sigmoid(self.score(h))
        return pxyz, torch.cat([h, s.to(h.dtype)], dim=-1), kept


def _proposal_distance(floor_xyz: Tensor, prop_xyz: Tensor) -> Tensor:
    """[B,M,3], [B,P,3] -> [B,M,1] 3-D distance to the nearest proposal (no gradient, see ``three_nn``)."""
    d, _ = three_nn(floor_xyz, prop_xyz)
    return d[..., :1].sqrt()  # three_nn measures its picks by coordinate differences: never below 0


class SeedVotingNet(nn.Module, abc.ABC):
    """The trunk the VoteNet- and H3DNet-style nets share: seeds that vote, decoded to floor scores.

    PointNet++ SSG over the observation + robot MLP, FP back to the seed level (``backbone``); a
    subclass builds its vote heads on ``seed_channels`` and implements :meth:`decode`.

    Args:
        feat_channels, robot_dim, robot_width: scene features and robot MLP;
        npoints, radii, nsamples, mlps: SSG levels; seed_fp: FP widths from the deepest level to the
        seed level (one entry per FP).
    """

    def __init__(
        self,
        feat_channels: int,
        robot_dim: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        seed_fp: Sequence[Sequence[int]],
        robot_width: int = 64,
    ) -> None:
        super().__init__()
        self.backbone = SceneEncoderDecoder(
            feat_channels, robot_dim, robot_width, npoints, radii, nsamples, mlps, seed_fp, True
        )

    @property
    def seed_channels(self) -> int:
        return self.backbone.out_channels

    def sample(self, scene_xyz: Tensor, scene_mask: Tensor) -> list[Tensor | None]:
        return self.backbone.sample(scene_xyz, scene_mask)

    @abc.abstractmethod
    def decode(
        self,
        seed_xyz: Tensor,
        seed_feat: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        target_xyz: Tensor,
        seed_src: Tensor | None = None,
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """Seeds [B,S,3]/[B,S,C], floor [B,M,3]/[B,M], target [B,3] -> (floor logits [B,M], vote geometry).

        Padded floor points (``floor_mask`` False) stay out of the per-point layers' batch statistics.
        ``seed_src`` [B,S] (``repeat_sources``, None when no seed repeats): a cloud with fewer distinct points than
        seeds repeats the first seed, which must count once wherever the seeds are a set."""

    def forward(
        self,
        scene_xyz: Tensor,
        scene_feat: Tensor,
        scene_mask: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        robot: Tensor,
        target_xyz: Tensor,
        fps: list[Tensor | None] | None = None,
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """Scene [B,N,3]/[B,N,C]/[B,N], floor [B,M,3]/[B,M], robot [B,R], target [B,3] ->
        (scores [B,M] in [0,1], aux {seed_xyz [B,S,3], + seed_mask [B,S] bool when a seed repeats, + the subclass's
        vote geometry}).

        ``seed_mask`` is False on the repeats of the first seed (a cloud with fewer distinct points than seeds): a
        vote loss over the seeds must leave them out, or the first seed's vote counts once per repeat. It is absent
        when no seed repeats (known from ``repeat_sources`` already: no further host sync)."""
        if fps is None:
            fps = self.sample(scene_xyz, scene_mask)
        srcs = self.backbone.encoder.sources(fps)
        seed_xyz, seed_feat, _ = self.backbone(scene_xyz, scene_feat, scene_mask, robot, fps, srcs)
        seed_src = srcs[self.backbone.stop_level - 1]
        logits, aux = self.decode(seed_xyz, seed_feat, floor_xyz, floor_mask, target_xyz, seed_src)
        kept = kept_centres(seed_src)
        masks = {} if kept is None else {"seed_mask": kept}
        return torch.sigmoid(logits.float()), {"seed_xyz": seed_xyz, **masks, **aux}


class VoteNetNet(SeedVotingNet):
    """VoteNet-style floor affordance (see ``floaff_zoo.models.votenet`` for the mapping).

    One vote per seed; vote aggregation (FPS over votes + grouping + PointNet) into proposals; floor
    scores from the proposals by 3-NN feature propagation plus the distance to the nearest proposal.
    (Trunk arguments: see :class:`SeedVotingNet`.)
    """

    def __init__(
        self,
        feat_channels: int,
        robot_dim: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        seed_fp: Sequence[Sequence[int]],
        num_proposals: int = 64,
        proposal_radius: float = 0.3,
        proposal_nsample: int = 16,
        proposal_width: int = 128,
        floor_fp: Sequence[int] = (128, 128),
        robot_width: int = 64,
        head_width: int = 64,
        dropout: float = 0.1,
    ) -> None:
        super().__init__(feat_channels, robot_dim, npoints, radii, nsamples, mlps, seed_fp, robot_width)
        c = self.seed_channels
        self.vote = VoteModule(c)
        self.aggregate = VoteAggregation(c, num_proposals, proposal_radius, proposal_nsample, proposal_width)
        self.floor_fp = FeaturePropagation(7 + self.aggregate.out_channels, floor_fp)
        self.head = PerPointHead(self.floor_fp.out_channels, head_width, dropout)

    def decode(
        self,
        seed_xyz: Tensor,
        seed_feat: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        target_xyz: Tensor,
        seed_src: Tensor | None = None,
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """-> (floor logits [B,M], {vote_xyz [B,S,3], proposal_xyz [B,P,3]})."""
        vote_xyz, vote_feat = self.vote(seed_xyz, seed_feat, seed_src)
        pxyz, pfeat, pkept = self.aggregate(vote_xyz, vote_feat, vote_mask=kept_centres(seed_src))
        skip = torch.cat([floor_local_features(floor_xyz, target_xyz), _proposal_distance(floor_xyz, pxyz)], dim=-1)
        h = self.floor_fp(floor_xyz, pxyz, skip, pfeat, mask_sparse=pkept, mask_dense=floor_mask)
        return self.head(h, floor_mask), {"vote_xyz": vote_xyz, "proposal_xyz": pxyz}


# ============================================================================ H3DNet-style
PRIMITIVES = ("centre", "face", "edge_left", "edge_right")


def target_primitives(target_xyz: Tensor, target_yaw: Tensor, face_offset: float, edge_half_width: float) -> Tensor:
    """Geometric primitives of the target from its centre and front normal.

    centre = target centre; face = centre + ``face_offset`` along the front normal; the two front
    edges = face -/+ ``edge_half_width`` along the normal's left perpendicular.

    Args:
        target_xyz: [B, 3]; target_yaw: [B].
    Returns:
        [B, 4, 3] in ``PRIMITIVES`` order.
    """
    n = torch.stack([torch.cos(target_yaw), torch.sin(target_yaw), torch.zeros_like(target_yaw)], dim=-1)
    perp = torch.stack([-torch.sin(target_yaw), torch.cos(target_yaw), torch.zeros_like(target_yaw)], dim=-1)
    face = target_xyz + face_offset * n
    return torch.stack([target_xyz, face, face + edge_half_width * perp, face - edge_half_width * perp], dim=1)


class H3DNetNet(SeedVotingNet):
    """H3DNet-style hybrid-primitive floor affordance (see ``floaff_zoo.models.h3dnet``).

    The seeds vote for four primitives of the target: its centre, its front-face centre and its two
    front edges. Per primitive type the votes are (a) aggregated into proposals (FPS over votes +
    grouping + PointNet) and (b) pooled into one predicted primitive location (softmax-weighted mean
    of votes). Floor points get, per type, the FP-interpolated proposal features and their geometry
    relative to the predicted primitive (offset and distance); the fused vector goes through a
    per-point head. (Trunk arguments: see :class:`SeedVotingNet`.)
    """

    def __init__(
        self,
        feat_channels: int,
        robot_dim: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        seed_fp: Sequence[Sequence[int]],
        num_proposals: int = 32,
        proposal_radius: float = 0.3,
        proposal_nsample: int = 16,
        proposal_width: int = 64,
        fuse_width: int = 128,
        robot_width: int = 64,
        head_width: int = 64,
        dropout: float = 0.1,
    ) -> None:
        super().__init__(feat_channels, robot_dim, npoints, radii, nsamples, mlps, seed_fp, robot_width)
        c = self.seed_channels
        self.votes = nn.ModuleList(VoteModule(c) for _ in PRIMITIVES)
        self.seed_logit = nn.ModuleList(nn.Linear(c, 1) for _ in PRIMITIVES)
        self.aggregate = nn.ModuleList(
            VoteAggregation(c, num_proposals, proposal_radius, proposal_nsample, proposal_width) for _ in PRIMITIVES
        )
        per_type = self.aggregate[0].out_channels + 4  # + offset xy, distance, proposal distance
        self.fuse = SharedMLP(6 + len(PRIMITIVES) * per_type, [fuse_width, fuse_width])
        self.head = PerPointHead(fuse_width, head_width, dropout)

    def decode(
        self,
        seed_xyz: Tensor,
        seed_feat: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        target_xyz: Tensor,
        seed_src: Tensor | None = None,
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """-> (floor logits [B,M], {vote_xyz [B,4,S,3], primitive_xyz [B,4,3]})."""
        parts = [floor_local_features(floor_xyz, target_xyz)]
        votes, prims = [], []
        kept = kept_centres(seed_src)
        for vote, logit, agg in zip(self.votes, self.seed_logit, self.aggregate):
            vxyz, vfeat = vote(seed_xyz, seed_feat, seed_src)
            seed_logit = logit(seed_feat).float().squeeze(-1)  # [B, S]
            if kept is not None:  # a repeated seed's vote counts once in the primitive's weighted mean
                seed_logit = seed_logit.masked_fill(~kept, float("-inf"))
            w = torch.softmax(seed_logit, dim=1)
            prim = (w[..., None] * vxyz).sum(dim=1)  # [B, 3]
            pxyz, pfeat, pkept = agg(vxyz, vfeat, vote_mask=kept)
            f = three_interpolate(floor_xyz, pxyz, pfeat, pkept)
            off = floor_xyz[..., :2] - prim[:, None, :2]
            parts += [
                f,
                off.to(f.dtype),
                off.norm(dim=-1, keepdim=True).to(f.dtype),
                _proposal_distance(floor_xyz, pxyz).to(f.dtype),
            ]
            votes.append(vxyz)
            prims.append(prim)
        h = self.fuse(torch.cat(parts, dim=-1), floor_mask)
        return self.head(h, floor_mask), {"vote_xyz": torch.stack(votes, 1), "primitive_xyz": torch.stack(prims, 1)}


# ============================================================================ N2M-style
class GMM(nn.Module):
    """Head turning a code into a K-component Gaussian mixture over D dims (N2M).

    Outputs K*(D + D*D + 1) numbers: means, raw D x D matrices -> covariance
    ``matrix_exp(sym(raw)) + 1e-6 I`` (always SPD), and softmax weights.
    """

    def __init__(self, in_channels: int, num_components: int = 2, dim: int = 3) -> None:
        super().__init__()
        # 0 built an empty head that failed in a reshape at the first batch, naming no argument
        check_integer("num_components", num_components, 1, owner="GMM")
        check_integer("dim", dim, 1, owner="GMM")
        self.k, self.d = num_components, dim
        self.out = nn.Linear(in_channels, num_components * (dim + dim * dim + 1))

    def forward(self, code: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """code [B, C] -> (means [B,K,D], covariances [B,K,D,D], log-weights [B,K]), float32."""
        o = self.out(code).float()
        k, d = self.k, self.d
        means = o[:, : k * d].reshape(-1, k, d)
        raw = o[:, k * d : k * (d + d * d)].reshape(-1, k, d, d)
        sym = 0.5 * (raw + raw.transpose(-1, -2))
        cov = torch.linalg.matrix_exp(sym) + 1e-6 * torch.eye(d, device=o.device)
        logw = torch.log_softmax(o[:, k * (d + d * d) :], dim=-1)
        return means, cov, logw


def gmm_log_prob(x: Tensor, means: Tensor, cov: Tensor, logw: Tensor, wrap_dim: int | None = 2) -> Tensor:
    """Log density of a GMM at poses, with the angle dimension wrapped (sum over theta + 2 pi k).

    Args:
        x: [B, P, D]; means [B,K,D]; cov [B,K,D,D]; logw [B,K]; wrap_dim: angle dim or None.
    Returns:
        [B, P] log densities.
    """
    dist = torch.distributions.MultivariateNormal(means[:, None], covariance_matrix=cov[:, None])
    shifts = [0.0] if wrap_dim is None else [-2 * math.pi, 0.0, 2 * math.pi]
    terms = []
    for s in shifts:
        xs = x.clone() if s else x
        if s:
            xs[..., wrap_dim] = xs[..., wrap_dim] + s
        terms.append(dist.log_prob(xs[:, :, None, :]) + logw[:, None, :])  # [B, P, K]
    return torch.logsumexp(torch.cat(terms, dim=-1), dim=-1)


class N2MNet(nn.Module):
    """N2M-style pose-distribution predictor: PointNet++ SSG over the egocentric cloud, pooled
    max ⊕ mean, MLP decoder with dropout, GMM over SE(2) base poses (x, y, theta).

    N2M uses a PointBERT encoder and no robot descriptor; PointNet++ keeps the zoo CPU-friendly.
    """

    def __init__(
        self,
        feat_channels: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        decoder: Sequence[int] = (512, 256),
        num_components: int = 2,
        dropout: float = 0.1,
    ) -> None:
        super().__init__()
        self.encoder = PointNet2Encoder(feat_channels, npoints, radii, nsamples, mlps, xyz_first=True)
        c = 2 * self.encoder.out_channels
        self.decoder = _mlp([c, *decoder], dropout)
        self.act = nn.ReLU()
        self.drop = nn.Dropout(dropout)
        self.gmm = GMM(decoder[-1] if decoder else c, num_components, 3)

    def sample(self, scene_xyz: Tensor, scene_mask: Tensor) -> list[Tensor | None]:
        return self.encoder.sample(scene_xyz, scene_mask)

    def forward(
        self, scene_xyz: Tensor, scene_feat: Tensor, scene_mask: Tensor, fps: list[Tensor | None] | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """-> GMM (means [B,K,3], cov [B,K,3,3], log-weights [B,K])."""
        if fps is None:
            fps = self.sample(scene_xyz, scene_mask)
        srcs = self.encoder.sources(fps)
        levels = self.encoder(scene_xyz, scene_feat, scene_mask, fps, srcs)
        f = levels[-1][1]
        kept = kept_centres(srcs[-1])
        # a repeated centre (a cloud with fewer distinct points than the last level's) counts once in the mean; the
        # max is the same either way (a repeat copies its first occurrence's row)
        mean = f.mean(dim=1) if kept is None else (f * kept[..., None]).sum(dim=1) / kept.sum(dim=1, keepdim=True)
        code = torch.cat([f.amax(dim=1), mean], dim=-1)
        code = self.drop(self.act(self.decoder(code)))
        return self.gmm(code)
