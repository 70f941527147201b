"""Which bricks of a level a slab around a plane covers: the geometry of slice-shaped windows.

Why: a cutting plane through a huge volume touches a thin slab of bricks, and away from the point
of interest only coarse ones (LaMar, Hamann & Joy, *Multiresolution cutting planes*). A clip-texture
that fills cubes around the centre reads most of a level for one slice; one that is handed the
bricks of the slab reads the slice. Pure numpy, no threads, no I/O, so the rule can be tested
against a brute-force enumeration alone.

Definitions
-----------
A brick ``(level, b)`` is represented by its octree node box (:meth:`Pyramid.node_box`). The slab
of a plane (``origin``, unit ``normal``) with half-thickness ``h`` is the open set
``|normal . (x - origin)| < h``. A brick is *in the slab* when its box meets it: the box's signed
distances to the plane span an interval that meets ``(-h, h)`` (for ``h = 0`` nothing is in
the slab; the slice action never asks for that). Optionally the bricks are also limited to those
whose box comes closer than ``radius`` to a point (its nearest point, 0 inside the box).

The slice action's half-thickness at level ``L`` is half a voxel of ``L``: the voxels within one
voxel of the plane - the trilinear footprint of a sample on it - are exactly those whose
node-box cells meet that slab.

Enumeration does not visit the whole grid (a 4096^3 store bricked at 16 has 16.7 million level-0
bricks): per column of bricks along the normal's dominant axis it computes the range of bricks the
slab can meet there, then tests those candidates exactly.
"""

from __future__ import annotations

import math

import numpy as np

from ..bricking.pyramid import Pyramid
from ..errors import ParameterError

__all__ = ["slab_mask", "slab_bricks", "near_mask"]


def _unit(normal) -> np.ndarray:
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(n))
    if not (norm > 0 and math.isfinite(norm)):
        raise ParameterError(f"normal: expected a finite non-zero vector (x, y, z), got {tuple(n.tolist())}")
    return n / norm


def _half(h) -> float:
    h = float(h)
    if not (h >= 0 and math.isfinite(h)):
        raise ParameterError(f"half_thickness: expected a finite distance >= 0 (world units), got {h!r}")
    return h


def slab_mask(pyramid: Pyramid, level: int, indices, origin, normal, half_thickness: float) -> np.ndarray:
    """``(n,)`` bool: which bricks ``indices`` (``(n, 3)`` ``z, y, x``) of ``level`` meet the slab."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    if not len(idx):
        return np.zeros(0, dtype=bool)
    n = _unit(normal)
    h = _half(half_thickness)
    lo, hi = pyramid.node_box(level, idx)
    c, r = (lo + hi) * 0.5, (hi - lo) * 0.5
    d = (c - np.asarray(origin, dtype=np.float64).reshape(1, 3)) @ n
    gap = np.maximum(np.abs(d) - r @ np.abs(n), 0.0)  # distance from the plane to the box
    return gap < h


def near_mask(pyramid: Pyramid, level: int, indices, point, radius: float) -> np.ndarray:
    """``(n,)`` bool: which bricks' boxes come closer than ``radius`` to ``point`` (``inf``: all)."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    if not math.isfinite(radius):
        return np.ones(len(idx), dtype=bool)
    lo, hi = pyramid.node_box(level, idx)
    p = np.asarray(point, dtype=np.float64).reshape(1, 3)
    return np.linalg.norm(np.clip(p, lo, hi) - p, axis=1) < radius


def _axis_bricks(pyramid: Pyramid, level: int, axis_xyz: int, lo: float, hi: float) -> tuple[int, int]:
    """``[first, last]`` brick indices along world axis ``axis_xyz`` whose node extent may meet ``[lo, hi]``."""
    a = 2 - axis_xyz  # array axis
    sp = pyramid.spacing[a]
    ext = pyramid.brick_shape[a] * 2.0**level
    g = pyramid.grid(level)[a]
    f = math.floor((lo / sp + 0.5) / ext) if math.isfinite(lo) else 0
    last = math.floor((hi / sp + 0.5) / ext) if math.isfinite(hi) else g - 1
    return max(f, 0), min(last, g - 1)


def slab_bricks(pyramid: Pyramid, level: int, origin, normal, half_thickness: float, *, point=None,
                radius: float = math.inf) -> np.ndarray:
    """All bricks ``(n, 3)`` (``z, y, x``, row-major order) of ``level`` in the slab (module docstring),
    and, with ``point``, whose boxes come closer than ``radius`` to it."""
    n = _unit(normal)
    h = _half(half_thickness)
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    radius = float(radius)
    if point is None:
        radius = math.inf
    elif not radius >= 0:
        raise ParameterError(f"radius: expected a distance >= 0 or inf (world units), got {radius!r}")
    empty = np.zeros((0, 3), dtype=np.int64)
    if h == 0 or radius == 0:
        return empty
    vlo, vhi = pyramid.volume_box()
    # the bricks meeting the ball's box limit the columns (and the run along the dominant axis)
    blo, bhi = vlo.copy(), vhi.copy()
    if math.isfinite(radius):
        p = np.asarray(point, dtype=np.float64).reshape(3)
        blo, bhi = np.maximum(blo, p - radius), np.minimum(bhi, p + radius)
        if np.any(blo > bhi):
            return empty
    a = int(np.argmax(np.abs(n)))  # dominant world axis: one short run of bricks per column
    u, v = [k for k in range(3) if k != a]
    ranges = [_axis_bricks(pyramid, level, k, blo[k], bhi[k]) for k in range(3)]
    if any(f > last for f, last in ranges):
        return empty
    iu = np.arange(ranges[u][0], ranges[u][1] + 1)
    iv = np.arange(ranges[v][0], ranges[v][1] + 1)
    cu, cv = np.meshgrid(iu, iv, indexing="ij")
    cu, cv = cu.ravel(), cv.ravel()
    # node boxes of the columns along u and v (any index along a: only the u, v extents are used)
    col = np.zeros((len(cu), 3), dtype=np.int64)
    col[:, 2 - u], col[:, 2 - v] = cu, cv
    lo, hi = pyramid.node_box(level, col)
    mu = np.stack([n[u] * (lo[:, u] - o[u]), n[u] * (hi[:, u] - o[u])])
    mv = np.stack([n[v] * (lo[:, v] - o[v]), n[v] * (hi[:, v] - o[v])])
    m_lo, m_hi = mu.min(axis=0) + mv.min(axis=0), mu.max(axis=0) + mv.max(axis=0)
    # n_a (x_a - o_a) must lie in (-h - m_hi, h - m_lo) for some x_a of the column
    t1, t2 = (-h - m_hi) / n[a] + o[a], (h - m_lo) / n[a] + o[a]
    t_lo, t_hi = np.minimum(t1, t2), np.maximum(t1, t2)
    t_lo, t_hi = np.maximum(t_lo, vlo[a]), np.minimum(t_hi, vhi[a])
    ea = 2 - a
    ext = pyramid.brick_shape[ea] * 2.0**level
    sp = pyramid.spacing[ea]
    g = pyramid.grid(level)[ea]
    with np.errstate(invalid="ignore"):
        b_lo = np.clip(np.floor((t_lo / sp + 0.5) / ext), ranges[a][0], g - 1)
        b_hi = np.clip(np.floor((t_hi / sp + 0.5) / ext), 0, ranges[a][1])
    ok = (t_lo <= t_hi) & (b_lo <= b_hi)
    if not ok.any():
        return empty
    b_lo, b_hi, cu, cv = b_lo[ok].astype(np.int64), b_hi[ok].astype(np.int64), cu[ok], cv[ok]
    span = int((b_hi - b_lo).max()) + 1
    steps = np.arange(span)
    ba = b_lo[:, None] + steps[None, :]
    keep = ba <= b_hi[:, None]
    cand = np.zeros((int(keep.sum()), 3), dtype=np.int64)
    cand[:, ea] = ba[keep]
    cand[:, 2 - u] = np.broadcast_to(cu[:, None], ba.shape)[keep]
    cand[:, 2 - v] = np.broadcast_to(cv[:, None], ba.shape)[keep]
    sel = slab_mask(pyramid, level, cand, o, n, h)
    if math.isfinite(radius):
        sel &= near_mask(pyramid, level, cand, point, radius)
    out = cand[sel]
    order = np.lexsort((out[:, 2], out[:, 1], out[:, 0]))
    return out[order]
