"""The viewer's cut, probe and ruler keys under Xvfb (``clipvol.viewer.cut_keys``), on an analytic ball.

The probe under the centre pixel must be on the ball's surface with the array's value at the voxel
it names; ``V`` cuts the near half away (the probe then sits on the cut face); ``F`` + ``X`` move a
box face by the editor's step; the ruler (``U`` twice) measures numpy's distance of its two ends.
"""

from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("glfw")
pytest.importorskip("moderngl")

from test_view_window import _converge, xdisplay  # noqa: E402,F401,F811  (the Xvfb fixture and the wait, shared)

N, R = 40, 10.0


def ball():
    z, y, x = np.mgrid[0:N, 0:N, 0:N].astype(np.float64)
    c = (N - 1) / 2.0
    r = np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)
    return np.where(r <= R, 0.6 + 0.3 * x / N, 0.0).astype(np.float32)



def test_probe_cut_and_ruler_keys_in_the_window(xdisplay):
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.viewer.window import Viewer

    vol = ball()
    c = np.full(3, (N - 1) / 2.0)
    with Viewer(NumpyLoader(vol, brick=8, value_range=(0.0, 1.0)), size=(96, 72), tf="grey", visible=False,
                frame_time=0) as v:
        v.key("H")  # HUD off: the screen shows the frame only (its lines are checked from cut.hud_lines)
        _converge(v, limit=300)
        whole = v.read_screen()
        w, h = v.framebuffer_size
        p = v.probe_at(w / 2, h / 2)
        assert p is not None and p.level == 0
        assert abs(np.linalg.norm(p.position - c) - R) <= 1.0  # the ball's surface
        assert p.value == vol[p.voxel]
        assert any(line.startswith("probe ") for line in v.cut.hud_lines())
        v.cut.probe = None
        v._hover = (w / 2, h / 2)  # what a cursor move over the still view records
        v.step()
        assert v.cut.probe is not None and v.cut.probe.voxel == p.voxel
        # the ruler: two probed points, numpy's distance of their world positions
        v.key("U")
        q = v.probe_at(w / 2 + 6, h / 2 + 4)
        assert q is not None
        v.key("U")
        a, b = v.cut.ruler.ends
        assert np.allclose(a, p.world) and np.allclose(b, q.world)
        assert v.cut.ruler.length == pytest.approx(float(np.sqrt(((p.world - q.world) ** 2).sum())))
        # V: a plane through the centre of interest facing away from the eye cuts the near half away
        v.key("V")
        assert len(v.session.params.shape.planes) == 1
        _converge(v, limit=300)
        cut = v.read_screen()
        assert np.abs(cut.astype(int) - whole.astype(int)).max() > 20
        f = v.controls.forward
        p = v.probe_at(w / 2, h / 2)
        assert p is not None and abs(float(np.dot(p.position - v.controls.center_of_interest, f))) <= 0.5
        assert p.value == vol[p.voxel]
        v.key("O")  # remove it: the whole ball again
        assert v.session.params.shape is None
        _converge(v, limit=300)
        assert np.abs(v.read_screen().astype(int) - whole.astype(int)).max() <= 2
        # F selects the box's x- face, X pushes it in by one step
        v.key("F")
        v.key("X")
        lo = v.session.pyramid.volume_box()[0]
        assert v.session.params.shape.box[0][0] == pytest.approx(lo[0] + v.cut.editor.step)
        assert any(line.startswith("cut: box") for line in v.cut.hud_lines())
        v.key("H")
        v.step(force=True)
        assert any(line.startswith("cut: box") for line in v._hud_text)  # the window's HUD shows it
