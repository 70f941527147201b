"""Selection policies: interchangeable strategies over the one octree traversal.

The registry (:mod:`clipvol.scene.policy_registry`, a leaf that ``RenderParams`` validates
against) maps a name (``RenderParams.policy``) to a policy class; a class is built with the frozen
:class:`~clipvol.scene.params.RenderParams` and implements
:class:`~clipvol.scene.selection.policies.base.SelectionPolicy`. To add a policy, write one module
in this folder (copy ``distance.py``) and add its class to :data:`BUILT_IN` below.
"""

from __future__ import annotations

from ...policy_registry import POLICIES, register
from .base import RefinePolicy, SelectionPolicy
from .distance import Distance
from .field_of_view import FieldOfView
from .fixed_level import FixedLevel
from .image_based import ImageBased
from .plane import PlaneCut
from .projected_size import ProjectedSize, TexelBudget
from .roaming import ROAMING_MAX_BRICKS, Roaming

__all__ = ["POLICIES", "BUILT_IN", "register", "policy_for", "SelectionPolicy", "RefinePolicy", "ROAMING_MAX_BRICKS"]

#: the policies shipped with clipvol, registered by name (one line per policy)
BUILT_IN: tuple[type, ...] = (
    ProjectedSize,
    TexelBudget,
    FixedLevel,
    Roaming,
    Distance,
    FieldOfView,
    ImageBased,
    PlaneCut,
)
for _cls in BUILT_IN:
    register(_cls)


def policy_for(params) -> SelectionPolicy:
    """The policy ``params.policy`` names, built from ``params``."""
    return POLICIES[params.policy](params)
