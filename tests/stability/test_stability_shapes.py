"""Stability matrix, shapes: 1x1x1, 1xNxM, Nx1x1, prime sizes, 2**k + 1 sizes, a brick larger than
the volume, extreme anisotropy (spacing 1e3 against 1e-3) - each through the whole pipeline:
``brick_volume`` -> ``ZarrLoader`` -> ``ClipTexture`` -> ``ClipRenderAction``.

References: every stored level against an independent numpy 2x2x2 mean (edge replication, written
here, not :func:`clipvol.bricking.pyramid.downsample`); images against ``vol.max(axis=...)`` (MIP, axis-aligned
orthographic, one pixel per voxel) and the numpy ray caster (composite).
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.scene.camera import Camera
from clipvol.paging.cliptexture import ClipTexture
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.scene.transfer import TransferFunction

import reference_raycast as ref
from render_helpers import render_converged

TF = TransferFunction.preset("viridis")

#: name -> (shape (z, y, x), brick, spacing (z, y, x))
CASES = {
    "1x1x1": ((1, 1, 1), 8, (1.0, 1.0, 1.0)),
    "1xNxM": ((1, 13, 20), 8, (1.0, 1.0, 1.0)),
    "Nx1x1": ((19, 1, 1), 8, (1.0, 1.0, 1.0)),
    "1xNx1": ((1, 11, 1), 8, (1.0, 1.0, 1.0)),
    "primes": ((13, 17, 19), 8, (1.0, 1.0, 1.0)),
    "pow2_plus_1": ((17, 33, 9), 8, (1.0, 1.0, 1.0)),
    "brick_larger_than_volume": ((5, 6, 7), 16, (1.0, 1.0, 1.0)),
    "anisotropic_1e3_1e-3": ((6, 10, 12), 8, (1e3, 1.0, 1e-3)),
    "anisotropic_1e-3_1e3": ((6, 10, 12), 8, (1e-3, 1.0, 1e3)),
}

#: the shapes bricked and drawn in the default run (one of each kind: a point, a plane, a line, odd sizes, one brick
#: larger than the volume, anisotropy)
RENDER_DEFAULT = ("1x1x1", "1xNxM", "Nx1x1", "primes", "brick_larger_than_volume", "anisotropic_1e3_1e-3")


def mean_reference(a: np.ndarray) -> np.ndarray:
    """2x2x2 mean with edge replication of odd axes, in float64, cast back (written independently)."""
    a64 = a.astype(np.float64)
    for axis in range(3):
        if a64.shape[axis] % 2:
            last = np.take(a64, [-1], axis=axis)
            a64 = np.concatenate([a64, last], axis=axis)
    z, y, x = a64.shape
    m = a64.reshape(z // 2, 2, y // 2, 2, x // 2, 2).mean(axis=(1, 3, 5))
    return m.astype(a.dtype)


def volume(shape, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).random(shape).astype(np.float32)




def build(tmp_path, name):
    shape, brick, spacing = CASES[name]
    vol = volume(shape)
    out = tmp_path / f"{name}.zarr"
    brick_volume(vol, out, brick=brick, spacing=spacing, progress=False, workers=1)
    return vol, ZarrLoader(out)


def read_level(loader, L) -> np.ndarray:
    pyr = loader.pyramid
    shp, B = pyr.levels[L].shape, pyr.brick_shape
    g = pyr.grid(L)
    full = np.empty(tuple(gi * b for gi, b in zip(g, B)), pyr.dtype)
    for b in np.ndindex(*g):
        full[tuple(slice(i * s, (i + 1) * s) for i, s in zip(b, B))] = loader.read_brick(L, b)
    return full[: shp[0], : shp[1], : shp[2]]


@pytest.mark.parametrize("name", [n if n in RENDER_DEFAULT else pytest.param(n, marks=pytest.mark.slow) for n in CASES])
def test_bricked_levels_match_independent_mean(tmp_path, name):
    vol, loader = build(tmp_path, name)
    pyr = loader.pyramid
    shape, brick, spacing = CASES[name]
    assert pyr.shape == shape and pyr.spacing == spacing
    assert max(pyr.grid(pyr.num_levels - 1)) == 1  # the top level is one brick
    want = vol
    for L in range(pyr.num_levels):
        got = read_level(loader, L)
        assert got.shape == want.shape
        np.testing.assert_array_equal(got, want)
        # edge bricks are padded by edge replication (the loader contract)
        last = tuple(g - 1 for g in pyr.grid(L))
        b = loader.read_brick(L, last)
        start, stop = pyr.brick_voxel_box(L, last)
        valid = tuple(e - s for s, e in zip(start, stop))
        padded = np.pad(b[: valid[0], : valid[1], : valid[2]], [(0, B - v) for B, v in zip(pyr.brick_shape, valid)], mode="edge")
        np.testing.assert_array_equal(b, padded)
        want = mean_reference(want)
        # node boxes of the level tile the volume box exactly
        lo, hi = pyr.node_box(L, np.array(list(np.ndindex(*pyr.grid(L)))))
        vlo, vhi = pyr.volume_box()
        np.testing.assert_allclose(np.min(lo, axis=0), vlo)
        np.testing.assert_allclose(np.max(hi, axis=0), vhi)
        assert np.isclose(np.prod(hi - lo, axis=1).sum(), np.prod(vhi - vlo), rtol=1e-9)


def _render(ctx, loader, cam, mode, step=0.5):
    from clipvol.render.action import ClipRenderAction

    with ClipTexture(loader, "16MB", threads=2) as clip:
        # every brick in RAM first: which neighbours reach the GPU (open vs clamped faces) must not
        # depend on load timing (see test_stability_geometry::test_converged_render_independent_of_load_timing)
        assert clip.wait_until_idle(timeout=30)
        action = ClipRenderAction(ctx, clip, mode=mode, policy="fixed", level=0, step=step)
        try:
            img = render_converged(action, cam, TF, timeout=20)
            return img
        finally:
            action.close()


def _views(pyr, shift=0.0):
    """(camera, numpy MIP of the voxels it looks through) for views along +z and +x.

    ``shift`` moves the lattice origin (the camera centre) along the view by that many voxels of
    the view axis: 0.125 keeps every sample off the volume's faces, where the half-open sample
    interval makes a sample exactly on a face a floating-point tie (in or out by one ulp)."""
    Z, Y, X = pyr.shape
    sz, sy, sx = pyr.spacing
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    along_z = Camera.orthographic(c + (0, 0, shift * sz), (0, 0, 1), (0, -1, 0), X * sx, Y * sy, size=(X, Y))
    # along +x with up -y: right = (1,0,0) x (0,-1,0) = (0,0,-1): columns run towards -z
    along_x = Camera.orthographic(c + (shift * sx, 0, 0), (1, 0, 0), (0, -1, 0), Z * sz, Y * sy, size=(Z, Y))
    return [(along_z, lambda v: v.max(axis=0)), (along_x, lambda v: v.max(axis=2).T[:, ::-1])]


def _step_for(pyr, cam) -> float:
    """Default 0.5 voxel, but along a coarse axis of an anisotropic volume one sample per 0.5
    voxel *of that axis* (the default would take 1e6 samples per voxel)."""
    sp = np.array(pyr.spacing[::-1])  # (x, y, z)
    along = float(np.abs(cam.forward) @ sp)
    return 0.5 * along / float(sp.min())


@pytest.mark.gl
@pytest.mark.parametrize("name", [n if n in RENDER_DEFAULT else pytest.param(n, marks=pytest.mark.slow) for n in CASES])
def test_render_shape_mip_and_composite(gl, tmp_path, name):
    vol, loader = build(tmp_path, name)
    pyr = loader.pyramid
    for (cam, project), (shifted, _) in zip(_views(pyr), _views(pyr, 0.125)):
        step = _step_for(pyr, cam)
        img = _render(gl, loader, cam, "mip", step)
        want = np.rint(TF.lookup(project(vol).astype(np.float64), pyr.value_range) * 255).astype(np.uint8)
        want[want[..., 3] == 0, :3] = 0  # straight alpha: colour 0 where the 8-bit alpha is 0
        d = np.abs(img.astype(int) - want.astype(int))
        # colour means nothing where both alphas round to 0 (the TF's alpha is 0 at its low end)
        d[(img[..., 3] == 0) & (want[..., 3] == 0)] = 0
        assert d.max() <= 1, f"MIP along {cam.forward}: max diff {d.max()}"
        cam = shifted
        img = _render(gl, loader, cam, "composite", step)
        fc = cam.fit_depth(*pyr.volume_box())
        want = ref.to_uint8(ref.raycast(vol, pyr.spacing, fc, TF.table, TF.window(pyr.value_range), step))
        a = img[..., 3:4].astype(float)
        b = want[..., 3:4].astype(float)
        d = np.abs(np.concatenate([img[..., :3] * a / 255, a], -1) - np.concatenate([want[..., :3] * b / 255, b], -1))
        assert d.max() <= 2, f"composite along {cam.forward}: max diff {d.max():.1f}"


@pytest.mark.gl
@pytest.mark.parametrize("name", ["anisotropic_1e3_1e-3", "anisotropic_1e-3_1e3"])
def test_render_anisotropic_default_step_is_right_or_refused(gl, tmp_path, name):
    """The default step (0.5 of the *smallest* voxel) along the coarse axis needs 1.2e7 samples per
    ray: the renderer must either draw the right MIP or refuse with an error naming ``step`` -
    never cut the rays short silently."""
    from clipvol.errors import ParameterError

    vol, loader = build(tmp_path, name)
    pyr = loader.pyramid
    coarse = int(np.argmax(pyr.spacing))  # array axis (z, y, x)
    cam, project = _views(pyr)[0 if coarse == 0 else 1]
    try:
        img = _render(gl, loader, cam, "mip", 0.5)
    except ParameterError as e:
        assert "step" in str(e)
        return
    want = np.rint(TF.lookup(project(vol).astype(np.float64), pyr.value_range) * 255).astype(np.uint8)
    want[want[..., 3] == 0, :3] = 0  # straight alpha: colour 0 where the 8-bit alpha is 0
    d = np.abs(img.astype(int) - want.astype(int))
    assert d.max() <= 1, f"MIP along the coarse axis with step 0.5: max diff {d.max()} (rays cut short?)"
