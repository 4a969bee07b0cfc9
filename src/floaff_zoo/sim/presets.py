"""Generation presets: ``tiny`` (tests/CI), ``demo``, ``small``, ``dense`` (the paper's view density) and
``paper`` (FloAff-Kitchen scene and view counts).

Paper view totals come from the appendix table "Statistics of RoboCasa dataset" (per benchmark and task: train front,
train side, test front, test side); they are spread over the scenes of a split (5 train, 1 test) as evenly as possible.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from floaff_zoo.checks import check_flag, check_integer, check_number, check_numbers
from floaff_zoo.names import BENCHMARKS as ALL_BENCHMARKS  # defined once there; the old names re-exported
from floaff_zoo.names import TASKS as ALL_TASKS

__all__ = [
    "ALL_BENCHMARKS",
    "ALL_TASKS",
    "PAPER_VIEW_TOTALS",
    "PRESETS",
    "GenPreset",
    "check_view_regions",
    "get_preset",
    "view_counts",
]


# benchmark -> task -> (train front, train side, test front, test side); totals 13,610 (Styles) + 11,172 (Layouts)
PAPER_VIEW_TOTALS: dict[str, dict[str, tuple[int, int, int, int]]] = {
    "styles": {
        "PnPCounterToCab": (960, 1920, 200, 400),
        "OpenSingleDoor": (1000, 2000, 200, 400),
        "CloseDrawer": (1000, 1780, 200, 400),
        "CloseDoubleDoor": (1000, 1630, 200, 320),
    },
    "layouts": {
        "PnPCounterToCab": (1000, 1200, 200, 200),
        "OpenSingleDoor": (1000, 1400, 200, 200),
        "CloseDrawer": (1000, 1783, 200, 199),
        "CloseDoubleDoor": (1000, 1190, 200, 200),
    },
}


@dataclass
class GenPreset:
    """Everything that decides what a generation run produces (recorded in the manifest).

    views_per_scene: (front, side) views per scene, used when use_paper_view_counts is False.
    max_candidates: cap on the rollouts per scene passed to annotate_scene (None = every filtered candidate; the
        cells over the cap are labelled failures "skipped_budget": for tests/CI only).
    floor_only: mark the grid cells on free floor (centre outside every furniture/wall footprint) in
        ``candidates.on_floor`` and draw only those in topdown.png (format 1 views stored exactly these cells; format 2
        views store the cells their own cloud observes as ground, see docs/data_format.md).
    max_seed_attempts: a slot whose scene has no positive candidate is retried with the next derived seed.
    r_arm: the reach filter's radius; only None (each task's own reach) is accepted by ``annotate_scene``, since the
        evaluation refuses poses by the task's reach.
    View geometry (front_rx ... max_dist) and rendering (image_size, depth_max, max_points) mirror ViewConfig.
    """

    name: str = "custom"
    tasks: tuple[str, ...] = ALL_TASKS
    benchmarks: tuple[str, ...] = ALL_BENCHMARKS
    n_train: int = 5
    n_test: int = 1
    cell: float = 0.05
    sigma_cells: float = 1.0
    r_arm: float | None = None
    max_candidates: int | None = None
    floor_only: bool = True
    views_per_scene: tuple[int, int] = (8, 8)
    use_paper_view_counts: bool = False
    min_views: int = 0
    max_seed_attempts: int = 6
    image_size: int = 128
    depth_max: float = 4.0
    max_points: int = 8192
    front_rx: float = 0.45
    front_ry: float = 0.55
    side_rx: float = 0.75
    side_ry: float = 0.9
    max_dist: float = 2.4
    min_target_pixels: int = 4
    max_tries_per_view: int = 60
    picture_size: int = 256

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["tasks"] = list(self.tasks)
        d["benchmarks"] = list(self.benchmarks)
        d["views_per_scene"] = list(self.views_per_scene)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "GenPreset":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown preset fields: {sorted(unknown)}")
        d = dict(d)
        for k in ("tasks", "benchmarks", "views_per_scene"):
            if k in d:
                d[k] = tuple(d[k])
        return cls(**d)

    def validate(self) -> "GenPreset":
        for name in ("tasks", "benchmarks"):  # a text was read letter by letter; none planned no scene, said nothing
            values = getattr(self, name)
            if not isinstance(values, (tuple, list)) or not values:
                raise ValueError(f"{name} must be a non-empty tuple of names, got {values!r}")
        for name in ("floor_only", "use_paper_view_counts"):  # the text "false" was true
            check_flag(name, getattr(self, name))
        bad = [t for t in self.tasks if t not in ALL_TASKS]
        if bad:
            raise ValueError(f"unknown task(s) {bad}; choose from {list(ALL_TASKS)}")
        bad = [b for b in self.benchmarks if b not in ALL_BENCHMARKS]
        if bad:
            raise ValueError(f"unknown benchmark(s) {bad}; choose from {list(ALL_BENCHMARKS)}")
        for name in ("tasks", "benchmarks"):  # a repeated one would fill its slots twice, racing for one folder
            values = getattr(self, name)
            twice = sorted({v for v in values if values.count(v) > 1})
            if twice:
                raise ValueError(f"{name}: {twice} given more than once")
        if self.r_arm is not None:
            raise ValueError(
                f"r_arm must be None (each task's own reach; the evaluation refuses by it), got {self.r_arm}"
            )
        check_integer("n_train", self.n_train, 0)
        check_integer("n_test", self.n_test, 0)
        if self.n_train + self.n_test == 0:
            raise ValueError(f"need at least one scene, got {self.n_train}/{self.n_test} (n_train/n_test)")
        check_number("cell", self.cell, strict=True)
        check_integer("max_seed_attempts", self.max_seed_attempts, 1)
        # annotate smooths only when sigma > 0: a NaN or negative one left the labels unsmoothed without a word
        # (0 = no smoothing); a NaN or negative view region gives none of its views, found only after each annotation
        check_numbers({k: getattr(self, k) for k in ("sigma_cells", "front_rx", "front_ry", "side_rx", "side_ry")})
        check_number("max_dist", self.max_dist, strict=True)
        check_view_regions(self.front_rx, self.front_ry, self.side_rx, self.side_ry, self.max_dist)
        # view_counts reads two numbers: one failed the plan, a third was ignored
        if not isinstance(self.views_per_scene, (tuple, list)) or len(self.views_per_scene) != 2:
            raise ValueError(f"views_per_scene must be (front, side), got {self.views_per_scene!r}")
        for side, n in zip(("front", "side"), self.views_per_scene, strict=True):
            check_integer(f"views_per_scene ({side})", n, 0)
        check_integer("min_views", self.min_views, 0)
        if not self.use_paper_view_counts and sum(self.views_per_scene) == 0 and self.min_views == 0:
            # every scene would be built and rolled out, and no DataModule could read a view of it
            raise ValueError("views_per_scene: at least one front or side view per scene, got (0, 0)")
        # rendering and rollout sizes: a bad one would otherwise fail each scene only after its annotation
        for name in ("image_size", "max_points", "picture_size", "max_tries_per_view"):
            check_integer(name, getattr(self, name), 1)
        check_integer("max_candidates", self.max_candidates, 1, none_means="no cap")
        # 0 stored views whose cloud shows no target point: the models read the target from it, predict refuses one
        check_integer("min_target_pixels", self.min_target_pixels, 1)
        check_number("depth_max", self.depth_max, strict=True)
        return self


def check_view_regions(
    front_rx: float, front_ry: float, side_rx: float, side_ry: float, max_dist: float, owner: str = ""
) -> None:
    """Refuse view regions (finite numbers >= 0, max_dist > 0, already checked) that hold no base position:
    V_front = {|x| < front_rx, y < -front_ry, r <= max_dist} is empty when front_rx is 0 or front_ry >= max_dist,
    V_side = {|x| > side_rx, |y| < side_ry, r <= max_dist} when side_ry is 0 or side_rx >= max_dist. Every proposal
    was refused and no view of the region sampled, after each scene's annotation, without a word."""
    who = f"{owner}: " if owner else ""
    if front_rx <= 0 or side_ry <= 0:
        name, value = ("front_rx", front_rx) if front_rx <= 0 else ("side_ry", side_ry)
        raise ValueError(f"{who}{name} must be > 0 (its view region holds no base position), got {value}")
    for name, value in (("front_ry", front_ry), ("side_rx", side_rx)):
        if value >= max_dist:
            raise ValueError(
                f"{who}{name} must be < max_dist (its view region holds no base position), got {value} "
                f"(max_dist {max_dist})"
            )


PRESETS: dict[str, GenPreset] = {
    # tests / CI: 2 tasks x (1 train + 1 test) scenes of the Styles benchmark, coarse grid, 64x64 images
    "tiny": GenPreset(
        name="tiny",
        tasks=("CloseDrawer", "OpenSingleDoor"),
        benchmarks=("styles",),
        n_train=1,
        n_test=1,
        cell=0.2,
        max_candidates=24,
        views_per_scene=(2, 2),
        image_size=64,
        max_points=2048,
        max_seed_attempts=4,
        picture_size=128,
    ),
    # `floaff-zoo demo`: the Layouts benchmark, all tasks, 2 + 1 scenes per task (one train scene per task is
    # held out for validation), the small preset's grid and views: a few minutes on 2 cores
    "demo": GenPreset(
        name="demo",
        benchmarks=("layouts",),
        n_train=2,
        n_test=1,
        cell=0.1,
        max_candidates=60,
        views_per_scene=(6, 6),
        image_size=96,
        max_points=4096,
    ),
    # all tasks, both benchmarks, 5 + 1 scenes per task, coarser grid, fewer views
    "small": GenPreset(
        name="small",
        cell=0.1,
        max_candidates=60,
        views_per_scene=(6, 6),
        image_size=96,
        max_points=4096,
    ),
    # the paper's view density at 2-core cost: both benchmarks, all tasks, 5 train + 4 test scenes per task
    # (4 test scenes for statistics), 80 front + 120 side views per scene (the paper's ~2:3 front/side mix,
    # ~560 views per scene in the paper), topped up to 200 where a region yields fewer (at least 200 views in every
    # scene; `--min-views 0` gives the copy behind the chapters of docs/results_history.md), every filtered candidate
    # rolled out on the small preset's 0.1 m grid (0.05 m quadruples the rollouts: docs/performance.md)
    "dense": GenPreset(
        name="dense",
        n_train=5,
        n_test=4,
        cell=0.1,
        max_candidates=None,
        views_per_scene=(80, 120),
        min_views=200,
        image_size=96,
        max_points=4096,
    ),
    # the paper: 0.05 m grid and the appendix table's view counts (24,782 views)
    "paper": GenPreset(
        name="paper",
        cell=0.05,
        use_paper_view_counts=True,
        image_size=128,
        max_points=8192,
    ),
}


def get_preset(name: str, **overrides: Any) -> GenPreset:
    """A copy of a named preset with field overrides (None values are ignored)."""
    if not isinstance(name, str) or name not in PRESETS:  # a list failed with "unhashable type"
        raise ValueError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}")
    ov = {k: v for k, v in overrides.items() if v is not None}
    known = {f.name for f in fields(GenPreset)}
    unknown = set(ov) - known
    if unknown:
        raise ValueError(f"unknown preset fields: {sorted(unknown)}")
    return replace(PRESETS[name], **ov).validate()


def _spread(total: int, n: int, i: int) -> int:
    """Share of scene i when `total` items are spread over n scenes (earlier scenes get the remainder)."""
    return total // n + (1 if i < total % n else 0)


def view_counts(preset: GenPreset, benchmark: str, task: str, split: str, slot: int) -> tuple[int, int]:
    """(front, side) number of views for one scene slot."""
    if not preset.use_paper_view_counts:
        return int(preset.views_per_scene[0]), int(preset.views_per_scene[1])
    tf, ts, ef, es = PAPER_VIEW_TOTALS[benchmark][task]
    if split == "train":
        n = max(1, preset.n_train)
        return _spread(tf, n, slot), _spread(ts, n, slot)
    n = max(1, preset.n_test)
    return _spread(ef, n, slot), _spread(es, n, slot)
