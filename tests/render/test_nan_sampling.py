"""NaN-aware sampling (issue: finite voxels next to NaN vanished) and the shader variants.

References are independent of the renderer: numpy's ``nanmax`` / ``nanmean`` of the volume.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from clipvol.loaders.numpy_array import NumpyLoader

from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

GREY = TransferFunction.preset("grey")


def masked_map(shape=(24, 28, 20), seed=3) -> np.ndarray:
    """A smooth positive 'statistical map' NaN-masked outside an ellipsoid, as such maps are."""
    z, y, x = np.mgrid[0:shape[0], 0:shape[1], 0:shape[2]].astype(np.float64)
    v = 0.5 + 0.4 * np.sin(x / 2.3) * np.cos(y / 3.1) + 0.1 * np.random.default_rng(seed).random(shape)
    c = [(n - 1) / 2 for n in shape]
    inside = ((z - c[0]) / (0.45 * shape[0])) ** 2 + ((y - c[1]) / (0.45 * shape[1])) ** 2 + ((x - c[2]) / (0.45 * shape[2])) ** 2 < 1
    v[~inside] = np.nan
    return v.astype(np.float32)


def render(ctx, vol, cam, brick=8, tf=GREY, nonfinite=None, **kw):
    loader = NumpyLoader(vol, brick=brick)
    clip = ClipTexture(loader, "64MB", threads=2)
    action = ClipRenderAction(ctx, clip, policy="fixed", level=0, **kw)
    if nonfinite is not None:
        action.nonfinite = nonfinite
    try:
        img = action.render(cam, tf, wait=True, timeout=20)
        assert action.last_frame_stats.converged
        return img, action.defines()
    finally:
        action.close()
        clip.close()


def straight_to_uint8(rgba: np.ndarray) -> np.ndarray:
    return ref.to_uint8(np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], axis=-1))


def test_mip_of_a_nan_masked_map_is_numpy_nanmax(ctx, draw_path):
    vol = masked_map()
    nz, ny, nx = vol.shape
    # pixel centres on voxel centres, samples on voxel centres along z (step 1, lattice plane at a centre)
    centre = ((nx - 1) / 2, (ny - 1) / 2, float(nz // 2))
    cam = Camera.orthographic(centre, (0, 0, 1), (0, -1, 0), nx, ny, size=(nx, ny))
    img, defines = render(ctx, vol, cam, mode="mip", step=1.0, path=draw_path)
    assert defines["HAS_NAN"]
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        m = np.nanmax(vol, axis=0)  # all-NaN columns warn and give NaN: nothing drawn there
    lo, hi = float(np.nanmin(vol)), float(np.nanmax(vol))
    rgba = ref.tf_lookup(GREY.table, (np.nan_to_num(m, nan=lo) - lo) / (hi - lo))
    rgba[np.isnan(m)] = 0.0
    expect = straight_to_uint8(rgba)
    d = np.abs(img.astype(int) - expect.astype(int))
    assert d.max() <= 1, f"{int((d > 1).sum())} pixels differ from nanmax"
    # the finite voxels next to the mask are really there (they were 0 before)
    # (where the reference's 8-bit alpha is 0 - the presets fade to 0 at their window's bottom -
    # there is nothing to see either way)
    edge = np.isfinite(m) & ~np.isfinite(np.pad(m, 1, constant_values=np.nan)[:-2, 1:-1]) & (expect[..., 3] > 0)
    assert edge.sum() > 10 and (img[edge][:, 3] > 0).all()


def test_reference_trilinear_is_nanmean_at_cell_centres():
    """The numpy reference itself, against numpy's nanmean: at a cell centre all eight weights
    are equal, so NaN-aware trilinear is the mean of the finite corners."""
    rng = np.random.default_rng(0)
    vol = rng.random((6, 7, 8))
    vol[rng.random(vol.shape) < 0.4] = np.nan
    vol[0:2, 0:2, 0:2] = np.nan  # one cell entirely NaN
    idx = np.stack(np.meshgrid(np.arange(7), np.arange(6), np.arange(5), indexing="ij"), -1).reshape(-1, 3)  # (x, y, z)
    u = idx + 0.5
    got = ref.trilinear(vol, u)
    corners = np.stack([vol[idx[:, 2] + dz, idx[:, 1] + dy, idx[:, 0] + dx]
                        for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], axis=1)
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        want = np.nanmean(corners, axis=1)
    np.testing.assert_allclose(got, want, rtol=1e-12, equal_nan=True)
    assert np.isnan(got[0])  # the all-NaN cell stays NaN (transparent)


def test_reference_mip_is_nanmax():
    vol = masked_map((10, 12, 9)).astype(np.float64)
    nz, ny, nx = vol.shape
    cam = Camera.orthographic(((nx - 1) / 2, (ny - 1) / 2, float(nz // 2)), (0, 0, 1), (0, -1, 0), nx, ny,
                              size=(nx, ny))
    lo, hi = float(np.nanmin(vol)), float(np.nanmax(vol))
    table = np.stack([np.linspace(0, 1, 256)] * 4, axis=1)
    spacing = (1.0, 1.0, 1.0)
    from clipvol.bricking.pyramid import Pyramid

    fc = cam.fit_depth(*Pyramid.build(vol.shape, (16, 16, 16)).volume_box())
    prem = ref.raycast(vol, spacing, fc, table, (lo, hi), 1.0, "mip")
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        m = np.nanmax(vol, axis=0)
    want = np.where(np.isnan(m), 0.0, ref.tf_lookup(table, (np.nan_to_num(m) - lo) / (hi - lo))[..., 3])
    np.testing.assert_allclose(prem[..., 3], want, atol=1e-9)


def test_variants_fast_path_for_finite_data_and_both_agree(ctx):
    """Finite float data compiles the variant without NaN handling; forcing the NaN-aware
    variant (manual trilinear) on the same data draws the same image within 1 LSB."""
    z, y, x = np.mgrid[0:32, 0:32, 0:32].astype(np.float32)
    vol = ((np.sin(x / 3) + np.cos(y / 4) + np.sin(z / 2.5) + 3) / 6).astype(np.float32)
    tf = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (1.0, (1, 0, 0, 0.3))])
    cam = Camera.perspective((55.0, 45.0, -35.0), (15.5, 15.5, 15.5), size=(64, 64), fov_y=40)
    fast, d1 = render(ctx, vol, cam, tf=tf)
    nan, d2 = render(ctx, vol, cam, tf=tf, nonfinite=True)
    nan_sp, _ = render(ctx, vol, cam, tf=tf, nonfinite=True, path="single-pass")
    fast_sp, _ = render(ctx, vol, cam, tf=tf, path="single-pass")
    assert np.abs(nan_sp.astype(int) - fast.astype(int)).max() <= 1
    assert np.abs(fast_sp.astype(int) - fast.astype(int)).max() <= 1
    assert not d1["HAS_NAN"] and d2["HAS_NAN"]
    assert (fast[..., 3] > 0).mean() > 0.3
    assert np.abs(fast.astype(int) - nan.astype(int)).max() <= 1
    fc = cam.fit_depth(*NumpyLoader(vol, brick=8).pyramid.volume_box())
    r = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, tf.table, (float(vol.min()), float(vol.max())), 0.5))
    assert np.abs(fast.astype(int) - r.astype(int)).max() <= 2
