"""The rule of a multiresolution slice's cover stated point by point (the tests' independent reference).

At a world point ``q`` and level ``L``, the brick holding ``q`` has the box ``[b e - 0.5, (b + 1) e -
0.5]`` per axis (``e`` = brick edge times ``2**L`` level-0 voxels of spacing 1, ``b = floor((q +
0.5) / e)``), clipped to the volume ``[-0.5, n - 0.5]``. It is in reach when its nearest point comes
closer to the point of interest than ``distance_factor`` times the diagonal of the box of level ``L
+ 1`` holding ``q`` (its parent's, clipped the same way); every brick of the coarsest level is. The
point's level is the finest in reach.
"""

from __future__ import annotations

import numpy as np


def brick_box(shape_zyx, brick: int, level: int, q: np.ndarray):
    """``(lo, hi)`` ``(m, 3)`` (x, y, z) of the boxes of the level's bricks holding points ``q``."""
    ext = brick * 2.0**level
    vhi = np.array(shape_zyx[::-1], dtype=np.float64) - 0.5
    b = np.floor((np.asarray(q, dtype=np.float64) + 0.5) / ext)
    return np.maximum(b * ext - 0.5, -0.5), np.minimum((b + 1) * ext - 0.5, vhi)


def finest_in_reach(q, focus, distance_factor: float, shape_zyx, brick: int, levels: int) -> np.ndarray:
    """``(m,)`` the finest level in reach at each point ``q`` ``(m, 3)``."""
    focus = np.asarray(focus, dtype=np.float64)
    out = np.full(len(q), levels - 1)
    for L in range(levels - 2, -1, -1):
        out = np.where(in_reach_at(q, focus, distance_factor, shape_zyx, brick, L), L, out)
    return out


def in_reach_at(q, focus, distance_factor: float, shape_zyx, brick: int, level: int) -> np.ndarray:
    """``(m,)`` bool: is the brick of ``level`` (below the coarsest) holding each point ``q`` in reach."""
    focus = np.asarray(focus, dtype=np.float64)
    lo, hi = brick_box(shape_zyx, brick, level, q)
    plo, phi = brick_box(shape_zyx, brick, level + 1, q)
    near = np.linalg.norm(np.clip(focus, lo, hi) - focus, axis=1)
    return near < distance_factor * np.linalg.norm(phi - plo, axis=1)


def off_faces(q, brick: int, levels: int, margin: float = 1e-6) -> np.ndarray:
    """``(m,)`` bool: points farther than ``margin`` (level-0 voxels) from every brick face of every level."""
    ok = np.ones(len(q), dtype=bool)
    for L in range(levels):
        t = (np.asarray(q) + 0.5) / (brick * 2.0**L)
        ok &= np.all(np.abs(t - np.rint(t)) * brick * 2.0**L > margin, axis=1)
    return ok


def cover_levels(cover, q, shape_zyx, brick: int) -> tuple[np.ndarray, np.ndarray]:
    """``(count, level)``, each ``(m,)``: how many of a cover's drawn boxes hold each point ``q`` strictly
    inside, and the data level of the box that holds it (-1: none). Reads the cover's records only;
    the boxes are computed here from the brick grid, not by the code under test."""
    q = np.asarray(q, dtype=np.float64)
    count = np.zeros(len(q), dtype=int)
    level = np.full(len(q), -1)
    for dl, _, bl, bidx in cover.records:
        ext = brick * 2.0**bl
        lo = np.maximum(bidx[:, ::-1] * ext - 0.5, -0.5)
        hi = np.minimum((bidx[:, ::-1] + 1) * ext - 0.5, np.array(shape_zyx[::-1]) - 0.5)
        inside = np.all((q[:, None] > lo[None]) & (q[:, None] < hi[None]), axis=2)
        count += inside.sum(axis=1)
        level[inside.any(axis=1)] = dl
    return count, level
