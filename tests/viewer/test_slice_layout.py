"""The viewer's slice mode, offscreen: panel orientation against a ramp volume, the point of
interest moving the planes and the clip-texture's centre, stepping and tilting planes."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.app.session import RenderSession
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.scene.camera import Camera
from clipvol.viewer.slice_layout import SliceLayout

pytestmark = pytest.mark.gl


@pytest.fixture
def session(gl):
    z = np.arange(32, dtype=np.float32)[:, None, None]
    vol = np.broadcast_to(z, (32, 48, 40)).copy()  # value = z index
    with RenderSession(NumpyLoader(vol, brick=16), gl, memory_budget="32MB", threads=2, texture_budget="32MB") as s:
        yield s


def _cam(size):
    return Camera.perspective((100.0, 80.0, -60.0), (20.0, 24.0, 16.0), up=(0, -1, 0), size=size)


def test_panels_show_the_planes_in_radiological_order(session):
    lay = SliceLayout(session)
    lay.set_poi((20.0, 24.0, 10.0))
    img = lay.render(_cam, (160, 120))
    assert img.shape == (120, 160, 4)
    grey = img[..., 0].astype(float)
    ax = grey[0:60, 0:80]
    drawn = ax[ax > 0]
    # the axial plane at z = 10 of a volume whose value is z: one grey level, 10/31 of white
    assert drawn.size > 500 and np.ptp(drawn) <= 1 and abs(drawn.mean() - 255 * 10 / 31) <= 1.5
    # coronal (top-right panel): superior (high z, bright) at the top
    cor = grey[0:60, 80:160]
    rows = [cor[r][cor[r] > 0].mean() for r in range(60) if (cor[r] > 0).sum() > 10]
    assert len(rows) > 20 and rows[0] > rows[-1] + 100
    assert all(a >= b - 1 for a, b in zip(rows, rows[1:]))
    assert img[60:, 80:, :3].any()  # the 3D view
    assert any(line.startswith("axial: L") for line in lay.hud_lines())


def test_click_sets_the_point_of_interest_and_the_clip_texture_centre(session):
    lay = SliceLayout(session)
    lay.render(_cam, (160, 120))
    x0, y0, pw, ph = lay.panel_rect("axial", (160, 120))
    name, px, py = lay.panel_at(x0 + pw / 2 + 10, y0 + ph / 2, (160, 120))
    assert name == "axial"
    p = lay.point_at("axial", px, py)
    lay.click(name, px, py)
    assert np.allclose(lay.poi, p) and np.allclose(session.clip_texture.center, p)
    for pl in lay.planes.values():
        assert abs(pl.signed_distance(p)[0]) < 1e-9
    assert p[0] > lay.planes["coronal"].origin[0] - 1e-9 and abs(p[2] - lay.planes["axial"].origin[2]) < 1e-9


def test_step_and_tilt(session):
    lay = SliceLayout(session)
    z0 = lay.planes["axial"].origin[2]
    lay.step_plane("axial", 3)
    assert lay.planes["axial"].origin[2] == pytest.approx(z0 + 3)
    lay.step_plane("axial", 1000)
    assert lay.planes["axial"].origin[2] == pytest.approx(31.5)  # kept inside the volume box
    lay.tilt("sagittal", 40.0, -20.0)
    pl = lay.planes["sagittal"]
    n = np.asarray(pl.normal)
    assert np.linalg.norm(n) == pytest.approx(1) and abs(n @ np.asarray(pl.up)) < 1e-9
    assert np.degrees(np.arccos(abs(n @ np.array([-1.0, 0, 0])))) > 5  # oblique now
    img = lay.render(_cam, (160, 120))
    assert img[60:, 0:80, 0].any()  # the oblique sagittal panel still draws
