"""A multiresolution slice never reads more than the full-resolution slice of the same plane.

The count is independent of clipvol's byte counters: a wrapper records every ``read_brick`` the
clip-texture's threads make (tests/counting_loader.py), and the bytes are the bricks' array sizes
from numpy. Before the slice region left out the coarse bricks nothing blends with, the slice with a
point of interest on an MNI-sized store (197 x 233 x 189, 32³ bricks, one pixel a voxel) read every
coarser slab besides the whole level-0 slab: more than the full-resolution slice.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.region import Region
from clipvol.render.slice_action import SliceAction
from clipvol.scene.plane import Plane

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from counting_loader import Counting  # noqa: E402

pytestmark = pytest.mark.gl


def _bytes_read(gl, vol, plane, **params) -> tuple[int, bool]:
    ld = Counting(NumpyLoader(vol, brick=32))
    # an empty region, as `clipvol slice` starts one: without it the threads page the cube windows
    # around the centre until the slice sets its region (33 extra bricks read under load)
    empty = Region.empty(ld.pyramid.num_levels)
    with ClipTexture(ld, "256MB", 2, region=empty) as ct, SliceAction(gl, ct, **params) as sa:
        sa.render(plane, wait=True, timeout=120)
        assert ct.wait_until_idle(120)
        converged = sa.last_stats.converged
    reads = set(ld.reads)
    return sum(int(np.prod(ld.inner.read_brick(L, b).shape)) * vol.itemsize for L, b in reads), converged


@pytest.mark.parametrize("axis", ["axial", "coronal"])
def test_multiresolution_slice_reads_no_more_than_full_resolution(gl, axis):
    rng = np.random.default_rng(5)
    vol = (rng.random((189, 233, 197)) * 255).astype(np.uint8)
    pyr = NumpyLoader(vol, brick=32).pyramid
    plane = Plane.axis(pyr, axis, {"axial": 94, "coronal": 116}[axis])
    full, ok_full = _bytes_read(gl, vol, plane, level=0)
    multi, ok_multi = _bytes_read(gl, vol, plane, focus=tuple(plane.origin))
    assert ok_full and ok_multi
    assert multi <= full, (multi, full)


@pytest.mark.parametrize("origin,normal,focus", [
    # found by `bench_slice_io.py --never-more` (random planes, seed 0): at the default distance_factor
    # the per-brick cover of these planes holds 59 / 62 bricks where the full-resolution slab holds
    # 57 / 58 - the level-1 parents its tiles blend towards cost more than the level-0 bricks it saves
    ((103.5, 82.3, 120.0), (0.0, 0.0, 1.0), (132.6, 129.6, 120.0)),
    ((14.0, 15.9, 163.7), (-0.036, -0.951, -0.306), (130.4, 26.0, 118.5)),
])
def test_a_store_without_a_manifest_reads_no_more_than_the_full_resolution_slice(gl, origin, normal, focus):
    """A store without a manifest (in memory, procedural) is priced by the bytes its bricks hold:
    where the full-resolution slab holds no more, the slice draws that."""
    rng = np.random.default_rng(5)
    vol = (rng.random((189, 233, 197)) * 255).astype(np.uint8)
    plane = Plane.through(origin, normal)
    full, ok_full = _bytes_read(gl, vol, plane, level=0)
    multi, ok_multi = _bytes_read(gl, vol, plane, focus=focus, distance_factor=1.0)
    assert ok_full and ok_multi
    assert multi <= full, (multi, full)


class _CountingStore(Counting):
    """The counting wrapper of a store on disk that also shows the store's manifest (what the slice
    action prices a region by); the bytes the test counts come from the chunk files' sizes."""

    @property
    def manifest(self):
        return self.inner.manifest


def _head(shape=(189, 233, 197), seed=11) -> np.ndarray:
    """An MNI-sized 'head': incompressible noise inside an ellipsoid, zero (the fill) around it, so
    the level-0 bricks at the edges hold background and the coarse bricks over them hold tissue."""
    z, y, x = np.ogrid[: shape[0], : shape[1], : shape[2]]
    c = [(n - 1) / 2 for n in shape]
    inside = ((z - c[0]) / 80.0) ** 2 + ((y - c[1]) / 100.0) ** 2 + ((x - c[2]) / 84.0) ** 2 <= 1.0
    vol = np.random.default_rng(seed).integers(1, 256, size=shape, dtype=np.uint8)
    return np.where(inside, vol, 0).astype(np.uint8)


def _file_bytes(store, reads) -> int:
    """Bytes of the chunk files ``reads`` name, from the file system (0: no file, the fill)."""
    total = 0
    for L, (bz, by, bx) in reads:
        f = store / str(L) / "c" / str(bz) / str(by) / str(bx)
        total += f.stat().st_size if f.is_file() else 0
    return total


@pytest.mark.parametrize("distance_factor", [1.0, 0.5])
def test_a_slice_of_a_store_reads_no_more_bytes_than_the_full_resolution_slice(gl, tmp_path, distance_factor):
    """Counted in bytes of the chunk files, not in bricks: a coarse brick over tissue costs more than
    the background level-0 bricks it replaces. Before the slice priced its region by the manifest,
    this slice read more bytes than the full-resolution one (at both distance factors); now it reads
    no more, and where it draws the full-resolution slice its values are numpy's plane exactly."""
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.paging.open import open_store

    vol = _head()
    store = tmp_path / "head.zarr"
    brick_volume(vol, store, brick=32, progress=False)
    pyr = open_store(store).pyramid
    plane = Plane.axis(pyr, "axial")  # z = 94, through the centre
    got = {}
    for name, params in [("full", dict(level=0)),
                         ("multi", dict(focus=tuple(plane.origin), distance_factor=distance_factor))]:
        ld = _CountingStore(open_store(store))
        # no cube windows filled before the slice hands its region (what `clipvol slice` does)
        with ClipTexture(ld, "256MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
                SliceAction(gl, ct, **params) as sa:
            _, values = sa.render(plane, wait=True, timeout=120, return_values=True)
            assert ct.wait_until_idle(120) and sa.last_stats.converged
            got[name] = (_file_bytes(store, set(ld.reads)), values, sa.last_params.level)
    assert got["multi"][0] <= got["full"][0], (got["multi"][0], got["full"][0])
    assert got["full"][2] == 0
    if got["multi"][2] == 0:  # drawn at full resolution: numpy's plane, exactly
        np.testing.assert_array_equal(got["multi"][1], vol[94].astype(np.float32))


def test_a_slice_drawn_again_prices_its_region_once(gl, tmp_path, monkeypatch):
    """The region of a slice and its full-resolution alternative are priced once per slice: drawing
    the same plane again (a window redrawing, a viewer waiting for bricks) reuses the choice, and a
    moved plane prices anew. The values drawn again are the first drawing's."""
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.paging.open import open_store
    from clipvol.render import slice_action

    vol = _head()
    store = tmp_path / "head.zarr"
    brick_volume(vol, store, brick=32, progress=False)
    pyr = open_store(store).pyramid
    plane = Plane.axis(pyr, "axial")
    calls = []
    real = slice_action.slice_region
    monkeypatch.setattr(slice_action, "slice_region", lambda *a, **k: calls.append(1) or real(*a, **k))
    with ClipTexture(open_store(store), "256MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
            SliceAction(gl, ct, focus=tuple(plane.origin), distance_factor=0.5) as sa:
        _, first = sa.render(plane, wait=True, timeout=120, return_values=True)
        n_first = len(calls)
        _, again = sa.render(plane, wait=True, timeout=120, return_values=True)
        # the slice's region, the full-resolution one and (the store has summary tables: the slice
        # draws coarser data where it looks the same, clipvol.scene.slice_exact) distance alone's, once
        assert len(calls) == n_first == 3
        np.testing.assert_array_equal(again, first)
        sa.render(Plane.axis(pyr, "axial", 90), wait=True, timeout=120)
        assert len(calls) == 6  # a moved plane is priced anew


def test_a_slice_of_16_bricks_a_side_reads_an_eighth_of_the_full_resolution_slab(gl):
    """A 128³ store of 8³ bricks (16 a side, as 1024³ at 64³), the plane between two brick layers at
    every level and the point of interest where eight bricks meet at every level: the per-brick
    cover reads 33 bricks at ``distance_factor`` 0.25 where the full-resolution slice reads 513.
    Counted by the wrapper, so every brick the frame asked for besides the region is in the count.
    The whole-node cut with 2:1 balance read 97 at 0.25 (and at 0.5): its refined nodes brought all
    their children in the slab, and each coarser level a ring."""
    vol = np.random.default_rng(3).random((128, 128, 128), dtype=np.float32)
    pyr = NumpyLoader(vol, brick=8).pyramid
    plane = Plane.axis(pyr, "axial", 63.5)
    got = {}
    for name, params in [("full", dict(level=0)), ("multi", dict(focus=(63.5, 63.5, 63.5), distance_factor=0.25))]:
        ld = Counting(NumpyLoader(vol, brick=8))
        with ClipTexture(ld, "256MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
                SliceAction(gl, ct, **params) as sa:
            sa.render(plane, wait=True, timeout=120)
            assert ct.wait_until_idle(120) and sa.last_stats.converged
        got[name] = set(ld.reads)
    assert len(got["full"]) == 2 * 16 * 16 + 1
    assert 8 * len(got["multi"]) <= len(got["full"]), len(got["multi"])
