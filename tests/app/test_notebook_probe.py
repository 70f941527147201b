"""``clipvol.show``: probe, ruler and cut in the notebook view, against an analytic ball.

The ball (radius R voxels at the volume centre, spacing (2, 1, 0.5) so world distances differ from
voxel distances) is the only visible thing; the turntable camera looks at the centre, so the
centre pixel's first visible sample lies on the ball's surface, its value is the array's value at
the voxel reported, and its world position is that voxel's place through the spacing.
"""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.gl
pytest.importorskip("moderngl")
pytest.importorskip("anywidget")

N, R = 32, 8.0
SPACING = (2.0, 1.0, 0.5)  # z, y, x


def ball():
    z, y, x = np.mgrid[0:N, 0:N, 0:N].astype(np.float64)
    c = (N - 1) / 2.0
    r = np.sqrt(((x - c) * SPACING[2]) ** 2 + ((y - c) * SPACING[1]) ** 2 + ((z - c) * SPACING[0]) ** 2)
    return np.where(r <= R, 0.6 + 0.3 * x / N, 0.0).astype(np.float32)


@pytest.fixture
def view():
    import clipvol
    from clipvol.loaders.numpy_array import NumpyLoader

    v = clipvol.show(NumpyLoader(ball(), brick=16, spacing=SPACING), size=(64, 48), tf="grey", threads=2)
    yield v
    v.close()


def test_probe_under_the_centre_pixel_is_the_ball_surface_and_the_array_value(view):
    vol = ball()
    p = view.probe(32, 24)
    assert p is not None
    centre = (np.array([N, N, N]) - 1) / 2.0 * np.array(SPACING[::-1])  # world (x, y, z) of the centre
    assert abs(np.linalg.norm(p.world - centre) - R) <= max(SPACING)  # on the surface, within a voxel
    z, y, x = p.voxel
    assert p.value == vol[z, y, x] and p.value >= 0.6
    assert np.all(np.abs(p.world - np.array([x, y, z]) * np.array(SPACING[::-1])) <= 0.5 * np.array(SPACING[::-1]))
    assert "probe" in view.widget.hud and f"{p.value:.6g}" in view.widget.hud
    assert view.probe(1, 1) is None  # a corner ray misses the ball


def test_ruler_from_two_picks_is_the_numpy_distance_of_the_world_points(view):
    view.widget.pick = [32.0, 24.0, 1.0, 1.0]  # shift+click in the browser: a ruler end
    view.widget.pick = [34.0, 26.0, 1.0, 2.0]
    a, b = view.ruler.ends
    assert view.ruler.length == pytest.approx(float(np.sqrt(((a - b) ** 2).sum())))
    assert view.ruler.length > 0 and "ruler:" in view.widget.hud
    d = view.measure((30, 24), (34, 26))
    pa, pb = view.probe(30, 24), view.probe(34, 26)
    assert d == pytest.approx(float(np.linalg.norm(pa.world - pb.world)))


def test_a_clip_plane_cuts_the_view_and_the_probe_sees_the_cut_face(view):
    whole = view.snapshot()
    c = (N - 1) / 2.0 * np.array(SPACING[::-1])
    cam, _ = view.camera()
    fwd = c - np.asarray(cam.eye)  # the turntable looks at the volume centre
    fwd = fwd / np.linalg.norm(fwd)
    cut = view.set_cut(clip_planes=[(*c, *fwd)])  # keep the far half: the plane faces away from the eye
    assert np.abs(cut.astype(int) - whole.astype(int)).max() > 20
    p = view.probe(32, 24)
    assert p is not None and abs(float(np.dot(p.world - c, fwd))) <= max(SPACING)  # on the cut face
    assert p.value == ball()[p.voxel]
    back = view.set_cut()  # no cut: the whole ball again
    assert np.abs(back.astype(int) - whole.astype(int)).max() <= 1
