"""The contract of a selection policy, and the base most policies extend.

A policy decides one thing: which nodes of the brick octree to refine. Culling, residency,
fallback, merging and visibility order are shared (:mod:`clipvol.scene.selection.traversal`), so a
policy is a few lines and can be swapped per frame. A policy is built from the frozen
:class:`~clipvol.scene.params.RenderParams` and never touches GL; its output is the cut (recorded on
the :class:`~clipvol.scene.selection.traversal.Traversal`) plus optional per-node data.
"""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

__all__ = ["SelectionPolicy", "RefinePolicy"]


@runtime_checkable
class SelectionPolicy(Protocol):
    """What :func:`~clipvol.scene.selection.select` needs of a policy.

    Optional members a policy may add: ``keep(t, level, lo, hi) -> mask`` (extra culling, e.g.
    nodes a cutting plane crosses), ``priority(t, level, lo, hi) -> array`` (the greedy order) and
    ``node_data`` (a dict attached to the :class:`~clipvol.scene.selection.cut.Selection`).
    """

    name: ClassVar[str]

    def cut(self, t) -> None:
        """Record the leaves of the cut on the traversal ``t`` (``t.descend()``, ``t.greedy(...)``,
        ``t.leaves(...)``)."""

    def refine(self, t, level: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: refine these nodes of ``level`` (world boxes ``lo``/``hi`` ``(n, 3)``)."""


class RefinePolicy:
    """A policy given by a vectorised refine predicate: level by level, or greedily under
    ``max_texels_drawn`` (largest projected voxel first) when that budget is set."""

    name: ClassVar[str] = ""

    def __init__(self, params) -> None:
        self.params = params

    def camera_free(self) -> bool:
        """Does the cut depend on the camera only through the frustum? Then a cut stays the
        same cut for another camera while no box the frustum culled enters the view and every
        leaf stays in it (:mod:`clipvol.scene.selection.coherence`), and a frame loop may draw it
        again instead of walking the octree (a fixed-level cut of thousands of bricks, orbited).
        False unless a policy says so."""
        return False

    def cut(self, t) -> None:
        if self.params.max_texels_drawn is not None:
            t.greedy(self.params.max_texels_drawn)
        else:
            t.descend()

    def refine(self, t, level: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError
