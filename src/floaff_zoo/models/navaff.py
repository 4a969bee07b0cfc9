"""NavAffModule: the MoMa-Kitchen NavAff architecture (docs/background.md §3), rewritten channels-last."""

from __future__ import annotations

from typing import Literal

from torch import Tensor

from floaff_zoo.contract import Batch
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig, check_dropout
from floaff_zoo.models.pointnet2 import floor_inputs, maybe_bf16, maybe_compile, scene_inputs
from floaff_zoo.nn.nets import NAVAFF_NSAMPLES, NAVAFF_RADII, NavAffNet


class NavAffModule(FloAffModule):
    """NavAff (class ``NaviAff`` of MoMaKitchen/MoMaKitchen ``model/NaviAff.py@64ca7a4``).

    Architecture (defaults = official sizes):

    - two PointNet++ MSG encoders, global (xyz + target flag) and floor (xyz):
      sa1 512 centres, r (0.1, 0.2, 0.4), K (32, 64, 128), MLPs [32,32,64] [64,64,128] [64,96,128];
      sa2 128, r (0.4, 0.8), K (64, 128), [128,128,256] [128,196,256];
      sa3 N_p = 64, r (0.2, 0.4), K (16, 32), as sa2;
    - robot token Linear(2, 256)-ReLU-Linear(256, 512);
    - one 8-head cross-attention of width 512 (query = floor sa3 tokens, key/value = [robot token;
      global sa3 tokens]), dropout 0.1, no residual, no LayerNorm: it replaces the floor tokens;
    - FP decoder fp3 (1024 -> 768, 512), fp2 (832 -> 768, 512), fp1 (518 -> 512, 512; skip
      [xyz, xyz]); head Linear(512, 64)-BN-ReLU-Linear(64, 1)-sigmoid.

    Training recipe (official): loss ``navaff`` (0.7 weight on zero-label points picked by a fresh
    Bernoulli(0.5)), Adam 8e-4, weight decay 1e-3, cosine schedule (T_max = epochs, eta_min 1e-6),
    batch 64, 6 epochs. The official code's dead modules (``Conv1D1``/``Conv1D2``, the unused
    ResNet-18 image encoder) are not built. Differences: padded points are never sampled or
    grouped here (the official code lets zero padding into FPS/grouping) and FPS starts at the
    first valid point instead of a random one. The scene is normalised like ``pc_normalize``.

    Args:
        npoints: sa1/sa2/sa3 centres (official [512, 128, 64]); tiny configs shrink them.
        radii, nsamples: per level and scale (official by default).
        num_heads, dropout: fusion attention (official 8, 0.1).
        normalize_global: centre and scale the scene cloud like the official loader.
        floor_encoder: ``set`` (official) or ``pointwise`` (query-independent: the floor encoder runs over the
            cloud's observed ground points, each query interpolates from them; a departure, docs/method.md).
        compile, bf16: opt-in speed modes (see :class:`~floaff_zoo.models.pointnet2.PointNet2Module`).
        (the rest: see :class:`FloAffModule`; defaults follow the official recipe)
    """

    def __init__(
        self,
        npoints: list[int] = [512, 128, 64],  # noqa: B006 - primitive default, never mutated
        radii: list[list[float]] = NAVAFF_RADII,  # noqa: B006
        nsamples: list[list[int]] = NAVAFF_NSAMPLES,  # noqa: B006
        num_heads: int = 8,
        dropout: float = 0.1,
        normalize_global: bool = True,
        floor_encoder: Literal["set", "pointwise"] = "set",
        compile: bool = False,
        bf16: bool = False,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(loss="navaff", lr=8e-4, weight_decay=1e-3),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=weights)

    def configure_models(self) -> None:
        h = self.hparams
        check_dropout(h["dropout"], type(self).__name__)
        self.net = NavAffNet(
            npoints=h["npoints"],
            radii=h["radii"],
            nsamples=h["nsamples"],
            feat_channels=h["feat_channels"],
            robot_dim=h["robot_dim"],
            num_heads=h["num_heads"],
            dropout=h["dropout"],
            normalize_global=h["normalize_global"],
            floor_encoder=h["floor_encoder"],
        )
        maybe_compile(self.net, h["compile"])

    def forward(self, batch: Batch) -> Tensor:
        xyz, feat, mask = scene_inputs(batch, self.hparams["feat_channels"])
        fxyz, fmask = floor_inputs(batch)
        fps = self.net.sample(xyz, mask, fxyz, fmask)
        with maybe_bf16(self.hparams["bf16"], xyz.device):
            out = self.net(xyz, feat, mask, fxyz, fmask, batch["robot"].float(), fps=fps)
        return out.float()
