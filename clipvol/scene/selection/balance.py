"""Balancing a cut of the brick octree, and the blend ratios at node corners (pure numpy).

After LaMar, Hamann & Joy, *Multiresolution cutting planes* (section 4.3): blending inside a node
can only mix two resolutions - the node's own data ("high tile") and its parent's data over the
same region ("low tile") - so every pair of 26-neighbours (nodes sharing a face, an edge or a
corner) may differ by at most one level. :func:`balance` splits coarse leaves until that holds;
:func:`blend_ratios` then gives each leaf a ratio per corner: 1 where any of the seven other nodes
around that corner is coarser (the corner must show the low tile, which is exactly what the
coarser neighbour shows there), else 0. Interpolated across the node (trilinearly), the ratios
make the image continuous across every level change.

Leaves are ``(level, (bz, by, bx))`` keys; positions outside a level's grid do not exist.
"""

from __future__ import annotations

from typing import Callable, Iterable

import numpy as np

__all__ = ["balance", "blend_ratios", "covering_leaf", "unbalanced_pairs", "NEIGHBOURS_26"]

Key = tuple[int, tuple[int, int, int]]

#: the 26 offsets (dz, dy, dx) of a node's neighbourhood
NEIGHBOURS_26 = [(dz, dy, dx) for dz in (-1, 0, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dz, dy, dx) != (0, 0, 0)]


def _in_grid(b, grid) -> bool:
    return 0 <= b[0] < grid[0] and 0 <= b[1] < grid[1] and 0 <= b[2] < grid[2]


def covering_leaf(leaves: set, level: int, b, top: int) -> Key | None:
    """The leaf at ``level`` or coarser that covers position ``b`` of ``level``, or None
    (the position is covered by finer leaves, or by nothing)."""
    for M in range(level, top + 1):
        k = M - level
        key = (M, (b[0] >> k, b[1] >> k, b[2] >> k))
        if key in leaves:
            return key
    return None


def balance(leaves: Iterable[Key], grids, top: int, split: Callable[[int, tuple], list]) -> set:
    """Split leaves until no two 26-neighbours are two or more levels apart.

    Parameters
    ----------
    leaves : iterable of (level, index)
        The cut (leaves tile the region of interest without overlap).
    grids : sequence
        Bricks per axis ``(z, y, x)`` of each level.
    top : int
        The coarsest level a leaf may have.
    split : callable
        ``split(level, index) -> list of child keys`` that replace the leaf (the children that
        still cross the region of interest); an empty list means "cannot split" (no data for the
        children): the leaf stays and the pair stays unbalanced.

    Returns
    -------
    set of (level, index)
    """
    leaf = set((int(L), tuple(int(i) for i in b)) for L, b in leaves)
    stuck: set = set()
    changed = True
    while changed:
        changed = False
        for L, b in sorted(leaf):  # finest first
            if (L, b) not in leaf:
                continue
            grid = grids[L]
            for d in NEIGHBOURS_26:
                n = (b[0] + d[0], b[1] + d[1], b[2] + d[2])
                if not _in_grid(n, grid):
                    continue
                for M in range(L + 2, top + 1):
                    k = M - L
                    key = (M, (n[0] >> k, n[1] >> k, n[2] >> k))
                    if key in leaf:
                        if key not in stuck:
                            kids = split(*key)
                            if kids:
                                leaf.remove(key)
                                leaf.update((int(cl), tuple(int(i) for i in ci)) for cl, ci in kids)
                                changed = True
                            else:
                                stuck.add(key)
                        break
    return leaf


def unbalanced_pairs(leaves: set, grids, top: int) -> list[tuple[Key, Key]]:
    """Pairs of 26-neighbouring leaves two or more levels apart (empty for a balanced cut)."""
    out = []
    for L, b in leaves:
        for d in NEIGHBOURS_26:
            n = (b[0] + d[0], b[1] + d[1], b[2] + d[2])
            if not _in_grid(n, grids[L]):
                continue
            c = covering_leaf(leaves, L, n, top)
            if c is not None and c[0] >= L + 2:
                out.append(((L, b), c))
    return out


def blend_ratios(leaves: set, grids, top: int) -> dict[Key, np.ndarray]:
    """Per leaf with a coarser 26-neighbour, its ``(2, 2, 2)`` corner ratios ``[cz, cy, cx]``.

    Ratio 1 at a corner means "show the low tile (the parent's data) here"; leaves without a
    coarser neighbour are left out (all ratios 0).
    """
    out: dict[Key, np.ndarray] = {}
    for L, b in leaves:
        if L >= top:
            continue  # no parent data to blend towards
        r = np.zeros((2, 2, 2))
        grid = grids[L]
        coarser: dict[tuple, bool] = {}
        for d in NEIGHBOURS_26:
            n = (b[0] + d[0], b[1] + d[1], b[2] + d[2])
            if _in_grid(n, grid):
                c = covering_leaf(leaves, L, n, top)
                coarser[d] = c is not None and c[0] > L
        if not any(coarser.values()):
            continue
        for cz in (0, 1):
            for cy in (0, 1):
                for cx in (0, 1):
                    for d, is_coarse in coarser.items():
                        if is_coarse and all(di in ((-1, 0) if ci == 0 else (0, 1)) for di, ci in zip(d, (cz, cy, cx))):
                            r[cz, cy, cx] = 1.0
                            break
        out[(L, b)] = r
    return out
