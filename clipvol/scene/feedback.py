"""Ray feedback: the page-table nodes a single pass's rays sampled, and the bricks they ask for (pure numpy).

Why: the clip-texture loads a window's bricks nearest the centre of interest first, whether or not
any ray reaches them. Ray-guided renderers (C. Crassin, F. Neyret, S. Lefebvre and E. Eisemann,
"GigaVoxels: Ray-Guided Streaming for Efficient and Detailed Voxel Rendering", I3D 2009;
M. Hadwiger, J. Beyer, W.-K. Jeong and H. Pfister, "Interactive Volume Exploration of Petascale
Microscopy Data Streams Using a Visualization-Driven Virtual Memory Approach", IEEE TVCG 2012) let
the rays report what they sampled, so that bricks hidden behind opaque matter or outside every
ray's reach load last. With ``RenderParams.feedback`` the single pass (``FEEDBACK`` in
``shaders/raymarch.frag.glsl``) marks each DRAWN page-table entry its rays marched in a flag
texture laid out like the table; :func:`sampled_nodes` turns the flags into node keys and
:func:`wanted_under` into the cut's wanted bricks under those nodes (a node drawn from a coarse
stand-in asks for its own brick and the finer ones the cut wants inside it).
"""

from __future__ import annotations

import numpy as np

from ..rows import rows_in

__all__ = ["sampled_nodes", "wanted_under"]


def sampled_nodes(table, flags: np.ndarray) -> np.ndarray:
    """``(n, 4)`` int64 ``(level, z, y, x)`` of the nodes of ``table`` whose flag is set.

    Parameters
    ----------
    table : clipvol.scene.page_table.PageTable
        The table the pass walked (its ``base``, ``c0`` and ``size`` place each entry).
    flags : ndarray
        One value per table entry, at least ``len(table.entries)`` long (the flag texture read
        back, flattened): non-zero where a ray sampled the entry's node.
    """
    hit = np.flatnonzero(np.asarray(flags).reshape(-1)[:len(table.entries)])
    out = []
    for L in range(len(table.base)):
        size = np.asarray(table.size[L], dtype=np.int64)
        n = int(np.prod(size))
        if n == 0:
            continue
        b = int(table.base[L])
        local = hit[(hit >= b) & (hit < b + n)] - b
        if len(local):
            cells = np.stack(np.unravel_index(local, tuple(size)), axis=1) + np.asarray(table.c0[L], dtype=np.int64)
            out.append(np.concatenate([np.full((len(local), 1), L, dtype=np.int64), cells], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 4), dtype=np.int64)


def wanted_under(nodes: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """The rows of ``wanted`` (``(m, 4)`` ``(level, z, y, x)``) that lie in one of ``nodes``' boxes:
    a wanted brick of level ``Lw`` under node ``(L, cell)`` has ``Lw <= L`` and ``index >> (L - Lw)
    == cell``. In ``wanted``'s order (its load-priority order)."""
    wanted = np.asarray(wanted, dtype=np.int64).reshape(-1, 4)
    nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 4)
    keep = np.zeros(len(wanted), dtype=bool)
    for L in np.unique(nodes[:, 0]).tolist():
        below = wanted[:, 0] <= L
        if not below.any():
            continue
        w = wanted[below]
        anc = np.concatenate([np.full((len(w), 1), L, dtype=np.int64), w[:, 1:] >> (L - w[:, :1])], axis=1)
        keep[np.flatnonzero(below)[rows_in(anc, nodes)]] = True
    return wanted[keep]
