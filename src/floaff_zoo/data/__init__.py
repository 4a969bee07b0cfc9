"""DataModule registry: importing this package makes every DataModule resolvable by bare name."""

from floaff_zoo.data.base import FloAffDataModule
from floaff_zoo.data.synthetic import SyntheticDataModule

__all__ = ["FloAffDataModule", "SyntheticDataModule"]
