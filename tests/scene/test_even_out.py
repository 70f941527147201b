"""The projected-size policy evened out: level by level, where the paper's rule refines some nodes of
a sibling group and not the others, all of them are refined when that grows the group at most 2x.

The reference recurses level by level from first principles (node boxes from the brick grid, the
projected voxel size from the box's nearest corner depth, the growth test written from its
definition), sharing nothing with the vectorised traversal under test; a whole-volume frustum
(nothing culled) and a full octree (8 children per node) keep the recursion plain.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import select
from clipvol.scene.selection.policies.projected_size import even_out

from test_policies import PYR, TOP, node_box  # the same 64³ pyramid of 8³ bricks and its node boxes


def px(cam, level, b):
    """Pixels a voxel of ``level`` covers at node ``b``'s nearest corner depth."""
    lo, hi = node_box(level, b)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    depth = ((corners - cam.eye) @ cam.forward).min()
    if depth <= 0:
        return math.inf
    return 2.0**level * cam.size[1] / (2 * math.tan(math.radians(cam.fov_y) / 2) * depth)


def reference(cam, thr, evened=True):
    """Leaves of the level-by-level cut: the paper's rule, then (``evened``) every node of a sibling
    group refined where ``r`` of its ``n`` are and ``8 n <= 2 ((n - r) + 8 r)``, then the same test
    over all the level's nodes."""
    leaves, level, nodes = set(), TOP, [(0, 0, 0)]
    while nodes:
        need = {b: level > 0 and px(cam, level, b) > thr for b in nodes}
        if evened:
            for p in {tuple(i // 2 for i in b) for b in nodes}:  # per sibling group (one parent's children)
                group = [b for b in nodes if tuple(i // 2 for i in b) == p]
                n, r = len(group), sum(need[b] for b in group)
                if 0 < r < n and 8 * n <= 2 * ((n - r) + 8 * r):
                    need.update({b: True for b in group})
            n, r = len(nodes), sum(need.values())  # then the level as a whole
            if 0 < r < n and 8 * n <= 2 * ((n - r) + 8 * r):
                need = {b: True for b in nodes}
        need = [need[b] for b in nodes]
        leaves |= {(level, b) for b, nd in zip(nodes, need) if not nd}
        nodes = [(2 * b[0] + dz, 2 * b[1] + dy, 2 * b[2] + dx) for b, nd in zip(nodes, need) if nd
                 for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]
        level -= 1
    return leaves


EYES = [(31.5, 31.5, -70.0), (-50.0, 10.0, -40.0), (100.0, 80.0, 90.0), (31.5, 20.0, -30.0)]
THRESHOLDS = [0.5, 1.0, 1.5, 2.0, 3.0, 4.0]


def whole_view(eye):
    return Camera.perspective(eye, (31.5, 31.5, 31.5), up=(0, 1, 0), fov_y=100.0, size=(64, 64)).fit_depth(
        *PYR.volume_box())


@pytest.mark.parametrize("eye", EYES)
def test_the_cut_is_the_evened_rule(eye):
    cam = whole_view(eye)
    for thr in THRESHOLDS:
        sel = select(PYR, cam, RenderParams(lod_threshold=thr))
        assert sel.counts["culled_frustum"] == 0
        assert set(sel.wanted) == reference(cam, thr)


def test_evening_out_happens_and_only_refines():
    """Not vacuous: some of the cases above are evened; evened leaves are never coarser than the
    rule's and the cut at most doubles per evened level."""
    evened_cases = 0
    for eye in EYES:
        cam = whole_view(eye)
        for thr in THRESHOLDS:
            rule, ev = reference(cam, thr, evened=False), reference(cam, thr)
            if rule != ev:
                evened_cases += 1
                assert len({lv for lv, _ in ev}) <= len({lv for lv, _ in rule})
            for lv, b in rule:  # every leaf of the rule is covered by evened leaves as fine or finer
                covered = [(l2, c) for l2, c in ev if l2 <= lv and all((ci >> (lv - l2)) == bi for ci, bi in zip(c, b))]
                assert covered
    assert evened_cases >= 3


def test_even_out_growth_rule():
    # 7 of 8 refined: 64 <= 2 * (1 + 56): all refined
    assert even_out(np.array([True] * 7 + [False])).all()
    # 1 of 8: 64 > 2 * (7 + 8): the mixed cut stays
    assert even_out(np.array([True] + [False] * 7)).sum() == 1
    # 2 of 8 (6 + 16 = 22, 44 < 64) stays; 3 of 8 (5 + 24 = 29, 58 < 64) stays; 4 of 8 (4 + 32 = 36, 72 >= 64) evens
    assert even_out(np.array([True] * 2 + [False] * 6)).sum() == 2
    assert even_out(np.array([True] * 3 + [False] * 5)).sum() == 3
    assert even_out(np.array([True] * 4 + [False] * 4)).all()
    assert not even_out(np.zeros(5, dtype=bool)).any()
    # per group: 7 of 8 in one group (evened), 1 of 8 in the other (kept)
    need = np.array([True] * 7 + [False] + [True] + [False] * 7)
    got = even_out(need, np.repeat([5, 9], 8))
    assert got[:8].all() and got[8:].sum() == 1


def test_a_smaller_threshold_is_never_coarser():
    """Per sibling group, evening keeps the threshold's order: every leaf of the cut at a threshold
    is covered by leaves as fine or finer at any smaller one."""
    for eye in EYES:
        cam = whole_view(eye)
        cuts = [set(select(PYR, cam, RenderParams(lod_threshold=t)).wanted) for t in sorted(THRESHOLDS)]
        for finer, coarser in zip(cuts, cuts[1:]):
            for lv, b in coarser:
                assert any(l2 <= lv and all((ci >> (lv - l2)) == bi for ci, bi in zip(c, b)) for l2, c in finer)


def test_the_greedy_form_is_not_evened():
    cam = whole_view(EYES[3])
    texels = int(np.prod(PYR.brick_shape))
    for bricks in (8, 15, 22, 29):
        sel = select(PYR, cam, RenderParams(lod_threshold=0.5, max_texels_drawn=bricks * texels))
        assert len(sel.items) <= bricks
