"""Frame-to-frame coherence of a cut: when the last frame's cut is this frame's, and its order.

A fixed-level cut of thousands of bricks does not change when the camera turns: the policy's
refine decision ignores the camera (``policy.camera_free()``), and the camera only culls. Walking
the octree again, resolving residency, merging and building the page table for it costs tens of
milliseconds of host time a frame (a 6,000-brick cut) while the rays cost about one on a GPU. The
frame loop (:mod:`clipvol.render.frame_loop`) keeps the last converged cut and draws it again while
:func:`cut_holds` says the new camera's traversal would make the same cut; what the render stage
derives from a cut (merged boxes, page table) is kept with it. Neuroglancer and BigDataViewer keep
their page tables between frames the same way; ray-guided renderers (Crassin et al.,
*GigaVoxels*, 2009; Hadwiger et al., *Interactive Volume Exploration of Petascale Microscopy Data
Streams Using a Visualization-Driven Virtual Memory Approach*, 2012) go further and let the rays
report what they need.

The test is exact, not a heuristic: the traversal culls a node only by the frustum (the shape,
the transfer function and the policy's ``keep`` do not depend on the camera), a node's box holds
its children's, and :meth:`~clipvol.scene.camera.Camera.boxes_in_frustum` is the traversal's own
test. So the same nodes are kept and refined when every box the frustum culled stays outside the
new frustum and every leaf stays inside it. It is answered over flat arrays in two vectorised
calls (one, for the leaves, when their bounding box lies wholly inside the frustum).

Pure numpy.
"""

from __future__ import annotations

import numpy as np

from .cut import Selection
from .order import back_to_front

__all__ = ["replayable", "cut_holds", "node_order"]


def replayable(sel: Selection) -> bool:
    """Can ``sel`` be drawn again for another camera? Only a cut made by a camera-free policy
    (:attr:`Selection.frustum_culled` kept) whose every item is a whole node box drawn from its own
    brick: no ancestor stands in (fallback), no region is missing, no child outside the window
    is drawn from its parent - so its items are exactly its leaves and :func:`node_order` can order
    them (and their merged boxes) for any camera."""
    c = sel.counts
    return sel.frustum_culled is not None and not c.get("fallback") and not c.get("missing") \
        and not c.get("outside_window")


def cut_holds(sel: Selection, camera) -> bool:
    """Would :func:`~clipvol.scene.selection.select` make ``sel``'s cut again for ``camera``
    (the same parameters, transfer function and residency)? True when :func:`replayable`, no box
    the frustum culled enters ``camera``'s frustum, and every item (a leaf) stays in it."""
    if not replayable(sel):
        return False
    lo, hi = sel.frustum_culled
    if len(lo) and bool(np.any(camera.boxes_in_frustum(lo, hi))):
        return False
    items = sel.items
    if not len(items):
        return True
    # the cut's bounding box wholly inside the frustum answers for every leaf (an orbit around a
    # volume in view: no test per leaf); else the traversal's own test, leaf by leaf
    if bool(camera.boxes_within_frustum(items.lo.min(axis=0), items.hi.max(axis=0))[0]):
        return True
    return bool(np.all(camera.boxes_in_frustum(items.lo, items.hi)))


def node_order(items, pyramid, camera) -> np.ndarray:
    """Back-to-front permutation of whole-node draw items, merged or not (a merged item of ``span``
    bricks from brick ``index`` of ``level`` is the node ``index / span`` of level
    ``level + log2(span)``): the order :func:`~clipvol.scene.selection.merge_items` would have
    kept had the items been selected for ``camera``."""
    rows = np.asarray([(it.level, *it.index, it.span) for it in items], dtype=np.int64).reshape(-1, 5)
    shift = np.round(np.log2(np.maximum(rows[:, 4], 1))).astype(np.int64)
    return back_to_front(pyramid, camera, rows[:, 0] + shift, rows[:, 1:4] >> shift[:, None])
