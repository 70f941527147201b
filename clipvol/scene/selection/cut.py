"""What a selection produces: draw items in visibility order, the ideal cut, counts (pure data).

A selection policy's output is a cut of the brick octree plus per-node data, never GL: the render
actions (volume, slice, splat) turn it into draws, the frame loop into loads and uploads.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

__all__ = ["DrawItem", "Selection", "Residency"]


class Residency(Protocol):
    """What the selection asks of a clip-texture (or of a GPU-cache-aware wrapper around one)."""

    def in_window_mask(self, level: int, indices: np.ndarray) -> np.ndarray: ...

    def resident_mask(self, level: int, indices: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, slots=True)
class DrawItem:
    """One box to draw: sample brick ``(level, index)`` over the world box ``[lo, hi]`` (``(x, y, z)``).

    The box is the brick's node box, or a sub-box of it where finer bricks are not available (the
    brick is then an ancestor of the region's ideal brick).
    """

    level: int
    index: tuple[int, int, int]
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    #: bricks per axis this item covers from ``index`` (a power of two; > 1 only after
    #: :func:`~clipvol.scene.selection.merge.merge_items`), clipped to the level's grid
    span: int = 1


@dataclass
class Selection:
    """The result of :func:`~clipvol.scene.selection.select`.

    Attributes
    ----------
    items : list of DrawItem
        What to draw, in exact back-to-front order for the camera.
    wanted : list of (level, index)
        The ideal cut ignoring residency (inside the window), coarse levels first, then nearest
        first: the load priority and the target of ``wait``.
    counts : dict
        ``visited``, ``culled_frustum``, ``culled_shape``, ``culled_transparent``,
        ``culled_policy`` (nodes a policy's own test left out), ``refined``, ``outside_window``
        (boxes drawn from the parent because the child is outside the window), ``fallback`` (items
        drawn from an ancestor because the ideal brick is not resident), ``missing`` (regions not
        drawn: nothing resident), ``texels`` (of the items' bricks), ``level`` (roaming / fixed:
        the level chosen, else -1).
    policy : str
        The policy that chose the cut.
    node_data : dict
        Per-node data a policy attaches to the cut, keyed by ``(level, index)`` (e.g. importance,
        blend ratios); empty for the built-in volume policies.
    """

    items: list[DrawItem]
    wanted: list[tuple[int, tuple[int, int, int]]]
    counts: dict = field(default_factory=dict)
    policy: str = ""
    node_data: dict = field(default_factory=dict)

    def is_converged(self) -> bool:
        """Every wanted brick is drawn at its own level."""
        drawn = {(it.level, tuple(it.index)) for it in self.items}
        return drawn.issuperset((L, tuple(idx)) for L, idx in self.wanted)  # numpy ints hash as ints

    def missing_wanted(self) -> list[tuple[int, tuple[int, int, int]]]:
        """Wanted bricks not drawn at their own level, in load-priority order."""
        drawn = {(it.level, tuple(it.index)) for it in self.items}
        out = []
        for L, idx in self.wanted:
            key = (int(L), tuple(int(i) for i in idx))
            if key not in drawn:
                out.append(key)
        return out
