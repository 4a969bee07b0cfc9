"""Model registry: importing this package makes every model class resolvable by bare name."""

from floaff_zoo.models.axisnet import AxisNetModule
from floaff_zoo.models.base import FloAffModule
from floaff_zoo.models.c2f_exp import C2FExpModule
from floaff_zoo.models.cfar import CFARModule
from floaff_zoo.models.h3dnet import H3DNetModule
from floaff_zoo.models.n2m import N2MModule
from floaff_zoo.models.navaff import NavAffModule
from floaff_zoo.models.pointnet2 import PointNet2Module
from floaff_zoo.models.prior import CanonicalPriorModule
from floaff_zoo.models.tiny import TinyPointNetModule
from floaff_zoo.models.votenet import VoteNetModule

__all__ = [
    "AxisNetModule",
    "CanonicalPriorModule",
    "C2FExpModule",
    "CFARModule",
    "FloAffModule",
    "H3DNetModule",
    "N2MModule",
    "NavAffModule",
    "PointNet2Module",
    "TinyPointNetModule",
    "VoteNetModule",
]
