"""Selection policies: interchangeable strategies over the one octree traversal.

The registry maps a name (``RenderParams.policy``) to a policy class; a class is built with the
frozen :class:`~clipvol.scene.params.RenderParams` and implements
:class:`~clipvol.scene.selection.policies.base.SelectionPolicy`. To add a policy, write one module
in this folder (copy ``distance.py``) and add one line to :data:`POLICIES` below.
"""

from __future__ import annotations

from .base import RefinePolicy, SelectionPolicy
from .distance import Distance
from .field_of_view import FieldOfView
from .fixed_level import FixedLevel
from .image_based import ImageBased
from .plane import PlaneCut
from .projected_size import ProjectedSize, TexelBudget
from .roaming import ROAMING_MAX_BRICKS, Roaming

__all__ = ["POLICIES", "policy_for", "SelectionPolicy", "RefinePolicy", "ROAMING_MAX_BRICKS"]

#: name -> policy class (one line per policy)
POLICIES: dict[str, type] = {
    ProjectedSize.name: ProjectedSize,
    TexelBudget.name: TexelBudget,
    FixedLevel.name: FixedLevel,
    Roaming.name: Roaming,
    Distance.name: Distance,
    FieldOfView.name: FieldOfView,
    ImageBased.name: ImageBased,
    PlaneCut.name: PlaneCut,
}


def policy_for(params) -> SelectionPolicy:
    """The policy ``params.policy`` names, built from ``params``."""
    return POLICIES[params.policy](params)
