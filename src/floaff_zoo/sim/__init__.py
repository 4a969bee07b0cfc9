"""floaff_zoo.sim: procedural MuJoCo kitchens, scripted rollouts and floor-affordance annotation.

Pure numpy + mujoco (+ robosuite's robot model API); never imports torch or lightning.
Submodules are imported lazily so ``import floaff_zoo.sim`` stays cheap. ``floaff_zoo.sim.rollout`` is the submodule
(its function is ``floaff_zoo.sim.rollout.rollout``): a lazy name equal to a submodule's would read as the function
or the module depending on what was imported before.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "SceneSpec": "kitchen",
    "SimScene": "kitchen",
    "build_scene": "kitchen",
    "TASKS": "kitchen",
    "LAYOUTS": "kitchen",
    "STYLES": "kitchen",
    "TargetInfo": "tasks",
    "TASK_REGISTRY": "tasks",
    "candidate_region": "tasks",
    "RolloutResult": "rollout",
    "RolloutService": "rollout",
    "heading_to_target": "rollout",
    "Annotation": "annotate",
    "annotate_scene": "annotate",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        mod = importlib.import_module(f"floaff_zoo.sim.{_LAZY[name]}")
        return getattr(mod, name)
    raise AttributeError(f"module 'floaff_zoo.sim' has no attribute {name!r}")
