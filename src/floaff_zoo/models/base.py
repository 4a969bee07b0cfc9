"""The LightningModules every model of the zoo derives from (torchgeo style).

:class:`ZooModule` holds what every model shares: the training recipe (one ``train`` argument, a
:class:`TrainConfig`), optimiser and scheduler, pretrained weights, input checks, the step/logging
skeleton and ``save_pretrained``/``from_pretrained``. Two families derive from it:

* :class:`FloAffModule`: floor-affordance maps, ``forward(batch) -> [B, M]`` scores in [0, 1], with the
  affordance losses and metrics (its ``train`` is a :class:`FloAffTrainConfig`);
* :class:`~floaff_zoo.models.axisnet.AxisNetModule`: the target's yaw, ``forward(batch) -> [B]``.

Subclasses declare their typed, defaulted init args (the LightningCLI schema): their own, the family's
(``feat_channels``, ``robot_dim``), ``train`` with the model's default recipe and ``weights``; they pass
the shared ones to ``super().__init__`` and implement ``configure_models`` (build ``self.net``) and
``forward(batch)``. ``validation_step``/``test_step`` return ``{"loss": ..., output_key: prediction}``
(``scores`` [B, M] or ``yaw`` [B]); callbacks read the prediction from the ``outputs`` of their hooks.

Checkpoints and hub configs written before the ``train`` group hold the training arguments flat
(``lr: 0.001`` beside the model's own): :meth:`ZooModule.upgrade_init_args` moves them into ``train``
(``load_from_checkpoint``, the hub and ``--ckpt_path`` go through it).
"""

from __future__ import annotations

import collections.abc
import dataclasses
import inspect
import numbers
import os
import random
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, ClassVar, Literal

import lightning as L
import numpy as np
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch import Tensor
from torchmetrics import MetricCollection

from floaff_zoo import checks
from floaff_zoo.contract import Batch, NonFiniteError, SampleError, best_pose, check_batch
from floaff_zoo.losses import build_loss
from floaff_zoo.metrics import affordance_metrics

#: checkpoint entry of the random streams a resumed fit restores (``ZooModule.on_save_checkpoint``)
RNG_KEY = "floaff_rng_states"
#: the size attributes of the layers ``check_layer_sizes`` reads
_LAYER_SIZES: dict[type, tuple[str, ...]] = {
    torch.nn.Linear: ("in_features", "out_features"),
    torch.nn.Conv1d: ("in_channels", "out_channels"),
    torch.nn.BatchNorm1d: ("num_features",),
}


def check_layer_sizes(module: torch.nn.Module) -> None:
    """Refuse a network with a layer of width 0 (a width or mlps argument set to 0): it builds and trains, but
    the layer ignores its input, so the model would learn a constant.

    Raises:
        ValueError: naming the first such layer.
    """
    for name, m in module.named_modules():
        zero = [k for k in _LAYER_SIZES.get(type(m), ()) if getattr(m, k) < 1]
        if zero:
            raise ValueError(
                f"{type(module).__name__}: layer {name} ({type(m).__name__}) has {zero[0]} 0; every width, channel "
                "count and mlps entry must be >= 1"
            )


def literal_choices(hint: Any) -> tuple[Any, ...]:
    """The values a ``Literal[...]`` hint allows (None too for ``Literal[...] | None``); () for any other hint."""
    if typing.get_origin(hint) is Literal:
        return typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        parts = typing.get_args(hint)
        if any(p is not type(None) and typing.get_origin(p) is not Literal for p in parts):
            return ()  # ``Literal["auto"] | float``: any float is a choice too
        literals = [c for p in parts for c in literal_choices(p)]
        return (*literals, *([None] * (type(None) in parts))) if literals else ()
    return ()


def check_choices(cls: type, args: Mapping[str, Any]) -> None:
    """Refuse an init arg of ``cls`` typed ``Literal[...]`` whose value in ``args`` is not one of its choices.

    The CLI validates its own input; checkpoints, hub configs and Python land here, where an unknown text passed:
    ``variant="SSG"`` built the MSG sizes, a mistyped ``yaw_source`` failed at the first batch.

    Raises:
        ValueError: ``"{cls}: {name} must be one of [...], got {value!r}"``.
    """
    try:
        hints = typing.get_type_hints(cls.__init__)
    except (NameError, TypeError, AttributeError, SyntaxError):  # a user's hint naming what only a type checker sees
        return
    for name, hint in hints.items():
        choices = literal_choices(hint)
        if choices and name in args and args[name] not in choices:
            raise ValueError(f"{cls.__name__}: {name} must be one of {list(choices)}, got {args[name]!r}")


_PLURAL = {bool: "flags", int: "integers", float: "numbers", str: "texts"}
_SINGULAR = {bool: "true or false", int: "an integer", float: "a number", str: "a text", type(None): "null"}


def _expected(hint: Any, plural: bool = False) -> str:
    """How a message words the values ``hint`` allows ("an integer", "a list of lists of numbers")."""
    origin = typing.get_origin(hint)
    if origin in (list, tuple, collections.abc.Sequence):
        args = typing.get_args(hint)
        inner = f" of {_expected(args[0], plural=True)}" if args else ""
        return f"{'lists' if plural else 'a list'}{inner}"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_expected(p, plural) for p in typing.get_args(hint))
    if origin in (dict, Mapping, collections.abc.Mapping):
        return "mappings" if plural else "a mapping"
    return (_PLURAL if plural else _SINGULAR).get(hint, str(hint))


def _type_mismatch(value: object, hint: Any, path: str) -> tuple[str, str] | None:
    """(path of the first part of ``value`` that ``hint`` does not allow, the words for what it allows); None when
    ``value`` fits (or ``hint`` is one this check does not read: ``Literal``, dataclasses, ``Any``)."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        parts = [p for p in typing.get_args(hint) if p is not type(None)]
        if value is None and len(parts) < len(typing.get_args(hint)):
            return None
        if len(parts) == 1:  # ``X | None`` given something else: the error is X's (an entry of a list named)
            wrong = _type_mismatch(value, parts[0], path)
            return (path, f"{wrong[1]} or null") if wrong and wrong[0] == path else wrong
        fits = any(_type_mismatch(value, p, path) is None for p in parts)
        return None if fits else (path, _expected(hint))
    if origin in (list, tuple, collections.abc.Sequence):
        if not isinstance(value, (list, tuple)):  # a text is a sequence too: "64" read as [6, 4]
            return path, _expected(hint)
        args = typing.get_args(hint)
        for i, item in enumerate(value if args else ()):
            wrong = _type_mismatch(item, args[0], f"{path}[{i}]")
            if wrong:
                return wrong
        return None
    if origin in (dict, Mapping, collections.abc.Mapping):
        return None if isinstance(value, Mapping) else (path, _expected(hint))
    fits = {
        bool: checks.is_flag,
        int: lambda v: isinstance(v, numbers.Integral) and not checks.is_flag(v),
        float: checks.is_number,
        str: lambda v: isinstance(v, (str, os.PathLike)),
        type(None): lambda v: v is None,
    }.get(hint)
    return None if fits is None or fits(value) else (path, _expected(hint))


def wrong_init_type(cls: type, args: Mapping[str, Any]) -> tuple[str, str] | None:
    """The first init arg of ``cls`` in ``args`` whose value its type hint does not allow: (its name, the message).

    The CLI checks types itself; checkpoints, hub configs and Python do not: the text "false" for a flag was true, a
    NaN ``rounds`` or ``num_pose_samples`` passed every bound, and a number for a list failed inside torch naming no
    argument. ``Literal`` hints are :func:`check_choices`'s; ranges are each model's own checks.
    """
    try:
        hints = typing.get_type_hints(cls.__init__)
    except (NameError, TypeError, AttributeError, SyntaxError):  # a user's hint naming what only a type checker sees
        return None
    for name, hint in hints.items():
        if name in ("return", "train") or name not in args:
            continue
        wrong = _type_mismatch(args[name], hint, name)
        if wrong:
            path, what = wrong
            value = _at_path(args[name], path[len(name) :])
            return name, f"{cls.__name__}: {path} must be {what}, got {checks.shown(value)}"
    return None


def _at_path(value: Any, path: str) -> Any:
    """``value`` at an index path such as ``"[0][2]"`` (the part :func:`_type_mismatch` names)."""
    for index in re.findall(r"\[(\d+)\]", path):
        value = value[int(index)]
    return value


def names_argument(message: str, name: str) -> bool:
    """Whether ``message`` names ``name`` as a word (``mlps`` is not named by ``fp_mlps`` or ``SharedMLP``)."""
    return re.search(rf"(?<!\w){re.escape(name)}(?!\w)", message) is not None


def check_sizes(args: Mapping[str, Any], names: tuple[str, ...], owner: str) -> None:
    """Refuse a width or count among ``names`` of ``args`` that is not an integer >= 1, naming it: the nets word a
    0 or -1 by their own parameter (``proposal_radius: 0`` was reported as ``radii``, another init arg), or by the
    layer it leaves empty.

    Raises:
        ValueError: ``"{owner}: {name} must be an integer >= 1, got {value}"``.
    """
    for name in names:
        checks.check_integer(name, args[name], 1, owner=owner)


def check_dropout(value: object, owner: str) -> None:
    """Refuse a dropout probability outside [0, 1): 1 zeroed every activation (the head learned a constant), NaN
    passed torch's constructor and failed at the first training batch, and torch's own error named no model.

    Raises:
        ValueError: ``"{owner}: dropout must be a finite number >= 0 and < 1, got {value}"``.
    """
    if not (checks.is_number(value) and 0 <= value < 1):
        raise ValueError(f"{owner}: dropout must be a finite number >= 0 and < 1, got {checks.shown(value)}")


# ----------------------------------------------------------------------------- training recipe
@dataclass(frozen=True)
class TrainConfig:
    """How a model is optimised: ``model.init_args.train`` in a config (one group, every model).

    Args:
        optimizer: ``adam`` or ``adamw``.
        lr: learning rate (> 0).
        weight_decay: weight decay (>= 0).
        scheduler: ``cosine`` (eta_min 1e-6; per optimizer step over the steps the fit will take whenever the
            trainer has a step budget, ``max_steps`` > 0, with or without ``max_epochs``; else per epoch with T_max =
            max_epochs; refused with neither), ``plateau`` on the model's monitor, or ``none``.
    """

    optimizer: Literal["adam", "adamw"] = "adam"
    lr: float = 1e-3
    weight_decay: float = 0.0
    scheduler: Literal["cosine", "plateau", "none"] = "cosine"

    def __post_init__(self) -> None:
        # the CLI validates choices itself; dicts from checkpoints, hub configs and Python land here
        for name, hint in typing.get_type_hints(type(self)).items():
            choices = literal_choices(hint)
            if choices and getattr(self, name) not in choices:
                raise ValueError(f"train.{name}: {getattr(self, name)!r} is not one of {list(choices)}")
        # inf passed the bounds, and every step's loss was then NaN
        checks.check_number("train.lr", self.lr, strict=True)
        checks.check_number("train.weight_decay", self.weight_decay)


@dataclass(frozen=True)
class FloAffTrainConfig(TrainConfig):
    """:class:`TrainConfig` plus the floor-map objective and metric settings.

    Args:
        loss: ``mse``; ``aff`` = MSE + ``sdl_beta`` x Soft Dice (paper); ``navaff`` = NavAff's
            randomised 0.7-weighted MSE.
        sdl_beta: weight of the Soft Dice term for ``loss="aff"`` (>= 0).
        rank_weight: weight of the listwise ranking term added to ``loss`` (``losses.listwise_rank_loss``;
            a departure, 0 = off, the default).
        rank_temperature: temperature of that term's softmax over the predicted log-odds (> 0).
        sim_variant: SIM metric variant, ``cosine`` (FloAff paper) or ``hist`` (MoMa-Kitchen code).
        metric_reduction: ``per_sample`` or ``official_batchwise`` (64-sample chunks, MoMa-Kitchen).
        optimizer, lr, weight_decay, scheduler: see :class:`TrainConfig`.
    """

    loss: Literal["mse", "aff", "navaff"] = "mse"
    sdl_beta: float = 1.0
    rank_weight: float = 0.0
    rank_temperature: float = 1.0
    sim_variant: Literal["cosine", "hist"] = "cosine"
    metric_reduction: Literal["per_sample", "official_batchwise"] = "per_sample"

    def __post_init__(self) -> None:
        super().__post_init__()
        checks.check_numbers({"train.sdl_beta": self.sdl_beta, "train.rank_weight": self.rank_weight})
        checks.check_number("train.rank_temperature", self.rank_temperature, strict=True)


#: the arguments every model took flat before the ``train`` group (older checkpoints and hub configs)
LEGACY_FLAT_ARGS = (
    "feat_channels",
    "robot_dim",
    "loss",
    "sdl_beta",
    "optimizer",
    "lr",
    "weight_decay",
    "scheduler",
    "sim_variant",
    "metric_reduction",
    "weights",
)


def init_arg_names(cls: type) -> set[str] | None:
    """The argument names ``cls.__init__`` takes; None when it takes ``**kwargs`` (anything goes)."""
    params = inspect.signature(cls.__init__).parameters.values()
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    return {p.name for p in params if p.kind is not p.VAR_POSITIONAL} - {"self"}


def default_train(cls: type[ZooModule]) -> TrainConfig:
    """The ``train`` default of ``cls``'s constructor (the model's recipe), else its family's."""
    for c in cls.__mro__:
        if "__init__" in vars(c):
            p = inspect.signature(c.__init__).parameters.get("train")
            if p is not None and isinstance(p.default, TrainConfig):
                return p.default
    return cls.train_config()


def as_train_config(value: TrainConfig | Mapping[str, Any], default: TrainConfig, owner: str) -> TrainConfig:
    """``value`` (a train config or a dict of some of its fields) over ``default``, as ``default``'s type.

    Raises:
        ValueError: naming the model and the field for an unknown field or a bad value.
    """
    if type(value) is type(default):
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    if not isinstance(value, Mapping):
        raise TypeError(f"{owner}: train must be a {type(default).__name__} or a dict, got {type(value).__name__}")
    names = [f.name for f in dataclasses.fields(default)]
    unknown = sorted(set(value) - set(names))
    if unknown:
        raise ValueError(f"{owner}: train has no field(s) {unknown}; its fields are {names}")
    try:
        return dataclasses.replace(default, **value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{owner}: {exc}") from exc


def sample_names(batch: Batch) -> list[str]:
    """``sample_id`` of every sample of a batch (its index when missing), for error messages."""
    return [str(m.get("sample_id", i)) for i, m in enumerate(batch.get("meta") or [])]


def _checkpoint_hparams(path: Any, weights_only: bool | None) -> dict[str, Any]:
    """``hyper_parameters`` of a local checkpoint file; {} for streams, remote paths and unreadable files
    (Lightning's own loader then reports those)."""
    if not isinstance(path, (str, os.PathLike)) or not Path(path).is_file():
        return {}
    try:  # mmap: only the small hparams are read, not the weights
        ckpt = torch.load(path, map_location="cpu", weights_only=weights_only is not False, mmap=True)
    except Exception:  # noqa: BLE001
        return {}
    return dict(ckpt.get("hyper_parameters") or {}) if isinstance(ckpt, dict) else {}


# ----------------------------------------------------------------------------- common parent
#: the note on an error raised while loading a model's ``weights`` init arg (``floaff-zoo`` turns it into one line)
WEIGHTS_FAILURE_NOTE = "floaff-zoo: raised while loading the model's weights"


#: the trainer precisions every model runs at (Lightning's names): float32 weights, optionally autocast activations
SUPPORTED_PRECISIONS = ("32-true", "16-mixed", "bf16-mixed")


class ZooModule(L.LightningModule):
    """The model: any model of the zoo; --model.help CLASS lists one's arguments

    The parent of every model: training recipe, optimiser, weights, steps, export. (The first line is the title of
    the --model group in ``floaff-zoo fit --help``.)

    Args:
        train: the training recipe (:class:`TrainConfig`, or the family's extension of it); a dict of
            some of its fields is taken too and filled from the model's default recipe.
        weights: pretrained initialisation: a ``.ckpt``/``.safetensors`` path, an exported
            directory or a hub name. Not for resuming (use ``--ckpt_path``).
    """

    monitor: ClassVar[str] = "val_loss"
    mode: ClassVar[str] = "min"
    #: models without learnable parameters (C2F-Exp) set this False; ``fit`` then refuses.
    trainable: ClassVar[bool] = True
    #: list arguments an older version read as their default (None) when given ``[]``, which is now refused: a saved
    #: ``[]`` is read as None (:meth:`upgrade_init_args`), so such checkpoints and hub configs still load
    empty_means_default: ClassVar[tuple[str, ...]] = ()
    #: the type of the ``train`` argument
    train_config: ClassVar[type[TrainConfig]] = TrainConfig
    #: name of the prediction in the outputs of ``validation_step``/``test_step``
    output_key: ClassVar[str] = "pred"
    #: show the validation metrics in the progress bar (for models with one or two metrics)
    metrics_in_progress_bar: ClassVar[bool] = False

    def __init__(self, train: TrainConfig = TrainConfig(), weights: str | None = None) -> None:  # noqa: B008 - frozen
        super().__init__()
        train = as_train_config(train, default_train(type(self)), type(self).__name__)
        self.save_hyperparameters()  # the init args of the whole class chain (or the CLI's config)
        # ... with the train group as a plain dict: checkpoints stay weights_only-loadable, hub configs JSON
        self.save_hyperparameters({**self.hparams, "train": dataclasses.asdict(train)})
        try:
            self.configure_models()
        except (TypeError, ValueError, IndexError) as exc:  # a wrongly typed argument fails inside torch, unnamed
            wrong = wrong_init_type(type(self), self.hparams)
            if wrong is None or names_argument(str(exc), wrong[0]):  # a model's own check words it first
                raise
            raise ValueError(wrong[1]) from exc
        except RuntimeError as exc:  # torch's own words name no argument
            if "negative dimension" not in str(exc):
                raise
            raise ValueError(
                f"{type(self).__name__}: a size argument is negative ({exc}); every width, channel count and mlps "
                "entry must be >= 1"
            ) from exc
        wrong = wrong_init_type(type(self), self.hparams)  # what the build took: "false" for a flag, a NaN count
        if wrong is not None:
            raise ValueError(wrong[1])
        check_choices(type(self), self.hparams)  # after configure_models: its own checks word some choices first
        check_layer_sizes(self)
        self.configure_losses()
        self.configure_metrics()
        #: model tensors that ``weights`` did not provide (``load_pretrained``); evaluation commands refuse them
        self.weights_not_loaded: list[str] = []
        #: sha256 of the ``weights`` read (``load_pretrained``); a saved model records it under ``floaff_lineage``
        self.weights_sha256: str | None = None
        if weights:
            try:
                self.load_pretrained(weights)
            except Exception as exc:  # marked, so the CLI can find it inside jsonargparse's wrapping
                exc.add_note(WEIGHTS_FAILURE_NOTE)
                raise

    @property
    def train_cfg(self) -> TrainConfig:
        """The training recipe (typed view of ``hparams["train"]``)."""
        return as_train_config(self.hparams["train"], default_train(type(self)), type(self).__name__)

    # ----------------------------------------------------------------- hooks for subclasses
    def configure_models(self) -> None:
        """Build ``self.net``. Subclasses must override."""
        raise MisconfigurationException(f"{type(self).__name__} must implement configure_models()")

    def configure_losses(self) -> None:
        """Set ``self.criterion``."""

    def configure_metrics(self) -> None:
        """Set ``self.{train,val,test}_metrics`` (one MetricCollection per stage)."""
        for stage in ("train", "val", "test"):
            setattr(self, f"{stage}_metrics", MetricCollection({}, prefix=f"{stage}_"))

    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """Forward + loss. Returns (loss, prediction, extra scalars to log). Subclasses must override."""
        raise MisconfigurationException(f"{type(self).__name__} must implement model_step(batch)")

    def update_metrics(self, metrics: MetricCollection, pred: Tensor, batch: Batch) -> None:
        """Feed one batch's (detached) prediction to a stage's metrics."""

    def augment(self, batch: Batch) -> Batch:
        """Training-only augmentation that also changes the labels (AxisNet's rotation); identity here."""
        return batch

    def check_inputs(self, batch: Batch) -> None:
        """Fail early and clearly when the data does not fit the model's configuration."""
        check_batch(batch)
        need, c = int(self.hparams.get("feat_channels", 1)), batch["scene_feat"].shape[-1]
        if c < need:
            hint = "; lower model.init_args.feat_channels or add features" if "feat_channels" in self.hparams else ""
            raise SampleError(
                f"{type(self).__name__}: model.feat_channels={need} but the data gives scene_feat with {c} "
                f"channel(s) (channel 0 = target flag){hint}"
            )

    # ----------------------------------------------------------------- steps
    def _shared_step(self, batch: Batch, stage: str) -> dict[str, Tensor]:
        """Checks, (training) augmentation, loss, logging and metrics: ``{"loss", output_key}``."""
        self.check_inputs(batch)
        if stage == "train":
            batch = self.augment(batch)
        loss, pred, extra = self.model_step(batch)
        if not torch.isfinite(loss):
            raise NonFiniteError(f"{stage} loss is {loss.item()} on samples {sample_names(batch)[:4]}")
        bsz = batch["scene_xyz"].shape[0]
        # Under DDP an evaluation loss is the batch-size-weighted mean over every rank (without sync each rank kept
        # its own, and rank 0's share alone reached the report and the checkpoint monitor). It still counts the
        # at most world_size - 1 repeats DistributedSampler pads with: the loss is a batch mean, not per sample.
        sync = stage != "train"
        self.log(
            f"{stage}_loss",
            loss,
            batch_size=bsz,
            prog_bar=stage != "test",
            on_epoch=True,
            on_step=stage == "train",
            sync_dist=sync,
        )
        for name, value in extra.items():
            self.log(f"{stage}_{name}", value, batch_size=bsz, on_epoch=True, on_step=False, sync_dist=sync)
        metrics = getattr(self, f"{stage}_metrics")
        self.update_metrics(metrics, pred.detach(), batch)
        self.log_dict(
            metrics,
            batch_size=bsz,
            on_epoch=True,
            on_step=False,
            prog_bar=self.metrics_in_progress_bar and stage == "val",
        )
        return {"loss": loss, self.output_key: pred.detach()}

    def training_step(self, batch: Batch, batch_idx: int) -> Tensor:
        return self._shared_step(batch, "train")["loss"]

    def validation_step(self, batch: Batch, batch_idx: int) -> dict[str, Tensor]:
        return self._shared_step(batch, "val")

    def test_step(self, batch: Batch, batch_idx: int) -> dict[str, Tensor]:
        return self._shared_step(batch, "test")

    def setup(self, stage: str) -> None:
        """Refuse a trainer precision the networks cannot run at, before Lightning converts the weights."""
        precision = str(self.trainer.precision) if self._trainer is not None else "32-true"
        if precision not in SUPPORTED_PRECISIONS:
            raise MisconfigurationException(
                f"trainer.precision {precision!r}: {type(self).__name__} runs at {list(SUPPORTED_PRECISIONS)} (its "
                "point ops take float32 inputs, so precisions that convert the weights themselves meet float32 "
                "activations)"
            )

    def on_fit_start(self) -> None:
        if not self.trainable:
            raise MisconfigurationException(
                f"{type(self).__name__} is training-free: it has no weights to fit. "
                "Run `floaff-zoo test` or `predict` with it directly (no --ckpt_path needed)."
            )

    def configure_optimizers(self) -> Any:
        params = [p for p in self.parameters() if p.requires_grad]
        if not params:
            raise MisconfigurationException(f"{type(self).__name__} has no trainable parameters")
        t = self.train_cfg
        cls = torch.optim.AdamW if t.optimizer == "adamw" else torch.optim.Adam
        opt = cls(params, lr=t.lr, weight_decay=t.weight_decay)
        match t.scheduler:
            case "none":
                return opt
            case "cosine":
                tr = self._trainer
                epochs = int(tr.max_epochs or 0) if tr is not None else 0
                steps = int(tr.max_steps or -1) if tr is not None else -1
                if steps > 0 and tr is not None:  # a step budget (alone, max_epochs -1, or with max_epochs: per
                    # epoch it never annealed when the steps ran out first): anneal per optimizer step over the steps
                    # the fit will take, as Lightning counts them (max_steps, or fewer when the epochs end first)
                    total = max(1, int(tr.estimated_stepping_batches))
                    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=total, eta_min=1e-6)
                    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
                if epochs < 1 and tr is not None:  # T_max 1 would swing the rate between lr and eta_min every epoch
                    raise MisconfigurationException(
                        f"{type(self).__name__}: train.scheduler 'cosine' anneals over trainer.max_epochs or "
                        "trainer.max_steps, and this trainer sets neither (max_epochs -1, or max_time alone): set one, "
                        "or use train.scheduler 'none' or 'plateau'"
                    )
                t_max = max(1, epochs)  # (no trainer: a call outside fit)
                sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=t_max, eta_min=1e-6)
                return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}
            case "plateau":
                if getattr(getattr(self._trainer, "datamodule", None), "validates", True) is False:
                    raise MisconfigurationException(
                        f"{type(self).__name__}: train.scheduler 'plateau' follows {self.monitor}, but the data "
                        "module has no validation (val_scenes 0): use 'cosine' or 'none'"
                    )
                if self._trainer is not None and self._trainer.check_val_every_n_epoch is None:
                    raise MisconfigurationException(
                        f"{type(self).__name__}: train.scheduler 'plateau' steps at epoch ends on {self.monitor}, but "
                        "this trainer validates every val_check_interval steps (check_val_every_n_epoch null, as "
                        "dense_budget.yaml): the metric is missing or stale there; use 'cosine' or 'none'"
                    )
                sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode=self.mode, patience=3)
                return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": self.monitor}}
        raise MisconfigurationException(f"unknown scheduler {t.scheduler!r}")

    # ----------------------------------------------------------------- weights in and out
    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        # the random streams of the training augmentation (torch's global generator, and numpy's and Python's for
        # transforms that use them): a fit resumed from this checkpoint goes on with them instead of redrawing the
        # first epochs' noise from the seed (on_load_checkpoint)
        kind, keys, pos, has_gauss, gauss = np.random.get_state()
        checkpoint[RNG_KEY] = {  # tensors and plain numbers only: checkpoints are read with weights_only
            "torch": torch.get_rng_state(),
            "numpy": [str(kind), torch.from_numpy(np.asarray(keys, dtype=np.int64)), int(pos), int(has_gauss), gauss],
            "python": random.getstate(),
        }
        # GPU dropout and sampling draw from each device's own generator. Under DDP (a process per device) only rank
        # 0's checkpoint is written, holding none of the other ranks' streams: those fits resume without them
        trainer = self._trainer
        if torch.cuda.is_initialized() and (trainer is None or trainer.world_size == 1):
            checkpoint[RNG_KEY]["cuda"] = torch.cuda.get_rng_state_all()
        # The state dict already holds the pretrained weights: record where they came from, but
        # save ``weights: null`` so reloading the checkpoint never needs that source again.
        hp = checkpoint.get("hyper_parameters")
        if hp and hp.get("weights"):
            lineage = checkpoint.setdefault("floaff_lineage", {})
            lineage.update({"weights": hp["weights"], "weights_sha256": self.weights_sha256})
            checkpoint["hyper_parameters"] = {**hp, "weights": None}

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """A fit resumed from ``checkpoint`` restores the saved random streams (only then: loading a model to test or
        predict with leaves the caller's generators alone)."""
        trainer = self._trainer
        state = checkpoint.get(RNG_KEY)
        if not state or trainer is None or trainer.state.fn != "fit":
            return
        kind, keys, pos, has_gauss, gauss = state["numpy"]
        torch.set_rng_state(state["torch"])
        np.random.set_state((kind, keys.numpy().astype(np.uint32), pos, has_gauss, float(gauss)))
        random.setstate(state["python"])
        cuda = state.get("cuda")
        if cuda and torch.cuda.is_available() and trainer.world_size == 1:  # fewer devices: the ones it has
            torch.cuda.set_rng_state_all(cuda[: torch.cuda.device_count()])

    def load_pretrained(self, name_or_path: str) -> None:
        """Initialise from a checkpoint/hub name; layers whose shapes differ are dropped with a warning.

        The model tensors left at their initial values are listed in ``weights_not_loaded`` (``floaff-zoo
        test``/``validate``/``predict`` refuse such a model; a fit may start from it).
        """
        from floaff_zoo.hub import resolve_state_dict
        from floaff_zoo.hub.registry import sha256_file

        state, info = resolve_state_dict(name_or_path)
        # what a saved model records as its initial weights (``floaff_lineage``): a hub entry's or export's own
        # hash, else the file's
        self.weights_sha256 = info["sha256"] or sha256_file(info["source"])
        # a part configured from a file of its own (CFAR's AxisNet) keeps that file's weights: the copy ``weights``
        # carries is another stage's, which the recorded lineage would not name
        own_files = self._parts_with_own_weights()
        state = {k: v for k, v in state.items() if not k.startswith(own_files)}
        unloaded = load_matching_state(self, state, source=name_or_path)
        self.weights_not_loaded = [line for line in unloaded if not line.startswith(own_files)]

    def weights_gap(self) -> str | None:
        """What ``weights`` left unloaded, in one phrase for an error (None: everything loaded). Evaluating such a
        half-random model (``floaff-zoo test``/``validate``/``predict``, ``predict()``) is refused with it."""
        gaps = list(self.weights_not_loaded)
        if not gaps:
            return None
        return (
            f"{len(gaps)} tensor(s) or part(s) of {type(self).__name__} and its weights "
            f"{self.hparams.get('weights')} not loaded (shape in the weights vs the model's, or a part only one side "
            f"has: {'; '.join(gaps[:5])}{'; ...' if len(gaps) > 5 else ''})"
        )

    def _parts_with_own_weights(self) -> tuple[str, ...]:
        """State-dict prefixes of parts loaded from a file of their own (``teacher``, CFAR's ``axisnet``: an init
        arg naming a file and a submodule of the same name): ``weights`` need not provide them."""
        return tuple(
            f"{name}."
            for name, value in self.hparams.items()
            if name != "weights" and isinstance(value, str) and isinstance(getattr(self, name, None), torch.nn.Module)
        )

    def save_pretrained(self, directory: str | os.PathLike[str]) -> Path:
        """Write ``config.json`` + ``model.safetensors`` into ``directory``, without CLI or checkpoint.

        ``from_pretrained(directory)`` (or ``weights: <directory>``) rebuilds the model; the export is
        the hub's format (``floaff_zoo.hub.export``), weights only (no pickle). Returns ``directory``.
        """
        from floaff_zoo.hub.export import save_model_dir

        return save_model_dir(self, directory)

    @classmethod
    def from_pretrained(cls, name_or_path: str | os.PathLike[str], map_location: str = "cpu") -> ZooModule:
        """Build the model a checkpoint/export/hub entry describes and load its weights (no code is executed)."""
        from floaff_zoo.hub import load_model

        model = load_model(name_or_path, map_location=map_location, expected=cls)
        if not isinstance(model, cls):
            raise TypeError(f"{name_or_path!r} holds a {type(model).__name__}, not a {cls.__name__}")
        return model

    @classmethod
    def upgrade_init_args(cls, init_args: Mapping[str, Any]) -> dict[str, Any]:
        """``init_args`` of an older checkpoint or hub config, in today's form.

        The training arguments used to be flat (``lr: 0.001`` beside the model's own): the ones ``train``
        has move into it (an explicit ``train`` entry wins). The old shared ones this class does not take
        (AxisNet's ``loss``, C2F-Exp's ``weights``) are dropped: the old base class took them, nothing
        used them. A ``[]`` under ``empty_means_default`` becomes None, as it was read then. Anything else is kept,
        so a really unknown argument still fails in the constructor.
        """
        names = init_arg_names(cls)
        fields = {f.name for f in dataclasses.fields(cls.train_config)}
        out: dict[str, Any] = {}
        moved: dict[str, Any] = {}
        for k, v in init_args.items():
            if names is not None and k in names:
                out[k] = v
            elif k in fields:
                moved[k] = v
            elif k not in LEGACY_FLAT_ARGS:
                out[k] = v
        if moved:
            given = out.get("train") or {}
            out["train"] = {**moved, **(dataclasses.asdict(given) if dataclasses.is_dataclass(given) else given)}
        for k in cls.empty_means_default:
            if isinstance(out.get(k), (list, tuple)) and not out[k]:
                out[k] = None
        return out

    @classmethod
    def load_from_checkpoint(  # type: ignore[override]
        cls,
        checkpoint_path: str | os.PathLike[str] | IO[bytes],
        map_location: Any = None,
        hparams_file: str | os.PathLike[str] | None = None,
        strict: bool | None = None,
        weights_only: bool | None = None,
        **kwargs: Any,
    ) -> ZooModule:
        """Lightning's ``load_from_checkpoint``, also for checkpoints with the old flat training arguments
        (see :meth:`upgrade_init_args`; ``kwargs`` may use either form too: ``train={"metric_reduction": ...}`` or
        ``metric_reduction=...``). Training fields given override the checkpoint's one by one: a partial ``train``
        was completed from the class defaults (the saved recipe lost), and a flat one lost to the saved ``train``."""
        saved = {k: v for k, v in _checkpoint_hparams(checkpoint_path, weights_only).items() if not k.startswith("_")}
        over = cls.upgrade_init_args(kwargs)  # the caller's flat training fields move into its train
        train = {**_as_dict(cls.upgrade_init_args(saved).get("train")), **_as_dict(over.get("train"))}
        kwargs = {k: v for k, v in over.items() if k != "train"}
        if train:
            kwargs["train"] = train
        return super().load_from_checkpoint(
            checkpoint_path,
            map_location=map_location,
            hparams_file=hparams_file,
            strict=strict,
            weights_only=weights_only,
            **kwargs,
        )


def batch_index(batch: Batch, device: torch.device) -> Tensor | None:
    """Each sample's position in its split [B] long (``meta['index']``), or None when a sample has none: the
    metrics count a sample once per index (DDP pads the last rank-batches with repeats)."""
    index = torch.as_tensor([int(m.get("index", -1)) for m in batch["meta"]], device=device, dtype=torch.long)
    return index if (index >= 0).all() else None


def _as_dict(train: Any) -> dict[str, Any]:
    """A ``train`` init arg (a config dataclass, a mapping or None) as a plain dict."""
    if train is None:
        return {}
    return dataclasses.asdict(train) if dataclasses.is_dataclass(train) else dict(train)


# ----------------------------------------------------------------------------- floor maps
class FloAffModule(ZooModule):
    """Floor-affordance regression on the sample contract (see ``floaff_zoo.contract``).

    ``forward(batch) -> [B, M]`` scores in [0, 1], one per floor point; losses and map metrics live here.

    Args:
        feat_channels: how many ``scene_feat`` channels the net consumes (channel 0 = target flag).
        robot_dim: size of the robot descriptor.
        train: optimiser, schedule, loss and metric settings (:class:`FloAffTrainConfig`).
        weights: pretrained initialisation (see :class:`ZooModule`).
    """

    monitor: ClassVar[str] = "val_rmse"
    train_config: ClassVar[type[TrainConfig]] = FloAffTrainConfig
    output_key: ClassVar[str] = "scores"

    def __init__(
        self,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        # a negative count sliced channels off the end (scene_feat[..., :-1]) and failed in the first Linear
        checks.check_integer("feat_channels", feat_channels, owner=type(self).__name__)
        checks.check_integer("robot_dim", robot_dim, owner=type(self).__name__)
        super().__init__(train=train, weights=weights)

    def configure_losses(self) -> None:
        """Set the training and evaluation losses (``set_criteria``) from ``train.loss``."""
        self.set_criteria(self.train_cfg.loss)  # type: ignore[attr-defined]

    def set_criteria(self, name: str) -> None:
        """``self.criterion`` and ``self.eval_criterion``: (pred [B,M], target [B,M], mask [B,M]) -> scalar.

        The evaluation loss draws nothing at random (NavAff's Bernoulli weights become their expectation), so
        ``val_loss`` / ``test_loss`` repeat and validation does not move torch's global generator, which the
        training augmentation draws from.
        """
        t: FloAffTrainConfig = self.train_cfg  # type: ignore[assignment]
        self.criterion = build_loss(name, t.sdl_beta, t.rank_weight, t.rank_temperature)  # type: ignore[arg-type]
        self.eval_criterion = build_loss(name, t.sdl_beta, t.rank_weight, t.rank_temperature, deterministic=True)  # type: ignore[arg-type]

    def configure_metrics(self) -> None:
        """One MetricCollection per stage (train keeps the cheap ones)."""
        t: FloAffTrainConfig = self.train_cfg  # type: ignore[assignment]
        full = affordance_metrics(sim_variant=t.sim_variant, reduction=t.metric_reduction)
        self.val_metrics = full.clone(prefix="val_")
        self.test_metrics = full.clone(prefix="test_")
        self.train_metrics = MetricCollection({k: full[k].clone() for k in ("rmse", "mae")}, prefix="train_")

    def forward(self, batch: Batch) -> Tensor:  # pragma: no cover - abstract
        """Scores in [0, 1] for every floor point: [B, M]."""
        raise MisconfigurationException(f"{type(self).__name__} must implement forward(batch)")

    def affordance_loss(self, scores: Tensor, batch: Batch) -> Tensor:
        """Masked affordance loss of ``scores`` [B, M] against ``batch['floor_label']``.

        Training: the loss of the batch (the MSE pooled over its valid points, docs/method.md "The loss"). Evaluation:
        the mean over maps of each map's own loss. Lightning averages ``val_loss``/``test_loss`` over batches weighted
        by their sample count, so a batch-pooled MSE made the epoch value depend on the eval batch size whenever maps
        hold different numbers of valid points (padded floors); a per-map mean does not. (Every map has a valid point:
        ``check_batch`` refuses a batch with an empty one.)
        """
        label, mask = batch["floor_label"], batch["floor_mask"]
        if self.training:
            return self.criterion(scores, label, mask)
        per_map = [
            self.eval_criterion(scores[i : i + 1], label[i : i + 1], mask[i : i + 1]) for i in range(len(scores))
        ]
        return torch.stack(per_map).mean()

    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """Forward + loss. Returns (loss, scores [B, M], extra scalars to log)."""
        scores = self(batch)
        return self.affordance_loss(scores, batch), scores, {}

    def check_inputs(self, batch: Batch) -> None:
        super().check_inputs(batch)
        r, want = batch["robot"].shape[-1], self.hparams["robot_dim"]
        if r != want:
            raise SampleError(
                f"{type(self).__name__}: model.robot_dim={want} but the data gives robot descriptors of size {r}; "
                f"set model.init_args.robot_dim: {r}"
            )

    def update_metrics(self, metrics: MetricCollection, pred: Tensor, batch: Batch) -> None:
        """Map metrics of scores [B, M] (per-sample ``index`` from the metadata when every sample has one)."""
        metrics.update(pred.float(), batch["floor_label"], batch["floor_mask"], batch_index(batch, pred.device))

    def predict_step(self, batch: Batch, batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        self.check_inputs(batch)
        return self.prediction(batch, self(batch))

    @staticmethod
    def prediction(batch: Batch, scores: Tensor, **extra: Tensor) -> dict[str, Any]:
        """A ``predict_step`` record (CPU): scores [B, M] and the floor points [B, M, 3] they belong to, both NaN
        where ``floor_mask`` [B, M] is False (the batch's padding, whose scores would otherwise win an argmax at the
        robot's own origin), the target [B, 3], ``best_pose`` [B, 3] (the top-scored floor point, facing the target,
        robot base frame: the pose the success-rate callback stands on at top-1, ties broken by the sample's
        ``index``), meta, and any ``extra`` tensors (e.g. the yaw used)."""
        mask = batch["floor_mask"].cpu()
        scores = scores.detach().cpu().float()
        floor = batch["floor_xyz"].cpu()
        target = batch["target_xyz"].cpu()
        nan = float("nan")
        scored = mask & torch.isfinite(scores)  # a view with no finite score gets a NaN pose, not an error mid-run
        poses = [
            best_pose(floor[i], scores[i], scored[i], target[i], seed=int(meta.get("index", i)))[0]
            if bool(scored[i].any())
            else (nan, nan, nan)
            for i, meta in enumerate(batch["meta"])
        ]
        out = {
            "scores": scores.masked_fill(~mask, nan),
            "floor_xyz": floor.masked_fill(~mask[..., None], nan),
            "floor_mask": mask,
            "target_xyz": target,
            "best_pose": torch.tensor(poses, dtype=torch.float32).reshape(len(poses), 3),
            "meta": batch["meta"],
        }
        out.update({k: v.detach().cpu() for k, v in extra.items()})
        return out


def load_matching_state(module: torch.nn.Module, state: dict[str, Tensor], source: str) -> list[str]:
    """Load ``state`` into ``module``, skipping (and reporting) keys with mismatched shapes.

    Returns:
        what did not load, one ``"key: why"`` line each: the tensors of ``module`` left as they were (``(shape in
        state) vs (module's shape)`` for a skipped key, ``not in the weights`` for a key ``state`` lacks; keys a
        module's own loading hook fills in, e.g. a legacy buffer, are not listed), and ``<part>.*: ...`` for a part of
        the weights the module has no place for (a CFAR trained over the prior, built without it, scored on
        without its prior: evaluation must refuse that too).
    Raises:
        ValueError: when nothing at all matches (almost surely the wrong checkpoint).
    """
    import warnings

    own = module.state_dict()
    # keys a submodule's own loading hook adapts whatever their saved shape (the prior grid's task names: it puts
    # the saved task layers in its own order, or refuses other tasks); skipped, the layers loaded unaligned
    adapts = {
        f"{name}.{key}" if name else key
        for name, sub in module.named_modules()
        for key in getattr(sub, "state_keys_it_adapts", ())
    }
    keep, skipped = {}, []
    for k, v in state.items():
        if k in own and (own[k].shape == v.shape or k in adapts):
            keep[k] = v
        elif k in own:
            skipped.append(f"{k}: {tuple(v.shape)} vs {tuple(own[k].shape)}")
    if not keep:
        raise ValueError(f"no parameter of {source} matches {type(module).__name__}; wrong checkpoint?")
    if skipped:
        warnings.warn(f"{source}: skipped {len(skipped)} layer(s) with other shapes: {skipped[:5]}", stacklevel=2)
    unused = sorted({k.split(".")[0] for k in state if k not in own})
    if unused:
        # e.g. a CFAR/prior entry's ``axisnet.*`` when this model was built without an AxisNet: its yaw then
        # comes from another source; from_pretrained rebuilds the whole model instead
        warnings.warn(
            f"{source}: weights of {unused} are not used (this {type(module).__name__} has no such part); "
            "use from_pretrained, or configure the part, to load them",
            stacklevel=2,
        )
    result = module.load_state_dict(keep, strict=False)
    absent = [f"{k}: not in the weights" for k in result.missing_keys if k not in state]
    parts = [f"{p}.*: in the weights, no such part in this {type(module).__name__}" for p in unused]
    return skipped + absent + parts
