"""A slice reads a coarser brick where the store's summary tables show it looks the same.

A bricked store (``brick_volume`` into a temporary folder, with its summary tables) whose x < 64
half is a gentle gradient and whose other half holds thin bright lines (1/16 of its voxels). Every
``read_brick`` is recorded by a wrapper (tests/counting_loader.py), independently of clipvol's
counters; the exact slice is the level-0 plane from numpy, mapped to grey and compared in CIELUV.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.region import Region
from clipvol.render.slice_action import SliceAction
from clipvol.scene.metrics import percent_delta_e
from clipvol.scene.plane import Plane

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from counting_loader import ReadThrough  # noqa: E402

pytestmark = pytest.mark.gl

Z = 20  # the slice: a layer of lines, inside a brick at every level
FOCUS = (63.5, 31.5, float(Z))


class _Reads(ReadThrough):
    """The store's loader (its path, manifest and tables stay visible) recording every brick read."""

    def __init__(self, inner) -> None:
        super().__init__(inner)
        self.reads: list = []

    def read_brick(self, level, index):
        self.reads.append((int(level), tuple(int(v) for v in index)))
        return self._inner.read_brick(level, index)


def _volume() -> np.ndarray:
    z, y, x = np.ogrid[:32, :64, :128]
    vol = np.broadcast_to((100 + 10 * x / 64).astype(np.uint8), (32, 64, 128)).copy()
    vol[:, :, 64:] = 100
    vol[::4, ::4, 64:] = 250  # lines along x, one voxel thick, 4 apart in y and z
    return vol


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    from clipvol.bricking.pipeline import brick_volume

    base = tmp_path_factory.mktemp("exact")
    vol = _volume()
    brick_volume(vol, base / "tables.zarr", brick=8, progress=False)
    brick_volume(vol, base / "plain.zarr", brick=8, progress=False, summary=False)
    return vol, base / "tables.zarr", base / "plain.zarr"


def _grey(values, center, width):
    return np.rint(np.clip((values - (center - width / 2)) / width, 0, 1) * 255).astype(np.uint8)


def _render(gl, store, windows, tol="default", distance_factor=8.0, z=Z):
    """Draw the slice at level-0 voxel ``z`` once per window (one slice action); per window the bricks
    read for it (cumulative) and the RGBA."""
    from clipvol.paging.open import open_store

    ld = _Reads(open_store(store))
    pyr = ld.pyramid
    plane = Plane.axis(pyr, "axial", z)
    out = []
    with ClipTexture(ld, "256MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
            SliceAction(gl, ct, focus=FOCUS[:2] + (float(z),), distance_factor=distance_factor) as sa:
        if tol != "default":
            sa.exact_tol = tol
        for w in windows:
            rgba = sa.render(plane, window=w, wait=True, timeout=120)
            assert ct.wait_until_idle(120) and sa.last_stats.converged
            out.append((set(ld.reads), rgba, sa.last_params.level))
    return out


def _x_range(level, index):
    """Level-0 voxel columns a brick spans along x."""
    ext = 8 * 2**level
    return index[2] * ext, (index[2] + 1) * ext


FULL = (175.0, 150.0)  # the value range 100..250


def test_a_slice_reads_coarse_bricks_where_the_data_looks_the_same(gl, stores):
    vol, tables, _ = stores
    (reads, rgba, level), = _render(gl, tables, [FULL])
    assert level is None  # the multiresolution slice, not the full-resolution fallback
    (plain_reads, _, _), = _render(gl, tables, [FULL], tol=None)
    fine = {b for L, b in reads if L == 0}
    # level 0 over the lines, none over the gradient; distance alone read level 0 everywhere in the slab
    assert fine and all(_x_range(0, b)[0] >= 64 for b in fine)
    assert any(_x_range(0, b)[1] <= 64 for L, b in plain_reads if L == 0)
    assert any(L >= 2 and _x_range(L, b)[1] <= 64 for L, b in reads)
    assert len(reads) < len(plain_reads)
    # the drawn slice against the exact one (numpy's level-0 plane)
    exact = _grey(vol[Z].astype(np.float64), *FULL)
    exact = np.dstack([exact, exact, exact, np.full_like(exact, 255)])
    assert percent_delta_e(rgba, exact) <= 1.0
    assert percent_delta_e(rgba[:, 64:], exact[:, 64:]) == 0.0  # the lines at full resolution


def test_a_plane_beside_a_coarse_brick_face_does_not_blend_towards_it(gl, stores):
    """At z = 16 the plane lies half a voxel off the level-1 bricks below it: the slab holds them for
    their samples' footprint, though the plane does not pass through them. Counted as boxes beside
    the level-0 tiles over the lines, they blended every tile 94 % towards its parent (the lines
    averaged away: half of those pixels wrong); only boxes the plane passes through may blend."""
    vol, tables, _ = stores
    (_, rgba, level), = _render(gl, tables, [FULL], z=16)
    assert level is None
    exact = _grey(vol[16].astype(np.float64), *FULL)
    exact = np.dstack([exact, exact, exact, np.full_like(exact, 255)])
    assert percent_delta_e(rgba[:, 64:], exact[:, 64:]) == 0.0
    assert percent_delta_e(rgba, exact) <= 1.0


def test_a_narrow_window_reads_finer_bricks(gl, stores):
    """The window over the gradient (100..110) shows its steps: the same slice action reads level 0 there."""
    _, tables, _ = stores
    (wide, _, _), (narrow, _, _) = _render(gl, tables, [FULL, (105.0, 10.0)])
    fine = lambda reads: {b for L, b in reads if L == 0 and _x_range(0, b)[1] <= 64}  # noqa: E731
    assert not fine(wide)
    assert fine(narrow)


def test_without_summary_tables_a_slice_reads_what_distance_alone_reads(gl, stores):
    _, tables, plain = stores
    (no_tables, _, _), = _render(gl, plain, [FULL])
    (rule_off, _, _), = _render(gl, tables, [FULL], tol=None)
    assert no_tables == rule_off
    assert any(L == 0 and _x_range(0, b)[1] <= 64 for L, b in no_tables)


def test_a_transfer_function_that_shows_no_difference_reads_the_coarsest_level(gl, stores):
    """Under a transfer function whose colour is one orange everywhere (its opacity ramps: a slice
    does not use it) no brick differs from its parent: the slice reads the coarsest brick alone and
    shows that colour on every pixel; under a grey ramp it reads level 0 over the lines."""
    from clipvol.paging.open import open_store
    from clipvol.scene.transfer import TransferFunction

    _, tables, _ = stores
    flat = TransferFunction.from_points([(0.0, (1.0, 0.5, 0.0, 0.0)), (1.0, (1.0, 0.5, 0.0, 1.0))])
    ramp = TransferFunction.from_points([(0.0, (0.0, 0.0, 0.0, 1.0)), (1.0, (1.0, 1.0, 1.0, 1.0))])
    got = {}
    for name, tf in (("flat", flat), ("ramp", ramp)):
        ld = _Reads(open_store(tables))
        pyr = ld.pyramid
        with ClipTexture(ld, "256MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
                SliceAction(gl, ct, focus=FOCUS, distance_factor=8.0) as sa:
            rgba = sa.render(Plane.axis(pyr, "axial", Z), transfer_function=tf, wait=True, timeout=120)
            assert ct.wait_until_idle(120) and sa.last_stats.converged
        got[name] = (set(ld.reads), rgba, pyr.num_levels - 1)
    reads, rgba, top = got["flat"]
    assert reads == {(top, (0, 0, 0))}
    assert np.abs(rgba.astype(int) - [255, 128, 0, 255]).max() <= 1  # 0.5 * 255 rounds either way
    assert any(L == 0 and _x_range(0, b)[0] >= 64 for L, b in got["ramp"][0])


def test_one_thin_vessel_in_a_smooth_brick_keeps_its_level(gl, tmp_path):
    """A single bright line through a gentle gradient (16 voxels of a 32³ brick; with the parent
    voxels it shares, 64 voxels differ: 0.2 % of the brick) hides in a 99 % quantile: the slice
    through it must still read the line's brick at level 0 and draw the line as numpy's plane
    shows it (with the quantile, it drew the parent and the line was gone)."""
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.paging.open import open_store

    z, y, x = np.ogrid[:64, :64, :64]
    vol = np.broadcast_to((100 + 10 * x / 64).astype(np.uint8), (64, 64, 64)).copy()
    vol[40, 9, 36:52] = 250  # one line along x inside the level-0 brick (1, 0, 1)
    brick_volume(vol, tmp_path / "v.zarr", brick=32, progress=False)
    ld = _Reads(open_store(tmp_path / "v.zarr"))
    pyr = ld.pyramid
    with ClipTexture(ld, "256MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
            SliceAction(gl, ct, focus=(44.0, 9.0, 40.0), distance_factor=8.0) as sa:
        rgba = sa.render(Plane.axis(pyr, "axial", 40), window=FULL, wait=True, timeout=120)
        assert ct.wait_until_idle(120) and sa.last_stats.converged
    assert (0, (1, 0, 1)) in set(ld.reads)
    exact = _grey(vol[40].astype(np.float64), *FULL)
    exact = np.dstack([exact, exact, exact, np.full_like(exact, 255)])
    assert percent_delta_e(rgba[9:10, 36:52], exact[9:10, 36:52]) == 0.0  # the line, every pixel of it
    assert percent_delta_e(rgba, exact) <= 1.0
