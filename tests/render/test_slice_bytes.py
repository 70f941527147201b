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
from clipvol.render.slice_action import SliceAction
from clipvol.scene.plane import Plane

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from counting_loader import Counting  # noqa: E402

pytestmark = pytest.mark.gl


def _bytes_read(gl, vol, plane, **params) -> tuple[int, bool]:
    ld = Counting(NumpyLoader(vol, brick=32))
    with ClipTexture(ld, "256MB", 2) as ct, SliceAction(gl, ct, **params) as sa:
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
