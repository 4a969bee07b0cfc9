"""The ``floaff-zoo`` command line.

Trainer commands (``fit``, ``validate``, ``test``, ``predict``) are a LightningCLI in subclass
mode, so ``model: {class_path: PointNet2Module}`` and ``--model CFARModule`` resolve. The other
commands (``generate``, ``curriculum``, ``table``, ``montage``, ``hub``, ``demo``) are dispatched to their own
modules' ``main`` before LightningCLI sees the arguments.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import importlib
import inspect
import re
import sys
import typing
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

import lightning as L
import yaml
from jsonargparse import Namespace
from lightning.pytorch.callbacks import ModelCheckpoint, TQDMProgressBar
from lightning.pytorch.cli import LightningCLI, SaveConfigCallback
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo import quiet, runtime
from floaff_zoo._version import __version__
from floaff_zoo.atomic import atomic_write_text
from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.contract import NonFiniteError, SampleError
from floaff_zoo.data.base import FloAffDataModule
from floaff_zoo.models.base import WEIGHTS_FAILURE_NOTE, ZooModule
from floaff_zoo.nn import _fps_ext, ops
from floaff_zoo.runs import (
    CHECKPOINT_KEYS,
    RunError,
    config_value,
    config_values,
    is_config_file,
    load_checkpoint,
    resolve_ckpt_alias,
)

TRAINER_COMMANDS = ("fit", "validate", "test", "predict")
#: commands that evaluate a trained model: ``--ckpt_path best|last`` and strict ``weights`` apply to them
EVAL_COMMANDS = ("validate", "test", "predict")
#: non-trainer command -> "module:function" taking argv and returning an exit code
OTHER_COMMANDS: dict[str, tuple[str, str]] = {
    "generate": ("floaff_zoo.sim.generate:main", "generate a FloAff-Kitchen-style benchmark in MuJoCo"),
    "curriculum": ("floaff_zoo.curriculum:main", "run a PFAL curriculum (a list of fit stages)"),
    "table": ("floaff_zoo.report.table:main", "aggregate report.json files into paper-style tables"),
    "montage": ("floaff_zoo.report.montage:main", "compare the test figures of several runs side by side"),
    "hub": ("floaff_zoo.hub.cli:main", "list / info / pull / push / verify pretrained checkpoints"),
    "demo": ("floaff_zoo.demo:main", "run the end-to-end demo on generated data"),
}


class CLIError(RuntimeError):
    """A user-facing command-line error (printed without a traceback)."""


#: the errors a trainer command prints in one line (exit code 2) instead of a traceback; the curriculum names the
#: stage in front of them (a NonFiniteError: a diverged loss or NaN scores, with the samples named)
USER_ERRORS: tuple[type[BaseException], ...] = (
    CLIError,
    RunError,
    SampleError,
    MisconfigurationException,
    NonFiniteError,
)


def _import_registries() -> None:
    """Import the model and data packages so bare class names resolve in configs."""
    import floaff_zoo.data  # noqa: F401
    import floaff_zoo.models  # noqa: F401


def explicit_model_args(args: list[str]) -> list[str]:
    """Model init-arg keys given on the command line: ``--model.init_args.k v``, ``--model.init_args.k=v`` or the
    short ``--model.k v`` -> ``["k", ...]`` (dotted for nested keys)."""
    keys = []
    for tok in args:
        if not tok.startswith("--model."):
            continue
        key = tok[len("--model.") :].split("=", 1)[0]
        key = key.removeprefix("init_args.")
        if key and key not in ("class_path", "init_args", "dict_kwargs", "help"):
            keys.append(key)
    return keys


def _import_class(path: Any) -> Any:
    """The class a dotted path names (``floaff_zoo.models.X`` and ``floaff_zoo.models.x.X`` are one), else the path."""
    try:
        mod, name = str(path).rsplit(".", 1)
        return getattr(importlib.import_module(mod), name)
    except (ValueError, ImportError, AttributeError):
        return path


def _upgrade_legacy_model_args(model: Any) -> None:
    """A checkpoint written before the ``train`` group lands its flat training args (``lr``, ``loss``...) in the
    model's ``dict_kwargs``: move them into ``init_args.train`` (``ZooModule.upgrade_init_args``)."""
    extra = dict(model.get("dict_kwargs") or {}) if model is not None else {}
    cls = _import_class(model.get("class_path")) if extra else None
    if not (isinstance(cls, type) and issubclass(cls, ZooModule)):
        return
    upgraded = cls.upgrade_init_args(extra)
    for key, value in upgraded.pop("train", {}).items():
        model[f"init_args.train.{key}"] = value
    model["dict_kwargs"] = upgraded


def _weights_failure(exc: BaseException) -> BaseException | None:
    """The error that loading a model's ``weights`` raised (marked with ``WEIGHTS_FAILURE_NOTE`` by ``ZooModule``),
    found in the chain of exceptions jsonargparse wraps it in; None when ``exc`` did not come from there."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        if WEIGHTS_FAILURE_NOTE in getattr(cur, "__notes__", ()):
            return cur
        cur = cur.__cause__ or cur.__context__
    return None


def _frames(tb: TracebackType | None) -> list[FrameType]:
    """The frames of a traceback, outermost first."""
    frames = []
    while tb is not None:
        frames.append(tb.tb_frame)
        tb = tb.tb_next
    return frames


def _in_jsonargparse(frame: FrameType) -> bool:
    """Whether ``frame`` runs jsonargparse's code (which wraps the errors of the classes it instantiates)."""
    return str(frame.f_globals.get("__name__", "")).startswith("jsonargparse")


def _instantiated_part(exc: BaseException) -> str | None:
    """The config key (``model``, ``data``, ``trainer.callbacks``...) whose class jsonargparse was instantiating
    when ``exc`` escaped it: jsonargparse names it only in the ``component`` its instantiation loop is at, a local
    of its own code (None when that is not found: the error is then printed without the key)."""
    for frame in _frames(exc.__traceback__):
        dest = getattr(frame.f_locals.get("component"), "dest", None) if _in_jsonargparse(frame) else None
        if isinstance(dest, str):
            return dest
    return None


def _user_error(exc: BaseException) -> BaseException | None:
    """The first error in the chain of ``exc`` that was raised outside jsonargparse (by the class being
    instantiated), past the union-type errors jsonargparse wraps it in."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        frames = _frames(cur.__traceback__)
        if frames and not _in_jsonargparse(frames[-1]):
            return cur
        cur = cur.__cause__ or cur.__context__
    return None


def _one_line(text: str) -> str:
    """``text`` on one line (the messages of torch and jsonargparse span several)."""
    return " ".join(text.split())


_LIMIT_STAGES = ("train", "val", "test", "predict")


def integer_limits(args: list[str]) -> dict[str, int]:
    """stage -> its ``limit_<stage>_batches`` where the value given last (the command line and ``--config`` files in
    order, as the parser applies them) is an integer: a literal such as ``1``, or an int in the file's YAML."""
    given: dict[str, Any] = {}
    for i, arg in enumerate(args):
        config = config_value(args, i)
        if config is not None:
            trainer = _yaml_mapping(config).get("trainer")
            for stage in _LIMIT_STAGES:
                if isinstance(trainer, dict) and f"limit_{stage}_batches" in trainer:
                    given[stage] = trainer[f"limit_{stage}_batches"]
            continue
        for stage in _LIMIT_STAGES:
            flag = f"--trainer.limit_{stage}_batches"
            if arg == flag and i + 1 < len(args):
                text = args[i + 1]
            elif arg.startswith(flag + "="):
                text = arg.partition("=")[2]
            else:
                continue
            given[stage] = int(text) if text.strip().isdigit() else text
    return {s: v for s, v in given.items() if isinstance(v, int) and not isinstance(v, bool)}


def config_files(args: list[str]) -> list[str]:
    """The ``--config`` values of ``args``, in order, that name existing files (a value that is no file is YAML
    text, or a missing file jsonargparse names itself)."""
    return [v for v in config_values(args) if is_config_file(v)]


def check_config_file(path: str) -> None:
    """Raise CLIError naming ``path`` unless it is UTF-8 YAML holding a mapping: with several ``--config`` files
    the parser's own messages ("Unexpected config", a position in "<unicode string>", a UnicodeDecodeError
    traceback) do not say which file."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise CLIError(f"--config {path}: unreadable ({_one_line(str(exc))})") from exc
    except yaml.YAMLError as exc:
        raise CLIError(f"--config {path}: not valid YAML ({_one_line(str(exc))})") from exc
    if data is None:
        raise CLIError(f"--config {path}: empty file")
    if not isinstance(data, dict):
        kind = type(data).__name__
        raise CLIError(f"--config {path}: expected a mapping of settings (e.g. 'trainer:'), got a {kind}")


def _yaml_mapping(value: str) -> dict[str, Any]:
    """A ``--config`` value's top-level mapping: its file's, or the value read as YAML text where it names no file
    (jsonargparse takes both; only files were read, so an inline ``limit_train_batches: 1`` ran every batch). {}
    when it is not a mapping: the parser reports that itself."""
    try:
        data = yaml.safe_load(Path(value).read_text() if is_config_file(value) else value)
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


def _model_init_args(config: dict[str, Any]) -> dict[str, Any]:
    """The ``model.init_args`` mapping of a config file's top level ({} when it has none)."""
    model = config.get("model")
    init = model.get("init_args") if isinstance(model, dict) else None
    return init if isinstance(init, dict) else {}


def _plain(value: Any) -> Any:
    """A parsed config value as plain data (namespaces as dicts), to compare two of them."""
    return value.as_dict() if isinstance(value, Namespace) else value


def _check_schedule_values(trainer: Namespace) -> None:
    """Trainer settings whose 0 Lightning meets as a ZeroDivisionError mid-fit (a traceback naming none of them)."""
    for key, none_means in (
        ("check_val_every_n_epoch", "validate by val_check_interval alone"),
        ("accumulate_grad_batches", None),
    ):
        check_integer(f"trainer.{key}", trainer.get(key), 1, error=CLIError, none_means=none_means)
    interval = trainer.get("val_check_interval")
    ok = interval is None or (
        not isinstance(interval, bool)
        and (interval >= 1 if isinstance(interval, int) else isinstance(interval, float) and 0 < interval <= 1)
    )
    if not ok:
        raise CLIError(
            "trainer.val_check_interval must be a fraction of an epoch in (0, 1], a number of batches >= 1 "
            f"or null, got {interval!r}"
        )


class SaveConfig(SaveConfigCallback):
    """Lightning's config.yaml of a run, with the batch limits given as integers written as integers: the parser
    stores ``1`` as ``1.0`` (see ``FloAffCLI._integer_limits``), and rerunning a config that says ``1.0`` would run
    every batch. A fit's file leaves out where it resumed from (``ckpt_path``) and a fixed logger ``version`` (a
    resumed curriculum stage pins it): ``floaff-zoo test --config <run>/config.yaml`` read them, tested the older
    checkpoint the fit resumed from without ``--ckpt_path``, and logged into the fit's own folder, replacing its
    metrics.csv and config.yaml."""

    integer_limits: dict[str, int] = {}
    _log_dir: str | None = None

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        # trainer.log_dir is a broadcast under DDP: read here on every rank, never in save_config (rank 0 only,
        # where a collective would wait for the other ranks forever)
        if self.save_to_log_dir and not self.already_saved:
            self._log_dir = trainer.log_dir
        super().setup(trainer, pl_module, stage)

    def save_config(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        """Called on rank 0 right after the file is written."""
        path = Path(self._log_dir or "") / self.config_filename
        if not self.save_to_log_dir or not path.is_file():
            return
        data = yaml.safe_load(path.read_text())
        trainer_cfg = data.get("trainer") if isinstance(data, dict) else None
        if not isinstance(trainer_cfg, dict):
            return
        changed = bool(self.integer_limits)
        for stage_name, value in self.integer_limits.items():
            trainer_cfg[f"limit_{stage_name}_batches"] = value
        if stage == "fit":
            if data.get("ckpt_path") is not None:
                data["ckpt_path"], changed = None, True
            loggers = trainer_cfg.get("logger")
            for logger in loggers if isinstance(loggers, list) else [loggers]:
                init = logger.get("init_args") if isinstance(logger, dict) else None
                if isinstance(init, dict) and init.get("version") is not None:
                    init["version"], changed = None, True
        if not changed:
            return
        text = yaml.safe_dump(data, sort_keys=False)
        atomic_write_text(path, text)


class FloAffCLI(LightningCLI):
    """LightningCLI with the zoo's defaults and guards."""

    def add_arguments_to_parser(self, parser: Any) -> None:
        parser.set_defaults({"trainer.default_root_dir": "runs"})

    def parse_arguments(self, parser: Any, args: Any) -> None:
        raw = args if isinstance(args, list) else (sys.argv[1:] if args is None else [])
        self._raw_args = [str(a) for a in raw]  # what the user typed (``_integer_limits``)
        for path in config_files(self._raw_args):
            check_config_file(path)
        self._explicit_model_args = explicit_model_args(self._raw_args)
        super().parse_arguments(parser, args)

    def _set_seed(self) -> None:
        """Lightning's seeding, after :meth:`_check_values` (the first hook after parsing)."""
        self._check_values()
        super()._set_seed()

    def _check_values(self) -> None:
        """Values the parser takes but Lightning or a class would refuse with a traceback or a misleading message,
        named in one line. Also run by :func:`check_trainer_args` (a curriculum's pre-check of every stage)."""
        seed = self._get(self.config, "seed_everything")
        if isinstance(seed, int) and not isinstance(seed, bool) and not 0 <= seed <= 2**32 - 1:
            raise CLIError(f"seed_everything: {seed} is not a seed (0 to {2**32 - 1}, true for a random one)")
        cfg = self.config[self.subcommand]
        trainer = cfg.trainer
        if not isinstance(trainer, Namespace):  # `trainer: null` in a config: an AttributeError below
            raise CLIError(f"trainer: expected a mapping of trainer settings, got {trainer!r}")
        # Lightning's message for a NaN misleads ("use only one of them")
        check_number(
            "trainer.gradient_clip_val", trainer.get("gradient_clip_val"), error=CLIError, none_means="no clipping"
        )
        _check_schedule_values(trainer)
        train = cfg.model.get("init_args", Namespace()).get("train") if isinstance(cfg.model, Namespace) else None
        if train is not None and not isinstance(train, (Namespace, dict)):  # a TypeError deep in jsonargparse
            raise CLIError(f"model.init_args.train: expected a mapping of training settings, got {train!r}")

    def _parse_ckpt_path(self) -> None:
        """Lightning rebuilds the model config from the hyper-parameters of a ``--ckpt_path`` file (so the trained
        architecture is used whatever the config says). That would also silently drop evaluation-time choices
        given on the command line (e.g. ``--model.init_args.eval_yaw_source gt``): those are applied again.
        ``best``/``last`` are turned into their file first: Lightning reads the hyper-parameters of a file only."""
        self._resolve_ckpt_alias()
        self._check_ckpt_file()
        sub = self.config.get("subcommand")
        before = self.config[sub].get("model") if sub else None
        before = before.clone() if before is not None else None
        super()._parse_ckpt_path()
        if sub:
            _upgrade_legacy_model_args(self.config[sub].get("model"))
        keys = getattr(self, "_explicit_model_args", [])
        if before is None:
            return
        after = self.config[sub].model
        if _import_class(after.get("class_path")) is not _import_class(before.get("class_path")):
            return  # another model class: the command-line values belong to the config's class
        self._note_dropped_model_args(before, after, keys)
        if not keys:
            return
        kept = []
        for key in keys:
            full = f"init_args.{key}"
            if full in before:
                after[full] = before[full]
                kept.append(key)
        if kept and self.config[sub].get("ckpt_path") and Path(str(self.config[sub].ckpt_path)).is_file():
            print(
                f"floaff-zoo: model hyper-parameters from {self.config[sub].ckpt_path}, except "
                f"{', '.join(kept)} (given on the command line)",
                file=sys.stderr,
            )

    def _note_dropped_model_args(self, before: Namespace, after: Namespace, explicit: list[str]) -> None:
        """Say which model settings of the ``--config`` files the checkpoint's hyper-parameters replaced (an
        evaluation-time choice in a config file, e.g. ``eval_yaw_source: gt``, was dropped without a word); those
        typed on the command line are applied again (``_parse_ckpt_path``)."""
        ckpt = self.config[self.config.get("subcommand")].get("ckpt_path")
        if not ckpt or not Path(str(ckpt)).is_file():
            return
        old, new = before.get("init_args") or Namespace(), after.get("init_args") or Namespace()
        # keys the --config files set, a run's own config.yaml left out (its values are the run's: ``weights`` is
        # blanked in the checkpoint on purpose, derived records such as ``axisnet_arch`` are added there)
        given = {
            k
            for v in config_values(self._raw_args)  # files and inline YAML alike
            if not (is_config_file(v) and (Path(v).parent / "checkpoints").is_dir())
            for k in _model_init_args(_yaml_mapping(v))
        }
        dropped = [
            k
            for k in sorted(given)
            if not any(e == k or e.startswith(f"{k}.") for e in explicit)  # applied again: not dropped
            and k in vars(old)
            and k in vars(new)
            and _plain(old[k]) != _plain(new[k])
        ]
        if dropped:
            print(
                f"floaff-zoo: the --config value(s) of model {', '.join(dropped)} are replaced by those of {ckpt} "
                "(give one on the command line, --model.init_args.<name>, to use it)",
                file=sys.stderr,
            )

    def _resolve_ckpt_alias(self) -> None:
        """``--ckpt_path best|last`` of an evaluation command, and ``last`` of ``fit`` (resume), -> the checkpoint
        file (``runs.resolve_ckpt_alias``). Lightning's own ``last`` looks in the new run's folder, where a fit
        finds nothing and trains from scratch."""
        sub = self.config.get("subcommand")
        cfg = self.config[sub] if sub else None
        alias = cfg.get("ckpt_path") if cfg is not None else None
        if sub in EVAL_COMMANDS and alias in ("best", "last"):
            cfg.ckpt_path = resolve_ckpt_alias(alias, self._run_dir(cfg), self._configured_class("model"))
        elif sub == "fit" and alias == "last":
            # only the run a --config came from: the newest run of the class under default_root_dir may be another
            # experiment's (a Styles fit resumed a Layouts run that way)
            run = self._run_dir(cfg)
            if not (run / "checkpoints").is_dir():
                raise CLIError(
                    "fit --ckpt_path last resumes the run a --config <run>/config.yaml came from; none was given "
                    "(pass that config, or the checkpoint file)"
                )
            cfg.ckpt_path = resolve_ckpt_alias(alias, run, self._configured_class("model"))
            print(f"floaff-zoo fit: resuming {cfg.ckpt_path}", file=sys.stderr)

    def _check_ckpt_file(self) -> None:
        """A ``--ckpt_path`` file must be a Lightning checkpoint: Lightning's own loaders fail on a truncated file,
        a text file or a bare state dict with a traceback that never names it. The check memory-maps the file, so a
        large one costs little. A path that is no file is refused here for ``fit`` (before a run folder is made;
        ``last`` was resolved to its file) and by ``_guard_eval`` otherwise; Lightning's ``hpc``/``registry`` resumes
        are refused."""
        sub = self.config.get("subcommand")
        ckpt = self.config[sub].get("ckpt_path") if sub else None
        if ckpt in ("hpc", "registry"):  # Lightning's SLURM / model-registry resumes: tracebacks, and an empty run
            raise CLIError(f"--ckpt_path {ckpt}: not supported by floaff-zoo; pass a checkpoint file or last")
        if sub == "fit" and ckpt is not None and ckpt != "last" and not Path(str(ckpt)).is_file():
            raise CLIError(f"--ckpt_path {ckpt}: no such file")
        if ckpt is None or not Path(str(ckpt)).is_file():
            return
        try:
            load_checkpoint(str(ckpt), "--ckpt_path ", CHECKPOINT_KEYS)
        except RunError as exc:
            raise CLIError(str(exc)) from exc

    def instantiate_classes(self) -> None:
        """Instantiate as Lightning does; an error loading ``model.init_args.weights`` (unknown hub name, corrupt
        or missing file), and a ``ValueError``/``MisconfigurationException`` by which a configured class rejects
        its init args, become one ``CLIError`` line instead of jsonargparse's traceback of union types. Other
        errors (a ``TypeError`` of a bug, say) keep their traceback."""
        try:
            super().instantiate_classes()
        except Exception as exc:
            error = self._weights_error(exc) or self._init_error(exc)
            if error is None:
                raise
            raise error from exc

    def _weights_error(self, exc: BaseException) -> CLIError | None:
        """The one-line error for a failure to load ``model.init_args.weights`` (None: ``exc`` is another)."""
        cause = _weights_failure(exc)
        if cause is None:
            return None
        weights, message = self._configured_weights(), _one_line(str(cause))
        named = "" if weights in message else f" {weights}"  # hub messages name the file or the name already
        return CLIError(f"--model.init_args.weights{named}: {message}")

    def _init_error(self, exc: BaseException) -> CLIError | None:
        """The one-line error for a configured class (model, data, a callback...) whose ``__init__`` rejected its
        init args, naming the config key and the class where jsonargparse shows them (None: ``exc`` is another
        error)."""
        cause = _user_error(exc)
        if not isinstance(cause, (ValueError, MisconfigurationException)):
            return None
        part = _instantiated_part(exc)
        cls = self._configured_class(part) if part else None
        where = f"{part}{f' ({cls})' if cls else ''}: " if part else ""
        return CLIError(f"{where}{_one_line(str(cause))}")

    def _configured_class(self, key: str) -> str | None:
        """The class name the config gives ``key`` (``model``, ``data``...); None for lists (callbacks)."""
        sub = self.config.get("subcommand")
        value = self.config[sub].get(key) if sub else None
        path = value.get("class_path") if isinstance(value, Namespace) else None
        return str(path).rsplit(".", 1)[-1] if path else None

    def _configured_weights(self) -> str:
        """The ``weights`` the model config names (for messages)."""
        model = self.config[self.config.get("subcommand")].get("model") if self.config.get("subcommand") else None
        init_args = model.get("init_args") if model is not None else None
        return str(init_args.get("weights") if init_args is not None else None)

    def _integer_limits(self, trainer: Any) -> None:
        """``limit_<stage>_batches: 1`` means one batch. Lightning types these ``float | int``, float first, so the
        parser reads ``1`` as 1.0, which Lightning takes as a fraction: every batch. A limit last given as an integer
        (``--trainer.limit_val_batches 1`` or a ``--config`` file's ``trainer: {limit_val_batches: 1}``) is set back
        to an int here, after the parser's last type check; ``1.0`` keeps meaning every batch."""
        for stage, value in integer_limits(getattr(self, "_raw_args", [])).items():
            setattr(trainer, f"limit_{stage}_batches", value)

    def before_instantiate_classes(self) -> None:
        cfg = self.config[self.subcommand]
        trainer = cfg.trainer  # a mapping: checked in _check_values
        if trainer.logger in (None, True):
            model_cfg = cfg.model
            name = str(getattr(model_cfg, "class_path", "model")).rsplit(".", 1)[-1].lower()
            trainer.logger = {
                "class_path": "lightning.pytorch.loggers.CSVLogger",
                "init_args": {"save_dir": trainer.default_root_dir, "name": name},
            }

    def instantiate_trainer(self, **kwargs: Any) -> L.Trainer:
        cfg = self.config_init[self.subcommand]["trainer"]
        self._integer_limits(cfg)
        extra = list(kwargs.pop("callbacks", None) or [])
        user = list(cfg.get("callbacks") or [])
        if cfg.get("enable_progress_bar", True) is not False and not any(isinstance(c, TQDMProgressBar) for c in user):
            # Rich breaks non-TTY logs; TQDM with a slow refresh keeps CI logs short.
            extra.append(TQDMProgressBar(refresh_rate=1 if sys.stdout.isatty() else 20, leave=True))
        model = self.model
        if (
            cfg.get("enable_checkpointing", True) is not False
            and not any(isinstance(c, ModelCheckpoint) for c in user)
            and self.subcommand == "fit"
        ):
            from floaff_zoo.callbacks.checkpoint import LatestCheckpoint  # here: the callbacks package is not light

            # a data module without validation (val_scenes 0) leaves nothing to monitor: last.ckpt only
            monitor = model.monitor if getattr(self.datamodule, "validates", True) else None
            extra.append(
                LatestCheckpoint(
                    monitor=monitor,
                    mode=model.mode,
                    save_last=True,
                    save_top_k=1 if monitor else 0,
                    filename=("epoch{epoch:03d}-" + monitor + "{" + monitor + ":.4f}") if monitor else None,
                    auto_insert_metric_name=False,
                )
            )
        if self.subcommand == "test":
            from floaff_zoo.callbacks import TestReport

            if not any(isinstance(c, TestReport) for c in user):
                extra.append(TestReport())  # every `floaff-zoo test` writes report.json/report.md
        if self.subcommand == "predict":
            from floaff_zoo.callbacks import PredictionWriter

            if not any(isinstance(c, PredictionWriter) for c in user):
                extra.append(PredictionWriter())  # predictions.npz/.json (Lightning would drop the records)
        # Lightning merges {**trainer_config, **kwargs}: pass the configured callbacks along too.
        trainer = super().instantiate_trainer(callbacks=[*user, *extra], **kwargs)
        for callback in trainer.callbacks:
            if isinstance(callback, SaveConfig):
                callback.integer_limits = integer_limits(getattr(self, "_raw_args", []))
        return trainer

    def _guard_eval(self) -> None:
        """Refuse to evaluate a model without trained weights, with a missing ``--ckpt_path`` file, or with
        ``weights`` that left some of its tensors untrained."""
        ckpt = self.config_init[self.subcommand].get("ckpt_path")
        if ckpt is None and self.model.trainable and not self.model.hparams.get("weights"):
            raise CLIError(
                f"`floaff-zoo {self.subcommand}` needs trained weights: pass --ckpt_path <file|best|last> "
                "(e.g. `floaff-zoo test --config <run>/config.yaml --ckpt_path best`) or "
                "--model.init_args.weights <hub name|file>; refusing to evaluate a randomly initialised model"
            )
        if ckpt is not None and not Path(ckpt).is_file():
            raise CLIError(f"--ckpt_path {ckpt}: no such file")
        if ckpt is None:
            self._guard_partial_weights()

    def _guard_partial_weights(self) -> None:
        """``weights`` that do not fit the model load leniently (right for initialising a fit); evaluating such a
        half-random model would write a meaningless report: refuse, naming the weights and the tensors."""
        gap = self.model.weights_gap()
        if gap is None:
            return
        raise CLIError(
            f"--model.init_args.weights {self.model.hparams.get('weights')}: {gap}; `floaff-zoo {self.subcommand}` "
            "needs weights that fit the configured model (same class and architecture init args), or pass --ckpt_path"
        )

    @staticmethod
    def _run_dir(cfg: Any) -> Path:
        """Where ``best``/``last`` are looked up: the run a ``--config <run>/config.yaml`` came from
        (the folder next to its ``checkpoints/``), else ``trainer.default_root_dir`` (``cfg``: the subcommand's
        parsed config)."""
        for path in reversed(cfg.get("config") or []):
            folder = Path(str(getattr(path, "absolute", path))).parent
            if (folder / "checkpoints").is_dir():
                return folder
        return Path(str(cfg.trainer.default_root_dir))

    def before_fit(self) -> None:
        if not self.model.trainable:
            raise CLIError(
                f"{type(self.model).__name__} is training-free (no weights to fit); "
                "use `floaff-zoo test`/`predict` with it directly"
            )
        self._check_run_dir()
        self._stage_line(None)

    def _before_eval(self) -> None:
        self._guard_eval()
        self._check_run_dir()
        self._stage_line(self.config_init[self.subcommand].get("ckpt_path"))

    before_validate = _before_eval
    before_test = _before_eval
    before_predict = _before_eval

    def _check_run_dir(self) -> None:
        """Refuse a run folder (the logger's ``version_N``) that is a file or a dangling link: Lightning counts only
        folders when it picks the next version, and its ``makedirs`` then failed in the setup hook with a
        ``FileExistsError``."""
        log_dir = getattr(getattr(self.trainer, "logger", None), "log_dir", None)
        if log_dir and (Path(log_dir).exists() or Path(log_dir).is_symlink()) and not Path(log_dir).is_dir():
            raise CLIError(f"run folder {log_dir}: a file or link is in its place; move it away and run again")

    def _stage_line(self, ckpt: str | None) -> None:
        """One line per stage (Lightning's own banners and model summary are off unless --verbose)."""
        n = sum(p.numel() for p in self.model.parameters())
        weights = f" with weights {ckpt}" if ckpt else ""
        print(
            f"floaff-zoo {self.subcommand}: {type(self.model).__name__} ({n / 1e6:.3f} M params){weights} on "
            f"{type(self.datamodule).__name__} -> {self.trainer.log_dir}",
            flush=True,
        )

    def _run_subcommand(self, subcommand: str) -> None:
        try:
            super()._run_subcommand(subcommand)
        except BaseException:
            self._drop_empty_run_dir()
            raise

    def _drop_empty_run_dir(self) -> None:
        """Remove the run folder a failed command left empty (Lightning makes ``version_N`` before the data module's
        ``setup`` can refuse its files), so the next run is not ``version_N+1`` next to a folder with nothing in it.
        The logger's own ``log_dir``, not ``trainer.log_dir``: that one is a collective under DDP."""
        trainer = getattr(self, "trainer", None)
        log_dir = getattr(getattr(trainer, "logger", None), "log_dir", None)
        if trainer is None or not log_dir or not trainer.is_global_zero:
            return
        run = Path(log_dir)
        root = Path(str(trainer.default_root_dir)).absolute()
        for folder in (run, run.parent):  # version_N, then its <model> folder if nothing else is in it
            if folder.absolute() == root or root not in folder.absolute().parents:
                return
            try:
                folder.rmdir()  # only an empty folder: a run that wrote anything keeps it
            except OSError:
                return

    def after_fit(self) -> None:
        cb = self.trainer.checkpoint_callback
        best = getattr(cb, "best_model_path", "") or getattr(cb, "last_model_path", "")
        score = getattr(cb, "best_model_score", None)
        metric = f" ({cb.monitor} {float(score):.4f})" if score is not None and getattr(cb, "monitor", None) else ""
        print(
            f"floaff-zoo fit: done after {self.trainer.current_epoch} epoch(s); checkpoint {best or 'none'}{metric}",
            flush=True,
        )


def _print_overview() -> None:
    print(f"floaff-zoo {__version__}: floor-affordance model zoo\n")
    print("usage: floaff-zoo <command> [options]\n\ntrainer commands (LightningCLI; `floaff-zoo fit --help`):")
    for c in TRAINER_COMMANDS:
        print(f"  {c}")
    print("\nother commands (`floaff-zoo <command> --help`):")
    for c, (_, text) in OTHER_COMMANDS.items():
        print(f"  {c:<11} {text}")
    print(
        "\noptions:\n  -h, --help  show this overview\n  --version   print the version\n"
        "  --verbose   (anywhere) show all third-party output: warnings, Lightning banners, robosuite notices\n"
        "              (test/validate's own --verbose true|false, Lightning's results table, keeps its value)"
    )


def _dispatch(command: str, argv: list[str], from_python: bool) -> int:
    """Run a non-trainer command. Those whose ``main`` takes ``raise_errors`` (curriculum, demo) print their
    errors in one line and return 2 at the console, and raise them to a Python caller, as ``main`` does."""
    target, _ = OTHER_COMMANDS[command]
    mod_name, fn_name = target.split(":")
    try:
        mod = importlib.import_module(mod_name)
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.startswith("floaff_zoo"):
            raise CLIError(f"`floaff-zoo {command}` is not available in this build ({exc.name} missing)") from exc
        raise
    fn = getattr(mod, fn_name)
    if "raise_errors" in inspect.signature(fn).parameters:
        return int(fn(argv, raise_errors=from_python) or 0)
    return int(fn(argv) or 0)


class _ParseOnlyCLI(FloAffCLI):
    """Parses a trainer command as :func:`run_lightning` does; loads, seeds, instantiates and runs nothing."""

    def _parse_ckpt_path(self) -> None:
        pass  # a curriculum's later checkpoints do not exist yet

    def _set_seed(self) -> None:
        self._check_values()  # seeds nothing: only the checks

    def before_instantiate_classes(self) -> None:
        pass

    def instantiate_classes(self) -> None:
        pass

    def after_instantiate_classes(self) -> None:
        pass

    def _run_subcommand(self, subcommand: str) -> None:
        pass


#: jsonargparse's words for a key no class takes: (class path, group or None, the key)
_UNKNOWN_OPTION = re.compile(
    r"class_path '(?P<cls>[\w.]+)': (?:Group '(?P<group>\w+)' does not accept option|Option) '(?P<key>\w+)'"
)
#: ... and for a key the parser has no place for (``trainer.max_epoch``, a typo at the top level)
_UNKNOWN_KEY = re.compile(r"(?:does not accept option '|unrecognized arguments: --)(?P<key>[\w.]+)")


def _accepted_keys(cls_path: str | None, group: str | None) -> list[str]:
    """The keys a class's ``__init__`` takes, or those of its dataclass argument ``group`` ([] when unknown)."""
    try:
        module, _, name = (cls_path or "").rpartition(".")
        init = getattr(importlib.import_module(module), name).__init__
        if group is None:
            return [k for k in inspect.signature(init).parameters if k != "self"]
        kind = typing.get_type_hints(init).get(group)
        return [f.name for f in dataclasses.fields(kind)] if dataclasses.is_dataclass(kind) else []
    except (ImportError, AttributeError, ValueError, TypeError, NameError):
        return []


def _lookup(config: dict[str, Any], path: list[str]) -> tuple[bool, Any]:
    """Whether a config file's mapping sets ``path`` (e.g. ``["model", "init_args", "train", "lrr"]``), and the
    value it sets; a class's settings count also where the file gives them without ``init_args``, as jsonargparse
    takes them."""
    node: Any = config
    for i, part in enumerate(path):
        if not isinstance(node, dict):
            return False, None
        if part not in node:
            return _lookup(node, path[i + 1 :]) if part == "init_args" else (False, None)
        node = node[part]
    return True, node


def _sets(config: dict[str, Any], path: list[str]) -> bool:
    """Whether a config file's mapping sets ``path`` (see :func:`_lookup`)."""
    return _lookup(config, path)[0]


def _key_hint(message: str, args: list[str]) -> str:
    """For a parse error over an unknown key: the close names it may be a typo of, and the ``--config`` files that
    set it ('' when there is nothing to add). jsonargparse names the key, not the file it came from."""
    message = _one_line(message)
    section = re.search(r'Parser key "(\w+)"', message)
    m = _UNKNOWN_OPTION.search(message)
    if m and section:
        key, accepted = m["key"], _accepted_keys(m["cls"], m["group"])
        path = [section[1], "init_args", *([m["group"]] if m["group"] else []), key]
    elif (m := _UNKNOWN_KEY.search(message)) and m["key"].startswith("trainer."):
        key, accepted = m["key"].removeprefix("trainer."), _accepted_keys("lightning.Trainer", None)
        path = ["trainer", key]
    else:
        return ""
    close = difflib.get_close_matches(key, accepted, n=3, cutoff=0.6)
    files = [f for f in config_files(args) if _sets(_yaml_mapping(f), path)]
    parts = [f"did you mean {' or '.join(map(repr, close))}?"] if close else []
    parts += [f"{'.'.join(path)} is set in {', '.join(files)}"] if files else []
    return f" ({'; '.join(parts)})" if parts else ""


#: jsonargparse's words for a value of the wrong type: the key of its section (``trainer.max_epochs``, ``model``)
_SECTION_KEY = re.compile(r'^Parser key "(?P<key>[\w.]+)"')
#: ... and, inside a class's settings, the nested key (``train.lr`` of ``model``)
_NESTED_KEY = re.compile(r"class_path '[\w.]+': Parser key \"(?P<key>[\w.]+)\"")


def _value_hint(message: str, args: list[str]) -> str:
    """For a parse error over a value of the wrong type: the ``--config`` file that set it ('' when the value came
    from a flag or no file is found). jsonargparse checks each file as it loads it, so the first file whose value
    at the key is the refused one (its text is what the message quotes) is the one it refused."""
    message = _one_line(message)
    section, nested = _SECTION_KEY.search(message), _NESTED_KEY.search(message)
    if section is None:
        return ""
    path = section["key"].split(".") + (["init_args", *nested["key"].split(".")] if nested else [])
    for f in config_files(args):
        found, value = _lookup(_yaml_mapping(f), path)
        quoted = re.escape(str(value))
        if found and re.search(rf"(?:Given|Got) value: {quoted}(?: - | Given value|$)", message):
            return f" ({'.'.join(path)} is set in {f})"
    return ""


#: jsonargparse's words for a class name it cannot import (a bare name, or a dotted path with a mistyped last part)
_UNKNOWN_CLASS = re.compile(
    r"Expected a dot import path string: (?P<bare>[\w.]+)|Problem with given class_path '(?P<path>[\w.]+)': "
    r"(?:module '[\w.]+' has no attribute|No module named)"
)


def _subclass_names(base: type) -> list[str]:
    """Names of the classes under ``base`` that a config may name (the bases of ``*.base`` modules left out)."""
    out, todo = [], list(base.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if not inspect.isabstract(cls) and not cls.__module__.endswith(".base"):
            out.append(cls.__name__)
    return sorted(set(out))


def _class_hint(message: str) -> str:
    """For a ``model``/``data`` class that does not import (a typo of its name): the close class names, else the
    known ones ('' for other errors). jsonargparse says only that the name is no import path."""
    message = _one_line(message)
    section, m = _SECTION_KEY.search(message), _UNKNOWN_CLASS.search(message)
    if m is None or section is None or section["key"] not in ("model", "data"):
        return ""
    _import_registries()
    known = _subclass_names(ZooModule if section["key"] == "model" else FloAffDataModule)
    name = (m["bare"] or m["path"]).rpartition(".")[2]
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
    return f" (did you mean {' or '.join(map(repr, close))}?)" if close else f" ({section['key']} classes: {known})"


def _parse_hint(message: str, args: list[str]) -> str:
    """What a parse error leaves out: close names of an unknown key or class, the file that set a key or a refused
    value."""
    return _class_hint(message) + (_key_hint(message, args) or _value_hint(message, args))


def check_trainer_args(args: list[str]) -> Namespace:
    """Parse a trainer command (``["fit", "--config", ...]``) without running it: an unknown key, a value of the
    wrong type or a missing config file raises a one-line ``CLIError`` (``floaff-zoo curriculum`` checks every
    stage this way before the first one trains). Values a class rejects in its ``__init__`` are not checked.
    Returns the command's parsed config (``model``, ``data``, ``trainer``...)."""
    try:
        cli = _build_cli(_ParseOnlyCLI, args, {"exit_on_error": False})
    except argparse.ArgumentError as exc:
        raise CLIError(_one_line(str(exc)) + _parse_hint(str(exc), args)) from exc
    return cli.config[cli.subcommand]


def run_lightning(args: list[str]) -> FloAffCLI:
    """Run a trainer command; returns the CLI object (tests read ``cli.trainer``/``cli.model``).

    Raises:
        CLIError: the arguments do not parse (an unknown key, a value of the wrong type), in one line naming the key
            and, where a ``--config`` file set it, the file: jsonargparse printed its 50-line usage before the error.
    """
    try:
        return _build_cli(FloAffCLI, args, {"version": __version__, "exit_on_error": False})
    except argparse.ArgumentError as exc:
        command = args[0] if args and args[0] in TRAINER_COMMANDS else "<command>"
        hint = _parse_hint(str(exc), args)
        raise CLIError(f"{_one_line(str(exc))}{hint} (`floaff-zoo {command} --help` lists the options)") from exc


def _build_cli(cls: type[FloAffCLI], args: list[str], parser_kwargs: dict[str, Any]) -> FloAffCLI:
    """``cls`` over the zoo's model and data bases with the zoo's defaults, on ``args``."""
    import warnings

    _import_registries()
    # `floaff-zoo demo`/`curriculum` call this with args while sys.argv holds their own command.
    warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter is intended.*")
    # no prefixes of a flag: --trainer.limit_train_batch 1 ran as a fraction (integer_limits reads exact flags only)
    parser_kwargs = {**parser_kwargs, "allow_abbrev": False, "prog": "floaff-zoo"}
    return cls(
        ZooModule,
        FloAffDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=0,
        save_config_callback=SaveConfig,
        save_config_kwargs={"overwrite": True},
        parser_kwargs=parser_kwargs,
        auto_configure_optimizers=False,
        args=args,
    )


def _take_verbose(argv: list[str]) -> tuple[list[str], bool]:
    """``argv`` without the zoo's ``--verbose`` flag (any command, any position), and whether it was there. A
    ``--verbose`` followed by ``true`` or ``false`` is Lightning's option of ``test`` and ``validate`` (print the
    results table) and stays for their parser."""
    out, found = [], False
    for i, arg in enumerate(argv):
        value = argv[i + 1].strip().lower() if i + 1 < len(argv) else ""
        if arg == "--verbose" and value not in ("true", "false"):
            found = True
            continue
        out.append(arg)
    return out, found


def main(args: list[str] | None = None) -> int:
    """Entry point of ``floaff-zoo`` and ``python -m floaff_zoo``."""
    argv, verbose = _take_verbose(list(sys.argv[1:] if args is None else args))
    if verbose:
        quiet.set_verbose(True)
    quiet.install()
    try:
        runtime.keep_freed_memory()  # large activations reuse freed memory instead of fresh pages (runtime.py)
        ops.portable_requested()  # a mistyped FLOAFF_ZOO_CPU_PATHS fails here, not at the first batch
        _fps_ext.backend_requested()  # the same for FLOAFF_ZOO_FPS_BACKEND
    except ValueError as exc:
        print(f"floaff-zoo: error: {exc}", file=sys.stderr)
        return 2
    if not argv or argv[0] in ("-h", "--help"):
        _print_overview()
        return 0
    if argv[0] == "--version":
        print(__version__)
        return 0
    try:
        if argv[0] in OTHER_COMMANDS:
            return _dispatch(argv[0], argv[1:], from_python=args is not None)
        if argv[0] not in TRAINER_COMMANDS:
            raise CLIError(f"unknown command {argv[0]!r}; choose from {list(TRAINER_COMMANDS) + list(OTHER_COMMANDS)}")
        run_lightning(argv)
        return 0
    except USER_ERRORS as exc:
        print(f"floaff-zoo: error: {exc}", file=sys.stderr)
        if args is not None:  # called from Python (tests, curriculum): let callers see the exception
            raise
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
