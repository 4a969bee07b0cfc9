"""DataModule registry: importing this package makes every DataModule resolvable by bare name."""

from floaff_zoo.data.base import FloAffDataModule
from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
from floaff_zoo.data.moma_kitchen import MoMaKitchenDataModule
from floaff_zoo.data.synthetic import SyntheticDataModule

__all__ = ["FloAffDataModule", "FloAffKitchenDataModule", "MoMaKitchenDataModule", "SyntheticDataModule"]
