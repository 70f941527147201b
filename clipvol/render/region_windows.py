"""Texture window shapes that follow the render action's region of interest, within one budget.

Why: the GPU brick cache gives every level a cube of ``W`` bricks per axis
(:func:`~clipvol.render.gpu_cache.allocate_gpu_windows`), the right shape for a volume view that
roams. A slice draws a thin slab of each level - wide in the plane, one or two bricks across it
(LaMar, Hamann & Joy, *Multiresolution cutting planes*, 2000) - so at a given budget its fine part
can be wider than the cube: 8 bricks of level 0 against a 6-brick cube, for a 1024^3 store of 64^3
bricks at 1 GB, and the slice is then drawn coarser than the plane policy asks and never converges.
The clip-texture already fits its windows around the region it is handed
(:func:`~clipvol.paging.toroidal.region_window`); this module gives the GPU cache the same rule for
its textures. Pure numpy: no GL, so it can be tested alone.

Rule
----
A level whose region is ``None`` (no region, or "the whole window") keeps its cube shape. A level
with region bricks wants, per axis, ``max(extent, cube)`` bricks, where ``extent`` is the span of the
region's bricks along that axis: any ``extent`` consecutive bricks map to distinct toroidal slots
(``b mod w``), so the whole region is on the GPU at once, and the cube's room along the thin axis is
kept, so a plane that scrolls reuses the layers it already uploaded. A level whose current shape
already spans the region keeps that shape (a texture is reallocated only when the region outgrows
it). A level with an empty region keeps its shape while the budget allows. Each shape is also
capped by the grid, ``max_axis`` bricks per axis (the GL 3D texture limit) and ``max_bricks`` per
texture.

When the shapes together exceed ``slots`` (the budget in bricks), slots are taken back, one brick
layer at a time, first from levels with an empty region (down to one brick), then along the axes
with the most room beyond the region's extent, then - the region does not fit - from the longest
axis of the finest level that still has more than one brick on it (that part is then drawn
coarser, as with cube windows).
"""

from __future__ import annotations

import numpy as np

__all__ = ["region_extent", "region_gpu_windows"]

Shape = tuple[int, int, int]


def region_extent(bricks) -> np.ndarray | None:
    """``(z, y, x)`` span in bricks of an ``(n, 3)`` array of brick indices (``None`` if empty)."""
    b = np.asarray(bricks, dtype=np.int64).reshape(-1, 3)
    if not len(b):
        return None
    return b.max(axis=0) - b.min(axis=0) + 1


def _fit_texture(shape: np.ndarray, floor: np.ndarray, max_bricks: int) -> np.ndarray:
    """Shrink ``shape`` until one texture holds it: first where it exceeds ``floor``, then the longest axis."""
    while int(np.prod(shape)) > max_bricks:
        slack = shape - floor
        k = int(np.argmax(slack)) if slack.max() > 0 else int(np.argmax(shape))
        if shape[k] <= 1:
            break
        shape[k] -= 1
    return shape


def region_gpu_windows(grids, cube, bricks, current, slots: int, *, max_axis=(1 << 30,) * 3,
                       max_bricks: int = 1 << 62) -> list[Shape | None]:
    """Per level the texture window shape ``(wz, wy, wx)`` in bricks (``None``: no texture).

    Parameters
    ----------
    grids : sequence of (z, y, x)
        Bricks per axis of every level.
    cube : sequence of shape or None
        The cube windows of the budget (:func:`~clipvol.render.gpu_cache.allocate_gpu_windows`);
        a level without one gets none here either.
    bricks : sequence or None
        Per level the region's ``(n, 3)`` brick indices or ``None`` (cube); ``None`` as a whole: no
        region, every level keeps its cube.
    current : sequence of shape or None
        The shapes in use (a level whose shape already spans its region keeps it).
    slots : int
        Bricks the budget holds in all (``budget // brick bytes``); the result never exceeds it
        when the cube windows do not.
    max_axis : (z, y, x)
        Most bricks per axis of one texture.
    max_bricks : int
        Most bricks in one texture.
    """
    n = len(cube)
    if bricks is None:
        return [None if c is None else tuple(int(v) for v in c) for c in cube]
    cap_axis = np.asarray(max_axis, dtype=np.int64)
    shapes: list[np.ndarray | None] = []
    floors: list[np.ndarray | None] = []  # per level the extent the region needs (0: nothing needed)
    for L in range(n):
        if cube[L] is None:
            shapes.append(None)
            floors.append(None)
            continue
        c = np.asarray(cube[L], dtype=np.int64)
        g = np.asarray(grids[L], dtype=np.int64)
        cur = None if current is None or current[L] is None else np.asarray(current[L], dtype=np.int64)
        b = bricks[L]
        if b is None:
            shapes.append(c.copy())
            floors.append(c.copy())  # a cube level gives nothing back before the region levels do
            continue
        ext = region_extent(b)
        if ext is None:
            shapes.append((c if cur is None else cur).copy())
            floors.append(np.zeros(3, dtype=np.int64))
            continue
        ext = np.minimum(ext, np.minimum(g, cap_axis))
        if cur is not None and np.all(cur >= ext):
            want = cur.copy()
        else:
            want = np.minimum(np.maximum(ext, c), np.minimum(g, cap_axis))
        shapes.append(_fit_texture(want, ext, int(max_bricks)))
        floors.append(ext)

    def total() -> int:
        return sum(int(np.prod(s)) for s in shapes if s is not None)

    levels = [L for L in range(n) if shapes[L] is not None]
    # 1. levels with an empty region give their slots back, down to one brick
    for L in sorted(levels, key=lambda L: -L):  # finest last: the coarse empty levels first
        while total() > slots and floors[L].max() == 0 and shapes[L].max() > 1:
            shapes[L][int(np.argmax(shapes[L]))] -= 1
    # 2. room beyond a region's extent, the largest first
    while total() > slots:
        best, key = None, 0
        for L in levels:
            slack = shapes[L] - np.maximum(floors[L], 1)
            k = int(np.argmax(slack))
            if slack[k] > key:
                best, key = (L, k), int(slack[k])
        if best is None:
            break
        shapes[best[0]][best[1]] -= 1
    # 3. the region does not fit: the finest level's longest axis
    while total() > slots:
        cand = [L for L in levels if shapes[L].max() > 1]
        if not cand:
            break
        L = min(cand)
        shapes[L][int(np.argmax(shapes[L]))] -= 1
    return [None if s is None else tuple(int(v) for v in s) for s in shapes]  # type: ignore[misc]
