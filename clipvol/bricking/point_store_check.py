"""Checking a point store: every invariant of the octree, read back from the whole store.

The checker reads the store through :mod:`.point_store_open` only, so it judges what a reader sees.
"""

from __future__ import annotations

import numpy as np

from .point_store_open import open_point_store, read_node_table
from .points import GEO_BITS, node_box

__all__ = ["check_point_store"]


def check_point_store(path) -> list[str]:
    """Problems found in a point store (empty list: sound). Reads the whole node table and points.

    Checks: every node holds at most ``max_points`` points; leaves' counts equal their weights and
    add up to ``num_points``; an inner node's weight is its children's sum; every stored point lies
    in its node's box (within the quantum ``edge / 2**GEO_BITS``); node rows tile ``points/*``.
    """
    meta, g = open_point_store(path)
    t = read_node_table(g)
    probs = []
    if len(t["code"]) != meta.num_nodes:
        probs.append(f"nodes: expected {meta.num_nodes} nodes, found {len(t['code'])}")
    if (t["count"] > meta.max_points).any():
        probs.append(f"nodes: {(t['count'] > meta.max_points).sum()} node(s) hold more than max_points={meta.max_points}")
    leaf = t["child_mask"] == 0
    if (t["count"][leaf] != t["weight"][leaf]).any():
        probs.append("nodes: a leaf's count differs from its weight")
    if int(t["weight"][leaf].sum()) != meta.num_points:
        probs.append(f"nodes: leaves hold {int(t['weight'][leaf].sum())} points, expected num_points={meta.num_points}")
    # children's weights add up to the parent's
    inner = np.flatnonzero(~leaf)
    d = t["depth"].astype(np.int64)
    for dd in np.unique(d[inner]):
        sel = np.flatnonzero(d == dd + 1)
        pcode = t["code"][sel] >> 3
        ps = np.flatnonzero(d == dd)
        pos = np.searchsorted(t["code"][ps], pcode)
        ok = (pos < len(ps)) & (t["code"][ps][np.minimum(pos, len(ps) - 1)] == pcode)
        if not ok.all():
            probs.append(f"nodes: {(~ok).sum()} node(s) at depth {dd + 1} have no parent")
        sums = np.bincount(pos[ok], weights=t["weight"][sel][ok], minlength=len(ps))
        bad = (~leaf[ps]) & (sums != t["weight"][ps])
        if bad.any():
            probs.append(f"nodes: {bad.sum()} inner node(s) at depth {dd} whose weight is not their children's sum")
    order = np.argsort(t["offset"])
    ends = t["offset"][order] + t["count"][order]
    if len(order) and (t["offset"][order][1:] != ends[:-1]).any():
        probs.append("nodes: point rows do not tile points/xyz")
    xyz = np.asarray(g["points/xyz"][:], np.float64) + np.asarray(meta.origin)
    if len(order) and ends[-1] != len(xyz):
        probs.append(f"points: expected {ends[-1]} rows, found {len(xyz)}")
    node_of = np.repeat(np.arange(len(d)), t["count"])
    lo, hi = node_box(d, t["code"], meta.origin, meta.edge)
    rows = np.concatenate([np.arange(o, o + c) for o, c in zip(t["offset"], t["count"])]) if len(d) else np.zeros(0, int)
    q = meta.edge / 2**GEO_BITS + 1e-6 * meta.edge
    p = xyz[rows]
    out = np.any((p < lo[node_of] - q) | (p > hi[node_of] + q), axis=1)
    if out.any():
        probs.append(f"points: {out.sum()} stored point(s) outside their node's box")
    return probs
