"""Camera paths: orbit, fly and zoom over a pyramid's volume box (pure numpy)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.scene.paths import (
    PATHS,
    fit_distance,
    fly,
    make_path,
    orbit,
    volume_center,
    zoom,
)


@pytest.fixture
def pyr():
    return Pyramid.build((40, 64, 96), (16, 16, 16), spacing=(2.0, 1.0, 1.0))


def _inside(p, lo, hi, tol=1e-9):
    return np.all(p >= lo - tol) and np.all(p <= hi + tol)


def test_orbit_circles_the_centre_and_sees_the_whole_volume(pyr):
    lo, hi = pyr.volume_box()
    c = volume_center(pyr)
    views = list(orbit(pyr, 12, size=(64, 48), elevation=20))
    assert len(views) == 12
    dists = [np.linalg.norm(cam.eye - c) for cam, _ in views]
    np.testing.assert_allclose(dists, dists[0], rtol=1e-9)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for cam, coi in views:
        np.testing.assert_allclose(coi, c)
        np.testing.assert_allclose(cam.forward, (c - cam.eye) / np.linalg.norm(c - cam.eye), atol=1e-12)
        # every corner projects inside the image and between near and far
        m = cam.view_projection()
        ph = np.c_[corners, np.ones(8)] @ m.T
        ndc = ph[:, :3] / ph[:, 3:4]
        assert np.all(ph[:, 3] > 0)
        assert np.all(np.abs(ndc) <= 1.0 + 1e-9), ndc
    # equal azimuth steps: consecutive eye directions (projected on the horizontal plane) turn by 30 deg
    dirs = np.array([cam.eye - c for cam, _ in views])[:, [0, 2]]
    ang = np.degrees(np.arctan2(dirs[:, 0], -dirs[:, 1]))
    steps = np.diff(np.unwrap(np.radians(ang)))
    np.testing.assert_allclose(np.abs(np.degrees(steps)), 30.0, atol=1e-9)


def test_first_orbit_view_looks_along_z_with_numpy_orientation(pyr):
    cam, _ = next(orbit(pyr, 1, elevation=0.0))
    np.testing.assert_allclose(cam.forward, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(cam.right, [1, 0, 0], atol=1e-12)  # x grows to the right
    np.testing.assert_allclose(cam.up, [0, -1, 0], atol=1e-12)  # y grows down the image


def test_fly_stays_inside_the_volume_and_moves_the_centre(pyr):
    lo, hi = pyr.volume_box()
    views = list(fly(pyr, 20, size=(32, 32)))
    cois = np.array([coi for _, coi in views])
    for cam, coi in views:
        assert _inside(cam.eye, lo, hi)
        assert _inside(coi, lo, hi)
        # the camera looks at the centre of interest (it lies ahead, on the view axis)
        d = coi - cam.eye
        assert d @ cam.forward > 0
        np.testing.assert_allclose(d / np.linalg.norm(d), cam.forward, atol=1e-9)
        assert 0 < cam.near < cam.far
    # the centre of interest travels a good part of the box
    assert np.ptp(cois[:, 0]) > 0.5 * (hi[0] - lo[0])


def test_fly_through_waypoints_passes_them(pyr):
    lo, hi = pyr.volume_box()
    pts = np.array([lo + 0.2 * (hi - lo), volume_center(pyr), hi - 0.2 * (hi - lo)])
    views = list(fly(pyr, 9, points=pts, look_ahead=0.1))
    np.testing.assert_allclose(views[0][0].eye, pts[0], atol=1e-9)
    # way-points are interpolated: the path passes the middle one
    eyes = np.array([cam.eye for cam, _ in views])
    assert np.min(np.linalg.norm(eyes - pts[1], axis=1)) < 0.1 * np.linalg.norm(hi - lo)


def test_zoom_goes_from_whole_view_to_close_up(pyr):
    lo, hi = pyr.volume_box()
    target = lo + 0.25 * (hi - lo)
    views = list(zoom(pyr, 8, size=(64, 64), target=target))
    d = np.array([np.linalg.norm(cam.eye - coi) for cam, coi in views])
    assert np.all(np.diff(d) < 0)  # monotone approach
    np.testing.assert_allclose(d[0], fit_distance(pyr, 35.0, (64, 64)), rtol=1e-9)
    np.testing.assert_allclose(views[-1][1], target, atol=1e-9)
    # constant ratio between consecutive distances (geometric zoom)
    np.testing.assert_allclose(d[1:] / d[:-1], d[1] / d[0], rtol=1e-9)


def test_make_path_and_errors(pyr):
    assert set(PATHS) == {"orbit", "turntable", "fly", "zoom"}
    assert len(list(make_path("zoom", pyr, 3, size=(8, 8)))) == 3
    with pytest.raises(ParameterError, match="path"):
        make_path("spiral", pyr, 3)
    with pytest.raises(ParameterError, match="frames"):
        list(orbit(pyr, 0))
    with pytest.raises(ParameterError, match="size"):
        list(orbit(pyr, 2, size=(0, 4)))
    with pytest.raises(ParameterError, match="target"):
        list(zoom(pyr, 2, target=(1e9, 0, 0)))
    with pytest.raises(ParameterError, match="points"):
        list(fly(pyr, 2, points=[[0, 0, 0]]))
