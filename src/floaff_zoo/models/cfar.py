"""CFARModule: Canonical FloAff Representation + PFAL feature distillation (the FloAff-Kitchen method).

Pipeline per batch: T(P, S) (crop r around the target, centre, rotate the target's front to -y;
``floaff_zoo.nn.cfar``) -> :class:`~floaff_zoo.nn.cfar.CFARNet` -> one score per floor point, in the
input floor order (so scores need no mapping back to the robot frame; ``predict`` also returns the
4x4 canonical -> robot transform for pictures).

Yaw of the target (theta_o):

* ``yaw_source`` (training) and ``eval_yaw_source`` (validation, test, predict) take any source of
  ``floaff_zoo.models.yaw``: ``gt`` = ``batch["target_yaw"]`` (simulator / annotation; privileged at test
  time), ``axisnet``, ``axisnet_manhattan`` (AxisNet snapped onto the kitchen's axes), ``manhattan``,
  ``heading``, ``none`` = no rotation (the w/o-Align ablation, same as ``use_align: false``).
* ``eval_yaw_source`` defaults to ``axisnet`` when an AxisNet is configured, otherwise ``manhattan``
  (``none`` without alignment): never the simulator's yaw unless asked for. The paper trains with simulator
  yaw and estimates it with AxisNet at inference; validation then scores the deployed pipeline, so the
  best checkpoint is chosen with AxisNet in the loop.
* ``yaw_jitter_deg`` (training only): the paper's "random yaw perturbations within +-5 deg". A rotation
  of the whole scene (scene, floor, target pose) is a no-op for a gt-aligned CFAR, so the perturbation is
  applied to the alignment itself: the canonical cloud and floor turn by a uniform angle in +-5 deg about
  the target, which also teaches the net to tolerate AxisNet errors. (A data-side ``YawPerturb`` stays
  harmless but useless here.)

AxisNet (``axisnet``: checkpoint path or hub name) is loaded frozen (eval, no grad, kept in eval by
``train()``) and **kept in the student checkpoint** (``axisnet.*`` weights); its architecture, source and
sha256 are recorded in the ``axisnet_arch`` hparam, which is filled automatically so the student
checkpoint rebuilds the AxisNet without the original file. Training uses the simulator's yaw, so the
AxisNet of a trained model can be swapped: when ``axisnet`` names another AxisNet than the recorded
``axisnet_arch['source']`` (or a file of another sha256 at that path, such as an AxisNet retrained there), that one is
loaded and its weights replace the checkpoint's ``axisnet.*``, with a warning naming both.

Departures from the paper (switches, off by default; docs/method.md): ``prior_residual`` predicts a residual
logit over the canonical prior (a per-task label average on a canonical grid, filled from the training data at
the start of ``fit`` for tasks it has not seen, kept in the checkpoint); ``floor_encoder: pointwise`` encodes
each floor point alone, so scores do not depend on the other queries; ``occupancy_input`` gives the decoder, per floor
point, the obstacle points of the view's own cloud inside the base footprint parked there
(``nn.placement.footprint_occupancy``, the rectangle of ``floor.footprint_blocked``): two channels, log(1 + count) and
count >= 2 (what the callback's ``free_space: cloud`` check calls blocked), counts rescaled to a 1,024-point cloud;
``coverage_input`` adds one channel after them: the share of that footprint the view's cloud shows
(``nn.placement.footprint_seen``; a footprint the view does not show may hide furniture).

PFAL teacher (``teacher``: checkpoint path or hub name of the previous stage's best): loaded lazily in
``setup("fit")`` (so test/predict/``load_from_checkpoint`` never need the file), frozen, in eval mode,
never saved (``teacher.*`` is stripped in ``on_save_checkpoint`` and re-inserted in ``on_load_checkpoint``
when resuming, so loading stays strict for every other key). Its name and sha256 are stored in the
checkpoint under ``"floaff_lineage"`` (primitives only). ``L_pro = L_aff + distill_weight * L_shared``
with ``L_shared = mean_b ||g_teacher(P_hat) - g_student(P_hat)||^2``, g = the canonical-cloud encoder's
pooled global feature (output of its group-all level, before fusion with floor/robot codes).
``distill_bn="batch"`` (default) runs the teacher's BatchNorm on the current batch statistics, like the
student in training, without touching its buffers: teacher and student then compute the same function at
the start of a stage (L_shared = 0 at the first step) and the term measures drift of the weights only.
``"running"`` uses the teacher's running statistics (classic eval-mode teacher).
"""

from __future__ import annotations

import copy
import inspect
import math
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from typing import Any, ClassVar, Literal

import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch import Tensor, nn

from floaff_zoo.checks import check_number, check_numbers
from floaff_zoo.contract import Batch
from floaff_zoo.hub.io import resolve_state_dict
from floaff_zoo.hub.registry import HubError, sha256_file
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig, sample_names
from floaff_zoo.models.prior import prior_tasks
from floaff_zoo.models.yaw import (
    YawSource,
    check_manhattan_radius,
    check_yaw_sources,
    configured_axisnet,
    estimate_yaw,
    keep_configured_axisnet,
    yaw_or_nan,
)
from floaff_zoo.nn.axisnet import AxisNet
from floaff_zoo.nn.cfar import CanonicalCloud, CFARNet, canonical_transform, robot_from_canonical, sample_levels
from floaff_zoo.nn.placement import OCCUPANCY_CHANNELS, footprint_occupancy, footprint_seen
from floaff_zoo.nn.prior import CanonicalLabelGrid

TEACHER_PREFIX = "teacher."
#: the local encoder's arguments that shape its function without shaping its weights: a teacher is rebuilt with the
#: student's (a copy of its encoder), so they must agree
TEACHER_SAMPLING_ARGS = ("local_npoints", "local_radii", "local_nsamples")
#: the prior is clamped to [eps, 1 - eps] before its logit
PRIOR_EPS = 1e-3
DISTILLED_PREFIX = "net.local_encoder."


class TeacherError(MisconfigurationException, ValueError):
    """A ``teacher`` that does not load or does not fit the student: a user error, one line at the console (it is
    raised in ``setup``, past the CLI's checks of init args)."""


@contextmanager
def batch_statistics(module: nn.Module) -> Iterator[None]:
    """Run ``module``'s BatchNorm layers on batch statistics without updating their running buffers."""
    bns = [m for m in module.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    saved = [(m.training, m.track_running_stats) for m in bns]
    for m in bns:
        m.training, m.track_running_stats = True, False
    try:
        yield
    finally:
        for m, (tr, track) in zip(bns, saved):
            m.training, m.track_running_stats = tr, track


def _local_sampling(args: Any, name: str, who: str, error: type[ValueError] = ValueError) -> list[float]:
    """A local-encoder sampling argument of a CFAR's init args, ``None`` resolved to ``CFARNet``'s default;
    ``error`` naming ``who`` (whose arguments) when it is not a list of numbers."""
    value = args.get(name)
    if value is None:
        value = inspect.signature(CFARNet.__init__).parameters[name].default
    try:
        if isinstance(value, (str, bytes, dict)):  # iterable, but "64" read as [6.0, 4.0]
            raise TypeError(type(value).__name__)
        return [float(v) for v in value]
    except (TypeError, ValueError) as exc:  # a checkpoint's saved text failed float() naming nothing
        raise error(f"{who}: {name} must be a list of numbers, got {value!r}") from exc


def _sha256(path: str) -> str | None:
    from pathlib import Path

    return sha256_file(Path(path)) if Path(path).is_file() else None


def distills(teacher: str | None, use_fd: bool, distill_weight: float) -> bool:
    """Whether a CFAR configuration trains with L_shared, and so reads its teacher: a teacher, ``use_fd`` and a
    positive lambda (``floaff-zoo curriculum`` checks a stage's teacher only then)."""
    return bool(teacher and use_fd and distill_weight > 0)


class CFARModule(FloAffModule):
    """CFAR (+ PFAL distillation when ``teacher`` is set). See the module docstring for the design.

    Args:
        crop_radius: crop radius r (m): 1.3 Styles, 1.2 Layouts (paper).
        use_crop: False = w/o-Crop ablation (whole scene, still centred/rotated).
        use_align: False = w/o-Align ablation (no rotation; overrides ``yaw_source``; training still adds the
            ``yaw_jitter_deg`` augmentation).
        use_sdl: False = w/o-SDL ablation (``loss: aff`` becomes plain MSE).
        use_fd: False = w/o-FD ablation (no distillation even with a teacher, which is then not loaded; still
            initialise from ``weights``).
        yaw_source: where theta_o comes from in training.
        eval_yaw_source: where theta_o comes from in evaluation (validation, test, predict).
        axisnet: frozen AxisNet (checkpoint path or hub name).
        axisnet_arch: filled automatically (AxisNet architecture + source + sha256); leave None.
        yaw_jitter_deg: training perturbation of the alignment (deg; paper 5).
        teacher: previous PFAL stage (checkpoint path or hub name).
        distill_weight: lambda, the weight of the distillation term (paper 1.0).
        distill_bn: teacher BatchNorm mode, ``batch`` or ``running``.
        local_npoints: centres per SSG level of the local encoder (None: the default of
            :class:`~floaff_zoo.nn.cfar.CFARNet`, as for every architecture list below).
        local_radii: ball radius per local level (m).
        local_nsamples: neighbours per local level.
        local_mlps: MLP widths per local level.
        local_global_mlp: widths of the local encoder's group-all layer (its last is C_g).
        floor_npoints: centres per SSG level of the floor encoder.
        floor_radii: ball radius per floor level (m).
        floor_nsamples: neighbours per floor level.
        floor_mlps: MLP widths per floor level.
        floor_fp_mlps: feature-propagation widths, deepest level first.
        robot_mlp: widths of the robot-description MLP.
        head: hidden widths of the decoder.
        floor_encoder: ``set`` (paper) or ``pointwise`` (query-independent floor features; departure).
        prior_residual: predict a residual over the canonical prior (departure, see module docstring).
        residual_scale: the learned residual logit is multiplied by this before it is added to the prior's logit
            (with ``prior_residual``; 1 = the residual as trained, 0 = the prior alone). A shrinkage knob that can
            be set at test time (``--model.init_args.residual_scale``) without retraining.
        occupancy_input: give the decoder the base footprint's occupancy from the view's cloud at each floor
            point (departure, see module docstring; off by default).
        coverage_input: also give the decoder the share of that footprint the view's cloud shows (one channel after
            the occupancy's, if any; departure, see module docstring; off by default).
        prior_tasks: tasks the prior keeps a grid for (default: the four tasks).
        prior_centred: the prior's cells centred on the label lattice (``nn.prior``); False reproduces the
            binning of checkpoints written before (a loaded checkpoint keeps the binning its state records).
        manhattan_radius: neighbourhood (m) of the Manhattan face estimate (``*manhattan`` yaw sources).
        (the rest: see :class:`FloAffModule`; paper: Adam 2e-4, batch 8, 30 epochs/stage, beta = 1.)
    """

    empty_means_default: ClassVar[tuple[str, ...]] = ("prior_tasks",)

    def __init__(
        self,
        crop_radius: float = 1.3,
        use_crop: bool = True,
        use_align: bool = True,
        use_sdl: bool = True,
        use_fd: bool = True,
        yaw_source: YawSource = "gt",
        eval_yaw_source: YawSource | None = None,
        axisnet: str | None = None,
        axisnet_arch: dict[str, Any] | None = None,
        yaw_jitter_deg: float = 5.0,
        teacher: str | None = None,
        distill_weight: float = 1.0,
        distill_bn: Literal["batch", "running"] = "batch",
        local_npoints: list[int] | None = None,
        local_radii: list[float] | None = None,
        local_nsamples: list[int] | None = None,
        local_mlps: list[list[int]] | None = None,
        local_global_mlp: list[int] | None = None,
        floor_npoints: list[int] | None = None,
        floor_radii: list[float] | None = None,
        floor_nsamples: list[int] | None = None,
        floor_mlps: list[list[int]] | None = None,
        floor_fp_mlps: list[list[int]] | None = None,
        robot_mlp: list[int] | None = None,
        head: list[int] | None = None,
        floor_encoder: Literal["set", "pointwise"] = "set",
        prior_residual: bool = False,
        residual_scale: float = 1.0,
        occupancy_input: bool = False,
        coverage_input: bool = False,
        prior_tasks: list[str] | None = None,
        prior_centred: bool = True,
        manhattan_radius: float = 1.2,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(loss="aff", lr=2e-4, scheduler="none"),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=weights)

    # ----------------------------------------------------------------- hooks
    def configure_models(self) -> None:
        h = self.hparams
        owner, error = type(self).__name__, MisconfigurationException
        no_crop = "use_crop: false for no crop"  # NaN passed and blamed the data
        check_number("crop_radius", h["crop_radius"], strict=True, owner=owner, error=error, note=no_crop)
        # NaN passed '< 0' and turned the term off silently (as a negative jitter or Manhattan radius turned those off)
        check_numbers({k: h[k] for k in ("distill_weight", "yaw_jitter_deg")}, owner=owner, error=error)
        check_manhattan_radius(h["manhattan_radius"], owner)
        check_number("residual_scale", h["residual_scale"], owner=owner, error=error)
        if h["distill_bn"] not in ("batch", "running"):  # a typo ran the teacher on its running statistics
            raise MisconfigurationException(
                f"CFARModule: distill_bn must be 'batch' or 'running', got {h['distill_bn']!r}"
            )
        if h["residual_scale"] != 1.0 and not h["prior_residual"]:  # it would be ignored: say so instead
            raise MisconfigurationException(
                "CFARModule: residual_scale scales the prior residual; set prior_residual: true"
            )
        if h["prior_tasks"] is not None and not h["prior_residual"]:  # as residual_scale: ignored, silently
            raise MisconfigurationException("CFARModule: prior_tasks sets the prior's tasks; set prior_residual: true")
        arch = {
            k: h[k]
            for k in (
                "local_npoints",
                "local_radii",
                "local_nsamples",
                "local_mlps",
                "local_global_mlp",
                "floor_npoints",
                "floor_radii",
                "floor_nsamples",
                "floor_mlps",
                "floor_fp_mlps",
                "robot_mlp",
                "head",
            )
            if h[k] is not None
        }
        self.net = CFARNet(
            feat_channels=h["feat_channels"],
            robot_dim=h["robot_dim"],
            floor_encoder=h["floor_encoder"],
            floor_feat_channels=OCCUPANCY_CHANNELS * bool(h["occupancy_input"]) + int(bool(h.get("coverage_input"))),
            **arch,
        )
        self.prior: CanonicalLabelGrid | None = None
        if h["prior_residual"]:
            tasks = prior_tasks(h["prior_tasks"], "prior_tasks", owner)
            self.prior = CanonicalLabelGrid(tasks, centred=h["prior_centred"])
            # the residual starts at zero: an untrained model predicts the prior
            nn.init.zeros_(self.net.out.weight)
            nn.init.zeros_(self.net.out.bias)
        self.axisnet: AxisNet | None
        self.axisnet, self.axis_radius, arch = configured_axisnet(h["axisnet"], h["axisnet_arch"], type(self).__name__)
        self.hparams["axisnet_arch"] = arch  # saved with the checkpoint: rebuilds without the file
        sources = {"yaw_source": self.train_yaw_source, "eval_yaw_source": self.eval_yaw_source}
        check_yaw_sources(sources, self.axisnet, type(self).__name__)
        self.teacher: nn.Module | None = None
        self.teacher_info: dict[str, Any] | None = None

    def configure_losses(self) -> None:
        t = self.train_cfg
        name = "mse" if not self.hparams["use_sdl"] and t.loss == "aff" else t.loss  # w/o-SDL ablation
        self.set_criteria(name)

    # ----------------------------------------------------------------- yaw sources
    @property
    def train_yaw_source(self) -> str:
        return "none" if not self.hparams["use_align"] else self.hparams["yaw_source"]

    @property
    def eval_yaw_source(self) -> str:
        h = self.hparams
        if not h["use_align"]:
            return "none"
        if h["eval_yaw_source"] is not None:
            return h["eval_yaw_source"]
        if h["axisnet"] or h["axisnet_arch"]:
            return "axisnet"
        # never the simulator's yaw unless asked for (eval_yaw_source: gt): a robot does not have it
        return "none" if h["yaw_source"] == "none" else "manhattan"

    # ----------------------------------------------------------------- AxisNet
    def estimate_yaw(self, batch: Batch, source: str = "axisnet") -> Tensor | None:
        """The target's front yaw [B] (rad, robot frame) from ``source`` (``floaff_zoo.models.yaw``)."""
        return estimate_yaw(
            batch, source, self.axisnet, self.axis_radius, self.hparams["manhattan_radius"], type(self).__name__
        )

    # ----------------------------------------------------------------- teacher
    def setup(self, stage: str) -> None:
        super().setup(stage)
        # w/o FD (or lambda 0) never reads the teacher: not loaded, so its memory and lineage entry are not spent
        if stage == "fit" and self.teacher is None and self.distills:
            self.load_teacher(self.hparams["teacher"])

    @property
    def distills(self) -> bool:
        """Whether the configuration trains with L_shared (:func:`distills`)."""
        return distills(self.hparams["teacher"], self.hparams["use_fd"], self.hparams["distill_weight"])

    @property
    def distill_active(self) -> bool:
        return bool(self.teacher is not None and self.distills)

    def load_teacher(self, name: str) -> None:
        """Load the previous stage's canonical-cloud encoder, frozen.

        Raises:
            TeacherError: naming the teacher for one that does not load (a missing or corrupt file, an unknown hub
                name: a FileNotFoundError traceback mid-fit), listing missing / unexpected / shape-mismatched keys
                when the teacher's encoder does not match the student's, or naming the sampling arguments
                (``TEACHER_SAMPLING_ARGS``) the teacher was trained with when they differ from the student's.
        """
        try:
            state, info = resolve_state_dict(name)
        except (OSError, ValueError, HubError) as exc:
            raise TeacherError(f"teacher {name!r}: {exc}") from exc
        t_state = {k[len(DISTILLED_PREFIX) :]: v for k, v in state.items() if k.startswith(DISTILLED_PREFIX)}
        own = self.net.local_encoder.state_dict()
        missing = sorted(set(own) - set(t_state))
        unexpected = sorted(set(t_state) - set(own))
        shapes = [
            f"{DISTILLED_PREFIX}{k}: teacher {tuple(t_state[k].shape)} vs student {tuple(own[k].shape)}"
            for k in own
            if k in t_state and t_state[k].shape != own[k].shape
        ]
        if missing or unexpected or shapes:
            raise TeacherError(
                f"teacher {name!r} ({info.get('class_path') or 'unknown class'}) does not match the student's "
                f"canonical-cloud encoder ({DISTILLED_PREFIX}*): missing {[DISTILLED_PREFIX + k for k in missing]}, "
                f"unexpected {[DISTILLED_PREFIX + k for k in unexpected]}, shape mismatches {shapes}"
            )
        # same weights' shapes but other centres, radii or neighbour counts: the copy would run the teacher's weights
        # with the student's sampling, a function the teacher never computed (a file without its arguments: unchecked)
        saved = info.get("init_args") or {}
        teacher_of, student = f"teacher {name!r}", type(self).__name__
        pairs = {
            # the teacher's file is a user's input: TeacherError, one line at the console, not a setup traceback
            k: (_local_sampling(saved, k, teacher_of, TeacherError), _local_sampling(self.hparams, k, student))
            for k in TEACHER_SAMPLING_ARGS
            if k in saved
        }
        differ = [f"{k}: teacher {t} vs student {s}" for k, (t, s) in pairs.items() if t != s]
        if differ:
            raise TeacherError(
                f"teacher {name!r} was trained with another canonical-cloud sampling than the student's: "
                f"{'; '.join(differ)}; give the student the teacher's values"
            )
        teacher = copy.deepcopy(self.net.local_encoder)
        teacher.load_state_dict(t_state, strict=True)
        teacher.requires_grad_(False).eval()
        self.teacher = teacher.to(next(self.net.parameters()).device)
        self.teacher_info = {"name": str(name), "sha256": info.get("sha256") or _sha256(info.get("source", name))}

    def train(self, mode: bool = True) -> "CFARModule":
        super().train(mode)
        for frozen in (self.axisnet, self.teacher):
            if frozen is not None:
                frozen.eval()
        return self

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        super().on_save_checkpoint(checkpoint)
        state = checkpoint.get("state_dict") or {}
        for k in [k for k in state if k.startswith(TEACHER_PREFIX)]:
            del state[k]
        arch = self.hparams.get("axisnet_arch") or {}
        checkpoint.setdefault("floaff_lineage", {}).update(
            {
                "teacher": self.teacher_info["name"]
                if self.teacher_info
                else (self.hparams["teacher"] if self.distills else None),
                "teacher_sha256": self.teacher_info["sha256"] if self.teacher_info else None,
                "weights": self.hparams["weights"],
                "weights_sha256": self.weights_sha256,
                "axisnet": arch.get("source"),
                "axisnet_sha256": arch.get("sha256"),
            }
        )

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        super().on_load_checkpoint(checkpoint)
        # resuming a stage: the checkpoint has no teacher.* keys; keep the teacher loaded from its file
        if self.teacher is not None and "state_dict" in checkpoint:
            for k, v in self.teacher.state_dict().items():
                checkpoint["state_dict"].setdefault(TEACHER_PREFIX + k, v)
        # another AxisNet was configured than the one stored in the checkpoint, or the checkpoint has none (e.g.
        # `floaff-zoo test --ckpt_path stage2.ckpt --model.init_args.axisnet better_axisnet.ckpt`): keep the
        # configured one
        own = (self.hparams.get("axisnet_arch") or {}).get("sha256")
        stored = ((checkpoint.get("hyper_parameters") or {}).get("axisnet_arch") or {}).get("sha256")
        if own and own != stored:
            keep_configured_axisnet(checkpoint, self.axisnet, self.hparams.get("axisnet_arch"))

    # ----------------------------------------------------------------- forward
    def canonicalize(self, batch: Batch) -> tuple[CanonicalCloud, Tensor | None]:
        """T(P, S) of a batch with the yaw source of the current mode. Returns (canonical cloud, yaw [B] | None)."""
        source = self.train_yaw_source if self.training else self.eval_yaw_source
        yaw = self.estimate_yaw(batch, source)
        extra = None
        jitter = self.hparams["yaw_jitter_deg"]
        if self.training and jitter > 0:
            b = batch["scene_xyz"].shape[0]
            extra = (torch.rand(b, device=batch["scene_xyz"].device) * 2 - 1) * math.radians(jitter)
        canon = canonical_transform(
            batch["scene_xyz"],
            batch["scene_mask"],
            batch["floor_xyz"],
            batch["target_xyz"],
            yaw,
            self.hparams["crop_radius"] if self.hparams["use_crop"] else None,
            extra,
            sample_names(batch),
        )
        return canon, yaw

    def _run(self, batch: Batch) -> tuple[Tensor, Tensor, CanonicalCloud, Tensor | None]:
        canon, yaw = self.canonicalize(batch)
        feat = batch["scene_feat"][..., : self.hparams["feat_channels"]]
        logits, g = self.net.logits(
            canon.xyz,
            feat,
            canon.mask,
            canon.floor_xyz,
            batch["floor_mask"],
            batch["robot"],
            self.floor_features(batch),
        )
        if self.prior is not None:
            tasks = self.prior.task_index([str(m.get("task")) for m in batch["meta"]])
            p = self.prior.read(tasks, canon.floor_xyz[..., :2]).to(logits.dtype).clamp(PRIOR_EPS, 1 - PRIOR_EPS)
            logits = self.hparams["residual_scale"] * logits + torch.log(p) - torch.log1p(-p)
        return torch.sigmoid(logits), g, canon, yaw

    def floor_features(self, batch: Batch) -> Tensor | None:
        """The decoder's extra per-floor-point channels [B, M, C] (occupancy, then coverage), None when switched off."""
        parts = []
        if self.hparams["occupancy_input"]:
            parts.append(self.occupancy(batch))
        if self.hparams.get("coverage_input"):
            xy = batch["floor_xyz"][..., :2]
            parts.append(
                footprint_seen(batch["scene_xyz"], batch["scene_mask"], xy, batch["target_xyz"][..., :2])[..., None]
            )
        return torch.cat(parts, dim=-1) if parts else None

    @staticmethod
    def occupancy(batch: Batch) -> Tensor:
        """Footprint occupancy [B, M, 2] at every floor point from the view's whole (uncropped) cloud, robot frame
        (``nn.placement.footprint_occupancy``; independent of the yaw estimate and the crop)."""
        return footprint_occupancy(batch["scene_xyz"], batch["scene_mask"], batch["floor_xyz"], batch["target_xyz"])

    # ----------------------------------------------------------------- prior
    def on_fit_start(self) -> None:
        super().on_fit_start()
        if self.prior is not None and self.prior_needs_pass():
            self.fill_prior()

    def prior_needs_pass(self) -> bool:
        """Whether this fit averages training labels into the prior: a fresh fit always does (as before); a fit resumed
        from a checkpoint only when its data holds a task the checkpoint's prior has no labels of. For a resumed
        stage the pass added nothing, but it drew an epoch from the restored shuffle generator and augmentation stream
        (another order and noise than an uninterrupted fit trains)."""
        assert self.prior is not None
        if self.trainer.ckpt_path is None:
            return True
        tasks = getattr(getattr(self.trainer, "datamodule", None), "tasks", None)
        if not tasks:  # a data module that does not list its tasks: the checkpoint's prior is its first start's
            return False
        seen = {t for t, c in zip(self.prior.tasks, self.prior.counts.sum((1, 2)).tolist(), strict=True) if c > 0}
        return any(str(t) not in seen for t in tasks)

    @torch.no_grad()
    def fill_prior(self) -> None:
        """Average the training labels of tasks the prior has not seen yet (one pass, training yaw, no jitter).

        Tasks already in the prior (stage 1's task when stage 2 starts from its weights) keep their grid; a fit resumed
        from a checkpoint makes a pass only for a task its prior lacks (:meth:`prior_needs_pass`).
        """
        assert self.prior is not None
        dm = getattr(self.trainer, "datamodule", None)
        if dm is None:
            raise MisconfigurationException("CFARModule: prior_residual needs a datamodule to average its labels")
        fresh = CanonicalLabelGrid(
            self.prior.tasks,
            self.prior.cell,
            self.prior.extent,
            self.prior.smooth_sigma_cells,
            self.prior.fill,
            centred=bool(self.prior.centred),  # a grid loaded from an older checkpoint keeps its binning
        ).to(self.prior.sums.device)
        source = self.train_yaw_source if self.train_yaw_source in ("gt", "none") else "gt"
        for batch in dm.train_dataloader():
            batch = self.transfer_batch_to_device(batch, self.device, 0)
            yaw = self.estimate_yaw(batch, source)
            canon = canonical_transform(
                batch["scene_xyz"],
                batch["scene_mask"],
                batch["floor_xyz"],
                batch["target_xyz"],
                yaw,
                None,
                None,
                sample_names(batch),
            )
            tasks = fresh.task_index([str(m.get("task")) for m in batch["meta"]])
            fresh.add(tasks, canon.floor_xyz[..., :2], batch["floor_label"], batch["floor_mask"])
        new = (self.prior.counts.sum((1, 2)) == 0) & (fresh.counts.sum((1, 2)) > 0)
        self.prior.sums[new] = fresh.sums[new]
        self.prior.counts[new] = fresh.counts[new]

    def forward(self, batch: Batch) -> Tensor:
        """Scores [B, M] in [0, 1], one per floor point in the input order."""
        return self._run(batch)[0]

    def teacher_features(self, canon: CanonicalCloud, feat: Tensor) -> Tensor:
        """The teacher's pooled canonical-cloud feature [B, C_g] (no grad)."""
        assert self.teacher is not None
        ctx = batch_statistics(self.teacher) if self.hparams["distill_bn"] == "batch" else nullcontext()
        with torch.no_grad(), ctx:
            fps = sample_levels(self.teacher, canon.xyz, canon.mask)
            return self.teacher(canon.xyz, feat, canon.mask, fps)[-1][1][:, 0]

    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """L_aff (+ distill_weight * L_shared while training with a teacher)."""
        scores, g, canon, _ = self._run(batch)
        loss = self.affordance_loss(scores, batch)
        extra: dict[str, Tensor] = {}
        if self.training and self.distill_active:
            feat = batch["scene_feat"][..., : self.hparams["feat_channels"]]
            shared = ((g - self.teacher_features(canon, feat)) ** 2).sum(-1).mean()
            loss = loss + self.hparams["distill_weight"] * shared
            extra["distill"] = shared.detach()
            if self._trainer is not None:
                self.log(
                    "train_distill_step",
                    shared.detach(),
                    on_step=True,
                    on_epoch=False,
                    batch_size=batch["scene_xyz"].shape[0],
                )
        return loss, scores, extra

    def predict_step(self, batch: Batch, batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        """Scores plus the canonical -> robot transform [B, 4, 4], the yaw used [B] and the crop radius used [B]."""
        self.check_inputs(batch)
        scores, _, canon, yaw = self._run(batch)
        return self.prediction(
            batch,
            scores,
            yaw=yaw_or_nan(yaw, scores),
            robot_from_canonical=robot_from_canonical(canon.centre, canon.angle),
            crop_radius=canon.radius,
        )
