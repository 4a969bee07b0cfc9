"""Lightning callbacks of the zoo: simulator success rate and the test report."""

from floaff_zoo.callbacks.report import TestReport
from floaff_zoo.callbacks.rollout import RolloutSuccessRate

__all__ = ["RolloutSuccessRate", "TestReport"]
