"""Lightning callbacks of the zoo: simulator success rate, test report, predictions and the fit's checkpoints."""

from floaff_zoo.callbacks.checkpoint import LatestCheckpoint
from floaff_zoo.callbacks.predictions import PredictionWriter
from floaff_zoo.callbacks.report import TestReport
from floaff_zoo.callbacks.rollout import RolloutSuccessRate

__all__ = ["LatestCheckpoint", "PredictionWriter", "RolloutSuccessRate", "TestReport"]
