"""Which point-octree nodes to draw: splat size under a screen-space tolerance (pure numpy).

After Meredith & Ma (2001), section 3.3. Walking down from the root, a node outside the view
frustum is culled; otherwise its splats would be ``projected node size / cbrt(n)`` pixels wide
(``n`` its stored points: they are spread over ``cbrt(n)`` per axis). The first node on the way
down whose splat size is at most the tolerance is drawn, as is a leaf; otherwise its children are
visited. The tolerance is a fraction of the screen's linear size (Meredith & Ma's "maximum percentage
of linear screen space any one splat may cover"; 10 % of a 1000-pixel window is 100 pixels), or a
number of pixels.

Residency: the wanted cut is what the view asks for; where a wanted node is not in memory yet,
its nearest resident ancestor is drawn instead, over its whole subtree (every wanted or resident
node under it is dropped), so no region is drawn twice and none is left empty while an ancestor
is resident - the volume path's rule (a coarser level stands in for a missing finer one).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..bricking.points import NodeTable
from ..errors import ParameterError

__all__ = ["SplatSelection", "tolerance_pixels", "select_splat_nodes"]


@dataclass(frozen=True, slots=True)
class SplatSelection:
    """One frame's cut through the point octree.

    ``draw``: node ids to draw (resident, no one the ancestor of another); ``wanted``: the cut the
    view asks for at the tolerance; ``missing``: wanted ids not resident; ``splat_px``: per drawn
    node, its splat size in pixels; ``tolerance_px`` the tolerance used.
    """

    draw: np.ndarray
    wanted: np.ndarray
    missing: np.ndarray
    splat_px: np.ndarray
    tolerance_px: float

    @property
    def converged(self) -> bool:
        """Everything wanted is drawn at its own node."""
        return len(self.missing) == 0


def tolerance_pixels(tolerance, size) -> float:
    """Pixels of a tolerance: a fraction ``0 < t < 1`` of ``max(width, height)``, or ``"Npx"``.

    A bare number ``>= 1`` is also taken as pixels.
    """
    w, h = size
    if isinstance(tolerance, str):
        text = tolerance.strip().lower()
        try:
            if text.endswith("px"):
                px = float(text[:-2])
            elif text.endswith("%"):
                px = float(text[:-1]) / 100.0 * max(w, h)
            else:
                return tolerance_pixels(float(text), size)
        except ValueError:
            raise ParameterError(f"tolerance: expected a fraction such as 0.05, '5%' or '12px', got {tolerance!r}") from None
    else:
        try:
            t = float(tolerance)
        except (TypeError, ValueError):
            raise ParameterError(f"tolerance: expected a fraction such as 0.05, '5%' or '12px', got {tolerance!r}") from None
        px = t * max(w, h) if t < 1.0 else t
    if not (np.isfinite(px) and px > 0):
        raise ParameterError(f"tolerance: expected a value > 0, got {tolerance!r}")
    return float(px)


def select_splat_nodes(nodes: NodeTable, camera, tolerance, resident: Callable[[np.ndarray], np.ndarray] | None = None,
                       max_depth: int | None = None) -> SplatSelection:
    """The nodes to draw for ``camera`` at ``tolerance`` (see the module docstring).

    Parameters
    ----------
    nodes : NodeTable
        The octree (:class:`clipvol.bricking.points.NodeTable`).
    camera : Camera
        Frustum and projection (:class:`clipvol.scene.camera.Camera`).
    tolerance : float or str
        Largest splat: a fraction of the screen's linear size, or ``"Npx"`` (:func:`tolerance_pixels`).
    resident : callable, optional
        ``resident(ids) -> bool mask``; default: every node is resident.
    max_depth : int, optional
        Never descend below this depth.
    """
    tol = tolerance_pixels(tolerance, camera.size)
    if not len(nodes):
        e = np.zeros(0, np.int64)
        return SplatSelection(e, e, e, np.zeros(0), tol)
    cur = nodes.lookup(0, np.array([0]))
    cur = cur[cur >= 0]
    wanted = []
    while len(cur):
        lo, hi = nodes.boxes(cur)
        vis = camera.boxes_in_frustum(lo, hi)
        cur, lo, hi = cur[vis], lo[vis], hi[vis]
        if not len(cur):
            break
        h = nodes.edges(cur) / np.cbrt(np.maximum(nodes.count[cur], 1))
        px = camera.projected_size(lo, hi, h)
        stop = (px <= tol) | (nodes.child_mask[cur] == 0)
        if max_depth is not None:
            stop |= nodes.depth[cur] >= max_depth
        wanted.append(cur[stop])
        _, kids = nodes.children(cur[~stop])
        cur = kids[kids >= 0]
    wanted_ids = np.sort(np.concatenate(wanted)) if wanted else np.zeros(0, np.int64)
    res = np.ones(len(wanted_ids), bool) if resident is None else np.asarray(resident(wanted_ids), bool)
    missing = wanted_ids[~res]
    draw = wanted_ids[res]
    if len(missing):
        stand_in = _resident_ancestors(nodes, missing, resident)
        draw = np.union1d(draw, stand_in[stand_in >= 0])
        draw = _drop_covered(nodes, draw)
    lo, hi = nodes.boxes(draw)
    px = camera.projected_size(lo, hi, nodes.edges(draw) / np.cbrt(np.maximum(nodes.count[draw], 1)))
    return SplatSelection(draw, wanted_ids, missing, px, tol)


def _resident_ancestors(nodes: NodeTable, ids: np.ndarray, resident) -> np.ndarray:
    """Per node, its nearest resident ancestor (``-1`` if none)."""
    out = np.full(len(ids), -1, np.int64)
    depth = nodes.depth[ids].copy()
    code = nodes.code[ids].copy()
    todo = np.arange(len(ids))
    while len(todo):
        depth[todo] -= 1
        code[todo] >>= 3
        alive = depth[todo] >= 0
        todo = todo[alive]
        if not len(todo):
            break
        anc = np.empty(len(todo), np.int64)
        for d in np.unique(depth[todo]):
            m = depth[todo] == d
            anc[m] = nodes.lookup(int(d), code[todo][m])
        ok = np.asarray(resident(np.maximum(anc, 0)), bool) & (anc >= 0)
        out[todo[ok]] = anc[ok]
        todo = todo[~ok]
    return out


def _drop_covered(nodes: NodeTable, ids: np.ndarray) -> np.ndarray:
    """``ids`` without those that have an ancestor in ``ids``."""
    ids = np.unique(ids)
    keys = {(int(d), int(c)) for d, c in zip(nodes.depth[ids], nodes.code[ids])}
    keep = np.ones(len(ids), bool)
    for i, (d, c) in enumerate(zip(nodes.depth[ids].tolist(), nodes.code[ids].tolist())):
        for a in range(d - 1, -1, -1):
            c >>= 3
            if (a, c) in keys:
                keep[i] = False
                break
    return ids[keep]
