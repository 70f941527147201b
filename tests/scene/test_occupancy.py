"""Occupancy of cells (clipvol.scene.occupancy) against brute force over the voxels."""

from __future__ import annotations

import itertools

import numpy as np
from clipvol.scene.occupancy import cell_edges, cell_ranges, occupancy, widen
from clipvol.scene.transfer import TransferFunction


def test_widen_joins_the_seven_cells_ahead_with_wraparound(rng):
    lo = rng.random((3, 4, 5)).astype(np.float32)
    hi = lo + rng.random((3, 4, 5)).astype(np.float32)
    wl, wh = widen(lo, hi)
    for z, y, x in itertools.product(range(3), range(4), range(5)):
        block = [((z + dz) % 3, (y + dy) % 4, (x + dx) % 5) for dz, dy, dx in itertools.product((0, 1), repeat=3)]
        assert wl[z, y, x] == min(lo[c] for c in block)
        assert wh[z, y, x] == max(hi[c] for c in block)


def test_an_empty_cell_holds_no_visible_trilinear_sample(rng):
    """Brute force: the volume as one toroidal level; every cell whose flag is 0 is sampled at
    random positions assigned to it (voxel coordinate x with floor(x / e) == cell), trilinear with
    wraparound, and each sample's opacity through the table (as GL_LINEAR reads it) must be 0."""
    e = 4
    n = 16
    z, y, x = np.mgrid[0:n, 0:n, 0:n]
    vol = np.where((x - 7.5) ** 2 + (y - 7.5) ** 2 + (z - 7.5) ** 2 < 30, 180, 10).astype(np.float32)
    vol[3, 12, 5] = 120  # a lone voxel of the visible band
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.4, (0, 0, 0, 0)), (0.5, (1, 1, 1, 0.5)),
                                       (0.7, (1, 1, 1, 0.5)), (0.8, (0, 0, 0, 0)), (1.0, (0, 0, 0, 0))])
    data_range = (0.0, 255.0)
    lo, hi = widen(*cell_ranges(vol, (e, e, e)))
    flags = occupancy(lo, hi, tf, data_range)
    assert 0 < flags.mean() < 1  # both kinds of cell are there
    empty = np.argwhere(flags == 0)
    p = (empty[:, None, :] + rng.random((len(empty), 64, 3))) * e  # (cells, samples, zyx) voxel coords
    i0 = np.floor(p).astype(np.int64)
    f = p - i0
    val = np.zeros(p.shape[:2])
    for corner in itertools.product((0, 1), repeat=3):
        c = np.array(corner)
        w = np.prod(np.where(c == 1, f, 1 - f), axis=-1)
        q = (i0 + c) % n
        val += w * vol[q[..., 0], q[..., 1], q[..., 2]]
    alpha = tf.lookup(val, data_range)[..., 3]
    assert alpha.max() == 0.0
    # and a cell holding the lone visible voxel is flagged
    assert flags[3 // e, 12 // e, 5 // e] == 1


def test_occupancy_follows_the_table_and_the_stored_units():
    lo = np.array([0.0, 100.0, np.inf], dtype=np.float32)
    hi = np.array([10.0, 110.0, -np.inf], dtype=np.float32)  # the third cell holds no finite value
    ramp = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.5, (0, 0, 0, 0)), (1.0, (1, 1, 1, 1))])
    assert occupancy(lo, hi, ramp, (0.0, 250.0)).tolist() == [0, 0, 0]
    assert occupancy(lo, hi, ramp, (0.0, 150.0)).tolist() == [0, 1, 0]
    # stored units: raw = 2 * stored + 10 puts the second cell at 210..230, visible over 0..255
    assert occupancy(lo, hi, ramp, (0.0, 255.0), a=2.0, b=10.0).tolist() == [0, 1, 0]
    flat = TransferFunction.from_points([(0.0, (0, 0, 0, 0.2)), (1.0, (0, 0, 0, 0.2))])
    assert occupancy(lo, hi, flat, (0.0, 200.0)).tolist() == [1, 1, 0]
