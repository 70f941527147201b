"""Stability matrix, geometry: the camera inside the volume, inside a brick, on a brick face, on the
volume's face; views exactly along an axis and along a diagonal (ties in the octant order);
field of view 1 and 170 degrees; boxes straddling the eye plane in projected-size LOD; a camera
very far away.

Images are compared with the independent numpy ray caster (``reference_raycast.py``); draw
orders with the brute-force per-ray visibility check (``_raycheck.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clipvol.scene.camera import Camera
from clipvol.paging.cliptexture import ClipTexture
from clipvol.errors import ParameterError
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import select
from clipvol.scene.transfer import TransferFunction

import reference_raycast as ref
from render_helpers import render_converged

TF = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (0.4, (0, 1, 0, 0.05)), (1.0, (1, 0.3, 0, 0.35))])


def order_violations(cam, lo, hi, eps=1e-7):
    """Brute force: rays (one per pixel) along which a nearer box is drawn before a farther one.

    Returns ``(violating rays, rays that hit any box)``; the draw order is the row order of ``lo``/``hi``.
    """
    o, d = cam.rays()
    o, d = o.reshape(-1, 3)[:, None, :], d.reshape(-1, 3)[:, None, :]
    lo, hi = np.asarray(lo, float)[None], np.asarray(hi, float)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    zero = d == 0
    inside = (o > lo) & (o < hi)
    t0 = np.where(zero, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb)).max(axis=2)
    t1 = np.where(zero, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb)).min(axis=2)
    if not cam.orthographic:
        t0 = np.maximum(t0, 0.0)
    hit = (t1 - t0) > eps * max(1.0, float(np.abs(hi - lo).max()))
    key = np.where(hit, t0, np.inf)
    srt = np.argsort(key, axis=1, kind="stable")
    pos = np.take_along_axis(np.broadcast_to(np.arange(lo.shape[1]), key.shape), srt, axis=1)
    valid = np.take_along_axis(hit, srt, axis=1)
    bad = valid[:, 1:] & valid[:, :-1] & (np.diff(pos, axis=1) > 0)
    return int(bad.any(axis=1).sum()), int(hit.any(axis=1).sum())


def smooth(shape=(24, 24, 24)) -> np.ndarray:
    z, y, x = np.mgrid[0 : shape[0], 0 : shape[1], 0 : shape[2]].astype(np.float64)
    return ((np.sin(x / 3.0) + np.cos(y / 4.0) + np.sin(z / 2.5) + 3.0) / 6.0).astype(np.float32)


VOL = smooth()
PYR = NumpyLoader(VOL, brick=8).pyramid  # 24^3 voxels, bricks of 8: 3x3x3 bricks at level 0




def render(ctx, cam, vol=VOL, *, brick=8, policy="fixed", level=0, mode="composite", **kw):
    """Converged render; returns ``(image, action stats, selection)``."""
    from clipvol.render.action import ClipRenderAction

    loader = NumpyLoader(vol, brick=brick)
    with ClipTexture(loader, "16MB", threads=2) as clip:
        # every brick in RAM first: which neighbours reach the GPU (open vs clamped faces) must not
        # depend on load timing (see test_stability_geometry::test_converged_render_independent_of_load_timing)
        assert clip.wait_until_idle(timeout=30)
        action = ClipRenderAction(ctx, clip, policy=policy, level=level if policy == "fixed" else None,
                                  mode=mode, **kw)
        try:
            img = render_converged(action, cam, TF, timeout=20)
            return img, action.last_frame_stats, action.last_selection
        finally:
            action.close()


def reference(cam, vol=VOL, mode="composite"):
    pyr = NumpyLoader(vol, brick=8).pyramid
    fc = cam.fit_depth(*pyr.volume_box())
    return ref.to_uint8(ref.raycast(vol, pyr.spacing, fc, TF.table, TF.window(pyr.value_range), 0.5, mode))


def premultiplied(img):
    a = img[..., 3:4].astype(np.float64)
    return np.concatenate([img[..., :3] * a / 255.0, a], axis=-1)


def assert_close(img, want, max_diff=3, frac=0.002):
    """Premultiplied comparison (a colour under alpha ~0 means nothing): at most ``frac`` of the
    pixels differ by more than ``max_diff`` levels."""
    d = np.abs(premultiplied(img) - premultiplied(want)).max(axis=-1)
    assert (d > max_diff).mean() <= frac, f"{(d > max_diff).sum()} pixels differ by > {max_diff}, max {d.max():.1f}"
    assert want[..., 3].max() > 0  # the comparison is not of two empty images


# -- the camera inside / on the faces ---------------------------------------------------------------
EYES = {
    "inside_volume": (11.3, 12.1, 10.7),
    "inside_brick": (3.3, 4.2, 2.9),           # inside brick (0, 0, 0), away from its faces
    "on_brick_face": (7.5, 12.2, 11.1),        # exactly on the plane between bricks x=0 and x=1
    "on_brick_corner": (7.5, 15.5, 7.5),       # on three split planes at once (ties in every axis)
    "on_volume_face": (11.2, 12.3, -0.5),      # exactly on the volume's front face (depth 0)
    "outside_near_face": (11.2, 12.3, -0.5 - 1e-9),
}
#: eye positions where a sample lies exactly on a box boundary (see the test)
TIES = ("on_brick_corner", "on_volume_face")


@pytest.mark.gl
@pytest.mark.parametrize("where", list(EYES))
@pytest.mark.parametrize("look", [(0.3, -0.2, 1.0), (0.0, 0.0, 1.0), pytest.param((1.0, 1.0, 1.0), marks=pytest.mark.slow)])
def test_render_eye_inside_and_on_faces(gl, where, look):
    eye = np.array(EYES[where])
    cam = Camera.perspective(eye, eye + np.array(look), up=(0, -1, 0), fov_y=70, size=(48, 48))
    img, _, _ = render(gl, cam)
    if where in TIES:
        # the eye exactly on a corner / the volume's face: whether the sample at t = 0 (or one on a
        # ray grazing the face) counts is a floating-point tie; it may differ by one sample, no more
        assert_close(img, reference(cam), max_diff=9, frac=0.002)
        eye = eye + 1e-4  # one step off the tie: exact again
        cam = Camera.perspective(eye, eye + np.array(look), up=(0, -1, 0), fov_y=70, size=(48, 48))
        img, _, _ = render(gl, cam)
    assert_close(img, reference(cam))


@pytest.mark.gl
@pytest.mark.parametrize("depth", [0.5, 3.0])
def test_near_plane_exactly_on_the_volume_face(gl, depth):
    """A camera whose near plane passes exactly through the volume's front face (and one whose
    near plane cuts into the volume: the renderer re-fits near/far to the volume, never clipping it)."""
    eye = np.array([11.2, 12.3, -0.5 - depth])
    cam = Camera.perspective(eye, eye + np.array([0.0, 0.0, 1.0]), up=(0, -1, 0), fov_y=60, size=(40, 40),
                             near=depth, far=100.0)  # the front face z = -0.5 is exactly at depth `near`
    lo, hi = PYR.volume_box()
    assert cam.boxes_in_frustum(lo[None], hi[None])[0]  # touching the near plane is inside
    ps = cam.projected_size(lo[None], hi[None], 1.0)[0]
    assert np.isfinite(ps) and ps == pytest.approx(cam.pixels_per_unit(depth))
    img, _, _ = render(gl, cam)
    assert_close(img, reference(cam))
    deeper = cam.with_depth_range(depth + 5.0, 100.0)  # a user near plane inside the volume
    img2, _, _ = render(gl, deeper)
    assert_close(img2, reference(cam))


@pytest.mark.parametrize("where", list(EYES))
@pytest.mark.parametrize("look", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, -1, 0), (1, 1, 1), (-1, 1, -1), (0.3, -0.2, 1.0)])
def test_draw_order_exact_with_ties(where, look):
    """Mixed-level cut (eye-dependent LOD) in exact back-to-front order, the eye on split planes and
    the view exactly along an axis or a diagonal."""
    eye = np.array(EYES[where])
    up = (0, 1, 0) if abs(look[1]) < 0.9 * np.linalg.norm(look) else (0, 0, 1)
    cam = Camera.perspective(eye, eye + np.array(look, float), up=up, fov_y=90, size=(32, 32))
    sel = select(PYR, cam, RenderParams(lod_threshold=3.0))
    if where in ("on_volume_face", "outside_near_face") and tuple(look) == (0, 0, -1):  # looking away from the volume: nothing to draw
        assert sel.items == [] and sel.wanted == []
        return
    assert len(sel.items) > 1
    lo = np.array([it.lo for it in sel.items])
    hi = np.array([it.hi for it in sel.items])
    bad, hit = order_violations(cam, lo, hi)
    assert hit > 0 and bad == 0
    # the brick holding the eye is drawn at level 0 (its projected voxel size is infinite)
    inside = np.all((lo <= eye) & (eye <= hi), axis=1)
    assert all(sel.items[i].level == 0 for i in np.nonzero(inside)[0])


@pytest.mark.parametrize("direction", [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (1, 1, 1), (1, -1, 1), (-1, -1, -1)])
def test_orthographic_order_along_axes_and_diagonals(direction):
    """Orthographic: ties between octants (zero components of the direction) still give exact order."""
    c = np.array([11.5, 11.5, 11.5])
    up = (0, 0, 1) if direction[:2] == (0, 1) or direction == (0, 1, 0) else (0, 1, 0)
    cam = Camera.orthographic(c, direction, up, 40, 40, size=(24, 24))
    # a mixed cut: level 0 on one half, level 1 elsewhere
    lv, idx = [], []
    for b in np.ndindex(*PYR.grid(1)):
        if b[2] == 0:
            lv += [0] * 8
            idx += [tuple(2 * np.array(b) + o) for o in np.ndindex(2, 2, 2)]
        else:
            lv.append(1)
            idx.append(b)
    keep = [i for i, b in enumerate(idx) if all(v < g for v, g in zip(b, PYR.grid(lv[i])))]
    lv, idx = np.array(lv)[keep], np.array(idx)[keep]
    from clipvol.scene.selection import back_to_front

    order = back_to_front(PYR, cam, lv, idx)
    boxes = [PYR.node_box(int(L), b) for L, b in zip(lv, idx)]
    lo = np.array([b[0] for b in boxes])[order]
    hi = np.array([b[1] for b in boxes])[order]
    bad, hit = order_violations(cam, lo, hi)
    assert hit > 0 and bad == 0


# -- field of view, orthographic -------------------------------------------------------------------
@pytest.mark.gl
@pytest.mark.parametrize("fov", [1.0, 170.0])
def test_render_extreme_fov(gl, fov):
    target = np.array([11.5, 11.5, 11.5])
    dist = 12.0 / np.tan(np.radians(fov) / 2) * 1.2 if fov < 90 else 14.0
    eye = target + np.array([0.2, -0.1, -1.0]) / np.linalg.norm([0.2, -0.1, -1.0]) * dist
    cam = Camera.perspective(eye, target, up=(0, -1, 0), fov_y=fov, size=(48, 48))
    img, _, _ = render(gl, cam)
    assert_close(img, reference(cam))


def test_fov_outside_range_is_refused():
    for fov in (0.5, 0.0, 171.0, 180.0, float("nan")):
        with pytest.raises(ParameterError, match="fov_y"):
            Camera.perspective((0, 0, -10), (0, 0, 0), fov_y=fov)


@pytest.mark.gl
@pytest.mark.parametrize("direction", [(0, 0, 1), (1, 1, 1), (-0.3, 1.0, 0.2)])
def test_render_orthographic(gl, direction):
    up = (0, 0, 1) if direction[1] == 1.0 else (0, -1, 0)
    cam = Camera.orthographic((11.5, 11.5, 11.5), direction, up, 44, 44, size=(44, 44))
    img, _, _ = render(gl, cam)
    assert_close(img, reference(cam))
    mip, _, _ = render(gl, cam, mode="mip")
    assert_close(mip, reference(cam, mode="mip"))


# -- projected size across the eye plane -----------------------------------------------------------
def test_projected_size_straddling_eye_plane():
    cam = Camera.perspective((0, 0, 0), (0, 0, 1), fov_y=60, size=(100, 100))
    lo = np.array([[-1, -1, -1], [-1, -1, 2], [-1, -1, -5], [-1, -1, 0], [-1, -1, -1e-300]], float)
    hi = np.array([[1, 1, 1], [1, 1, 3], [1, 1, -2], [1, 1, 1e-12], [1, 1, 0]], float)
    ps = cam.projected_size(lo, hi, 1.0)
    assert ps[0] == np.inf            # contains the eye
    assert np.isfinite(ps[1]) and ps[1] > 0
    assert ps[2] == 0.0               # wholly behind
    assert ps[3] == np.inf            # touches the eye plane from the front
    assert ps[4] == 0.0               # touches it from behind
    assert not np.any(np.isnan(ps))


@settings(max_examples=150, deadline=None)
@given(eye=st.tuples(*[st.floats(-50, 50)] * 3), c=st.tuples(*[st.floats(-50, 50)] * 3),
       h=st.tuples(*[st.floats(0, 20)] * 3), ortho=st.booleans())
def test_projected_size_never_nan_or_negative(eye, c, h, ortho):
    eye, c, h = np.array(eye), np.array(c), np.array(h)
    if ortho:
        cam = Camera.orthographic(eye, (0.3, -0.5, 0.8), (0, 1, 0), 10, 10, size=(64, 64))
    else:
        cam = Camera.perspective(eye, eye + np.array([0.3, -0.5, 0.8]), fov_y=45, size=(64, 64))
    ps = cam.projected_size((c - h)[None], (c + h)[None], 1.0)
    assert ps.shape == (1,) and not np.isnan(ps[0]) and ps[0] >= 0
    # a box containing the eye always refines (the box as floats hold it: c +- a tiny h may round to c)
    if not ortho and np.all(c - h < eye) and np.all(eye < c + h):
        assert ps[0] == np.inf


# -- very far away ---------------------------------------------------------------------------------
@pytest.mark.gl
@pytest.mark.parametrize("dist", [2e3, 1e9])
def test_far_camera_draws_coarsest_level_correctly(gl, dist):
    """From far away every brick is at the top level, and the image is the reference of that level."""
    target = np.array([11.5, 11.5, 11.5])
    eye = target - np.array([0.0, 0.0, 1.0]) * dist
    fov = float(np.degrees(2 * np.arctan(20.0 / dist)))  # the volume fills most of the image
    fov = min(max(fov, 1.0), 170.0)
    cam = Camera.perspective(eye, target, up=(0, -1, 0), fov_y=fov, size=(16, 16))
    sel = select(PYR, cam, RenderParams(lod_threshold=8.0))
    top = PYR.num_levels - 1
    img, stats, s2 = render(gl, cam, policy="projected-size", lod_threshold=8.0)
    if dist > 1e6:  # the whole volume is a fraction of a pixel: only the top level
        assert {it.level for it in sel.items} == {top}
        assert set(stats.bricks_drawn) == {top}
    levels = sorted({it.level for it in s2.items})
    # reference: the drawn cut sampled from the loader's own levels
    loader = NumpyLoader(VOL, brick=8)
    arrs = []
    for L in range(PYR.num_levels):
        shp = PYR.levels[L].shape
        g = PYR.grid(L)
        full = np.zeros(tuple(gi * 8 for gi in g), np.float32)
        for b in np.ndindex(*g):
            full[b[0] * 8 : b[0] * 8 + 8, b[1] * 8 : b[1] * 8 + 8, b[2] * 8 : b[2] * 8 + 8] = loader.read_brick(L, b)
        lv = PYR.levels[L]
        arrs.append((full[: shp[0], : shp[1], : shp[2]], np.array(lv.scale[::-1]), np.array(lv.translation[::-1])))
    regions = [(it.level, np.array(it.lo), np.array(it.hi)) for it in s2.items]
    fc = cam.fit_depth(*PYR.volume_box())
    want = ref.to_uint8(ref.raycast_levels(arrs, regions, fc, TF.table, TF.window(PYR.value_range), 0.5,
                                           ref_spacing=1.0))
    assert levels
    d = np.abs(img.astype(int) - want.astype(int)).max(axis=-1)
    assert (d > 3).sum() <= 1, d.max()


@pytest.mark.gl
def test_converged_render_independent_of_load_timing(gl):
    """A converged render is the same picture whether or not the neighbours of the drawn bricks
    (here: the bricks behind the eye, outside the frustum) had finished loading: the samples at the
    eye interpolate across those faces, so ``converged`` must include them (or never use them)."""
    import time

    from clipvol.render.action import ClipRenderAction

    class LateBehind:
        """Bricks behind the eye (bz == 0) arrive 0.4 s late."""

        def __init__(self, inner):
            self.inner = inner

        @property
        def pyramid(self):
            return self.inner.pyramid

        def read_brick(self, level, index):
            if level == 0 and index[0] == 0:
                time.sleep(0.4)
            return self.inner.read_brick(level, index)

    eye = np.array(EYES["on_brick_corner"]) + 1e-4
    cam = Camera.perspective(eye, eye + np.array([0.3, -0.2, 1.0]), up=(0, -1, 0), fov_y=70, size=(48, 48))
    with ClipTexture(LateBehind(NumpyLoader(VOL, brick=8)), "16MB", threads=2) as clip:
        action = ClipRenderAction(gl, clip, policy="fixed", level=0)
        try:
            early = action.render(cam, TF, wait=True, timeout=20)
            assert action.last_frame_stats.converged
            assert clip.wait_until_idle(timeout=30)
            late = action.render(cam, TF, wait=True, timeout=20)
        finally:
            action.close()
    want = reference(cam)
    assert_close(late, want)
    d = np.abs(premultiplied(early) - premultiplied(late)).max(axis=-1)
    assert d.max() <= 3, f"the 'converged' frame changed by up to {d.max():.1f} once the neighbours arrived"
