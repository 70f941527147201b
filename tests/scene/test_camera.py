"""Camera math against independent numpy references (projection of points, sampled boxes)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.scene.camera import Camera


def _cams(offset=(0.0, 0.0, 0.0)):
    o = np.asarray(offset)
    return [
        Camera.perspective(o + (3, -2, -10), o + (0.5, 0.25, 0.375), up=(0, 1, 0), fov_y=50, size=(40, 30), near=0.5, far=40),
        Camera.perspective(o + (0, 0, -5), o, up=(0, -1, 0), fov_y=170, size=(16, 16), near=0.1, far=20),
        Camera.perspective(o + (0, 0, -500), o, up=(1, 1, 0), fov_y=1, size=(16, 24), near=100, far=1000),
        Camera.orthographic(o + (1, 2, 3), (1, -0.5, 2), (0, 1, 0), 8, 6, size=(32, 24), near=-20, far=20),
    ]


def _project(cam, pts):
    """NDC of world points through view_projection (the GL path)."""
    h = np.concatenate([pts, np.ones(pts.shape[:-1] + (1,))], axis=-1) @ cam.view_projection().T
    return h[..., :3] / h[..., 3:]


def test_basis_right_handed_and_image_convention():
    cam = Camera.perspective((0, 0, -5), (0, 0, 0), up=(0, -1, 0))
    np.testing.assert_allclose(cam.right, [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(cam.up, [0, -1, 0], atol=1e-15)
    for c in _cams():
        np.testing.assert_allclose(np.cross(c.forward, c.up), c.right, atol=1e-12)
        B = np.stack([c.right, c.up, c.forward])
        np.testing.assert_allclose(B @ B.T, np.eye(3), atol=1e-12)
    # row 0 of the image is the top (the up side): y world grows with rows for up = -y
    o, d = cam.rays()
    assert d[0, 0, 1] < 0 < d[-1, 0, 1] and d[0, 0, 0] < 0 < d[0, -1, 0]


@pytest.mark.parametrize("ci", range(4))
def test_rays_project_to_their_pixel_centres(ci):
    cam = _cams()[ci]
    o, d = cam.rays()
    w, h = cam.size
    t = 0.5 * (cam.near + cam.far) if cam.orthographic else 0.5 * (cam.near + cam.far)
    pts = o + d * t
    ndc = _project(cam, pts)
    cols = (ndc[..., 0] + 1) / 2 * w - 0.5
    rows = (1 - ndc[..., 1]) / 2 * h - 0.5
    rr, cc = np.mgrid[0:h, 0:w]
    np.testing.assert_allclose(cols, cc, atol=1e-6)
    np.testing.assert_allclose(rows, rr, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize("ci", range(4))
def test_frustum_planes_agree_with_clip_space(ci):
    cam = _cams()[ci]
    rng = np.random.default_rng(ci)
    pts = cam.center + rng.uniform(-30, 30, size=(4000, 3))
    ndc = _project(cam, pts)
    h = np.concatenate([pts, np.ones((len(pts), 1))], axis=1) @ cam.view_projection().T
    inside_clip = np.all(np.abs(h[:, :3]) <= h[:, 3:], axis=1) & (h[:, 3] > 0)
    p = cam.frustum_planes()
    val = pts @ p[:, :3].T + p[:, 3]
    inside_planes = np.all(val >= 0, axis=1)
    margin = np.min(np.abs(val), axis=1) > 1e-6
    assert inside_clip.any() and (~inside_clip).any()
    np.testing.assert_array_equal(inside_clip[margin], inside_planes[margin])
    assert np.all(np.abs(ndc[inside_planes & margin]) <= 1 + 1e-9)


@pytest.mark.parametrize("ci", range(4))
def test_boxes_in_frustum_is_conservative(ci):
    cam = _cams()[ci]
    rng = np.random.default_rng(10 + ci)
    lo = cam.center + rng.uniform(-25, 25, size=(400, 3))
    hi = lo + rng.uniform(0.01, 6, size=(400, 3))
    got = cam.boxes_in_frustum(lo, hi)
    p = cam.frustum_planes()
    s = rng.uniform(size=(1, 300, 3))
    pts = lo[:, None] + s * (hi - lo)[:, None]
    any_inside = np.any(np.all(pts @ p[:, :3].T + p[:, 3] >= 0, axis=-1), axis=1)
    assert not np.any(any_inside & ~got)  # never culls a box with a visible point
    assert (~got).sum() > 20  # and does cull


@pytest.mark.parametrize("ci", range(4))
def test_boxes_beside_view_meet_no_pixel_ray(ci):
    """A box reported beside the view is hit by no pixel's ray (slab test on cam.rays(), in front
    of the eye; the whole line for orthographic rays); boxes straddling the view are not reported."""
    cam = _cams()[ci]
    rng = np.random.default_rng(20 + ci)
    lo = cam.center + rng.uniform(-25, 25, size=(300, 3))
    hi = lo + rng.uniform(0.01, 6, size=(300, 3))
    got = cam.boxes_beside_view(lo, hi)
    o, d = cam.rays()
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(d) < 1e-300, 1e-300, d)
    hit = np.zeros(len(lo), dtype=bool)
    for k in range(len(lo)):
        t0, t1 = (lo[k] - o) * inv, (hi[k] - o) * inv
        near = np.minimum(t0, t1).max(axis=1)
        far = np.maximum(t0, t1).min(axis=1)
        ok = near <= far
        if not cam.ortho:
            ok &= far >= 0
        hit[k] = ok.any()
    assert not np.any(hit & got)  # never a box some pixel's ray passes through
    assert got.sum() > 20  # and it does find boxes beside the view
    # a box around the point of interest is in view, at any size
    c = np.asarray(cam.center, dtype=np.float64)
    assert not cam.boxes_beside_view(c - 0.01, c + 0.01)[0] and not cam.boxes_beside_view(c - 100, c + 100)[0]


def test_projected_size_matches_projection_of_a_segment():
    cam = Camera.perspective((0, 0, -10), (0, 0, 0), up=(0, 1, 0), fov_y=40, size=(200, 100))
    for z0 in (-5.0, 0.0, 7.0):
        lo, hi = np.array([[-1, -1, z0]]), np.array([[1, 1, z0 + 2]])
        got = cam.projected_size(lo, hi, 0.25)[0]
        a, b = _project(cam, np.array([[0, 0, z0], [0.25, 0, z0]]))
        ref = max(abs(b[0] - a[0]) * 200 / 2, abs(b[1] - a[1]) * 100 / 2)
        assert got == pytest.approx(ref, rel=1e-9)
    # orthographic: independent of depth
    oc = Camera.orthographic((0, 0, 0), (0, 0, 1), (0, 1, 0), 10, 5, size=(100, 50))
    s = oc.projected_size([[0, 0, -50], [0, 0, 50]], [[1, 1, -49], [1, 1, 51]], 1.0)
    a, b = _project(oc, np.array([[0, 0, 0], [1, 0, 0]]))
    np.testing.assert_allclose(s, abs(b[0] - a[0]) * 50)


def test_projected_size_edge_cases_never_nan_or_negative():
    cam = Camera.perspective((0, 0, 0), (0, 0, 1), size=(64, 64))
    lo = np.array([[-1, -1, -1], [5, 5, -3], [-1, -1, -9], [1e300, 0, 1], [-2, -2, 1e-300]])
    hi = np.array([[1, 1, 1], [6, 6, 3], [1, 1, -8], [1e301, 1, 2], [2, 2, 1]])
    s = cam.projected_size(lo, hi, np.array([1, 1, 1, np.inf, 1e300]))
    assert s[0] == np.inf and s[1] == np.inf  # eye inside; straddles the eye plane
    assert s[2] == 0.0  # wholly behind
    assert not np.any(np.isnan(s)) and np.all(s >= 0)


def test_huge_coordinates_behave_like_the_origin():
    rng = np.random.default_rng(3)
    # ~1e10 voxels from the origin; inputs on a 1/1024 grid so they are exact at both places
    off = np.array([2.0**33, -(2.0**34), 2.0**32])
    for c0, c1 in zip(_cams(), _cams(off)):
        lo = np.round((c0.center + rng.uniform(-20, 20, size=(300, 3))) * 1024) / 1024
        hi = lo + np.round(rng.uniform(0.1, 4, size=(300, 3)) * 1024) / 1024
        np.testing.assert_array_equal(c0.boxes_in_frustum(lo, hi), c1.boxes_in_frustum(lo + off, hi + off))
        np.testing.assert_allclose(c0.projected_size(lo, hi, 0.5), c1.projected_size(lo + off, hi + off, 0.5), rtol=1e-5)
        np.testing.assert_allclose(c0.rays()[1], c1.rays()[1], atol=1e-6)


def test_fit_depth_encloses_the_box():
    lo, hi = np.array([-1.0, -2, -3]), np.array([4.0, 5, 6])
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for cam in _cams() + [Camera.perspective((0, 0, 0), (1, 1, 1))]:
        c = cam.fit_depth(lo, hi)
        depth = (corners - c.eye) @ c.forward
        assert c.far >= depth.max()
        if c.orthographic:
            assert c.near <= depth.min()
        else:
            assert 0 < c.near <= max(depth.min(), c.near) and c.near < c.far


@pytest.mark.parametrize(
    "make",
    [
        lambda: Camera.perspective((1, 2, 3), (1, 2, 3)),
        lambda: Camera.perspective((0, 0, 0), (0, 1, 0), up=(0, 2, 0)),
        lambda: Camera.perspective((0, 0, 0), (0, 0, 1), size=(0, 10)),
        lambda: Camera.perspective((0, 0, 0), (0, 0, 1), fov_y=0),
        lambda: Camera.perspective((0, 0, 0), (0, 0, 1), fov_y=180),
        lambda: Camera.perspective((0, 0, 0), (0, 0, 1), near=-1),
        lambda: Camera.perspective((0, 0, 0), (0, 0, 1), near=5, far=1),
        lambda: Camera.perspective((0, 0, np.nan), (0, 0, 1)),
        lambda: Camera.orthographic((0, 0, 0), (0, 0, 0), (0, 1, 0), 1, 1),
        lambda: Camera.orthographic((0, 0, 0), (0, 0, 1), (0, 1, 0), 0, 1),
    ],
)
def test_invalid_parameters_raise_parameter_error(make):
    with pytest.raises(ParameterError):
        make()


def test_orthographic_flag_and_constructor_share_a_name():
    oc = Camera.orthographic((0, 0, 0), (0, 0, 1), (0, 1, 0), 2, 2)
    assert oc.orthographic is True and Camera.perspective((0, 0, -1), (0, 0, 0)).orthographic is False
    np.testing.assert_allclose(oc.center, [0, 0, 0]) and np.testing.assert_allclose(oc.forward, [0, 0, 1])
