"""Lightning callbacks of the zoo: simulator success rate, the test report and the fit's checkpoints."""

from floaff_zoo.callbacks.checkpoint import LatestCheckpoint
from floaff_zoo.callbacks.report import TestReport
from floaff_zoo.callbacks.rollout import RolloutSuccessRate

__all__ = ["LatestCheckpoint", "RolloutSuccessRate", "TestReport"]
