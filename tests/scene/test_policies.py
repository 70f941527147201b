"""Selection policies as strategies: each built-in policy's cut equals a brute-force recursion of its
rule written here from the paper's definition, and a policy added at run time needs only the registry.

The references compute node boxes from first principles (brick ``b`` of level ``L`` covers level-0
voxels ``[b B 2^L, (b+1) B 2^L)``, voxel centres at integer coordinates) and recurse node by node,
so they share nothing with the vectorised traversal under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import POLICIES, select
from clipvol.scene.selection.policies import RefinePolicy

N, B = 64, 8
PYR = Pyramid.build((N, N, N), (B, B, B))  # grids 8, 4, 2, 1: levels 0..3
TOP = PYR.num_levels - 1


def node_box(level, b):
    """World (x, y, z) box of brick ``b`` = (bz, by, bx) of ``level`` (spacing 1, centres at integers)."""
    ext = B * 2**level
    lo = np.array([b[2], b[1], b[0]], float) * ext - 0.5
    return lo, np.minimum(lo + ext, N - 0.5)


def brute_force(refine):
    """Leaves of the octree under ``refine(level, lo, hi) -> bool`` (level 0 never refined)."""
    leaves = set()

    def visit(level, b):
        lo, hi = node_box(level, b)
        if level > 0 and refine(level, lo, hi):
            for dz in (0, 1):
                for dy in (0, 1):
                    for dx in (0, 1):
                        visit(level - 1, (2 * b[0] + dz, 2 * b[1] + dy, 2 * b[2] + dx))
        else:
            leaves.add((level, b))

    visit(TOP, (0, 0, 0))
    return leaves


def whole_view(eye):
    """A camera whose frustum holds the whole volume, so no node is culled."""
    return Camera.perspective(eye, (31.5, 31.5, 31.5), up=(0, 1, 0), fov_y=100.0, size=(64, 64)).fit_depth(
        *PYR.volume_box())


EYES = [(31.5, 31.5, -70.0), (-50.0, 10.0, -40.0), (100.0, 80.0, 90.0)]


@pytest.mark.parametrize("eye", EYES)
@pytest.mark.parametrize("factor", [0.5, 1.0, 2.0])
def test_distance_policy_equals_the_papers_rule(eye, factor):
    cam = whole_view(eye)
    p = np.array(eye, float)

    def rule(level, lo, hi):  # accepted when the distance to the centre exceeds factor x diagonal
        return not (np.linalg.norm((lo + hi) / 2 - p) > factor * np.linalg.norm(hi - lo))

    sel = select(PYR, cam, RenderParams(policy="distance", distance_factor=factor))
    assert sel.counts["culled_frustum"] == 0
    assert set(sel.wanted) == brute_force(rule)


def test_distance_policy_uses_the_focus_point_and_gets_finer_near_it():
    cam = whole_view(EYES[0])
    focus = (60.0, 60.0, 60.0)
    sel = select(PYR, cam, RenderParams(policy="distance", focus=focus, distance_factor=1.0))
    f = np.array(focus)
    dist_by_level = {}
    for level, b in sel.wanted:
        lo, hi = node_box(level, b)
        dist_by_level.setdefault(level, []).append(np.linalg.norm((lo + hi) / 2 - f))
    # the finest bricks chosen are nearer the focus than the coarsest ones
    assert min(dist_by_level) < max(dist_by_level)
    assert np.mean(dist_by_level[min(dist_by_level)]) < np.mean(dist_by_level[max(dist_by_level)])


@pytest.mark.parametrize("eye", EYES)
@pytest.mark.parametrize("fraction", [0.1, 0.25, 0.5])
def test_field_of_view_policy_equals_the_papers_rule(eye, fraction):
    cam = whole_view(eye)
    p = np.array(eye, float)
    fov = math.radians(100.0)

    def rule(level, lo, hi):  # accepted when the subtended angle is below fraction x fov
        r = np.linalg.norm(hi - lo) / 2
        d = np.linalg.norm((lo + hi) / 2 - p)
        return d <= r or 2 * math.asin(r / d) > fraction * fov

    sel = select(PYR, cam, RenderParams(policy="field-of-view", fov_fraction=fraction))
    assert set(sel.wanted) == brute_force(rule)


def test_finer_filters_select_more_bricks():
    cam = whole_view(EYES[0])
    n = [len(select(PYR, cam, RenderParams(policy="distance", distance_factor=k)).wanted) for k in (0.25, 1, 4)]
    assert n[0] <= n[1] <= n[2] and n[0] < n[2]
    m = [len(select(PYR, cam, RenderParams(policy="field-of-view", fov_fraction=f)).wanted) for f in (0.5, 0.2, 0.05)]
    assert m[0] <= m[1] <= m[2] and m[0] < m[2]


def test_every_policy_gives_a_valid_cut_that_covers_the_view_once():
    """Whatever the policy, the cut is a set of non-nested nodes that tiles the volume (no hole,
    no region twice): the shared traversal guarantees it, not each policy."""
    cam = whole_view(EYES[1])
    pts = np.random.default_rng(0).uniform(-0.4, N - 0.6, size=(4000, 3))
    for name in sorted(POLICIES):
        if hasattr(POLICIES[name], "keep"):
            continue  # its own culling restricts the region (a cutting plane): tests/scene/test_plane_policy.py
        if name == "image":  # needs per-brick errors from a store's tables: tests/scene/test_image_policy.py
            continue
        params = RenderParams(policy=name, max_texels_drawn=40 * B**3 if name == "texel-budget" else None,
                              lod_threshold=2.0)
        sel = select(PYR, cam, params)
        lo = np.array([it.lo for it in sel.items])
        hi = np.array([it.hi for it in sel.items])
        inside = ((pts[:, None] > lo[None]) & (pts[:, None] < hi[None])).all(axis=2).sum(axis=1)
        np.testing.assert_array_equal(inside, 1, err_msg=name)
        assert sel.policy == name


def test_a_policy_added_at_run_time_needs_only_the_registry():
    class HalfWay(RefinePolicy):
        name = "test-halfway"

        def refine(self, t, level, lo, hi):  # refine only the nodes left of the volume's middle
            return lo[:, 0] < N / 2 - 1

    from clipvol.scene.policy_registry import register

    with pytest.raises(ParameterError, match="policy"):
        RenderParams(policy="test-halfway")
    register(HalfWay)  # the plug-in's one line: params (which never imports the policies) accepts it
    try:
        sel = select(PYR, whole_view(EYES[0]), RenderParams(policy="test-halfway"))
        assert set(sel.wanted) == brute_force(lambda level, lo, hi: lo[0] < N / 2 - 1)
    finally:
        del POLICIES[HalfWay.name]


def test_texel_budget_counts_regions_drawn_from_a_parent_outside_the_window():
    """With a residency window, children outside it are drawn from their parent: those boxes cost a
    brick each too, so the drawn texels stay within the budget whatever the window."""
    class Window:
        """Residency whose window at level 0 holds only the bricks with bx < 3."""

        def in_window_mask(self, level, idx):
            idx = np.asarray(idx).reshape(-1, 3)
            return idx[:, 2] < 3 if level == 0 else np.ones(len(idx), bool)

        def resident_mask(self, level, idx):
            return np.ones(len(np.asarray(idx).reshape(-1, 3)), bool)

    cam = whole_view(EYES[0])
    exercised = 0
    for bricks in range(8, 520, 12):
        sel = select(PYR, cam, RenderParams(policy="texel-budget", max_texels_drawn=bricks * B**3, lod_threshold=0.1),
                     residency=Window())
        exercised += sel.counts["outside_window"] > 0
        assert len(sel.items) <= bricks, (bricks, len(sel.items), sel.counts["outside_window"])
    assert exercised > 5  # the case this test is about did occur


def test_params_alone_knows_every_built_in_policy():
    """A fresh interpreter that imports only ``clipvol.scene.params`` validates every built-in policy
    name: the registry is full before the first RenderParams, though params never imports them."""
    import subprocess
    import sys

    names = ["projected-size", "texel-budget", "fixed", "roaming", "distance", "field-of-view", "image", "plane"]
    code = ("import sys; from clipvol.scene.params import RenderParams; "
            "[RenderParams(policy=n, max_texels_drawn=1) for n in sys.argv[1:]]; "
            "print(sorted(m for m in sys.modules if m.startswith('clipvol.scene.selection.policies.')))")
    out = subprocess.run([sys.executable, "-c", code, *names], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "clipvol.scene.selection.policies.distance" in out.stdout
