"""CanonicalPriorModule: the no-network reference every learned model must beat.

``fit`` accumulates each task's training labels in the canonical frame (target-centred, front normal
along -y, the frame CFAR works in; ``floaff_zoo.nn.cfar``) on a grid (:class:`~floaff_zoo.nn.prior.
CanonicalLabelGrid`); prediction reads the per-task mean at each query point, in the same frame. There is
no network and no gradient: one pass over the training set is enough (more epochs leave the mean
unchanged). The task comes from ``meta['task']``, which a robot knows (it is the task it was given).

Yaw: training uses ``yaw_source`` (default ``gt``, the simulator's yaw, as CFAR's training does); test and
predict use ``eval_yaw_source`` (``floaff_zoo.models.yaw``): by default ``none`` for a grid filled with
``yaw_source: none``, else ``axisnet_manhattan`` when an AxisNet is configured and ``manhattan``
(training-free). ``gt`` at test time is privileged and must be labelled so in tables ("canonical prior, simulator
yaw"); ``none`` is the unrotated, target-centred average.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch import Tensor

from floaff_zoo.contract import TASKS, Batch
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig
from floaff_zoo.models.yaw import (
    YawSource,
    check_manhattan_radius,
    check_yaw_sources,
    configured_axisnet,
    estimate_yaw,
    keep_configured_axisnet,
    yaw_or_nan,
)
from floaff_zoo.nn.cfar import alignment_angle, rotate_z
from floaff_zoo.nn.prior import CanonicalLabelGrid


def prior_tasks(value: Sequence[str] | None, name: str, owner: str) -> list[str]:
    """The tasks a prior keeps a grid for: ``value``, or every task for None.

    Raises:
        MisconfigurationException: naming ``name`` for a text, an empty list (it meant every task, silently), a
            task named twice or an unknown task.
    """
    if value is None:
        return list(TASKS)
    if isinstance(value, str):  # "CloseDrawer" was read letter by letter as unknown tasks
        raise MisconfigurationException(f"{owner}: {name} must be a list of task names, got the text {value!r}")
    tasks = list(value)
    if not tasks:
        raise MisconfigurationException(f"{owner}: {name} needs >= 1 task (null for all of {list(TASKS)}), got []")
    if len(set(tasks)) < len(tasks):
        raise MisconfigurationException(f"{owner}: {name} names a task twice: {tasks}")
    unknown = sorted(set(tasks) - set(TASKS))
    if unknown:
        raise MisconfigurationException(f"{owner}: unknown task(s) {unknown} in {name}; known: {list(TASKS)}")
    return tasks


class CanonicalPriorModule(FloAffModule):
    """Per-task mean of the training labels in the canonical frame (no network).

    Args:
        tasks: tasks with a grid (samples of other tasks are an error naming the task).
        cell: grid cell (m); extent: half-width of the grid around the target (m).
        smooth_sigma_cells: Gaussian smoothing of the mean map (cells; 0 = none).
        fill: prior where no training label fell.
        centred: cells centred on the label lattice (``nn.prior``); False reproduces the binning of checkpoints
            written before (a loaded checkpoint keeps the binning its state records).
        yaw_source: yaw used to accumulate the training labels (see module docstring).
        eval_yaw_source: yaw used to read the grid in evaluation (validation, test, predict).
        axisnet: AxisNetModule checkpoint or hub name (for the ``axisnet*`` sources).
        axisnet_arch: filled automatically (architecture + source + sha256 of the AxisNet); leave None.
        manhattan_radius: neighbourhood (m) of the Manhattan face estimate.
        (the rest: see :class:`FloAffModule`; ``train`` sets only the logged loss and the metrics.)
    """

    empty_means_default: ClassVar[tuple[str, ...]] = ("tasks",)

    def __init__(
        self,
        tasks: list[str] | None = None,
        cell: float = 0.05,
        extent: float = 3.0,
        smooth_sigma_cells: float = 1.0,
        fill: float = 0.0,
        centred: bool = True,
        yaw_source: YawSource = "gt",
        eval_yaw_source: YawSource | None = None,
        axisnet: str | None = None,
        axisnet_arch: dict[str, Any] | None = None,
        manhattan_radius: float = 1.2,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        # no optimiser: ``train`` only sets the logged loss and the metrics
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=weights)
        self.automatic_optimization = False  # no optimiser: training_step only accumulates

    def configure_models(self) -> None:
        h = self.hparams
        tasks = prior_tasks(h["tasks"], "tasks", type(self).__name__)
        self.net = CanonicalLabelGrid(tasks, h["cell"], h["extent"], h["smooth_sigma_cells"], h["fill"], h["centred"])
        check_manhattan_radius(h["manhattan_radius"], type(self).__name__)
        self.axisnet, self.axis_radius, arch = configured_axisnet(h["axisnet"], h["axisnet_arch"], type(self).__name__)
        self.hparams["axisnet_arch"] = arch  # saved with the checkpoint: rebuilds without the file
        sources = {"yaw_source": self.yaw_source, "eval_yaw_source": self.eval_yaw_source}
        check_yaw_sources(sources, self.axisnet, type(self).__name__)

    @property
    def yaw_source(self) -> str:
        return self.hparams["yaw_source"]

    @property
    def eval_yaw_source(self) -> str:
        h = self.hparams
        if h["eval_yaw_source"] is not None:
            return h["eval_yaw_source"]
        if h["yaw_source"] == "none":  # an unrotated grid is read unrotated
            return "none"
        return "axisnet_manhattan" if (h["axisnet"] or h["axisnet_arch"]) else "manhattan"

    def setup(self, stage: str) -> None:
        """Refuse a fit on several processes: each would sum only its own shard of the labels (and DDP refuses a
        module without a gradient with a message that names no option)."""
        super().setup(stage)
        world = self.trainer.world_size if self._trainer is not None else 1
        if stage == "fit" and world > 1:
            raise MisconfigurationException(
                f"CanonicalPriorModule: fitted on one process only (its label sums are not gathered across "
                f"processes), got {world}: run `fit` with --trainer.devices 1 (and no multi-node); testing on "
                "several is fine"
            )

    def train(self, mode: bool = True) -> "CanonicalPriorModule":
        super().train(mode)
        if self.axisnet is not None:
            self.axisnet.eval()
        return self

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        super().on_load_checkpoint(checkpoint)
        # evaluating a fitted prior with an AxisNet it was not saved with (or saved without one)
        keep_configured_axisnet(checkpoint, self.axisnet, self.hparams.get("axisnet_arch"))

    def canonical_floor(self, batch: Batch, source: str) -> tuple[Tensor, Tensor | None]:
        """Floor points in the canonical frame [B, M, 2] and the yaw used [B] (None = no rotation)."""
        yaw = estimate_yaw(
            batch, source, self.axisnet, self.axis_radius, self.hparams["manhattan_radius"], type(self).__name__
        )
        b = batch["floor_xyz"].shape[0]
        angle = alignment_angle(yaw, b, batch["floor_xyz"].device, batch["floor_xyz"].dtype)
        xyz = rotate_z(batch["floor_xyz"] - batch["target_xyz"][:, None, :], angle)
        return xyz[..., :2], yaw

    def task_index(self, batch: Batch) -> Tensor:
        return self.net.task_index([str(m.get("task")) for m in batch["meta"]])

    def scores_and_yaw(self, batch: Batch) -> tuple[Tensor, Tensor | None]:
        """(prior [B, M] in [0, 1] at the floor points, yaw used [B] or None), eval yaw source."""
        xy, yaw = self.canonical_floor(batch, self.eval_yaw_source)
        return self.net.read(self.task_index(batch), xy).to(batch["floor_xyz"].dtype).clamp(0, 1), yaw

    def forward(self, batch: Batch) -> Tensor:
        """Prior [B, M] in [0, 1] at the floor points (eval yaw source)."""
        return self.scores_and_yaw(batch)[0]

    def training_step(self, batch: Batch, batch_idx: int) -> None:
        self.check_inputs(batch)
        xy, _ = self.canonical_floor(batch, self.yaw_source)
        self.net.add(self.task_index(batch), xy, batch["floor_label"], batch["floor_mask"])
        if self._trainer is not None:
            # an accumulated batch counts as a step: checkpointing skips fits that took no step
            progress = self.trainer.fit_loop.epoch_loop.manual_optimization.optim_step_progress
            progress.increment_ready()
            progress.increment_completed()
        self.log(
            "train_labels",
            batch["floor_mask"].sum().float(),
            reduce_fx="sum",
            on_step=False,
            on_epoch=True,
            batch_size=batch["floor_xyz"].shape[0],
        )

    def configure_optimizers(self) -> None:
        return None

    def on_fit_end(self) -> None:
        missing = sorted(set(self.net.tasks) - set(self.net.seen_tasks()))
        if missing:
            import warnings

            warnings.warn(
                f"CanonicalPriorModule: no training label for task(s) {missing}; they predict fill={self.net.fill}",
                stacklevel=2,
            )

    def predict_step(self, batch: Batch, batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        self.check_inputs(batch)
        scores, yaw = self.scores_and_yaw(batch)
        return self.prediction(batch, scores, yaw=yaw_or_nan(yaw, scores))
