"""Database decomposition for sort-last rendering: a kd split of the volume into convex groups,
their visibility order from a camera, and the compositing of the groups' partial images.

Why a kd split: each group must be convex, so that a ray crosses it in one interval and the
groups' partial images can be composited per pixel in one order; a kd tree gives that order
for any eye position by a comparison per split plane (the child on the eye's side is in
front), as in the database decomposition of Bhaniramka and Demange (2002) §3.3. Planes fall on
level-0 brick faces, so each group holds whole finest-level bricks.

Compositing (pure numpy, float64): premultiplied partial images back to front with the
``(1, 1 - alpha)`` "over" operator, ``C = C_front + (1 - a_front) C_back``; maximum intensity
projection takes the per-pixel maximum of the raw values. Both are associative, so the groups
may be combined in any tree as long as the order is kept.

References
----------
Bhaniramka, P. and Demange, Y. (2002). OpenGL Volumizer: a toolkit for high quality volume
rendering of large data sets. Proc. IEEE/ACM Symposium on Volume Visualization and Graphics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError

__all__ = ["KdNode", "kd_split", "back_to_front", "composite_over", "composite_max"]


@dataclass(frozen=True)
class KdNode:
    """A node of the split: a leaf (``group`` set) or a plane ``x[axis] = plane`` between ``low`` and ``high``."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    group: int | None = None
    axis: int | None = None
    plane: float | None = None
    low: "KdNode | None" = None
    high: "KdNode | None" = None

    def leaves(self) -> list["KdNode"]:
        if self.group is not None:
            return [self]
        return self.low.leaves() + self.high.leaves()  # type: ignore[union-attr]


def kd_split(pyramid, n: int) -> KdNode:
    """Split ``pyramid``'s world box into ``n`` convex boxes with planes on level-0 brick faces.

    Each split cuts the longest axis (in bricks) of a box so that the two sides get brick counts
    in proportion to the groups they will hold. Raises :class:`ParameterError` when the volume
    has fewer level-0 bricks along its axes than ``n`` needs.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ParameterError(f"workers: expected an integer >= 1, got {n!r}")
    B = np.array(pyramid.brick_shape[::-1], dtype=np.int64)  # (x, y, z)
    shape = np.array(pyramid.shape[::-1], dtype=np.int64)
    sp = np.array(pyramid.spacing[::-1], dtype=np.float64)
    grid = -(-shape // B)
    counter = iter(range(n))

    def world(axis: int, brick: int) -> float:
        return float((min(brick * B[axis], shape[axis]) - 0.5) * sp[axis])

    def split(blo: np.ndarray, bhi: np.ndarray, k: int) -> KdNode:
        lo = tuple(world(a, int(blo[a])) for a in range(3))
        hi = tuple(world(a, int(bhi[a])) for a in range(3))
        if k == 1:
            return KdNode(lo, hi, group=next(counter))
        ext = bhi - blo
        axis = int(np.argmax(ext))
        if ext[axis] < 2:
            raise ParameterError(f"workers: expected at most as many groups as level-0 bricks can be split into, "
                                 f"got {n} for a brick grid of {tuple(int(g) for g in grid)} (x, y, z)")
        k1 = k // 2
        cut = int(blo[axis] + max(1, min(ext[axis] - 1, round(ext[axis] * k1 / k))))
        mid_hi, mid_lo = bhi.copy(), blo.copy()
        mid_hi[axis] = cut
        mid_lo[axis] = cut
        return KdNode(lo, hi, axis=axis, plane=world(axis, cut), low=split(blo, mid_hi, k1), high=split(mid_lo, bhi, k - k1))

    return split(np.zeros(3, dtype=np.int64), grid, int(n))


def back_to_front(node: KdNode, camera) -> list[int]:
    """Group ids of ``node``'s leaves from the farthest to the nearest to ``camera``'s eye.

    Perspective: the side of each plane holding the eye is in front. Orthographic: the side the
    view direction comes from is in front.
    """
    if node.group is not None:
        return [node.group]
    if camera.orthographic:
        low_in_front = float(camera.forward[node.axis]) > 0.0
    else:
        low_in_front = float(camera.eye[node.axis]) < float(node.plane)
    front, back = (node.low, node.high) if low_in_front else (node.high, node.low)
    return back_to_front(back, camera) + back_to_front(front, camera)


def composite_over(partials_back_to_front: list[np.ndarray]) -> np.ndarray:
    """``(h, w, 4)`` premultiplied images, back to front, combined with ``(1, 1 - alpha)``."""
    if not partials_back_to_front:
        raise ParameterError("partials: expected at least one partial image")
    acc = np.asarray(partials_back_to_front[0], dtype=np.float64).copy()
    for img in partials_back_to_front[1:]:
        front = np.asarray(img, dtype=np.float64)
        acc = front + (1.0 - front[..., 3:4]) * acc
    return acc


def composite_max(partials: list[np.ndarray]) -> np.ndarray:
    """Per-pixel maximum of raw MIP values (NaN-free ``(h, w)`` arrays); order does not matter."""
    if not partials:
        raise ParameterError("partials: expected at least one partial image")
    return np.maximum.reduce([np.asarray(p, dtype=np.float64) for p in partials])
