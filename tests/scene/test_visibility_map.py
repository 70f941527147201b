"""Per-brick visibility from occlusion layers: the summed-area-table mean equals numpy's mean over
the same pixels, and a box behind an opaque region of the map is invisible."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.scene.camera import Camera
from clipvol.scene.visibility import OcclusionLayers, march_occlusion, rect_mean, screen_rects, summed_area_table


def test_rect_mean_equals_numpy(rng):
    img = rng.random((37, 53))
    sat = summed_area_table(img)
    x0 = rng.integers(0, 52, 200)
    y0 = rng.integers(0, 36, 200)
    x1 = x0 + 1 + rng.integers(0, 53 - x0)
    y1 = y0 + 1 + rng.integers(0, 37 - y0)
    got = rect_mean(sat, x0, y0, x1, y1)
    want = [img[a:b, c:d].mean() for a, b, c, d in zip(y0, y1, x0, x1)]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def _cam():
    return Camera.orthographic((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), 20.0, 20.0, size=(40, 40))


def test_screen_rects_match_projected_corners():
    cam = _cam()  # 2 pixels per world unit, centre of the image at x = y = 0
    r, behind = screen_rects(cam, np.array([[-5.0, -5.0, 3.0]]), np.array([[5.0, 0.0, 6.0]]))
    assert not behind[0]
    # x in [-5, 5] -> pixels [10, 30]; up is -y so y = -5 is at the top of the image (row 10) ... y = 0 at row 20
    np.testing.assert_allclose(sorted(r[0, [0, 2]]), [10.0, 30.0], atol=1e-9)
    np.testing.assert_allclose(sorted(r[0, [1, 3]]), [10.0, 20.0], atol=1e-9)


def test_box_behind_an_opaque_patch_is_invisible():
    cam = _cam()
    eye_depth = float(np.dot(np.asarray(cam.center) - cam.eye, cam.forward))
    alpha = np.zeros((2, 20, 20))  # a map at half the camera's resolution
    alpha[1, :, :10] = 1.0  # everything behind depth d1 on the left half is hidden
    layers = OcclusionLayers(cam, np.array([0.0, eye_depth + 2.0]), alpha)
    lo = np.array([[-8.0, -8.0, 5.0], [2.0, -8.0, 5.0], [-8.0, -8.0, -1.0], [-2.0, -8.0, 5.0]])
    hi = np.array([[-2.0, 8.0, 7.0], [8.0, 8.0, 7.0], [-2.0, 8.0, 1.0], [2.0, 8.0, 7.0]])
    v = layers.visibility(lo, hi)
    assert v[0] == pytest.approx(0.0)  # behind the patch
    assert v[1] == pytest.approx(1.0)  # beside it
    assert v[2] == pytest.approx(1.0)  # in front of the layer's depth
    assert v[3] == pytest.approx(0.5)  # half its footprint hidden


def test_reuse_only_for_small_turns():
    cam = _cam()
    layers = OcclusionLayers(cam, np.array([0.0]), np.zeros((1, 4, 4)), key="tf")
    assert layers.reusable(cam, "tf")
    assert not layers.reusable(cam, "other tf")
    turned = Camera.orthographic((0.0, 0.0, 0.0), (np.sin(np.radians(10)), 0.0, np.cos(np.radians(10))), (0.0, -1.0, 0.0),
                                 20.0, 20.0, size=(40, 40))
    assert not layers.reusable(turned, "tf", max_angle=3.0)
    slight = Camera.orthographic((0.0, 0.0, 0.0), (np.sin(np.radians(1)), 0.0, np.cos(np.radians(1))), (0.0, -1.0, 0.0),
                                 20.0, 20.0, size=(40, 40))
    assert layers.reusable(slight, "tf", max_angle=3.0, scale=100.0)


def test_orbit_is_judged_by_its_angle_about_the_centre():
    """Far from the volume a 2-degree orbit moves the eye by more than 2 % of the diagonal: without a
    centre the estimate is redone, with the volume's centre it is kept, and so is a sideways step of
    the arc's length that keeps the view direction; a 5-degree orbit, a 10 % zoom and a view
    direction turned by 4 degrees are not kept."""
    centre = np.array([0.0, 0.0, 0.0])

    def orbit(deg, r=100.0):
        th = np.radians(deg)
        eye = (r * np.sin(th), 0.0, -r * np.cos(th))
        return Camera.perspective(eye, tuple(centre), up=(0, 1, 0), fov_y=30, size=(32, 32))

    layers = OcclusionLayers(orbit(0.0), np.array([0.0]), np.zeros((1, 4, 4)), key="tf")
    diag = 10.0  # eye moves 3.5 units for 2 degrees at r = 100: far more than 2 % of 10
    assert not layers.reusable(orbit(2.0), "tf", 3.0, 0.02, diag)
    assert layers.reusable(orbit(2.0), "tf", 3.0, 0.02, diag, centre)
    assert not layers.reusable(orbit(5.0), "tf", 3.0, 0.02, diag, centre)
    assert not layers.reusable(orbit(0.0, r=90.0), "tf", 3.0, 0.02, diag, centre)
    step = Camera.perspective((3.5, 0.0, -100.0), (3.5, 0.0, 0.0), up=(0, 1, 0), fov_y=30, size=(32, 32))
    assert layers.reusable(step, "tf", 3.0, 0.02, diag, centre)  # a 2-degree shift seen from the centre, same direction
    side = Camera.perspective((3.5, 0.0, -100.0), (3.5 + 100 * np.tan(np.radians(4)), 0.0, 0.0), up=(0, 1, 0),
                              fov_y=30, size=(32, 32))
    assert not layers.reusable(side, "tf", 3.0, 0.02, diag, centre)  # the view direction turned by 4 degrees


def test_cpu_march_follows_beer_lambert_along_each_ray():
    """In a uniform medium of opacity ``a`` per unit length, the opacity in front of depth ``d`` is
    ``1 - (1 - a) ** L`` with ``L`` the ray's length between the volume's near face and the last
    sample plane before ``d``: ``m`` planes of spacing 1 along the view, ``m / cos`` along an
    oblique ray (closed form, per pixel)."""
    vol = np.full((40, 40, 40), 0.5, np.float32)  # voxel centres 0..39, box -0.5..39.5 on every axis
    a = 0.05
    cam = Camera.perspective((19.5, 19.5, -30.0), (19.5, 19.5, 19.5), up=(0, 1, 0), fov_y=20, size=(9, 9))
    near = -0.5 - (-30.0)  # the box's nearest depth along +z
    m = np.array([0, 3, 10, 25])
    depths = np.concatenate([[0.0], near + m[1:].astype(float)])
    out = march_occlusion(vol, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), cam, lambda v: np.full(np.shape(v), a), depths,
                          ref_length=1.0, step=1.0)
    _, dirs = cam.rays()
    cos = dirs @ np.array([0.0, 0.0, 1.0])
    for k, mk in enumerate(m):
        want = 1.0 - (1.0 - a) ** (mk / cos)
        np.testing.assert_allclose(out[k], want, atol=1e-5)
    # and nothing is in front of the volume: outside samples are empty
    assert np.all(out[0] == 0.0)


def test_cpu_march_leaves_out_what_the_shape_cuts_away():
    vol = np.full((20, 20, 20), 1.0, np.float32)
    cam = Camera.orthographic((9.5, 9.5, 9.5), (0, 0, 1), (0, 1, 0), 20.0, 20.0, size=(8, 8))
    from clipvol.scene.geometry import Shape

    depth_far = float(np.dot(np.array([9.5, 9.5, 30.0]) - cam.eye, cam.forward))
    kw = dict(ref_length=1.0, step=1.0)
    full = march_occlusion(vol, (1,) * 3, (0,) * 3, cam, lambda v: np.full(np.shape(v), 0.1), [0.0, depth_far], **kw)
    left = Shape(planes=((-1.0, 0.0, 0.0, 9.5),))  # keeps x <= 9.5: the left half of the image
    cut = march_occlusion(vol, (1,) * 3, (0,) * 3, cam, lambda v: np.full(np.shape(v), 0.1), [0.0, depth_far],
                          shape=left, **kw)
    np.testing.assert_allclose(full[1], 1.0 - 0.9**20, atol=1e-5)
    x = (np.arange(8) + 0.5) / 8 * 20.0 - 0.5  # pixel centres in world x (the image's x runs along +x here)
    inside_cols = x <= 9.5 if cam.right[0] > 0 else x[::-1] <= 9.5
    assert np.allclose(cut[1][:, inside_cols], full[1][:, inside_cols], atol=1e-5)
    assert np.all(cut[1][:, ~inside_cols] == 0.0)


def test_silhouette_fraction_is_the_outline_share_of_the_footprint():
    from scipy import ndimage

    cam = _cam()  # 2 pixels per world unit; the map below has half that resolution: 1 map pixel per unit
    yy, xx = np.mgrid[0:20, 0:20]
    disc = (xx + 0.5 - 10) ** 2 + (yy + 0.5 - 10) ** 2 <= 36.0  # an opaque disc of radius 6 map pixels
    alpha = np.zeros((2, 20, 20))
    alpha[1] = np.where(disc, 0.9, 0.1)
    layers = OcclusionLayers(cam, np.array([0.0, 1.0]), alpha)
    cross = ndimage.generate_binary_structure(2, 1)
    outline = ndimage.binary_dilation(disc, cross) & ~ndimage.binary_erosion(disc, cross)  # both sides of the edge
    lo = np.array([[-2.0, -2.0, 5.0], [-10.0, -10.0, 5.0], [4.0, -1.0, 5.0], [-10.0, -10.0, 5.0]])
    hi = np.array([[2.0, 2.0, 7.0], [-8.0, -8.0, 7.0], [8.0, 1.0, 7.0], [10.0, 10.0, 7.0]])
    s = layers.silhouette(lo, hi)
    assert s[0] == 0.0 and s[1] == 0.0  # inside the disc, in the empty corner
    # the box straddling the disc's edge: x in [4, 8] -> map columns 14..17, y in [-1, 1] -> rows 9..10
    assert s[2] == pytest.approx(outline[9:11, 14:18].mean()) and s[2] > 0
    assert s[3] == pytest.approx(outline.mean())  # the whole image


@pytest.mark.parametrize("shape", [(7, 5, 9), (1, 6, 4), (3, 1, 1)])
def test_trilinear_equals_scipy(shape):
    """The numpy trilinear sampler of the visibility pass against scipy's (order 1, clamped edges)."""
    from scipy.ndimage import map_coordinates

    from clipvol.scene.visibility import trilinear

    rng = np.random.default_rng(3)
    vol = rng.random(shape).astype(np.float32)
    pts = rng.random((500, 3)) * (np.array(shape) - 1)
    pts[:5] = np.array(shape) - 1  # the far corner and edges
    pts[5:10] = 0.0
    ref = map_coordinates(vol, pts.T, order=1, mode="nearest")
    assert np.allclose(trilinear(vol, pts), ref, atol=1e-5)
