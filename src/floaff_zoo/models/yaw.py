"""Where a model's target yaw comes from: one home for the yaw sources CFAR and the canonical prior share.

Sources (``YawSource``):

* ``gt``: ``batch["target_yaw"]``, the simulator's (or annotation's) yaw. **Privileged** at test time: a
  robot does not get it; configs that use it at test time say so in their table label.
* ``axisnet``: a frozen AxisNet (``floaff_zoo.nn.axisnet``) on the cropped cloud with the target flag.
* ``axisnet_manhattan``: AxisNet's yaw snapped onto the kitchen's axes (``floaff_zoo.nn.yaw.manhattan_yaw``
  with AxisNet as the reference): the dominant orientation of the vertical faces near the target, known
  modulo 90 deg, fixes the angle; AxisNet only picks which of the four directions is the front.
* ``manhattan``: the same snapping with the direction to the robot as the reference (training-free; wrong
  when the robot stands more than 45 deg off the front normal, as in most side views).
* ``heading``: the direction from the target back to the robot (training-free, coarse: off by the viewing
  angle).
* ``none``: no rotation (the w/o-Align ablation).

AxisNet checkpoints are loaded through the hub's state-dict reader; the architecture, source and sha256
are returned as ``arch`` so a model can rebuild the AxisNet from its own checkpoint without the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import torch
from lightning.pytorch.utilities import rank_zero_warn
from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch import Tensor

from floaff_zoo.checks import check_number
from floaff_zoo.contract import Batch
from floaff_zoo.frames import PRIVILEGED_YAW  # kept in __all__: its home is frames.py, below models and report
from floaff_zoo.hub.io import resolve_state_dict
from floaff_zoo.hub.registry import HubError, sha256_file
from floaff_zoo.models.base import sample_names
from floaff_zoo.nn.axisnet import AxisNet, axis_inputs, yaw_from_vector
from floaff_zoo.nn.yaw import heading_yaw, manhattan_yaw

__all__ = [
    "PRIVILEGED_YAW",
    "YawSource",
    "build_axisnet",
    "check_manhattan_radius",
    "check_yaw_sources",
    "configured_axisnet",
    "estimate_yaw",
    "yaw_or_nan",
    "keep_configured_axisnet",
    "load_axisnet",
]

YawSource = Literal["gt", "axisnet", "axisnet_manhattan", "manhattan", "heading", "none"]
#: sources that need an AxisNet
AXISNET_YAW = frozenset({"axisnet", "axisnet_manhattan"})


def build_axisnet(arch: dict[str, Any], owner: str) -> tuple[AxisNet, float]:
    """A frozen AxisNet from a recorded ``arch`` (widths, head, crop_radius). Returns (net, crop radius).

    Raises:
        MisconfigurationException: naming ``axisnet_arch`` for a record that is not one, or whose crop_radius is not a
            finite number > 0 (a NaN one cropped every point away and blamed the samples; a text is no recorded number).
    """
    try:
        net = AxisNet(4, list(arch["widths"]), list(arch["head"]))
        radius = arch["crop_radius"]
    except (KeyError, TypeError) as exc:
        raise MisconfigurationException(f"{owner}: axisnet_arch {arch!r} is not a recorded AxisNet ({exc})") from exc
    check_number("axisnet_arch.crop_radius", radius, strict=True, owner=owner, error=MisconfigurationException)
    radius = float(radius)
    net.requires_grad_(False).eval()
    return net, radius


def load_axisnet(name: str, owner: str) -> tuple[AxisNet, float, dict[str, Any]]:
    """Load an AxisNetModule checkpoint / hub entry frozen. Returns (net, crop radius, arch record).

    Raises:
        MisconfigurationException: naming ``axisnet`` and the file or name, for one that does not load (a missing
            or corrupt file, an unknown hub name: a FileNotFoundError was a traceback through jsonargparse).
    """
    try:
        state, info = resolve_state_dict(name)
    except (OSError, ValueError, HubError) as exc:
        raise MisconfigurationException(f"{owner}: axisnet {name!r}: {exc}") from exc
    cls = str(info.get("class_path") or "")
    if cls and not cls.endswith("AxisNetModule"):
        raise MisconfigurationException(f"{owner}: axisnet {name!r} is a {cls} checkpoint, not an AxisNetModule")
    args = info.get("init_args") or {}
    source = Path(str(info.get("source", name)))
    arch = {
        "crop_radius": args.get("crop_radius", 1.3),  # build_axisnet checks it: float() of a text named nothing
        "widths": list(args.get("widths") or [64, 128, 256]),
        "head": list(args["head"]) if args.get("head") is not None else [128, 64],
        "source": str(name),
        "sha256": info.get("sha256") or (sha256_file(source) if source.is_file() else None),
    }
    net, radius = build_axisnet(arch, owner)
    arch["crop_radius"] = radius
    sub = {k[len("net.") :]: v for k, v in state.items() if k.startswith("net.")}
    missing, unexpected = net.load_state_dict(sub, strict=False)
    if missing or unexpected:
        raise MisconfigurationException(
            f"{owner}: axisnet {name!r} does not fit AxisNet{arch['widths']}: "
            f"missing {missing}, unexpected {unexpected}"
        )
    return net, radius, arch


def yaw_or_nan(yaw: Tensor | None, scores: Tensor) -> Tensor:
    """The yaw used [B] for a predict record; NaN for every sample when there was no rotation (source ``none``)."""
    if yaw is None:
        return torch.full((scores.shape[0],), float("nan"), device=scores.device)
    return yaw


def configured_axisnet(
    axisnet: str | None, recorded: dict[str, Any] | None, owner: str
) -> tuple[AxisNet | None, float, dict[str, Any] | None]:
    """The frozen AxisNet a model is configured with. Returns (net or None, crop radius, arch record).

    A recorded ``axisnet_arch`` rebuilds the net (its weights come with the model's checkpoint, the file is not
    needed) unless ``axisnet`` names another AxisNet than the recorded one: that one is loaded (swapping the
    orientation estimator of a trained model; :func:`keep_configured_axisnet` then keeps its weights).
    """
    if recorded and (not axisnet or str(recorded.get("source")) == str(axisnet)):
        net, radius = build_axisnet(recorded, owner)
        return net, radius, recorded
    if axisnet:
        return load_axisnet(axisnet, owner)
    return None, 0.0, None


def check_manhattan_radius(radius: float, owner: str) -> None:
    """Refuse a ``manhattan_radius`` that is not a finite number > 0: the face estimate found no point within it, and
    every sample kept its reference yaw without a word."""
    check_number("manhattan_radius", radius, strict=True, owner=owner, error=MisconfigurationException)


def check_yaw_sources(sources: dict[str, str], axisnet: AxisNet | None, owner: str) -> None:
    """Fail at construction when a configured yaw source ({argument name: source}) needs a missing AxisNet."""
    for name, src in sources.items():
        if src in AXISNET_YAW and axisnet is None:
            raise MisconfigurationException(
                f"{owner}: {name} resolves to {src!r} but no AxisNet is given; set model.init_args.axisnet to an "
                "AxisNetModule checkpoint or hub name"
            )


def keep_configured_axisnet(
    checkpoint: dict[str, Any], axisnet: AxisNet | None, arch: dict[str, Any] | None, prefix: str = "axisnet."
) -> None:
    """Make a checkpoint being loaded carry the configured AxisNet instead of its own (or none).

    Used when a trained model is evaluated with another AxisNet than the one it was saved with (e.g.
    ``floaff-zoo test --ckpt_path m.ckpt --model.init_args.axisnet better.ckpt``): the checkpoint's
    ``axisnet.*`` weights and ``axisnet_arch`` are replaced so the strict state-dict load succeeds.
    """
    if axisnet is None or not arch or "state_dict" not in checkpoint:
        return
    hp = checkpoint.setdefault("hyper_parameters", {})
    stored = (hp.get("axisnet_arch") or {}).get("sha256")
    has_keys = any(k.startswith(prefix) for k in checkpoint["state_dict"])
    own = arch.get("sha256")
    # a configured AxisNet without a sha256 was rebuilt from an architecture record, its weights still to come from
    # the checkpoint: only one loaded from a file of its own (a sha256) replaces the checkpoint's
    if has_keys and (not own or stored == own):
        return
    if has_keys:  # meant for a swap, but an AxisNet retrained at the configured path is swapped in just the same
        was = hp.get("axisnet_arch") or {}
        rank_zero_warn(
            f"the checkpoint's AxisNet (sha256 {str(stored)[:12] if stored else 'unrecorded'}, trained as "
            f"{was.get('source') or 'unrecorded'}) is replaced by the "
            f"configured one (sha256 {str(own)[:12]}, {arch.get('source')}): the configured AxisNet wins",
            category=UserWarning,
        )
    for k in [k for k in checkpoint["state_dict"] if k.startswith(prefix)]:
        del checkpoint["state_dict"][k]
    for k, v in axisnet.state_dict().items():
        checkpoint["state_dict"][prefix + k] = v
    hp["axisnet_arch"] = dict(arch)


def axisnet_yaw(batch: Batch, axisnet: AxisNet, radius: float) -> Tensor:
    """AxisNet's front-yaw estimate [B] (rad, robot frame), no grad."""
    with torch.no_grad():
        x, mask = axis_inputs(
            batch["scene_xyz"],
            batch["scene_feat"],
            batch["scene_mask"],
            batch["target_xyz"],
            radius,
            sample_names(batch),
        )
        return yaw_from_vector(axisnet(x, mask))


def estimate_yaw(
    batch: Batch, source: str, axisnet: AxisNet | None, axis_radius: float, manhattan_radius: float, owner: str
) -> Tensor | None:
    """The target's front yaw [B] from ``source`` (see the module docstring); None for ``none``."""
    if source in AXISNET_YAW and axisnet is None:
        raise MisconfigurationException(f"{owner}: yaw source {source!r} needs an AxisNet (model.init_args.axisnet)")
    match source:
        case "gt":
            return batch["target_yaw"].reshape(-1)
        case "axisnet":
            return axisnet_yaw(batch, axisnet, axis_radius)
        case "axisnet_manhattan":
            ref = axisnet_yaw(batch, axisnet, axis_radius)
            return manhattan_yaw(batch["scene_xyz"], batch["scene_mask"], batch["target_xyz"], manhattan_radius, ref)
        case "manhattan":
            return manhattan_yaw(batch["scene_xyz"], batch["scene_mask"], batch["target_xyz"], manhattan_radius)
        case "heading":
            return heading_yaw(batch["target_xyz"])
        case "none":
            return None
    raise MisconfigurationException(f"{owner}: unknown yaw source {source!r}; use one of {YawSource.__args__}")
