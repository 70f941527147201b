"""The cutting-plane policy: nodes the plane crosses, finer near the point of interest, balanced,
with blend ratios - checked against brute-force geometry on world boxes (not the balance module)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.scene.params import RenderParams
from clipvol.scene.plane import Plane, default_size
from clipvol.scene.selection import select
from clipvol.scene.selection.policies.plane import PlaneCut


def _cut(pyr, plane, **kw):
    params = RenderParams(policy="plane", **kw)
    size = default_size(pyr, plane, 1.0)
    lo, hi = pyr.volume_box()
    cam = plane.camera(size, 1.0).fit_depth(lo, hi)
    pol = PlaneCut(params, plane)
    sel = select(pyr, cam, params, policy=pol)
    return sel, pol


def _boxes(pyr, items):
    lv = np.array([it.level for it in items])
    lo = np.array([it.lo for it in items])
    hi = np.array([it.hi for it in items])
    return lv, lo, hi


PLANES = [
    ("axial", lambda p: Plane.axis(p, "axial", 70)),
    ("oblique", lambda p: Plane.through((100.0, 90.0, 60.0), (0.3, 0.4, 0.85))),
    ("steep", lambda p: Plane.through((60.0, 120.0, 64.0), (0.9, -0.1, 0.2))),
]


@pytest.fixture(scope="module")
def pyr():
    return Pyramid.build((128, 256, 256), (8, 8, 8), dtype="uint8", value_range=(0, 255))


@pytest.mark.parametrize("name,make", PLANES)
def test_balanced_cut_never_has_26_neighbours_two_levels_apart(pyr, name, make):
    pl = make(pyr)
    sel, _ = _cut(pyr, pl, focus=(30.0, 40.0, 60.0), distance_factor=1.0)
    lv, lo, hi = _boxes(pyr, sel.items)
    assert len(set(lv.tolist())) >= 3  # a real multiresolution cut
    eps = 1e-6
    # 26-neighbours: closed boxes touch (share a face, edge or corner)
    touch = np.all((lo[:, None] <= hi[None] + eps) & (lo[None] <= hi[:, None] + eps), axis=2)
    np.fill_diagonal(touch, False)
    gap = np.abs(lv[:, None] - lv[None])
    assert not np.any(touch & (gap >= 2)), f"{int(np.sum(touch & (gap >= 2)))} pairs two levels apart"


def _two_apart(lv, lo, hi) -> int:
    eps = 1e-6
    touch = np.all((lo[:, None] <= hi[None] + eps) & (lo[None] <= hi[:, None] + eps), axis=2)
    np.fill_diagonal(touch, False)
    return int(np.sum(touch & (np.abs(lv[:, None] - lv[None]) >= 2)))


def test_without_balancing_the_same_cut_has_pairs_two_levels_apart(pyr):
    """The control of the test above: the selection alone (no balancing) is unbalanced here."""

    class Unbalanced(PlaneCut):
        def cut(self, t):
            t.descend()

    pl = Plane.through((100.0, 90.0, 60.0), (0.3, 0.4, 0.85))
    params = RenderParams(policy="plane", focus=(30.0, 40.0, 60.0), distance_factor=0.5)
    lo, hi = pyr.volume_box()
    cam = pl.camera(default_size(pyr, pl, 1.0), 1.0).fit_depth(lo, hi)
    raw = select(pyr, cam, params, policy=Unbalanced(params, pl))
    assert _two_apart(*_boxes(pyr, raw.items)) > 0
    bal = select(pyr, cam, params, policy=PlaneCut(params, pl))
    assert _two_apart(*_boxes(pyr, bal.items)) == 0
    assert bal.counts["balance_splits"] > 0


@pytest.mark.parametrize("name,make", PLANES)
def test_tiles_cover_the_plane_inside_the_volume_once_and_all_cross_it(pyr, name, make):
    pl = make(pyr)
    sel, _ = _cut(pyr, pl, focus=(200.0, 30.0, 100.0))
    lv, lo, hi = _boxes(pyr, sel.items)
    assert np.all(pl.crosses(lo, hi))
    size = default_size(pyr, pl, 1.0)
    pts = pl.pixel_points(size, 1.0).reshape(-1, 3)
    vlo, vhi = pyr.volume_box()
    inside = np.all((pts > vlo) & (pts < vhi), axis=1)
    hits = np.zeros(len(pts), dtype=int)
    for a, b in zip(lo, hi):
        hits += np.all((pts >= a) & (pts < b), axis=1)
    assert np.all(hits[inside] == 1)


def test_finer_near_the_point_of_interest(pyr):
    pl = Plane.axis(pyr, "axial", 64)
    poi = np.array([20.0, 20.0, 64.0])
    sel, _ = _cut(pyr, pl, focus=tuple(poi))
    lv, lo, hi = _boxes(pyr, sel.items)
    d = np.linalg.norm(np.clip(poi, lo, hi) - poi, axis=1)  # distance from the POI to each tile
    assert lv[d == 0].max() == 0  # the tile holding the POI is full resolution
    far = d > 150
    assert far.any() and lv[far].min() >= 2
    # the level never decreases with distance by more than the balancing allows
    order = np.argsort(d)
    assert np.corrcoef(d[order], lv[order])[0, 1] > 0.7


def test_full_resolution_and_fixed_level(pyr):
    pl = Plane.axis(pyr, "coronal", 100)
    sel, _ = _cut(pyr, pl, level=0)
    lv, lo, hi = _boxes(pyr, sel.items)
    assert set(lv.tolist()) == {0}
    # every level-0 brick the plane crosses, brute force over the grid
    g = pyr.grid(0)
    idx = np.stack(np.meshgrid(*(np.arange(n) for n in g), indexing="ij"), -1).reshape(-1, 3)
    blo, bhi = pyr.node_box(0, idx)
    assert len(sel.items) == int(np.sum(pl.crosses(blo, bhi)))
    sel2, _ = _cut(pyr, pl, level=2)
    assert {it.level for it in sel2.items} == {2}


def test_blend_ratios_mark_corners_touching_a_coarser_tile(pyr):
    pl = Plane.through((100.0, 90.0, 60.0), (0.3, 0.4, 0.85))
    sel, pol = _cut(pyr, pl, focus=(90.0, 80.0, 60.0))
    lv, lo, hi = _boxes(pyr, sel.items)
    assert sel.node_data, "expected blending somewhere"
    eps = 1e-6
    for i, it in enumerate(sel.items):
        r = sel.node_data.get((it.level, tuple(it.index)), np.zeros((2, 2, 2)))
        for cz in (0, 1):
            for cy in (0, 1):
                for cx in (0, 1):
                    corner = np.array([(lo[i], hi[i])[cx][0], (lo[i], hi[i])[cy][1], (lo[i], hi[i])[cz][2]])
                    at = np.all((lo <= corner + eps) & (hi >= corner - eps), axis=1)
                    coarser = bool(np.any(at & (lv > it.level)))
                    assert r[cz, cy, cx] == float(coarser), (it, (cz, cy, cx))


def test_plane_policy_needs_a_plane(pyr):
    params = RenderParams(policy="plane")
    assert params.policy == "plane"
    cam = Plane.axis(pyr, "axial", 3).camera((64, 64), 1.0)
    with pytest.raises(ParameterError, match="plane"):
        select(pyr, cam, params)
