"""Orders over a cut: exact back-to-front visibility, and the load priority (pure numpy).

**Visibility** (:func:`back_to_front`): the draw order of a depth-first traversal of the octree whose
per-node child order comes from the eye (perspective: on each axis the child half on the far side
of the node's split plane first; orthographic: by the sign of the view direction). Because every
line crosses each split plane once, from the eye's side to the far side, octants are drawn in
decreasing number of "far" axes, which never draws a box before one that occludes it. Sorting by
centre distance is *not* a visibility order for mixed sizes (LaMar, Hamann & Joy 1999, section 4).

**Depth first** (:func:`depth_first`): the same traversal with children in a fixed order (Morton
order): no camera, one sort; siblings side by side, which is all a merge needs.

**Load priority** (:func:`load_order`): coarse levels first (they are the fallback of everything
below them), then nearest to the eye first.
"""

from __future__ import annotations

import numpy as np

from ...bricking.pyramid import Pyramid
from ..camera import Camera
from .octree import Octree

__all__ = ["back_to_front", "order_nodes", "depth_first", "load_order"]

# octant rank by its "far" bits (x, y, z in bits 2, 1, 0): more far axes first, ties by code
_FAR_ORDER = sorted(range(8), key=lambda c: (-bin(c).count("1"), -c))
_RANK = np.empty(8, dtype=np.int64)
_RANK[_FAR_ORDER] = np.arange(8)


def back_to_front(pyramid: Pyramid, camera: Camera, levels, indices) -> np.ndarray:
    """Permutation that puts non-nested octree nodes ``(levels[i], indices[i])`` in back-to-front order.

    The order is that of a depth-first traversal of the octree (virtual levels above the top
    included) whose children are visited far side first (see the module docstring): exact for any
    mix of levels, perspective or orthographic, with the eye anywhere (inside a node, on a split
    plane, exactly on an axis or diagonal).

    Parameters
    ----------
    levels : array_like of int, shape (n,)
    indices : array_like of int, shape (n, 3)
        Brick indices ``(bz, by, bx)``; no node may contain another.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` indices into the inputs, the first to draw first.
    """
    return order_nodes(Octree(pyramid), camera, np.asarray(levels, dtype=np.int64).reshape(-1),
                  np.asarray(indices, dtype=np.int64).reshape(-1, 3))


def order_nodes(tree: Octree, camera: Camera, levels: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """:func:`back_to_front` over an existing :class:`Octree`."""
    n = len(levels)
    if n < 2:
        return np.arange(n)
    depth = tree.root - int(levels.min())
    ranks = np.zeros((n, max(depth, 1)), dtype=np.int64)
    eye = camera.eye
    fwd = camera.forward
    for k in range(depth):
        plv = tree.root - k  # parent level of this step
        rows = np.nonzero(levels < plv)[0]
        if not len(rows):
            continue
        shift = (plv - levels[rows])[:, None]
        anc = idx[rows] >> shift  # ancestor at plv, (z, y, x)
        bit = ((idx[rows] >> (shift - 1)) & 1)[:, ::-1]  # child half per axis, (x, y, z)
        if camera.orthographic:
            far_high = np.broadcast_to(fwd >= 0, bit.shape)
        else:
            far_high = eye[None, :] <= tree.split(plv, anc)
        far = np.where(far_high, bit == 1, bit == 0)
        code = far[:, 0] * 4 + far[:, 1] * 2 + far[:, 2]
        ranks[rows, k] = _RANK[code]
    return np.lexsort(ranks.T[::-1])


def depth_first(levels: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Permutation putting non-nested octree nodes in depth-first order, children by octant number
    (``4 z + 2 y + x``): the Morton order of each node's first level-0 brick. Siblings come side by
    side, which is all :func:`~clipvol.scene.selection.merge_items` needs of an order."""
    first = idx.astype(np.int64) << levels[:, None]
    key = np.zeros(len(levels), dtype=np.int64)
    bits = int(first.max()).bit_length() if len(first) else 0
    for b in range(bits):
        key |= (((first[:, 0] >> b) & 1) << (3 * b + 2)) | (((first[:, 1] >> b) & 1) << (3 * b + 1)) \
            | (((first[:, 2] >> b) & 1) << (3 * b))
    return np.argsort(key, kind="stable")


def load_order(tree: Octree, camera: Camera, lv: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Permutation of nodes ``(lv, idx)``: coarse levels first, then by distance from the eye."""
    if not len(lv):
        return np.arange(0)
    dist = np.empty(len(lv))
    for L in np.unique(lv):
        rows = np.nonzero(lv == L)[0]
        lo, hi = tree.boxes(int(L), idx[rows])
        near = np.clip(camera.eye, lo, hi)
        dist[rows] = np.linalg.norm(near - camera.eye, axis=1)
    return np.lexsort((dist, -lv))
