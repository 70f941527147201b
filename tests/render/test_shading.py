"""Gradient lighting (the SHADING variant): a lit render equals the independent numpy reference ray
caster (central differences over the whole array with edges replicated, trilinear, the same
Blinn-Phong with the light at the eye), in both paths, with anisotropic spacing; and a volume cut
into 16^3 bricks renders lit like the same volume in one 128^3 brick (no seams where bricks meet:
the gradient reads the neighbour brick through the same toroidal level texture).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from render_helpers import every_draw_path
from scipy.ndimage import gaussian_filter

from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import ParameterError
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

SHAPE = (36, 44, 40)
SPACING = (1.5, 1.0, 0.8)  # (z, y, x): anisotropic
LIGHT = dict(ambient=0.2, diffuse=0.6, specular=0.4, shininess=8.0)


def volume() -> np.ndarray:
    """A smooth noisy ball: gradients vary everywhere, the surface is lit at every angle."""
    rng = np.random.default_rng(3)
    z, y, x = np.mgrid[0:SHAPE[0], 0:SHAPE[1], 0:SHAPE[2]].astype(float)
    zc, yc, xc = ((np.array(SHAPE) - 1) / 2)
    r = np.sqrt(((z - zc) * SPACING[0]) ** 2 + ((y - yc) * SPACING[1]) ** 2 + ((x - xc) * SPACING[2]) ** 2)
    v = np.clip(1.2 - r / 14.0, 0, 1) + 0.3 * gaussian_filter(rng.random(SHAPE), 2.0)
    return v.astype(np.float32)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    vol = volume()
    out = {}
    for b in (16, 128):
        p = tmp_path_factory.mktemp("shading") / f"b{b}.zarr"
        brick_volume(vol, p, brick=b, spacing=SPACING, progress=False, workers=1)
        out[b] = p
    return vol, out


def _render(ctx, store, cam, tf, nan_variant=False, **kw):
    clip = ClipTexture(ZarrLoader(store), "64MB", threads=2)
    action = ClipRenderAction(ctx, clip, policy="fixed", level=0, **kw)
    action.nonfinite = nan_variant or action.nonfinite  # the HAS_NAN + SHADING variant on finite data
    try:
        img = action.render(cam, tf, wait=True, timeout=30)
        assert action.last_frame_stats.converged
        return img
    finally:
        action.close()
        clip.close()


def _camera():
    ext = np.array(SHAPE[::-1]) * np.array(SPACING[::-1])
    c = tuple((ext / 2 - 0.5 * np.array(SPACING[::-1])).tolist())
    n = float(ext.max())
    return Camera.perspective((c[0] + 1.2 * n, c[1] + 0.8 * n, c[2] - 1.0 * n), c, size=(80, 80), fov_y=35)


@pytest.mark.parametrize("path,merge", [*(pytest.param(p, True, marks=pytest.mark.slow) if p == "bricks" else (p, True)
                                          for p in every_draw_path()),
                                        pytest.param("bricks", False, marks=pytest.mark.slow)],
                         ids=[*every_draw_path(), "bricks-unmerged"])
def test_lit_render_equals_the_reference_and_one_brick(ctx, stores, path, merge):
    vol, paths = stores
    tf = TransferFunction.preset("bone")
    cam = _camera()
    lit16 = _render(ctx, paths[16], cam, tf, path=path, merge_boxes=merge, shading=True, **LIGHT)
    lit128 = _render(ctx, paths[128], cam, tf, path=path, shading=True, **LIGHT)
    unlit = _render(ctx, paths[16], cam, tf, path=path)
    fc = cam.fit_depth(*ZarrLoader(paths[16]).pyramid.volume_box())
    rng = (float(vol.min()), float(vol.max()))
    light = tuple(LIGHT[k] for k in ("ambient", "diffuse", "specular", "shininess"))
    r = ref.to_uint8(ref.raycast(vol, SPACING, fc, tf.table, rng, 0.5, lighting=light))
    r_unlit = ref.to_uint8(ref.raycast(vol, SPACING, fc, tf.table, rng, 0.5))
    assert (r[..., 3] > 200).mean() > 0.08  # an opaque, lit surface fills much of the image
    # lighting really changes the picture (else the comparison below proves nothing)
    assert np.abs(r.astype(int) - r_unlit.astype(int))[..., :3].max() > 60
    assert np.abs(unlit.astype(int) - r_unlit.astype(int)).max() <= 1
    d_ref = np.abs(lit16.astype(int) - r.astype(int))
    d_one = np.abs(lit16.astype(int) - lit128.astype(int))
    assert d_ref.max() <= 2, f"{int((d_ref.max(axis=2) > 2).sum())} pixels differ from the reference"
    assert d_one.max() <= 1, f"{int((d_one.max(axis=2) > 1).sum())} pixels differ from one brick (seams)"
    # the NaN-aware variant lights finite data the same way
    lit_nan = _render(ctx, paths[16], cam, tf, nan_variant=True, path=path, shading=True, **LIGHT)
    assert np.abs(lit_nan.astype(int) - r.astype(int)).max() <= 2


def test_mip_ignores_shading_and_bad_weights_are_refused(ctx, stores):
    vol, paths = stores
    tf = TransferFunction.preset("gray")
    cam = _camera()
    a = _render(ctx, paths[16], cam, tf, mode="mip", shading=True)
    b = _render(ctx, paths[16], cam, tf, mode="mip")
    assert np.array_equal(a, b)
    with pytest.raises(ParameterError, match="specular"):
        RenderParams(specular=-1)
    with pytest.raises(ParameterError, match="shininess"):
        RenderParams(shininess=0)
