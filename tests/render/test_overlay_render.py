"""Overlays of co-registered volumes (the OVERLAY variant): a render of a primary store with one or two
overlay stores of other shapes, voxel sizes and origins (``brick_volume(origin=)``, OME
``translation``) equals an independent numpy two-volume reference (``reference_raycast.raycast_overlays``:
scipy ``map_coordinates`` at the world points of the primary's samples, the overlays' colours over
the primary's at each sample); bad overlays are refused with an error naming them.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from scipy.ndimage import gaussian_filter

from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import ParameterError
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.overlay import Overlay
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

P_SHAPE, P_SPACING, P_ORIGIN = (30, 34, 28), (1.2, 1.0, 0.9), (5.0, -3.0, 2.0)
A_SHAPE, A_SPACING, A_ORIGIN = (14, 18, 16), (2.0, 1.7, 1.5), (12.0, 4.0, 6.0)
B_SHAPE, B_SPACING, B_ORIGIN = (12, 12, 9), (1.6, 1.3, 2.2), (14.0, 6.0, 8.0)


def _smooth(shape, seed, signed=False):
    rng = np.random.default_rng(seed)
    v = gaussian_filter(rng.standard_normal(shape), 2.0)
    v = v / np.abs(v).max()
    return (v if signed else 0.5 + 0.5 * v).astype(np.float32)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    d = tmp_path_factory.mktemp("overlay")
    vols = {"p": _smooth(P_SHAPE, 1), "a": _smooth(A_SHAPE, 2, signed=True), "b": _smooth(B_SHAPE, 3)}
    geo = {"p": (P_SPACING, P_ORIGIN, 16), "a": (A_SPACING, A_ORIGIN, 8), "b": (B_SPACING, B_ORIGIN, 8)}
    paths = {}
    for k, v in vols.items():
        sp, org, b = geo[k]
        paths[k] = d / f"{k}.zarr"
        brick_volume(v, paths[k], brick=b, spacing=sp, origin=org, progress=False, workers=1, summary=False)
    return vols, paths


def _camera():
    ext = np.array(P_SHAPE[::-1]) * np.array(P_SPACING[::-1])
    c = ext / 2 - 0.5 * np.array(P_SPACING[::-1])
    n = float(ext.max())
    return Camera.perspective(tuple(c + np.array([1.1, -0.9, 1.3]) * n), tuple(c), size=(72, 64), fov_y=40)


def _render(ctx, path, cam, tf, overlays, **kw):
    clip = ClipTexture(ZarrLoader(path), "64MB", threads=2)
    try:
        with ClipRenderAction(ctx, clip, policy="fixed", level=0, overlays=tuple(overlays), **kw) as action:
            img = action.render(cam, tf, wait=True, timeout=30)
            assert action.last_frame_stats.converged
            return img
    finally:
        clip.close()


def _shift(origin):  # an overlay's origin in the primary's frame
    return tuple(np.subtract(origin, P_ORIGIN))


@pytest.mark.parametrize("merge, sampling", [(True, "interpolated"), pytest.param(False, "interpolated", marks=pytest.mark.slow),
                                             (True, "classified")],
                         ids=["merged", "bricks", "classified"])
def test_overlay_render_equals_the_numpy_two_volume_reference(ctx, stores, merge, sampling):
    vols, paths = stores
    tf = TransferFunction.preset("grey", value_range=(0.3, 1.0))
    a_tf = TransferFunction.preset("diverging", value_range=(-0.6, 0.6))  # thresholded: clear near 0
    cam = _camera()
    ov = Overlay(ZarrLoader(paths["a"]), a_tf, sampling=sampling)
    assert ov.origin == A_ORIGIN  # the store's own origin, from brick_volume(origin=)
    img = _render(ctx, paths["p"], cam, tf, [ov], merge_boxes=merge)
    plain = _render(ctx, paths["p"], cam, tf, [])
    fc = cam.fit_depth(*ZarrLoader(paths["p"]).pyramid.volume_box())
    layer = (vols["a"], A_SPACING, _shift(A_ORIGIN), a_tf.table, (-0.6, 0.6))
    if sampling == "classified":  # the map's voxels classified, then interpolated
        layer = ref.classified_overlay(*layer)
    r = ref.to_uint8(ref.raycast_overlays(vols["p"], P_SPACING, fc, tf.table, (0.3, 1.0), [layer]))
    r_plain = ref.to_uint8(ref.raycast(vols["p"], P_SPACING, fc, tf.table, (0.3, 1.0), 0.5))
    # the overlay changes the picture much (else the comparison proves nothing), with blue and red
    assert np.abs(r.astype(int) - r_plain.astype(int))[..., :3].max() > 80
    assert ((r[..., 2].astype(int) - r[..., 0] > 60) & (r[..., 3] > 100)).sum() > 20  # negative: blue
    assert ((r[..., 0].astype(int) - r[..., 2] > 60) & (r[..., 3] > 100)).sum() > 20  # positive: red
    assert np.abs(plain.astype(int) - r_plain.astype(int)).max() <= 1
    diff = np.abs(img.astype(int) - r.astype(int))
    assert diff.max() <= 3, (diff.max(), (diff > 1).mean())
    assert (diff > 1).mean() < 0.01


def test_two_overlays_first_on_top(ctx, stores):
    vols, paths = stores
    tf = TransferFunction.preset("grey", value_range=(0.3, 1.0))
    a_tf = TransferFunction.preset("diverging", value_range=(-0.6, 0.6))
    b_tf = TransferFunction.preset("viridis", value_range=(0.4, 0.7), opacity="flat")
    cam = _camera()
    ovs = [Overlay(ZarrLoader(paths["a"]), a_tf, sampling="interpolated"),
           Overlay(ZarrLoader(paths["b"]), b_tf, sampling="interpolated")]
    img = _render(ctx, paths["p"], cam, tf, ovs)
    fc = cam.fit_depth(*ZarrLoader(paths["p"]).pyramid.volume_box())
    layers = [(vols["a"], A_SPACING, _shift(A_ORIGIN), a_tf.table, (-0.6, 0.6)),
              (vols["b"], B_SPACING, _shift(B_ORIGIN), b_tf.table, (0.4, 0.7))]
    r = ref.to_uint8(ref.raycast_overlays(vols["p"], P_SPACING, fc, tf.table, (0.3, 1.0), layers))
    swapped = ref.to_uint8(ref.raycast_overlays(vols["p"], P_SPACING, fc, tf.table, (0.3, 1.0), layers[::-1]))
    assert np.abs(r.astype(int) - swapped.astype(int)).max() > 10  # the order is visible
    diff = np.abs(img.astype(int) - r.astype(int))
    assert diff.max() <= 3 and (diff > 1).mean() < 0.01, (diff.max(), (diff > 1).mean())


def test_bad_overlays_are_refused_naming_them(ctx, stores, tmp_path):
    vols, paths = stores
    clip = ClipTexture(ZarrLoader(paths["p"]), "16MB", threads=1)
    try:
        far = Overlay(ZarrLoader(paths["a"]), "diverging", origin=(500.0, 0.0, 0.0), name="far-map")
        with pytest.raises(ParameterError, match="far-map.*overlap"):
            ClipRenderAction(ctx, clip, overlays=(far,))
        mm = tmp_path / "mm.zarr"
        brick_volume(vols["a"], mm, brick=8, spacing=A_SPACING, unit="millimeter", progress=False, workers=1, summary=False)
        with pytest.raises(ParameterError, match="mm.zarr.*unit.*millimeter"):
            ClipRenderAction(ctx, clip, overlays=(Overlay(ZarrLoader(mm)),))
    finally:
        clip.close()
    with pytest.raises(ParameterError, match="a.zarr.*transfer function.*'nope'"):
        Overlay(ZarrLoader(paths["a"]), "nope")
    with pytest.raises(ParameterError, match="a.zarr.*sampling.*classified, interpolated.*'cubic'"):
        Overlay(ZarrLoader(paths["a"]), sampling="cubic")
    ov = Overlay(ZarrLoader(paths["a"]))
    with pytest.raises(ParameterError, match="mode 'composite'"):
        RenderParams(mode="mip", overlays=(ov,))
    with pytest.raises(ParameterError, match="single-pass"):
        RenderParams(path="single-pass", overlays=(ov,))


def test_transparent_primary_bricks_carry_the_overlay_and_are_culled_elsewhere(ctx, tmp_path):
    """The primary is air (transparent) but for one corner: bricks in the overlay's box are drawn
    (the map shows as in the reference), bricks clear of it are still culled."""
    prim = np.zeros((48, 48, 48), dtype=np.float32)
    prim[2:12, 2:12, 2:12] = 0.8
    brick_volume(prim, tmp_path / "air.zarr", brick=16, progress=False, workers=1, summary=False)
    zmap = _smooth((12, 12, 12), 6, signed=True)
    brick_volume(zmap, tmp_path / "m.zarr", brick=8, spacing=(1.5, 1.5, 1.5), origin=(26.0, 26.0, 26.0),
                 progress=False, workers=1, summary=False)
    tf = TransferFunction.preset("grey", value_range=(0.3, 1.0))
    m_tf = TransferFunction.preset("diverging", value_range=(-0.6, 0.6))
    lo, hi = ZarrLoader(tmp_path / "air.zarr").pyramid.volume_box()
    c = (lo + hi) / 2
    cam = Camera.perspective(tuple(c + np.array([1.0, 0.7, -1.2]) * 60), tuple(c), size=(64, 64), fov_y=40)
    clip = ClipTexture(ZarrLoader(tmp_path / "air.zarr"), "64MB", threads=2)
    try:
        with ClipRenderAction(ctx, clip, policy="fixed", level=0,
                              overlays=(Overlay(ZarrLoader(tmp_path / "m.zarr"), m_tf,
                                                sampling="interpolated"),)) as action:
            img = action.render(cam, tf, wait=True, timeout=30)
            drawn = {tuple(it.index) for it in action.last_selection.items}
    finally:
        clip.close()
    assert {(1, 1, 1), (2, 2, 2), (1, 2, 1)} <= drawn  # air bricks in the map's box (25..44) are drawn
    assert (0, 0, 0) in drawn and not drawn & {(0, 2, 2), (2, 0, 0), (0, 0, 2)}  # air clear of it is culled
    r = ref.to_uint8(ref.raycast_overlays(prim, (1, 1, 1), cam.fit_depth(lo, hi), tf.table, (0.3, 1.0),
                                          [(zmap, (1.5, 1.5, 1.5), (26.0, 26.0, 26.0), m_tf.table, (-0.6, 0.6))]))
    assert (r[..., 3] > 100).sum() > 50
    diff = np.abs(img.astype(int) - r.astype(int))
    assert diff.max() <= 3 and (diff > 1).mean() < 0.01, (diff.max(), (diff > 1).mean())
