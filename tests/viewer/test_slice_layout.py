"""The viewer's slice mode, offscreen: panel orientation against a ramp volume, the point of
interest moving the planes and the clip-texture's centre, stepping and tilting planes."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.app.session import RenderSession
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.scene.camera import Camera
from clipvol.viewer.slice_layout import SliceLayout

from test_view_window import _converge, loader, xdisplay  # noqa: F401  (the window tests' Xvfb fixtures)

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
    img = lay.render(_cam, (160, 120), wait=True, timeout=60)
    assert img.shape == (120, 160, 4)
    grey = np.where((img[..., 0] == img[..., 1]) & (img[..., 1] == img[..., 2]), img[..., 0], 0).astype(float)
    ax = grey[0:60, 0:80]  # (the yellow cross at the point of interest is left out)
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
    img = lay.render(_cam, (160, 120), wait=True, timeout=60)
    assert img[60:, 0:80, 0].any()  # the oblique sagittal panel still draws


def test_window_key_l_shows_the_slice_layout(xdisplay, loader):
    """Under Xvfb: L switches the window to the 2x2 slice layout and back; the wheel over the axial
    panel steps the axial plane."""
    from clipvol.viewer.window import Viewer

    with Viewer(loader, size=(128, 96), visible=False) as v:
        v.key("H")
        _converge(v)
        normal = v.read_screen()
        v.key("L")
        assert v.slices is not None and v.slices.active
        v.step(force=True)
        grid = v.read_screen()
        assert np.abs(grid.astype(int) - normal).max() > 50
        # the axial panel (top left) shows the middle axial slice of the source in grey
        assert grid[:48, :64].max() > 30
        z0 = v.slices.planes["axial"].origin[2]
        v.slices.step_plane("axial", 2)
        assert v.slices.planes["axial"].origin[2] == pytest.approx(z0 + 2)
        v.key("L")
        assert not v.slices.active
        _converge(v)
        assert np.abs(v.read_screen().astype(int) - normal).max() <= 3


@pytest.mark.parametrize("name", ["las", *(pytest.param(n, marks=pytest.mark.slow) for n in ("ras", "perm"))])
def test_patient_frame_store_gets_the_patients_planes(gl, tmp_path, name):
    """A NIfTI store's panels are the patient's axial, coronal and sagittal planes, radiological
    display (the axial's right edge is the patient's left, anterior at the top), any storage order."""
    pytest.importorskip("nibabel")
    from world_volumes import write_copy

    from clipvol.bricking.pipeline import brick_volume
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.orientation import view_labels

    brick_volume(write_copy(tmp_path, name), tmp_path / "s.zarr", brick=8, progress=False)
    loader = ZarrLoader(tmp_path / "s.zarr")
    with RenderSession(loader, gl, memory_budget="16MB", threads=2, texture_budget="16MB") as s:
        lay = SliceLayout(s)
        got = {k: view_labels(loader.frame.affine, p.right, p.up) for k, p in lay.planes.items()}
    assert got["axial"] == {"right": "L", "left": "R", "top": "A", "bottom": "P"}
    assert got["coronal"] == {"right": "L", "left": "R", "top": "S", "bottom": "I"}
    assert got["sagittal"] == {"right": "P", "left": "A", "top": "S", "bottom": "I"}


def test_a_crop_box_cuts_the_slice_panels_as_it_cuts_the_volume(session):
    """The volume cropped to x < 20 (of 40): the axial panel leaves out every pixel whose point lies
    beyond the box and draws the rest as the uncropped panel does."""
    from clipvol.scene.cut import cut_shape

    size = (160, 120)
    whole = SliceLayout(session)
    whole.set_poi((20.0, 24.0, 10.0))
    before = whole.render(_cam, size, wait=True, timeout=60)
    session.update(shape=cut_shape(session.pyramid, crop_voxels=((0, 0, 0), (32, 48, 20))))  # z, y, x
    lay = SliceLayout(session)
    lay.set_poi((20.0, 24.0, 10.0))
    after = lay.render(_cam, size, wait=True, timeout=60)
    x0, y0, pw, ph = lay.panel_rect("axial", size)
    xs = np.array([[lay.point_at("axial", i + 0.5, j + 0.5)[0] for i in range(pw)] for j in range(ph)])
    panel_before, panel_after = before[y0:y0 + ph, x0:x0 + pw, :3], after[y0:y0 + ph, x0:x0 + pw, :3]
    cross = (panel_after[..., 0] > 200) & (panel_after[..., 2] < 100)  # the yellow cross at the point of interest
    beyond, inside = (xs > 20.5) & ~cross, (xs < 19.5) & ~cross
    assert panel_before[beyond].any() and not panel_after[beyond].any()  # drawn whole before, left out now
    np.testing.assert_array_equal(panel_after[inside], panel_before[inside])
