"""A corrupt brick never reaches the screen: it is drawn from its sound ancestor, exactly as a
brick whose loader failed, and never as zeros or as its damaged data.

The store is written by ``brick_volume``; the damage is a 3-byte flip in one level-0 chunk. Three
renders of the same view (fixed level 0, composite, orthographic, 32² pixels): (a) the damaged
store through the checked loader; (b) the intact store with that one brick made to fail by a
loader wrapper (the established fallback: the parent stands in); (c) the damaged store with the
checks switched off (what used to happen). (a) must equal (b) and differ from (c).
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import BrickState, ClipTexture
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

B = 16
TF = TransferFunction.preset("viridis")


class FailOne:
    """A loader that raises for one brick (the reference fallback) and reads the rest through ``inner``."""

    def __init__(self, inner, key):
        self.inner, self.key, self.pyramid = inner, key, inner.pyramid
        self.brick_ranges = inner.brick_ranges
        # the same data as ``inner``: its statistics (finite data: the same shader variant) and the
        # spread beside its coarse levels (consistent levels)
        self.brick_statistics = inner.brick_statistics
        self.spread_levels, self.read_spread = inner.spread_levels, inner.read_spread

    def read_brick(self, level, index):
        if (level, tuple(index)) == self.key:
            raise RuntimeError("this brick fails")
        return self.inner.read_brick(level, index)


def _render(ctx, loader):
    from clipvol.render.action import ClipRenderAction

    with ClipTexture(loader, "32MB", threads=2, retries=0) as clip:
        action = ClipRenderAction(ctx, clip, policy="fixed", level=0)
        cam = Camera.orthographic((15.5, 15.5, 15.5), (0, 0, 1), (0, -1, 0), 32, 32, size=(32, 32))
        img = action.render(cam, TF, wait=True, timeout=30)
        state = clip.state(0, (1, 1, 1))
        drawn = dict(action.last_frame_stats.bricks_drawn)
        action.close()
        assert ctx.error == "GL_NO_ERROR"
    return img, state, drawn


@pytest.mark.gl
def test_corrupt_brick_is_drawn_from_its_ancestor_never_as_data(ctx, tmp_path):
    z, y, x = np.indices((32, 32, 32))
    vol = (0.5 + 0.4 * np.sin(z / 3.0) * np.cos(y / 4.0) * np.sin(x / 5.0)).astype(np.float32)
    good, bad = tmp_path / "good.zarr", tmp_path / "bad.zarr"
    brick_volume(vol, good, brick=B, progress=False, workers=1)
    brick_volume(vol, bad, brick=B, progress=False, workers=1)
    chunk = bad / "0" / "c" / "1" / "1" / "1"
    data = bytearray(chunk.read_bytes())
    for k in (100, 200, 300):
        data[k] ^= 0xFF
    chunk.write_bytes(bytes(data))

    checked, state, drawn = _render(ctx, ZarrLoader(bad))
    reference, ref_state, _ = _render(ctx, FailOne(ZarrLoader(good), (0, (1, 1, 1))))
    assert state == ref_state == BrickState.FAILED
    assert drawn.get(1, 0) >= 1  # the ancestor stands in
    assert np.all(checked[..., 3] > 0)  # no hole, no zeros
    np.testing.assert_array_equal(checked, reference)

    unchecked_loader = ZarrLoader(bad)
    unchecked_loader.verify_checksums = unchecked_loader.check_plausibility = False
    unchecked, u_state, _ = _render(ctx, unchecked_loader)
    assert u_state == BrickState.RESIDENT  # without the checks the damaged bytes load ...
    assert np.any(unchecked != checked)  # ... and would be drawn
