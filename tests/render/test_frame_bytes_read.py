"""FrameStats.bytes_read: the bytes a volume frame made the loader read, against the chunk files on disk."""

from __future__ import annotations

import os

import numpy as np

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.region import Region
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction


def _size(store, level, idx) -> int:
    f = os.path.join(store, str(level), "c", *(str(int(i)) for i in idx))
    return os.path.getsize(f) if os.path.exists(f) else 0


def test_frame_reports_the_chunk_bytes_it_read(gl, tmp_path, rng):
    vol = (rng.random((24, 32, 40)) * 1000).astype(np.uint16)
    store = tmp_path / "s.zarr"
    brick_volume(vol, store, brick=8, progress=False, workers=1)
    ld = ZarrLoader(store)
    pyr = ld.pyramid
    # nothing is read before the frame: the frame's own reads are all there is
    with ClipTexture(ld, "32MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
            ClipRenderAction(gl, ct, policy="fixed", level=0) as action:
        assert ld.read_counter.bytes == 0
        cam = Camera.perspective((60.0, 50.0, -40.0), (20.0, 16.0, 12.0), size=(64, 64), fov_y=40)
        action.render(cam, TransferFunction.preset("viridis"), wait=True, timeout=60)
        fs = action.last_frame_stats
        assert fs.converged
        drawn = {(int(L), tuple(int(v) for v in k)) for L, *k in action.last_selection.item_keys().tolist()}
        assert drawn and fs.bytes_read >= sum(_size(store, L, k) for L, k in drawn)
        assert ct.wait_until_idle(60)  # the cube windows (a volume view) go on filling after the frame
        assert fs.bytes_read <= ld.read_counter.bytes == sum(_size(store, L, k) for L, k in ct.resident_bricks())
