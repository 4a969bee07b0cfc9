"""A per-task average of floor labels on a grid in the canonical frame (the no-network prior).

The canonical frame is CFAR's (target at the origin, its front normal along -y, ``floaff_zoo.nn.cfar``).
:class:`CanonicalLabelGrid` keeps, for every task, the sum and the count of the training labels that fell
into each cell of a square grid centred on the target; the prior at a point is the (optionally Gaussian
smoothed) mean of its cell. Cells that no training label reached read as ``fill``; with smoothing, only cells
beyond the kernel's reach (three sigmas) of every label do.

Cells are centred on multiples of ``cell`` (``centred``, the default). The generated label grids are
target-aligned lattices with the target at a lattice point, so their cells sit at multiples of their spacing
in the canonical frame. A grid whose cell *edges* lie there (the binning of checkpoints written before the grid
recorded it, kept for them) assigns each label by floating-point rounding, and a yaw estimate 0.3 deg off moves
a point 1.5 m from the target by 8 mm, across an edge (docs/method.md, "The prior's cells").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from floaff_zoo.checks import check_number, check_numbers
from floaff_zoo.nn.ops import check_finite

__all__ = ["CanonicalLabelGrid"]


def _encode_names(names: Sequence[str]) -> Tensor:
    """Task names -> a uint8 tensor (their UTF-8 text, one per line): a buffer, saved with the state."""
    return torch.tensor(list("\n".join(names).encode()), dtype=torch.uint8)


def _decode_names(codes: Tensor) -> list[str]:
    """The task names ``_encode_names`` wrote."""
    return bytes(codes.to(torch.uint8).tolist()).decode().split("\n")


class CanonicalLabelGrid(nn.Module):
    """Sums and counts of labels per task on a ``size x size`` grid of ``cell`` metres (buffers, saved).

    Args:
        tasks: task names, one grid each; cell: cell size (m); extent: half-width of the grid (m);
        smooth_sigma_cells: std of the Gaussian applied to sums and counts before the division (0 = none);
        fill: value read in cells that no label reached;
        centred: cell centres at multiples of ``cell`` (True) or cell edges there (False: checkpoints written
            before this switch existed, whose state has no ``centred`` entry, load as False).
    """

    #: state entries whose saved shape may differ: ``_load_from_state_dict`` realigns the task layers by them
    state_keys_it_adapts = ("task_names",)

    def __init__(
        self,
        tasks: Sequence[str],
        cell: float = 0.05,
        extent: float = 3.0,
        smooth_sigma_cells: float = 1.0,
        fill: float = 0.0,
        centred: bool = True,
    ) -> None:
        super().__init__()
        # NaN passed these comparisons (and inf the next ones) and failed later in float-to-int conversions naming
        # no argument; a negative or NaN sigma silently turned the smoothing off, a NaN fill made unseen cells NaN
        owner = type(self).__name__
        check_numbers({"cell": cell, "extent": extent}, strict=True, owner=owner)
        if not cell < extent:
            raise ValueError(f"{owner}: need cell < extent, got cell={cell}, extent={extent}")
        check_number("smooth_sigma_cells", smooth_sigma_cells, owner=owner, note="0 = no smoothing")
        check_number("fill", fill, high=1.0, owner=owner)  # a label value
        if centred and abs(extent / cell - round(extent / cell)) > 1e-6:
            # centres sit at -extent + k cell: off the lattice's multiples of cell, labels fall on edges again
            raise ValueError(
                f"CanonicalLabelGrid: centred cells need extent to be a multiple of cell, got cell={cell}, "
                f"extent={extent}"
            )
        if isinstance(tasks, str) or not tasks:  # a text was read letter by letter as tasks
            raise ValueError(f"CanonicalLabelGrid: tasks must be a list of at least one task name, got {tasks!r}")
        # a repeated name's second grid was never read or filled; a newline split the saved names into others
        if not all(isinstance(t, str) and t and "\n" not in t for t in tasks) or len(set(tasks)) < len(tasks):
            raise ValueError(f"CanonicalLabelGrid: tasks must be distinct one-line names, got {list(tasks)}")
        self.tasks = list(tasks)
        self.cell, self.extent = float(cell), float(extent)
        self.size = int(math.ceil(2 * extent / cell))
        self.smooth_sigma_cells, self.fill = float(smooth_sigma_cells), float(fill)
        self.register_buffer("sums", torch.zeros(len(self.tasks), self.size, self.size, dtype=torch.float64))
        self.register_buffer("counts", torch.zeros(len(self.tasks), self.size, self.size, dtype=torch.float64))
        # saved with the sums: the binning they were accumulated with, and which task each layer holds
        self.register_buffer("centred", torch.tensor(bool(centred)))
        self.register_buffer("task_names", _encode_names(self.tasks))
        # the geometry the sums were binned with: a state of another (cell, extent) and the same size loaded silently
        self.register_buffer("geometry", torch.tensor([self.cell, self.extent], dtype=torch.float64))
        self._lower = self._lower_edge(bool(centred))
        self._maps: tuple[tuple, Tensor] | None = None  # (buffer versions, mean maps): read() runs every batch

    def task_index(self, names: Sequence[str]) -> Tensor:
        """Task names [B] -> grid indices [B] (long). Raises ValueError naming an unknown task."""
        out = []
        for name in names:
            if name not in self.tasks:
                raise ValueError(f"CanonicalLabelGrid: task {name!r} has no grid; known tasks: {self.tasks}")
            out.append(self.tasks.index(name))
        return torch.as_tensor(out, dtype=torch.long, device=self.sums.device)

    def _load_from_state_dict(
        self,
        state_dict: dict[str, Any],
        prefix: str,
        local_metadata: dict[str, Any],
        strict: bool,
        missing_keys: list[str],
        unexpected_keys: list[str],
        error_msgs: list[str],
    ) -> None:
        key = prefix + "centred"
        recorded = key in state_dict
        names_key = prefix + "task_names"
        named = names_key in state_dict
        if named:
            self._align_tasks(state_dict, prefix, error_msgs)
        geometry_key = prefix + "geometry"
        measured = geometry_key in state_dict
        if measured and not torch.allclose(state_dict[geometry_key].double().cpu(), self.geometry.cpu()):
            cell, extent = state_dict[geometry_key].tolist()
            error_msgs.append(
                f"CanonicalLabelGrid: the saved grid has cell {cell} m and extent {extent} m, this model is "
                f"configured for cell {self.cell} m and extent {self.extent} m"
            )
        super()._load_from_state_dict(
            state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs
        )
        if not recorded:  # saved before the grid recorded its binning: accumulated with edges on the lattice
            if key in missing_keys:
                missing_keys.remove(key)
            self.centred.fill_(False)
        if not named and names_key in missing_keys:  # saved before the grid named its tasks: read in today's order
            missing_keys.remove(names_key)
        if not measured and geometry_key in missing_keys:  # saved before the grid recorded its geometry
            missing_keys.remove(geometry_key)
        self._lower = self._lower_edge(bool(self.centred))

    def _align_tasks(self, state_dict: dict[str, Any], prefix: str, error_msgs: list[str]) -> None:
        """Put a saved grid's task layers in this grid's task order (``state_dict`` is the loader's own copy); an
        error when the saved grid holds other tasks. Without this a grid loaded under another task list (another
        order, a ``tasks`` argument given with a checkpoint) read each task from another task's layer."""
        saved = _decode_names(state_dict[prefix + "task_names"])
        if saved == self.tasks:
            return
        if sorted(saved) != sorted(self.tasks):
            error_msgs.append(
                f"CanonicalLabelGrid: the saved grid holds tasks {saved}, this model is configured for {self.tasks}"
            )
            return
        order = torch.as_tensor([saved.index(t) for t in self.tasks], dtype=torch.long)
        for name in ("sums", "counts"):
            if prefix + name in state_dict:
                state_dict[prefix + name] = state_dict[prefix + name].index_select(0, order)
        state_dict[prefix + "task_names"] = _encode_names(self.tasks)

    def _lower_edge(self, centred: bool) -> float:
        """Coordinate (m) of the grid's lower cell edge on both axes (kept as a float: no device sync per read)."""
        return -self.extent - (0.5 * self.cell if centred else 0.0)

    def _check_batch(self, task: Tensor, xy: Tensor) -> None:
        """Raise ValueError unless task [B] and xy [B, M, 2] (a [1] task was broadcast over the batch, an xy of 3
        columns had its z binned into the inside flag)."""
        if xy.ndim != 3 or xy.shape[-1] != 2:
            raise ValueError(f"CanonicalLabelGrid: xy must be [B, M, 2], got {list(xy.shape)}")
        if list(task.shape) != [xy.shape[0]]:
            raise ValueError(
                f"CanonicalLabelGrid: task must be [{xy.shape[0]}] for xy {list(xy.shape)}, got {list(task.shape)}"
            )

    def cells(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """Canonical xy [..., 2] -> (flat cell index [...] long, inside-grid flag [...] bool)."""
        if xy.shape[-1] != 2:
            raise ValueError(f"CanonicalLabelGrid: xy must be [..., 2], got {list(xy.shape)}")
        ij = torch.floor((xy - self._lower) / self.cell).long()
        inside = ((ij >= 0) & (ij < self.size)).all(-1)
        ij = ij.clamp(0, self.size - 1)
        return ij[..., 1] * self.size + ij[..., 0], inside

    @torch.no_grad()
    def add(self, task: Tensor, xy: Tensor, label: Tensor, mask: Tensor) -> None:
        """Accumulate labels. task [B] long, xy [B, M, 2] canonical, label [B, M], mask [B, M] bool.

        Raises:
            ValueError: for bad shapes (a [B, 1] mask was broadcast) or a task index outside [0, T).
        """
        self._check_batch(task, xy)
        for name, t in (("label", label), ("mask", mask)):
            if t.shape != xy.shape[:2]:
                raise ValueError(f"CanonicalLabelGrid: {name} must be {list(xy.shape[:2])}, got {list(t.shape)}")
        # one sync, in a method whose boolean indexing syncs anyway: a bad index failed inside index_add_
        if bool(((task < 0) | (task >= len(self.tasks))).any()):
            raise ValueError(f"CanonicalLabelGrid: task indices must be in [0, {len(self.tasks)}), got {task.tolist()}")
        flat, inside = self.cells(xy)
        keep = mask.bool() & inside
        index = (task[:, None] * self.size * self.size + flat)[keep]
        check_finite("CanonicalLabelGrid: label", label[keep])  # a NaN label made its cell NaN for good
        self.sums.view(-1).index_add_(0, index, label[keep].to(self.sums.dtype))
        self.counts.view(-1).index_add_(0, index, torch.ones_like(index, dtype=self.counts.dtype))

    def mean_maps(self) -> Tensor:
        """[T, size, size] float32: smoothed mean label per cell, ``fill`` where nothing was seen.

        Computed in float32 whatever the trainer's precision: under autocast (``bf16-mixed``, ``16-mixed``) the
        smoothing ran in half precision and the cached map moved the argmax cell of a few per cent of views."""
        with torch.autocast(self.sums.device.type, enabled=False):
            return self._mean_maps()

    def _mean_maps(self) -> Tensor:
        s, c = self.sums[:, None].float(), self.counts[:, None].float()
        if self.smooth_sigma_cells > 0:
            k = self._kernel().to(s)
            pad = k.shape[-1] // 2
            s = F.conv2d(
                F.conv2d(s, k[None, None, :, None], padding=(pad, 0)), k[None, None, None, :], padding=(0, pad)
            )
            c = F.conv2d(
                F.conv2d(c, k[None, None, :, None], padding=(pad, 0)), k[None, None, None, :], padding=(0, pad)
            )
        seen = c > 1e-6
        return torch.where(seen, s / c.clamp_min(1e-6), torch.full_like(s, self.fill))[:, 0]

    def _kernel(self) -> Tensor:
        r = max(1, int(math.ceil(3 * self.smooth_sigma_cells)))
        x = torch.arange(-r, r + 1, dtype=torch.float32)
        k = torch.exp(-0.5 * (x / self.smooth_sigma_cells) ** 2)
        return k / k.sum()

    def cached_mean_maps(self) -> Tensor:
        """:meth:`mean_maps`, recomputed only when the sums or counts changed (add, load_state_dict, .to)."""
        key = (self.sums._version, self.counts._version, self.sums.data_ptr(), self.sums.device)
        if self._maps is None or self._maps[0] != key:
            self._maps = (key, self.mean_maps())
        return self._maps[1]

    def read(self, task: Tensor, xy: Tensor) -> Tensor:
        """Prior [B, M] at canonical xy [B, M, 2] for tasks [B] (``fill`` outside the grid)."""
        self._check_batch(task, xy)
        maps = self.cached_mean_maps().flatten(1)  # [T, S*S]
        flat, inside = self.cells(xy)
        vals = maps[task[:, None].expand_as(flat), flat]
        return torch.where(inside, vals, torch.full_like(vals, self.fill))

    def seen_tasks(self) -> list[str]:
        """Tasks that received at least one label."""
        return [t for t, c in zip(self.tasks, self.counts.sum((1, 2)).tolist()) if c > 0]
