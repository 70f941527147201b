"""The window hatches a hole where bricks failed and nothing stands in for them, as every offscreen
command does, under Xvfb: the frame on screen is never a blank drawn as if it were data."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("glfw")
pytest.importorskip("moderngl")

from test_view_window import xdisplay  # noqa: E402,F401  (the Xvfb fixture, shared)


def test_a_hole_is_hatched_in_the_window(xdisplay):
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.render.failures import HATCH_RGBA
    from clipvol.viewer.window import Viewer

    class CornerFails(NumpyLoader):
        """Brick (0, 0, 0) fails at every level: the corner's column has no ancestor to stand in."""

        def read_brick(self, level, index):
            if tuple(int(v) for v in index) == (0, 0, 0):
                raise OSError(f"brick {level} {tuple(index)} is unreadable")
            return super().read_brick(level, index)

    vol = np.full((32, 32, 32), 0.8, dtype=np.float32)
    loader = CornerFails(vol, brick=8, value_range=(0.0, 1.0))
    with Viewer(loader, size=(96, 72), tf="grey", visible=False, frame_time=0) as v:
        v.key("H")
        deadline = time.monotonic() + 30.0  # bounded: until the corner's bricks have failed (after their
        while time.monotonic() < deadline:  # retries) and the rest is drawn
            v.step(force=True)
            fs = v.session.frame_stats
            if fs is not None and fs.unreplaced and v.session.clip_texture.stats.queued == 0:
                break
            time.sleep(0.02)
        fs = v.session.frame_stats
        assert fs.unreplaced and all(f.index == (0, 0, 0) for f in fs.unreplaced)
        hatched = np.all(v._frame == HATCH_RGBA, axis=-1)
        assert hatched.any(), "the hole is drawn without its hatch"
        assert hatched.mean() < 0.5  # the corner brick's footprint, not the whole frame
