"""The names every layer shares, defined once: the four tasks and the two FloAff benchmarks.

Standard library only (no numpy, torch or Lightning), so ``floaff_zoo.sim`` and the contract import the same tuples.
The order is part of the data: generation derives each kitchen's seed from a task's position in ``TASKS``
(``sim.generate``), the validation draw and the results tables walk tasks in this order.
"""

from __future__ import annotations

__all__ = ["BENCHMARKS", "TASKS"]

#: the four FloAff tasks, in the canonical order (seeds, draws and table columns follow it)
TASKS: tuple[str, ...] = ("PnPCounterToCab", "OpenSingleDoor", "CloseDrawer", "CloseDoubleDoor")
#: the two FloAff benchmarks (the dataset's benchmark folders): new styles, new layouts
BENCHMARKS: tuple[str, ...] = ("styles", "layouts")
