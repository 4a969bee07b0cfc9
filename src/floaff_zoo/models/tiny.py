"""TinyPointNetModule: a small, fast PointNet + per-floor-point head for smoke tests and demos."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from floaff_zoo.contract import Batch
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig, check_sizes


class TinyPointNet(nn.Module):
    """Global PointNet code of the scene + robot code, decoded at each floor point.

    Each floor point sees its own (x, y) and its offset to the target, so even this tiny net can
    express "a ring around the target" maps.
    """

    def __init__(self, feat_channels: int, robot_dim: int, width: int) -> None:
        super().__init__()
        self.point_mlp = nn.Sequential(
            nn.Linear(3 + feat_channels, width), nn.ReLU(), nn.Linear(width, 2 * width), nn.ReLU()
        )
        self.robot_mlp = nn.Sequential(nn.Linear(robot_dim, width), nn.ReLU())
        self.head = nn.Sequential(
            nn.Linear(2 * width + width + 5, 2 * width),
            nn.ReLU(),
            nn.Linear(2 * width, width),
            nn.ReLU(),
            nn.Linear(width, 1),
        )

    def forward(self, xyz: Tensor, feat: Tensor, mask: Tensor, floor: Tensor, robot: Tensor, target: Tensor) -> Tensor:
        """xyz [B,N,3], feat [B,N,C], mask [B,N], floor [B,M,3], robot [B,R], target [B,3] -> [B,M]."""
        h = self.point_mlp(torch.cat([xyz, feat], dim=-1))
        h = h.masked_fill(~mask[..., None], float("-inf")).amax(dim=1)  # [B, 2w]
        h = torch.nan_to_num(h, neginf=0.0)
        g = torch.cat([h, self.robot_mlp(robot)], dim=-1)  # [B, 3w]
        rel = floor[..., :2] - target[:, None, :2]
        dist = rel.norm(dim=-1, keepdim=True)
        local = torch.cat([floor[..., :2], rel, dist], dim=-1)  # [B, M, 5]
        z = torch.cat([g[:, None].expand(-1, floor.shape[1], -1), local], dim=-1)
        return torch.sigmoid(self.head(z).squeeze(-1))


class TinyPointNetModule(FloAffModule):
    """Smoke-test model: PointNet global feature + robot MLP + per-floor-point MLP head.

    Args:
        width: hidden width.
        (the rest: see :class:`FloAffModule`)
    """

    def __init__(
        self,
        width: int = 32,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=weights)

    def configure_models(self) -> None:
        h = self.hparams
        check_sizes(h, ("width",), type(self).__name__)
        self.net = TinyPointNet(h["feat_channels"], h["robot_dim"], h["width"])

    def forward(self, batch: Batch) -> Tensor:
        c = self.hparams["feat_channels"]
        return self.net(
            batch["scene_xyz"],
            batch["scene_feat"][..., :c],
            batch["scene_mask"],
            batch["floor_xyz"],
            batch["robot"],
            batch["target_xyz"],
        )
