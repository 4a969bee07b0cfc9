"""Model registry: importing this package makes every model class resolvable by bare name."""

from floaff_zoo.models.base import FloAffModule
from floaff_zoo.models.tiny import TinyPointNetModule

__all__ = ["FloAffModule", "TinyPointNetModule"]
