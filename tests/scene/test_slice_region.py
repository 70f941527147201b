"""The slice region holds every brick the plane policy's own traversal draws (and the parents its
tiles blend with), and far fewer than the slab at full resolution."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.params import RenderParams
from clipvol.scene.plane import Plane, default_pixel_size, default_size
from clipvol.scene.selection import select
from clipvol.scene.slice_cover import slice_cut
from clipvol.scene.slice_region import slice_region


def _drawn(pyr, plane, params, px):
    """Bricks the traversal draws for ``plane`` (every brick resident) and their blend parents."""
    size = default_size(pyr, plane, px)
    lo, hi = pyr.volume_box()
    cam = plane.camera(size, px).fit_depth(lo, hi)
    policy = slice_cut(pyr, plane, params, px, size)
    sel = select(pyr, cam, params, policy=policy)
    keys = {(int(it.level), tuple(int(v) for v in it.index)) for it in sel.items}
    parents = {(L + 1, tuple(i // 2 for i in idx)) for (L, idx) in policy.node_data if L + 1 < pyr.num_levels}
    return keys | parents


@pytest.mark.parametrize("normal,focus,df", [
    ((0, 0, 1), (100.0, 60.0, 70.5), 1.0),
    ((0, 1, 0), (30.0, 64.0, 20.0), 0.5),
    ((0.3, -0.5, 0.8), (90.0, 70.0, 60.0), 1.0),
    ((1, 0, 0), None, 1.0),
])
def test_region_holds_what_the_plane_policy_draws(normal, focus, df):
    pyr = Pyramid.build((96, 128, 160), (8, 8, 8), (1.0, 1.0, 1.0), "mean", "float32", (0.0, 1.0))
    origin = focus if focus is not None else (80.0, 64.0, 48.0)
    plane = Plane.through(origin, normal)
    params = RenderParams(policy="plane", focus=focus, distance_factor=df)
    px = default_pixel_size(pyr, plane)
    region = slice_region(pyr, plane, params, px, size=default_size(pyr, plane, px))
    held = {(L, tuple(int(v) for v in k)) for L, b in enumerate(region.bricks) for k in b.tolist()}
    drawn = _drawn(pyr, plane, params, px)
    missing = drawn - held
    assert not missing, sorted(missing)[:10]  # the region pages the very cut the slice draws


def test_region_stays_small_where_the_full_resolution_slab_grows():
    # a 2048^3 pyramid of 32^3 bricks: only the geometry is computed, no brick exists
    pyr = Pyramid.build((2048, 2048, 2048), (32, 32, 32), (1.0, 1.0, 1.0), "mean", "uint8", (0.0, 255.0))
    plane = Plane.axis(pyr, "axial", 1000)
    focus = tuple(plane.origin)
    multi = slice_region(pyr, plane, RenderParams(policy="plane", focus=focus, distance_factor=1.0), 1.0)
    full = slice_region(pyr, plane, RenderParams(policy="plane", level=0), 1.0)
    assert full.nbricks == 64 * 64 + 1  # one layer of level 0 (voxel 1000 lies inside layer 31) and the top brick
    assert multi.nbricks * 8 < full.nbricks


def test_fixed_level_pages_that_level_and_the_coarsest():
    pyr = Pyramid.build((64, 64, 64), (8, 8, 8), (1.0, 1.0, 1.0), "mean", "uint8", (0.0, 255.0))
    plane = Plane.axis(pyr, "axial", 20)
    region = slice_region(pyr, plane, RenderParams(policy="plane", level=1), 1.0)
    counts = [len(b) for b in region.bricks]
    assert counts[1] == 16 and counts[-1] == 1 and sum(counts) == 17  # one 4x4 layer of level 1


def test_zoomed_view_pages_only_the_bricks_under_the_image():
    pyr = Pyramid.build((256, 512, 512), (16, 16, 16), (1.0, 1.0, 1.0), "mean", "uint8", (0.0, 255.0))
    plane = Plane.through((200.0, 300.0, 100.0), (0, 0, 1))  # z = 100: inside brick layer 6 (voxels 96..111)
    region = slice_region(pyr, plane, RenderParams(policy="plane", level=0), 1.0, size=(64, 32))
    got = {tuple(int(v) for v in k) for k in region.bricks[0].tolist()}
    # brute force: brick boxes [16 b - 0.5, 16 b + 15.5] meeting x in [168, 232], y in [284, 316]
    want = {(6, by, bx) for by in range(32) for bx in range(32)
            if 16 * bx - 0.5 <= 232 and 16 * bx + 15.5 >= 168 and 16 * by - 0.5 <= 316 and 16 * by + 15.5 >= 284}
    assert got == want and len(want) == 5 * 3
