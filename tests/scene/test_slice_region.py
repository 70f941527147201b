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


def _full_slab_bruteforce(pyr, plane) -> int:
    """Level-0 bricks whose boxes meet the slab of half a level-0 voxel around ``plane`` (every brick's
    box from its index, the brick shape and unit spacing, clipped to the volume), and the top brick."""
    gz, gy, gx = (-(-s // b) for s, b in zip(pyr.shape, pyr.brick_shape))
    idx = np.stack(np.meshgrid(np.arange(gx), np.arange(gy), np.arange(gz), indexing="ij"), -1).reshape(-1, 3)
    b = np.array(pyr.brick_shape[::-1], dtype=np.float64)  # x, y, z
    lo = idx * b - 0.5
    hi = np.minimum(lo + b, np.array(pyr.shape[::-1], dtype=np.float64) - 0.5)
    n, o = np.asarray(plane.normal), np.asarray(plane.origin)
    reach = 0.5 * (hi - lo) @ np.abs(n) + 0.5 * np.abs(n).sum()
    return int(np.count_nonzero(np.abs(((lo + hi) / 2 - o) @ n) <= reach)) + 1


@pytest.mark.parametrize("shape,brick", [((189, 233, 197), 16), ((1024, 1024, 1024), 64)])
def test_the_cover_holds_fewer_chunks_than_the_full_resolution_slab(shape, brick):
    # random axial and oblique planes, each with a random point of interest on it inside the volume.
    # Not so at 32^3 bricks on the 197 x 233 x 189 shape: there the blend parents can outnumber the
    # level-0 bricks the cover saves, and the slice action draws full resolution
    # (tests/render/test_slice_bytes.py)
    pyr = Pyramid.build(shape, (brick,) * 3, (1.0, 1.0, 1.0), "mean", "uint8", (0.0, 255.0))
    rng = np.random.default_rng(7)
    lo, hi = pyr.volume_box()
    checked = 0
    while checked < 12:
        p, q = rng.uniform(lo, hi), rng.uniform(lo, hi)
        n = rng.normal(size=3) if checked % 2 else np.array([0.0, 0.0, 1.0])
        n /= np.linalg.norm(n)
        q -= ((q - p) @ n) * n
        if np.any(q < lo) or np.any(q > hi):
            continue
        plane = Plane.through(tuple(p), tuple(n))
        full = slice_region(pyr, plane, RenderParams(policy="plane", level=0), 1.0)
        assert full.nbricks == _full_slab_bruteforce(pyr, plane)
        for df in (1.0, 0.5, 0.25):
            multi = slice_region(pyr, plane, RenderParams(policy="plane", focus=tuple(q), distance_factor=df), 1.0)
            assert multi.nbricks <= full.nbricks, (tuple(p), tuple(n), tuple(q), df)
        checked += 1


def test_a_store_without_a_manifest_is_priced_by_the_bricks_it_hands_over():
    # every brick's price against the array the loader hands over for it (edge bricks padded)
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.scene.slice_region import region_bytes, stored_sizes

    ld = NumpyLoader(np.zeros((37, 50, 21), dtype=np.uint16), brick=16)
    pyr = ld.pyramid
    sizes = stored_sizes(ld)
    for L in range(pyr.num_levels):
        idx = np.array(list(np.ndindex(*pyr.grid(L))), dtype=np.int64)
        want = [ld.read_brick(L, tuple(int(v) for v in i)).nbytes for i in idx]
        np.testing.assert_array_equal(sizes[L][idx[:, 0], idx[:, 1], idx[:, 2]], want)
    plane = Plane.axis(pyr, "axial", 20)
    region = slice_region(pyr, plane, RenderParams(policy="plane", level=0), 1.0)
    assert region_bytes(region, sizes) == sum(ld.read_brick(L, tuple(int(v) for v in b)).nbytes
                                              for L, bb in enumerate(region.bricks) for b in bb)
