"""Splat node selection: the cut against a brute-force one, monotone in the tolerance, stand-ins."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.point_sources import ClusteredPointSource
from clipvol.bricking.point_store import build_point_store, open_point_store, read_node_table
from clipvol.bricking.points import NodeTable
from clipvol.errors import ParameterError
from clipvol.scene.camera import Camera
from clipvol.scene.splat_select import select_splat_nodes, tolerance_pixels


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    p = tmp_path_factory.mktemp("sel") / "p"
    build_point_store(ClusteredPointSource(30_000, seed=5), p, max_points=16, progress=False)
    meta, g = open_point_store(p)
    return NodeTable(read_node_table(g), meta.origin, meta.edge)


def _ortho(table, size=(200, 200)):
    c = table.origin + table.edge / 2
    return Camera.orthographic(tuple(c), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0), table.edge * 1.2, table.edge * 1.2, size=size)


def _brute_cut(table, tol_px, px_per_unit):
    """Every node whose splat fits (or a leaf) while all its ancestors' splats do not: dicts by (depth, code)."""
    splat = table.edge / 2.0 ** table.depth / np.cbrt(table.count) * px_per_unit
    stop = (splat <= tol_px) | (table.child_mask == 0)
    key = {(int(d), int(c)): i for i, (d, c) in enumerate(zip(table.depth, table.code))}
    out = set()
    for i, (d, c) in enumerate(zip(table.depth.tolist(), table.code.tolist())):
        if not stop[i]:
            continue
        if all(not stop[key[(a, c >> 3 * (d - a))]] for a in range(d)):
            out.add(i)
    return out


def test_cut_matches_brute_force_and_points_fall_as_tolerance_grows(table):
    cam = _ortho(table)
    ppu = 200 / (table.edge * 1.2)
    drawn = []
    for tol in ("1px", "2px", "4px", 0.04, 0.08, 0.16, 0.5):
        sel = select_splat_nodes(table, cam, tol)
        assert set(sel.draw.tolist()) == _brute_cut(table, tolerance_pixels(tol, cam.size), ppu)
        assert sel.converged and np.array_equal(sel.draw, sel.wanted)
        drawn.append(int(table.count[sel.draw].sum()))
    assert all(a >= b for a, b in zip(drawn, drawn[1:])), drawn
    assert drawn[0] > 4 * drawn[-1], drawn


def test_frustum_culls_nodes_outside_the_view(table):
    c = table.origin + table.edge / 2
    # a narrow orthographic view of one corner region
    cam = Camera.orthographic(tuple(table.origin + table.edge * 0.1), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0),
                              table.edge * 0.1, table.edge * 0.1, size=(64, 64))
    sel = select_splat_nodes(table, cam, "1px")
    lo, hi = table.boxes(sel.draw)
    half = table.edge * 0.05
    ctr = table.origin + table.edge * 0.1
    assert len(sel.draw)
    assert np.all((hi[:, 0] >= ctr[0] - half - 1e-9) & (lo[:, 0] <= ctr[0] + half + 1e-9))
    assert np.all((hi[:, 1] >= ctr[1] - half - 1e-9) & (lo[:, 1] <= ctr[1] + half + 1e-9))
    assert len(sel.draw) < len(select_splat_nodes(table, _ortho(table), "1px").draw)
    del c


def test_missing_nodes_are_drawn_by_their_nearest_resident_ancestor_once(table):
    cam = _ortho(table)
    resident_depth = 2
    sel = select_splat_nodes(table, cam, "1px", resident=lambda ids: table.depth[ids] <= resident_depth)
    assert not sel.converged and len(sel.missing)
    assert table.depth[sel.draw].max() <= resident_depth
    # every leaf is covered by exactly one drawn node (no region twice, none left out)
    drawn = {(int(d), int(c)) for d, c in zip(table.depth[sel.draw], table.code[sel.draw])}
    leaves = np.flatnonzero(table.child_mask == 0)
    for i in leaves[:: max(1, len(leaves) // 300)]:
        d, c = int(table.depth[i]), int(table.code[i])
        cover = sum((a, c >> 3 * (d - a)) in drawn for a in range(d + 1))
        assert cover == 1


def test_tolerance_parsing():
    assert tolerance_pixels(0.05, (1000, 800)) == 50.0
    assert tolerance_pixels("5%", (1000, 800)) == 50.0
    assert tolerance_pixels("12px", (1000, 800)) == 12.0
    assert tolerance_pixels(3, (1000, 800)) == 3.0
    for bad in ("abc", -1, 0, "0px"):
        with pytest.raises(ParameterError, match="tolerance"):
            tolerance_pixels(bad, (10, 10))
