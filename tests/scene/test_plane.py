"""Plane geometry: axis presets against numpy's slices, pixel points, plane-box polygons, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.scene.plane import Plane, default_size


@pytest.fixture
def pyr():
    return Pyramid.build((12, 20, 30), (8, 8, 8), spacing=(2.0, 1.0, 0.5))


def test_axial_pixel_grid_follows_x_and_y_at_the_slice_depth(pyr):
    pl = Plane.axis(pyr, "axial", 5)
    pts = pl.pixel_points((30, 20), 1.0)
    # columns follow +x, rows follow +y, all at z = 5 * spacing_z
    assert np.allclose(pts[..., 2], 10.0)
    assert np.all(np.diff(pts[..., 0], axis=1) > 0) and np.allclose(np.diff(pts[..., 0], axis=0), 0)
    assert np.all(np.diff(pts[..., 1], axis=0) > 0) and np.allclose(np.diff(pts[..., 1], axis=1), 0)


def test_presets_show_numpy_slices_in_radiological_order():
    pyr = Pyramid.build((6, 7, 9), (4, 4, 4))
    vol = np.arange(6 * 7 * 9).reshape(6, 7, 9)
    for name, k, ref in [("axial", 3, vol[3]), ("coronal", 2, vol[:, 2, :][::-1]), ("sagittal", 4, vol[:, :, 4][::-1])]:
        pl = Plane.axis(pyr, name, k)
        size = default_size(pyr, pl, 1.0)
        pts = pl.pixel_points(size, 1.0)
        idx = np.rint(pts[..., ::-1]).astype(int)
        assert np.allclose(pts[..., ::-1], idx)  # voxel centres exactly
        got = vol[idx[..., 0], idx[..., 1], idx[..., 2]]
        assert np.array_equal(got, ref), name


def test_pixel_points_and_to_pixels_invert(rng):
    pl = Plane.through((3.0, -2.0, 7.5), (0.2, 0.9, -0.4))
    pts = pl.pixel_points((17, 11), 0.37)
    cr = pl.to_pixels(pts.reshape(-1, 3), (17, 11), 0.37)
    cols, rows = np.meshgrid(np.arange(17) + 0.5, np.arange(11) + 0.5)
    assert np.allclose(cr[:, 0], cols.ravel()) and np.allclose(cr[:, 1], rows.ravel())
    assert np.allclose(pl.signed_distance(pts.reshape(-1, 3)), 0.0)
    assert np.allclose(np.cross(pl.right, pl.up), -np.asarray(pl.normal))  # right-handed like the camera


def test_box_polygon_lies_on_the_plane_and_the_box_and_has_the_sampled_area(rng):
    for _ in range(30):
        lo = rng.uniform(-5, 0, 3)
        hi = lo + rng.uniform(0.5, 4, 3)
        pl = Plane.through(rng.uniform(lo, hi), rng.normal(size=3))
        poly = pl.box_polygon(lo, hi)
        assert 3 <= len(poly) <= 6
        assert np.allclose(pl.signed_distance(poly), 0, atol=1e-9)
        assert np.all(poly >= lo - 1e-9) and np.all(poly <= hi + 1e-9)
        # every vertex on the box surface
        on_face = np.isclose(poly, lo).any(axis=1) | np.isclose(poly, hi).any(axis=1)
        assert on_face.all()
        # area of the fan vs Monte-Carlo fraction of in-plane points inside the box
        rel = poly - poly[0]
        area = 0.5 * sum(np.linalg.norm(np.cross(rel[k], rel[k + 1])) for k in range(1, len(poly) - 1))
        c = poly.mean(axis=0)
        R = float(np.max(np.linalg.norm(poly - c, axis=1)))
        uv = rng.uniform(-R, R, (40000, 2))
        pts = c + uv[:, :1] * pl.right + uv[:, 1:] * np.asarray(pl.up)
        frac = np.mean(np.all((pts >= lo) & (pts <= hi), axis=1))
        assert abs(frac * (2 * R) ** 2 - area) < 0.05 * area + 0.02 * R * R


def test_crosses_matches_corner_signs(rng):
    pl = Plane.through((0.3, 0.1, -0.2), (1.0, 2.0, -0.5))
    lo = rng.uniform(-3, 3, (500, 3))
    hi = lo + rng.uniform(0.01, 2, (500, 3))
    corners = np.stack([np.stack([np.where([i & 1, i & 2, i & 4], hi[j], lo[j]) for i in range(8)]) for j in range(500)])
    d = pl.signed_distance(corners.reshape(-1, 3)).reshape(500, 8)
    ref = (d.min(axis=1) <= 0) & (d.max(axis=1) >= 0)
    assert np.array_equal(pl.crosses(lo, hi), ref)


def test_bad_planes_name_the_parameter(pyr):
    with pytest.raises(ParameterError, match="normal"):
        Plane((0, 0, 0), (0, 0, 0))
    with pytest.raises(ParameterError, match="up"):
        Plane((0, 0, 0), (0, 0, 1), (0, 0, 2))
    with pytest.raises(ParameterError, match="index"):
        Plane.axis(pyr, "axial", 12)
    with pytest.raises(ParameterError, match="axis"):
        Plane.axis(pyr, "transverse", 1)
    far = Plane.through((0, 0, 1e4), (0, 0, 1))
    with pytest.raises(ParameterError, match="plane"):
        default_size(pyr, far, 1.0)
