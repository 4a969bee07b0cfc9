"""Reference-style PointNet++ (the form the public NavAff code relies on), for parity and speed.

Written for floaff-zoo in the layout of the classic PyTorch port (yanx27/Pointnet_Pointnet2_pytorch
``models/pointnet2_utils.py``, whose compiled copy NavAff ships): channels-first tensors
``[B, C, N]``, ``Conv2d`` 1x1 + ``BatchNorm2d`` shared MLPs with in-place ReLU, a **naive Python
FPS loop**, a **sort-based ball query**, and 3-NN interpolation by sorting the full distance
matrix. FPS starts at index 0 (the port draws a random start) and, like the port, ignores masks.

``convert_to_channels_last(ref, ours)`` copies its weights into ``floaff_zoo.nn.pointnet2``
modules, so both can be compared on identical inputs and FPS indices. ``reference_ops()`` runs any
zoo model on these operations instead of the zoo's (same parameters), so every model has a
reference-style counterpart to be timed and compared against.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def square_distance(src: Tensor, dst: Tensor) -> Tensor:
    """src [B,N,C], dst [B,M,C] -> [B,N,M] squared distances."""
    dist = -2 * torch.matmul(src, dst.permute(0, 2, 1))
    dist += torch.sum(src**2, -1)[:, :, None]
    dist += torch.sum(dst**2, -1)[:, None, :]
    return dist


def index_points(points: Tensor, idx: Tensor) -> Tensor:
    """points [B,N,C], idx [B,*S] -> [B,*S,C] (advanced indexing)."""
    b = points.shape[0]
    view = [b] + [1] * (idx.ndim - 1)
    batch = torch.arange(b, dtype=torch.long, device=points.device).view(view).expand_as(idx)
    return points[batch, idx, :]


def farthest_point_sample(xyz: Tensor, npoint: int) -> Tensor:
    """Naive FPS loop, start at index 0: xyz [B,N,3] -> [B,npoint]."""
    b, n, _ = xyz.shape
    centroids = torch.zeros(b, npoint, dtype=torch.long, device=xyz.device)
    distance = torch.ones(b, n, device=xyz.device) * 1e10
    farthest = torch.zeros(b, dtype=torch.long, device=xyz.device)
    batch = torch.arange(b, dtype=torch.long, device=xyz.device)
    for i in range(npoint):
        centroids[:, i] = farthest
        centroid = xyz[batch, farthest, :].view(b, 1, 3)
        dist = torch.sum((xyz - centroid) ** 2, -1)
        closer = dist < distance
        distance[closer] = dist[closer]
        farthest = torch.max(distance, -1)[1]
    return centroids


def query_ball_point(radius: float, nsample: int, xyz: Tensor, new_xyz: Tensor) -> Tensor:
    """Sort-based ball query: first ``nsample`` indices within ``radius``, padded with the first."""
    b, n, _ = xyz.shape
    s = new_xyz.shape[1]
    group_idx = torch.arange(n, dtype=torch.long, device=xyz.device).view(1, 1, n).repeat(b, s, 1)
    sqrdists = square_distance(new_xyz, xyz)
    group_idx[sqrdists > radius**2] = n
    group_idx = group_idx.sort(dim=-1)[0][:, :, :nsample]
    group_first = group_idx[:, :, 0].view(b, s, 1).repeat(1, 1, group_idx.shape[-1])
    m = group_idx == n
    group_idx[m] = group_first[m]
    return group_idx


class RefSetAbstraction(nn.Module):
    """SSG (``xyz_first=True``) or MSG (``xyz_first=False``) level; ``group_all`` for the last SSG level."""

    def __init__(
        self,
        npoint: int,
        radii: Sequence[float],
        nsamples: Sequence[int],
        in_channel: int,
        mlps: Sequence[Sequence[int]],
        group_all: bool = False,
        xyz_first: bool = True,
    ) -> None:
        super().__init__()
        self.npoint, self.radii, self.nsamples = npoint, list(radii), list(nsamples)
        self.group_all, self.xyz_first = group_all, xyz_first
        self.conv_blocks = nn.ModuleList()
        self.bn_blocks = nn.ModuleList()
        for mlp in mlps:
            convs, bns = nn.ModuleList(), nn.ModuleList()
            last = in_channel + 3
            for out in mlp:
                convs.append(nn.Conv2d(last, out, 1))
                bns.append(nn.BatchNorm2d(out))
                last = out
            self.conv_blocks.append(convs)
            self.bn_blocks.append(bns)

    def forward(self, xyz: Tensor, points: Tensor | None, fps_idx: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """xyz [B,3,N], points [B,D,N] -> new_xyz [B,3,S], new_points [B,C,S]."""
        xyz = xyz.permute(0, 2, 1)
        if points is not None:
            points = points.permute(0, 2, 1)
        b, n, c = xyz.shape
        if self.group_all:
            new_xyz = torch.zeros(b, 1, c, device=xyz.device)
            grouped = xyz.view(b, 1, n, c)
            if points is not None:
                grouped = torch.cat([grouped, points.view(b, 1, n, -1)], dim=-1)
            groups = [grouped]
        else:
            if fps_idx is None:
                fps_idx = farthest_point_sample(xyz, self.npoint)
            new_xyz = index_points(xyz, fps_idx)
            groups = []
            for radius, k in zip(self.radii, self.nsamples):
                idx = query_ball_point(radius, k, xyz, new_xyz)
                gxyz = index_points(xyz, idx) - new_xyz.view(b, -1, 1, c)
                if points is not None:
                    gp = index_points(points, idx)
                    gxyz = torch.cat([gxyz, gp] if self.xyz_first else [gp, gxyz], dim=-1)
                groups.append(gxyz)
        outs = []
        for grouped, convs, bns in zip(groups, self.conv_blocks, self.bn_blocks):
            g = grouped.permute(0, 3, 2, 1)  # [B, C, K, S]
            for conv, bn in zip(convs, bns):
                g = F.relu(bn(conv(g)), inplace=True)
            outs.append(torch.max(g, 2)[0])
        return new_xyz.permute(0, 2, 1), torch.cat(outs, dim=1)


class RefFeaturePropagation(nn.Module):
    """FP with sort-based 3-NN and Conv1d + BatchNorm1d MLP."""

    def __init__(self, in_channel: int, mlp: Sequence[int]) -> None:
        super().__init__()
        self.mlp_convs = nn.ModuleList()
        self.mlp_bns = nn.ModuleList()
        last = in_channel
        for out in mlp:
            self.mlp_convs.append(nn.Conv1d(last, out, 1))
            self.mlp_bns.append(nn.BatchNorm1d(out))
            last = out

    def forward(self, xyz1: Tensor, xyz2: Tensor, points1: Tensor | None, points2: Tensor) -> Tensor:
        """xyz1 [B,3,N] dense, xyz2 [B,3,S] sparse, points1 [B,D1,N], points2 [B,D2,S] -> [B,C,N]."""
        xyz1, xyz2 = xyz1.permute(0, 2, 1), xyz2.permute(0, 2, 1)
        points2 = points2.permute(0, 2, 1)
        b, n, _ = xyz1.shape
        s = xyz2.shape[1]
        if s == 1:
            interpolated = points2.repeat(1, n, 1)
        else:
            dists, idx = square_distance(xyz1, xyz2).sort(dim=-1)
            dists, idx = dists[:, :, :3], idx[:, :, :3]
            recip = 1.0 / (dists + 1e-8)
            weight = recip / torch.sum(recip, dim=2, keepdim=True)
            interpolated = torch.sum(index_points(points2, idx) * weight.view(b, n, 3, 1), dim=2)
        if points1 is not None:
            new_points = torch.cat([points1.permute(0, 2, 1), interpolated], dim=-1)
        else:
            new_points = interpolated
        new_points = new_points.permute(0, 2, 1)
        for conv, bn in zip(self.mlp_convs, self.mlp_bns):
            new_points = F.relu(bn(conv(new_points)), inplace=True)
        return new_points


class RefPointNet2Seg(nn.Module):
    """Reference counterpart of ``floaff_zoo.nn.pointnet2.PointNet2Seg`` (same constructor)."""

    def __init__(
        self,
        in_channels: int,
        npoints: Sequence[int],
        radii: Sequence[Sequence[float]],
        nsamples: Sequence[Sequence[int]],
        mlps: Sequence[Sequence[Sequence[int]]],
        fp_mlps: Sequence[Sequence[int]],
        head: Sequence[int] = (),
        xyz_first: bool = True,
    ) -> None:
        super().__init__()
        self.sa = nn.ModuleList()
        c = in_channels
        chans = [3 + in_channels]
        for npoint, r, k, m in zip(npoints, radii, nsamples, mlps):
            self.sa.append(RefSetAbstraction(npoint, r, k, c, m, xyz_first=xyz_first))
            c = sum(x[-1] for x in m)
            chans.append(c)
        self.fp = nn.ModuleList()
        cur = chans[-1]
        for lvl, widths in zip(range(len(npoints) - 1, -1, -1), fp_mlps):
            self.fp.append(RefFeaturePropagation(chans[lvl] + cur, widths))
            cur = widths[-1]
        self.head_convs = nn.ModuleList()
        self.head_bns = nn.ModuleList()
        for w in head:
            self.head_convs.append(nn.Conv1d(cur, w, 1))
            self.head_bns.append(nn.BatchNorm1d(w))
            cur = w
        self.out = nn.Conv1d(cur, 1, 1)

    def forward(self, xyz: Tensor, feat: Tensor | None, fps: list[Tensor] | None = None) -> Tensor:
        """xyz [B,N,3], feat [B,N,D] (channels-last in, like ours) -> logits [B,N]."""
        l_xyz = [xyz.permute(0, 2, 1)]
        l_pts = [feat.permute(0, 2, 1) if feat is not None else None]
        for i, sa in enumerate(self.sa):
            nx, npts = sa(l_xyz[-1], l_pts[-1], None if fps is None else fps[i])
            l_xyz.append(nx)
            l_pts.append(npts)
        skip0 = l_xyz[0] if feat is None else torch.cat([l_xyz[0], l_pts[0]], dim=1)
        skips = [skip0] + l_pts[1:]
        cur = l_pts[-1]
        n = len(self.sa)
        for j, fp in enumerate(self.fp):
            lvl = n - 1 - j
            cur = fp(l_xyz[lvl], l_xyz[lvl + 1], skips[lvl], cur)
        for conv, bn in zip(self.head_convs, self.head_bns):
            cur = F.relu(bn(conv(cur)), inplace=True)
        return self.out(cur).squeeze(1)


def _copy_bn(dst: nn.Module, src: nn.Module) -> None:
    dst.load_state_dict(src.state_dict())


@torch.no_grad()
def convert_to_channels_last(ref: RefPointNet2Seg, ours: nn.Module) -> None:
    """Copy ``ref``'s weights into a ``floaff_zoo.nn.pointnet2.PointNet2Seg`` of the same config."""
    for rsa, osa in zip(ref.sa, ours.encoder.levels):
        for convs, bns, mlp in zip(rsa.conv_blocks, rsa.bn_blocks, osa.mlps):
            for conv, bn, lin, norm in zip(convs, bns, mlp.linears, mlp.norms):
                lin.weight.copy_(conv.weight[:, :, 0, 0])
                lin.bias.copy_(conv.bias)
                _copy_bn(norm, bn)
    for rfp, ofp in zip(ref.fp, ours.fps_layers):
        for conv, bn, lin, norm in zip(rfp.mlp_convs, rfp.mlp_bns, ofp.mlp.linears, ofp.mlp.norms):
            lin.weight.copy_(conv.weight[:, :, 0])
            lin.bias.copy_(conv.bias)
            _copy_bn(norm, bn)
    if ref.head_convs:
        for conv, bn, lin, norm in zip(ref.head_convs, ref.head_bns, ours.head.linears, ours.head.norms):
            lin.weight.copy_(conv.weight[:, :, 0])
            lin.bias.copy_(conv.bias)
            _copy_bn(norm, bn)
    ours.out.weight.copy_(ref.out.weight[:, :, 0])
    ours.out.bias.copy_(ref.out.bias)


# ----------------------------------------------------------------------------- any zoo model on the port's ops
def _ref_fps(xyz: Tensor, mask: Tensor | None, npoint: int) -> Tensor:
    """The naive loop when every point is valid (the port has no masks), else the zoo's masked FPS."""
    from floaff_zoo.nn import ops

    if mask is None or bool(mask.all()):
        return farthest_point_sample(xyz.detach().float(), npoint)
    return ops.farthest_point_sample_torch(xyz, mask, npoint)


def _ref_ball_query_multi(
    radii: list[float], nsamples: list[int], xyz: Tensor, new_xyz: Tensor, mask: Tensor | None = None
) -> list[Tensor]:
    """One sort-based query per scale (the port recomputes distances per scale)."""
    if mask is not None and not bool(mask.all()):
        xyz = torch.where(mask[..., None], xyz, torch.full_like(xyz, 1e6))  # padding out of every ball
    return [query_ball_point(r, k, xyz.float(), new_xyz.float()) for r, k in zip(radii, nsamples)]


def _ref_three_interpolate(
    unknown: Tensor, known: Tensor, known_feat: Tensor, known_mask: Tensor | None = None
) -> Tensor:
    """3-NN by sorting the full distance matrix, as the port's FP."""
    b, n, _ = unknown.shape
    if known.shape[1] == 1:
        return known_feat.expand(b, n, known_feat.shape[-1])
    d = square_distance(unknown.float(), known.float())
    if known_mask is not None:
        d = d.masked_fill(~known_mask[:, None, :].bool(), float("inf"))
    dists, idx = d.sort(dim=-1)
    dists, idx = dists[:, :, :3], idx[:, :, :3]
    recip = 1.0 / (dists + 1e-8)
    weight = recip / torch.sum(recip, dim=2, keepdim=True)
    return torch.sum(index_points(known_feat, idx) * weight.view(b, n, 3, 1).to(known_feat.dtype), dim=2)


def _ref_layers(mlp, h: Tensor, last_relu: bool) -> Tensor:
    """Channels-first ``conv 1x1 -> BN -> ReLU`` with the SharedMLP's own parameters and buffers.

    h: [B, C, *spatial] (1 or 2 spatial dims, like the port's Conv1d / Conv2d layouts).
    """
    conv = F.conv2d if h.ndim == 4 else F.conv1d
    last = len(mlp.linears) - 1
    for i, (lin, norm) in enumerate(zip(mlp.linears, mlp.norms)):
        w = lin.weight.view(*lin.weight.shape, *([1] * (h.ndim - 2)))
        h = conv(h, w, lin.bias)
        if isinstance(norm, nn.BatchNorm1d):
            h = F.batch_norm(
                h,
                norm.running_mean,
                norm.running_var,
                norm.weight,
                norm.bias,
                norm.training or norm.running_mean is None,
                norm.momentum if norm.momentum is not None else 0.0,
                norm.eps,
            )
        if i < last or (last_relu and not isinstance(norm, nn.Identity)):
            h = F.relu(h, inplace=True)
    return h


def _ref_mlp_forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
    """x [..., C_in] -> [..., C_out] through the channels-first port layout; with ``mask`` and batch statistics,
    the valid rows only (the zoo's semantics: padding stays out of BatchNorm, its rows are 0)."""
    if mask is not None and not self.rowwise():
        from floaff_zoo.nn.pointnet2 import on_valid_rows

        return on_valid_rows(lambda rows: _ref_mlp_forward(self, rows), x, mask)
    shape = x.shape[:-1]
    h = x.reshape(1, -1, x.shape[-1]).transpose(1, 2)  # [1, C, R]
    h = _ref_layers(self, h, last_relu=True)
    return h.transpose(1, 2).reshape(*shape, h.shape[1])


def _ref_mlp_pooled(self, x: Tensor, dim: int, mask: Tensor | None = None, first: Tensor | None = None) -> Tensor:
    """The port's ``max(relu(bn(conv(...))))`` over grouped [B, S, K, C] (dim 2) or whole clouds [B, N, C]."""
    if x.ndim == 4 and dim == 2 and mask is None:
        h = _ref_layers(self, x.permute(0, 3, 2, 1), last_relu=True)  # [B, C, K, S]
        return torch.max(h, 2)[0].transpose(1, 2)
    out = _ref_mlp_forward(self, x)
    if mask is not None:
        out = out.masked_fill(~mask[..., None], torch.finfo(out.dtype).min)
    return out.amax(dim=dim)


@contextlib.contextmanager
def reference_ops() -> Iterator[None]:
    """Run any floaff_zoo point model on the port's operations: same parameters, same maths.

    Inside the block the zoo's PointNet++ pieces use the port's choices: the naive FPS loop, a
    sort-based ball query per scale, sort-based 3-NN, channels-first Conv + BN + ReLU MLPs that group
    before the first layer and apply the last ReLU before the max, no C++ kernels (CFAR's tie-tolerant
    FPS/3-NN run their torch loops). Everything else of a model (attention, heads, losses) is its own.
    """
    import floaff_zoo.nn.cfar as zoo_cfar
    import floaff_zoo.nn.nets as zoo_nets
    import floaff_zoo.nn.ops as zoo_ops
    import floaff_zoo.nn.pointnet2 as zoo_pn2

    patches = [
        (zoo_pn2, "farthest_point_sample", _ref_fps),
        (zoo_pn2, "ball_query_multi", _ref_ball_query_multi),
        (zoo_pn2, "three_interpolate", _ref_three_interpolate),
        (zoo_pn2, "GATHER_AFTER_FIRST_LAYER", 1 << 30),
        (zoo_pn2, "CHUNK_ROWS", 1 << 62),  # eval levels in one pass, through the patched ``pooled``
        (zoo_pn2.SharedMLP, "forward", _ref_mlp_forward),
        (zoo_pn2.SharedMLP, "pooled", _ref_mlp_pooled),
        (zoo_nets, "farthest_point_sample", _ref_fps),
        (zoo_nets, "three_interpolate", _ref_three_interpolate),
        (zoo_ops, "point_kernel", lambda device: None),
        (zoo_cfar, "point_kernel", lambda device: None),
    ]
    saved = [(obj, name, getattr(obj, name)) for obj, name, _ in patches]
    try:
        for obj, name, value in patches:
            setattr(obj, name, value)
        yield
    finally:
        for obj, name, value in saved:
            setattr(obj, name, value)
