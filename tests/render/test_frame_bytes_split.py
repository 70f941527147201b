"""The frame's bytes and the prefetch's, counted the same each time.

A volume view's clip-texture keeps filling its windows while and after a frame draws, so bytes
counted between two instants depend on timing (three identical renders once reported 104.9, 64.8
and 54.6 MB). Each read is charged to the brick it was read for and taken once: the same render in
fresh sessions reports the same frame bytes, and frame + prefetch equal the chunk bytes the process
read. References: the chunk files' sizes on disk (``os.path.getsize``) and every ``os.readv`` the
process made, counted by a wrapper independent of the loader's own counter.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.render.slice_action import SliceAction
from clipvol.scene.camera import Camera
from clipvol.scene.plane import Plane
from clipvol.scene.transfer import TransferFunction


def _size(store, level, idx) -> int:
    f = os.path.join(store, str(level), "c", *(str(int(i)) for i in idx))
    return os.path.getsize(f) if os.path.exists(f) else 0


@pytest.fixture
def store(tmp_path):
    vol = (np.random.default_rng(3).random((40, 48, 56)) * 1000).astype(np.uint16)
    out = tmp_path / "s.zarr"
    brick_volume(vol, out, brick=8, progress=False, workers=1)
    return out


@pytest.fixture
def counted_reads(monkeypatch):
    """Bytes every ``os.readv`` returned (the zarr loader reads each chunk file with one)."""
    total = [0]
    real = os.readv

    def readv(fd, buffers):
        n = real(fd, buffers)
        total[0] += n
        return n

    monkeypatch.setattr(os, "readv", readv)
    return total


def _render_once(gl, store, counted):
    counted[0] = 0
    ld = ZarrLoader(store)
    with ClipTexture(ld, "32MB", 4) as ct, ClipRenderAction(gl, ct, policy="fixed", level=0) as action:
        cam = Camera.perspective((70.0, 60.0, -45.0), (28.0, 24.0, 20.0), size=(64, 64), fov_y=30)
        action.render(cam, TransferFunction.preset("viridis"), wait=True, timeout=60)
        fs = action.last_frame_stats
        keys = np.concatenate([action.last_selection.item_keys(), action.last_selection.wanted_keys()])
    late = sum(ct.take_reads().values())  # what the threads read after the frame, until close stopped them
    drawn = {(int(L), (int(z), int(y), int(x))) for L, z, y, x in keys.tolist()}
    return fs, late, drawn


@pytest.mark.gl
def test_the_same_render_reports_the_same_frame_bytes_and_the_sum_is_what_was_read(gl, store, counted_reads):
    results = [_render_once(gl, store, counted_reads) + (counted_reads[0],) for _ in range(3)]
    frames = [fs.frame_bytes_read for fs, _, _, _ in results]
    assert len(set(frames)) == 1, frames
    for fs, late, drawn, read in results:
        assert fs.converged
        # the frame's figure is exactly the chunk files of the bricks it drew, as they are on disk
        assert fs.frame_bytes_read == sum(_size(store, L, k) for L, k in drawn) > 0
        # frame + prefetch (during the frame and after it) is every chunk byte the process read
        assert fs.frame_bytes_read + fs.prefetch_bytes_read + late == read


@pytest.mark.gl
def test_a_slice_reports_its_bricks_bytes_apart_from_the_prefetch(gl, store, counted_reads):
    seen = []
    for _ in range(2):
        counted_reads[0] = 0
        ld = ZarrLoader(store)
        with ClipTexture(ld, "32MB", 4) as ct, SliceAction(gl, ct, policy="plane", level=0) as action:
            action.render(Plane.axis(ld.pyramid, "axial", 20), wait=True, timeout=60)
            st = action.last_stats
        late = sum(ct.take_reads().values())
        seen.append(st.frame_bytes_read)
        assert st.converged and st.frame_bytes_read > 0
        assert st.frame_bytes_read + st.prefetch_bytes_read + late == counted_reads[0]
    assert seen[0] == seen[1]
