"""Framing what the transfer function shows: the visible box, and views that fit a box (pure numpy)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.scene.framing import MARGIN_VOXELS, fit_points_distance, visible_box, visible_points
from clipvol.scene.paths import orbit, turntable
from clipvol.scene.transfer import TransferFunction


def _ndc(cam, p):
    """Normalised device x, y of world points ``p`` ``(n, 3)`` by the pinhole model from the camera's
    eye, basis and field of view (not the camera's own matrices)."""
    q = np.asarray(p, dtype=np.float64) - cam.eye
    z = q @ cam.forward
    w, h = cam.size
    ty = np.tan(np.radians(cam.fov_y) / 2.0)
    return (q @ cam.right) / (z * ty * w / h), (q @ cam.up) / (z * ty), z


def _corners(lo, hi):
    return np.array([[a[0], b[1], c[2]] for a in (lo, hi) for b in (lo, hi) for c in (lo, hi)])


def _volume():
    """Air (0) with a block of tissue (value 900) off centre, in a 40 x 48 x 56 volume."""
    vol = np.zeros((40, 48, 56), dtype=np.uint16)
    vol[5:19, 20:31, 33:50] = 900
    vol[10, 25, 40] = 400  # inside the block: changes nothing
    return vol


@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (2.5, 0.8, 0.6)])
def test_visible_box_is_the_box_of_the_voxels_with_opacity(spacing):
    vol = _volume()
    loader = NumpyLoader(vol, brick=16, spacing=spacing)
    tf = TransferFunction.preset("bone", value_range=(0.0, 1000.0))
    pyr = loader.pyramid
    box = visible_box(loader, tf, max_voxels=vol.size)  # level 0 read whole
    assert box is not None
    # the reference: the voxels whose interpolated colour (TransferFunction.lookup) has alpha > 0
    seen = tf.lookup(vol.astype(np.float64), pyr.value_range)[..., 3] > 0
    idx = np.argwhere(seen)
    first, last = idx.min(axis=0), idx.max(axis=0)  # (z, y, x)
    lv = pyr.levels[0]
    lo_ref = np.asarray(lv.translation) + (first - 0.5 - MARGIN_VOXELS) * np.asarray(lv.scale)
    hi_ref = np.asarray(lv.translation) + (last + 0.5 + MARGIN_VOXELS) * np.asarray(lv.scale)
    vlo, vhi = pyr.volume_box()
    np.testing.assert_allclose(box[0], np.maximum(lo_ref[::-1], vlo))
    np.testing.assert_allclose(box[1], np.minimum(hi_ref[::-1], vhi))
    assert np.all(box[1] - box[0] < vhi - vlo)  # smaller than the volume on every axis
    # every visible voxel's widened cube lies within the points' reach: its centre is inside their box,
    # and the points are corners of surface voxels only (fewer than 8 per visible voxel)
    pts = visible_points(loader, tf, max_voxels=vol.size)
    centres = (np.asarray(lv.translation) + idx * np.asarray(lv.scale))[:, ::-1]
    assert np.all(centres >= pts.min(axis=0)) and np.all(centres <= pts.max(axis=0))
    assert len(pts) < 8 * len(idx)


def test_visible_box_from_a_coarse_level_holds_the_fine_box():
    vol = _volume()
    loader = NumpyLoader(vol, brick=16)
    tf = TransferFunction.preset("bone", value_range=(0.0, 1000.0))
    fine = visible_box(loader, tf, max_voxels=vol.size)
    coarse = visible_box(loader, tf, max_voxels=vol.size // 8)  # level 1
    assert np.all(coarse[0] <= fine[0] + 1e-9) and np.all(coarse[1] >= fine[1] - 1e-9)


def test_visible_box_none_when_all_transparent():
    loader = NumpyLoader(np.zeros((16, 16, 16), dtype=np.uint16), brick=8)
    tf = TransferFunction.preset("bone", value_range=(0.0, 1000.0))
    assert visible_box(loader, tf) is None
    with pytest.raises(ParameterError, match="max_voxels"):
        visible_box(loader, tf, max_voxels=0)


@pytest.mark.parametrize("size", [(64, 64), (96, 48), (40, 80)])
def test_fit_points_distance_fills_the_view_with_the_margin(size):
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(200, 3)) * [3.0, 4.0, 1.5] + [6.0, 2.0, 11.0]
    paths = list(turntable(_pyr(), 5, size=size, up=(0.0, 0.0, 1.0), front=(1.0, 0.3, 0.0), elevation=20.0,
                           fit=pts))
    c = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    cams = [cam for cam, _ in paths]
    d = fit_points_distance(pts, c, cams, margin=1.05)
    for cam, coi in paths:
        np.testing.assert_allclose(coi, c)
        np.testing.assert_allclose(np.linalg.norm(cam.eye - c), d)  # one distance along the path
    # every point inside every view, and some point of some view on the margin's edge
    reach = []
    for cam in cams:
        x, y, z = _ndc(cam, pts)
        assert np.all(z > 0)
        reach.append(max(np.abs(x).max(), np.abs(y).max()))
    assert max(reach) <= 1 / 1.05 + 1e-9
    assert max(reach) == pytest.approx(1 / 1.05, rel=1e-9)
    with pytest.raises(ParameterError, match="points"):
        fit_points_distance(np.zeros((1, 3)), np.zeros(3), cams)


def _pyr():
    from clipvol.bricking.pyramid import Pyramid

    return Pyramid.build((40, 48, 56), (16, 16, 16), (1.0, 1.0, 1.0), "mean", np.uint16, (0.0, 1000.0), 0.0)


def test_orbit_frames_points_closer_than_the_volume():
    pyr = _pyr()
    lo, hi = np.array([33.0, 20.0, 5.0]), np.array([50.0, 31.0, 19.0])
    whole = list(orbit(pyr, 4, size=(64, 64)))
    framed = list(orbit(pyr, 4, size=(64, 64), fit=_corners(lo, hi)))
    for (cw, _), (cf, coi) in zip(whole, framed):
        np.testing.assert_allclose(coi, (lo + hi) / 2.0)
        assert np.linalg.norm(cf.eye - coi) < np.linalg.norm(cw.eye - cw.target)
        x, y, _ = _ndc(cf, _corners(lo, hi))
        assert max(np.abs(x).max(), np.abs(y).max()) <= 1 / 1.05 + 1e-9
    with pytest.raises(ParameterError, match="fit"):
        list(orbit(pyr, 2, fit=np.full((2, 3), np.nan)))


def test_an_unreadable_brick_counts_as_visible():
    from clipvol.errors import BrickIntegrityError

    vol = _volume()

    class Damaged(NumpyLoader):
        def read_brick(self, level, index):
            if level == 0 and tuple(index) == (2, 0, 0):  # voxels z 32..39, y 0..15, x 0..15
                raise BrickIntegrityError("brick (0, 2, 0, 0): damaged")
            return super().read_brick(level, index)

    tf = TransferFunction.preset("bone", value_range=(0.0, 1000.0))
    pts = visible_points(Damaged(vol, brick=16), tf, max_voxels=vol.size)
    lo, hi = pts.min(axis=0), pts.max(axis=0)  # x y z: the damaged corner is inside the framed box
    assert lo[0] <= 0.0 and lo[1] <= 0.0 and hi[2] >= 39.0
    assert np.all(lo <= visible_box(NumpyLoader(vol, brick=16), tf, max_voxels=vol.size)[0])
