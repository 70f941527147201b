"""Per-cell value ranges (clipvol.paging.cells), and the clip-texture's loader threads computing
them for every brick they load, against loops over the source array."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cells import cell_edges, cell_ranges
from clipvol.paging.cliptexture import ClipTexture


def test_cell_edges_divide_the_brick():
    assert cell_edges((64, 32, 16)) == (8, 8, 8)
    assert cell_edges((12, 20, 6)) == (4, 4, 2)
    assert cell_edges((64, 64, 9)) is None  # an odd extent has no cells


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.float32])
def test_cell_ranges_equal_loops_over_each_cell(rng, dtype):
    b = (rng.random((8, 12, 16)) * 200 - (50 if dtype != np.uint8 else 0)).astype(dtype)
    lo, hi = cell_ranges(b, (4, 2, 8))
    assert lo.shape == (2, 6, 2)
    for i, j, k in itertools.product(range(2), range(6), range(2)):
        cell = b[4 * i:4 * i + 4, 2 * j:2 * j + 2, 8 * k:8 * k + 8].astype(np.float64)
        assert lo[i, j, k] == np.float32(cell.min()) and hi[i, j, k] == np.float32(cell.max())


def test_cell_ranges_ignore_nan_and_mark_all_nan_cells_empty(rng):
    b = rng.random((4, 4, 4)).astype(np.float32)
    b[:2, :2, :2] = np.nan
    b[2, 2, 2] = np.nan
    lo, hi = cell_ranges(b, (2, 2, 2))
    assert lo[0, 0, 0] == np.inf and hi[0, 0, 0] == -np.inf
    cell = b[2:, 2:, 2:]
    assert lo[1, 1, 1] == np.nanmin(cell) and hi[1, 1, 1] == np.nanmax(cell)


def test_64_bit_integers_round_outwards():
    b = np.full((2, 2, 2), 2**40 + 1, dtype=np.int64)  # not a float32
    b[0, 0, 0] = -(2**40) - 1
    lo, hi = cell_ranges(b, (2, 2, 2))
    assert float(lo[0, 0, 0]) <= -(2**40) - 1 and float(hi[0, 0, 0]) >= 2**40 + 1
    assert float(hi[0, 0, 0]) - (2**40 + 1) < 2**40 * 1e-6  # one float32 step, not more


def test_the_clip_texture_holds_each_loaded_bricks_cell_ranges(rng):
    vol = rng.normal(size=(40, 24, 32)).astype(np.float32)  # bricks of 16 at the faces hold padding
    vol[:8, :8, :8] = np.nan
    loader = NumpyLoader(vol, brick=16)
    with ClipTexture(loader, "16MB", threads=2, cells_on_load=True) as clip:
        assert clip.wait_until_idle(30)
        pyr = loader.pyramid
        for L in range(pyr.num_levels):
            for key in itertools.product(*(range(g) for g in pyr.grid(L))):
                res, lo, hi = clip.cell_ranges(L, [key])
                assert res.tolist() == [True]
                lo, hi = lo[0], hi[0]
                brick = loader.read_brick(L, key).astype(np.float64)
                for c in itertools.product(range(2), repeat=3):
                    cell = brick[tuple(slice(8 * i, 8 * i + 8) for i in c)]
                    finite = cell[np.isfinite(cell)]
                    if finite.size:
                        assert (lo[c], hi[c]) == (np.float32(finite.min()), np.float32(finite.max()))
                    else:
                        assert (lo[c], hi[c]) == (np.inf, -np.inf)


def test_cell_ranges_move_with_their_bricks_when_the_window_changes_shape(rng):
    """A new roaming window size re-assigns slots; bricks kept carry their data and cell ranges."""
    vol = rng.normal(size=(64, 48, 64)).astype(np.float32)
    loader = NumpyLoader(vol, brick=8)
    pyr = loader.pyramid
    budget = 3 * 3 * 3 * pyr.brick_nbytes * 2 + sum(pyr.num_bricks(L) * pyr.brick_nbytes for L in range(1, pyr.num_levels))
    with ClipTexture(loader, budget, threads=2, cells_on_load=True) as clip:
        assert clip.wait_until_idle(30)
        for size in (2, 3, 2):
            clip.set_roaming_window(size)
            assert clip.wait_until_idle(30)
            keys = [k for k in clip.resident_bricks() if k[0] == 0]
            assert keys
            res, lo, hi = clip.cell_ranges(0, [k for _, k in keys])
            assert res.all()
            for (_, key), l, h in zip(keys, lo, hi):
                brick = loader.read_brick(0, key)  # one cell of 8^3
                assert (l.item(), h.item()) == (brick.min(), brick.max())
