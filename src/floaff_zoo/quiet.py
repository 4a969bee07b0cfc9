"""Quiet by default: the known noise of third-party libraries is filtered out of the command line's output.

What is filtered (each item was seen in ``make demo`` output, and none of it needs action from the user):

* robosuite, at import: the "No private macro file" advice (3 lines) and the optional robosuite_models /
  mink IK notices, printed again by every worker process that builds a robot model;
* Lightning's INFO banners and tips ("GPU available", "TPU available", "Tip: ... litlogger", "Seed set to",
  the model summary table, "Restoring states from ..."): the CLI prints one line per stage instead;
* warnings about data-loader workers, logging intervals, checkpoint folders, ``ckpt_path`` callbacks,
  LightningCLI's ``args``, and deprecations inside Lightning and jsonargparse.

``floaff-zoo --verbose`` (or ``FLOAFF_ZOO_VERBOSE=1``) shows everything; worker processes inherit the
environment variable. Standard library only: the simulator, which must not import torch or Lightning, calls
:func:`quiet_robosuite` in its workers too.
"""

from __future__ import annotations

import logging
import os
import re
import warnings

VERBOSE_ENV = "FLOAFF_ZOO_VERBOSE"

#: messages of robosuite's "robosuite_logs" logger that are dropped
ROBOSUITE_NOISE = (
    r"No private macro file found",
    r"It is recommended to use a private macro file",
    r"To setup, run: .*setup_macros\.py",
    r"Could not import robosuite_models",
    r"Could not load the mink-based whole-body IK",
)
ROBOSUITE_LOGGER = "robosuite_logs"

#: Lightning loggers whose INFO records are banners, tips and summaries (their warnings still show)
LIGHTNING_INFO_LOGGERS = (
    "lightning.pytorch.utilities.rank_zero",
    "lightning.fabric.utilities.rank_zero",
    "lightning.fabric.utilities.seed",
    "lightning.pytorch.callbacks.model_summary",
)

#: (message regex, category, module regex) of warnings that are dropped
WARNING_NOISE: tuple[tuple[str, type[Warning], str], ...] = (
    (r".*does not have many workers.*", Warning, ""),
    (r".*GPU available but not used.*", Warning, ""),
    (r".*LightningCLI's args parameter is intended.*", Warning, ""),
    (r".*is an invalid version and will not be supported.*", DeprecationWarning, ""),
    (r".*The number of training batches .* is smaller than the logging interval.*", Warning, ""),
    (r".*sync_dist=True.*", Warning, ""),
    (r".*Checkpoint directory .* exists and is not empty.*", Warning, ""),
    (r".*module\(s\) in eval mode.*", Warning, ""),
    (r".*isinstance\(treespec, LeafSpec\)` is deprecated.*", Warning, ""),
    (r".*when using `ckpt_path`, callbacks used to create the checkpoint need to be provided.*", Warning, ""),
    (r".*skip_none parameter was deprecated.*", Warning, ""),  # jsonargparse, through Lightning's CLI
    (r".*configure_optimizers` returned `None`.*", Warning, ""),  # the canonical prior has no optimiser
    (r".*Total length of `list` across ranks is zero.*", Warning, ""),  # val_scenes 0: no validation loaders
    (r".*", DeprecationWarning, r"jsonargparse.*"),  # jsonargparse's own deprecation notices
)


def verbose() -> bool:
    """True when the user asked for all output (``--verbose`` / ``FLOAFF_ZOO_VERBOSE``)."""
    return os.environ.get(VERBOSE_ENV, "").strip().lower() not in ("", "0", "false", "no", "off")


def set_verbose(on: bool) -> None:
    """Record the choice in the environment, so that worker processes started later follow it."""
    if on:
        os.environ[VERBOSE_ENV] = "1"
    else:
        os.environ.pop(VERBOSE_ENV, None)


class _DropMatching(logging.Filter):
    """Drops records whose message matches one of ``patterns`` (a logger filter survives setLevel calls)."""

    def __init__(self, patterns: tuple[str, ...]) -> None:
        super().__init__()
        self.regex = re.compile("|".join(f"(?:{p})" for p in patterns))

    def filter(self, record: logging.LogRecord) -> bool:
        return not self.regex.search(record.getMessage())


def quiet_robosuite() -> None:
    """Drop robosuite's import-time notices (call before importing robosuite; idempotent; no-op when verbose)."""
    if verbose():
        return
    logger = logging.getLogger(ROBOSUITE_LOGGER)
    if not any(isinstance(f, _DropMatching) for f in logger.filters):
        logger.addFilter(_DropMatching(ROBOSUITE_NOISE))


def quiet_lightning() -> None:
    """Lightning's banners off (its loggers at WARNING) and the known warnings ignored; no-op when verbose."""
    if verbose():
        return
    for name in LIGHTNING_INFO_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)
    for message, category, module in WARNING_NOISE:
        warnings.filterwarnings("ignore", message=message, category=category, module=module)


def install() -> None:
    """Everything above, for the ``floaff-zoo`` process (the CLI entry point calls it once)."""
    quiet_robosuite()
    quiet_lightning()
