"""Selection: which bricks a frame draws, at which level, in which order (pure numpy, no GL).

:func:`select` runs one shared octree traversal (:mod:`.traversal`) whose refine decision comes
from a policy (:mod:`.policies`); :mod:`.order` gives exact back-to-front order and the load
priority, :mod:`.merge` turns complete sibling sets into single boxes, :mod:`.cut` holds the result
types.
"""

from __future__ import annotations

from .cut import BrickKeys, DrawItem, DrawItems, Residency, Selection
from .merge import merge_items
from .octree import Octree
from .order import back_to_front
from .policies import POLICIES, ROAMING_MAX_BRICKS, policy_for
from .traversal import Traversal, select

__all__ = ["select", "Selection", "DrawItem", "DrawItems", "BrickKeys", "Residency", "Traversal", "Octree",
           "back_to_front", "merge_items", "POLICIES", "policy_for", "ROAMING_MAX_BRICKS"]
