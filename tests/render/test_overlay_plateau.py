"""A statistical map of the clinical kind over a transparent primary: 70 % zeros (masked outside the
"brain"), blobs that are plateaus clipped at +-7.94 with voxel-jagged edges, 3 mm voxels under a 1 mm
primary. Sampled ``interpolated`` (the value, then the table), thin pale lines in a circuit-board
pattern run through the saturated blobs seen from above: a ray that grazes a vertical step of a
jagged plateau stays for many samples in the one-voxel ramp between the plateau and the zeros, whose
values the diverging table colours pale. The independent numpy caster
``reference_raycast.raycast_overlays`` (scipy ``map_coordinates`` of the map, the same table) draws
the same lines: that mode is faithful to "interpolate, then classify".

Sampled ``classified`` (the default: the 8 voxels classified, then their premultiplied colours
interpolated) the blob keeps the plateau's saturation. Reference: the map's voxels classified by the
table in numpy, each premultiplied RGBA channel interpolated by scipy's ``map_coordinates``
(``reference_raycast.classified_overlay``).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.overlay import Overlay
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

P_SHAPE, P_SPACING = (40, 48, 48), (1.0, 1.0, 1.0)
M_SHAPE, M_SPACING = (14, 16, 16), (3.0, 3.0, 3.0)
CLIP = 7.94


def _map() -> np.ndarray:
    """Zeros outside a noisy ball, the clipped plateau inside it, a one-voxel rim of lower values."""
    rng = np.random.default_rng(3)
    z, y, x = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in M_SHAPE), indexing="ij")
    r = np.sqrt((x - 7.5) ** 2 + (y - 7.5) ** 2 + ((z - 6.5) * 1.1) ** 2) + rng.uniform(-1.2, 1.2, M_SHAPE)
    return np.where(r < 5.5, CLIP, np.where(r < 6.5, rng.uniform(2.5, CLIP, M_SHAPE), 0.0)).astype(np.float32)


def _two_valued(m: np.ndarray) -> np.ndarray:
    """The map with its rim zeroed: only the clipped plateau and zeros, jagged voxel edges between them."""
    return np.where(m == CLIP, CLIP, 0.0).astype(np.float32)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    d = tmp_path_factory.mktemp("plateau")
    prim, m = np.full(P_SHAPE, 0.5, np.float32), _map()
    assert 0.6 < float((m == 0).mean()) < 0.8 and float((m == CLIP).mean()) > 0.1  # the kind of map
    brick_volume(prim, d / "p.zarr", brick=16, spacing=P_SPACING, progress=False, workers=1, summary=False)
    brick_volume(m, d / "m.zarr", brick=8, spacing=M_SPACING, progress=False, workers=1, summary=False)
    brick_volume(_two_valued(m), d / "m2.zarr", brick=8, spacing=M_SPACING, progress=False, workers=1, summary=False)
    return prim, m, d


def _cameras():
    ext = np.array(P_SHAPE[::-1]) * np.array(P_SPACING[::-1])
    c = ext / 2 - 0.5
    return {"straight": Camera.orthographic(tuple(c), (0, 0, -1), (0, 1, 0), ext[0], ext[1], size=(64, 64)),
            "tilted": Camera.perspective(tuple(c + np.array([8.0, 6.0, 110.0])), tuple(c), up=(0, 1, 0), fov_y=30,
                                         size=(64, 64))}


def _saturation(img: np.ndarray) -> np.ndarray:
    """HSV saturation (max - min) / max of each pixel's colour."""
    rgb = img[..., :3].astype(float)
    mx = rgb.max(axis=-1)
    return (mx - rgb.min(axis=-1)) / np.maximum(mx, 1.0)


def _pale_lines(img: np.ndarray) -> int:
    """Pixels of the opaque blob paler (green, the diverging table's white part) than both their
    neighbours across a row or a column by more than 10 of 255: thin light lines."""
    g = img[..., 1].astype(int)
    opaque = img[..., 3] > 250
    across = (g[:, 1:-1] - g[:, :-2] > 10) & (g[:, 1:-1] - g[:, 2:] > 10) & opaque[:, 1:-1]
    down = (g[1:-1] - g[:-2] > 10) & (g[1:-1] - g[2:] > 10) & opaque[1:-1]
    return int(across.sum() + down.sum())


def _render(ctx, d, cam, tf, mtf, sampling, store="m.zarr"):
    clip = ClipTexture(ZarrLoader(d / "p.zarr"), "64MB", threads=2)
    try:
        ov = Overlay(ZarrLoader(d / store), mtf, sampling=sampling)
        with ClipRenderAction(ctx, clip, policy="fixed", level=0, overlays=(ov,)) as a:
            return a.render(cam, tf, wait=True, timeout=60)
    finally:
        clip.close()


TF = TransferFunction.preset("grey", value_range=(10.0, 20.0))  # the primary transparent
MTF = TransferFunction.preset("diverging", value_range=(-CLIP, CLIP))  # the window ends at the clip value


@pytest.mark.parametrize("view", ["straight", "tilted"])
def test_interpolated_overlay_draws_the_fields_own_pale_lines(ctx, stores, view):
    prim, m, d = stores
    cam = _cameras()[view].fit_depth(*ZarrLoader(d / "p.zarr").pyramid.volume_box())
    img = _render(ctx, d, cam, TF, MTF, "interpolated")
    r = ref.to_uint8(ref.raycast_overlays(prim, P_SPACING, cam, TF.table, (10.0, 20.0),
                                          [(m, M_SPACING, (0.0, 0.0, 0.0), MTF.table, (-CLIP, CLIP))]))
    assert (r[..., 3] > 250).sum() > 400  # the blob covers much of the image
    assert _pale_lines(r) > 10  # the numpy reference has the lines ...
    diff = np.abs(img.astype(int) - r.astype(int))
    assert diff.max() <= 3 and (diff > 1).mean() < 0.01, (diff.max(), (diff > 1).mean())  # ... and GL draws them as it


@pytest.mark.parametrize("view", ["straight", "tilted"])
def test_classified_overlay_equals_classify_then_interpolate(ctx, stores, view):
    prim, m, d = stores
    cam = _cameras()[view].fit_depth(*ZarrLoader(d / "p.zarr").pyramid.volume_box())
    img = _render(ctx, d, cam, TF, MTF, "classified")
    r = ref.to_uint8(ref.raycast_overlays(prim, P_SPACING, cam, TF.table, (10.0, 20.0),
                                          [ref.classified_overlay(m, M_SPACING, (0.0, 0.0, 0.0), MTF.table,
                                                                  (-CLIP, CLIP))]))
    assert (r[..., 3] > 250).sum() > 400
    diff = np.abs(img.astype(int) - r.astype(int))
    assert diff.max() <= 3 and (diff > 1).mean() < 0.01, (diff.max(), (diff > 1).mean())


@pytest.mark.parametrize("view", ["straight", "tilted"])
def test_classified_overlay_draws_no_pale_lines_in_a_plateau(ctx, stores, view):
    """Plateau and zeros only: every voxel the table shows has the plateau's colour, so every pixel
    it colours must have that colour's saturation (interpolated, the ramp between them is pale)."""
    prim, m, d = stores
    cam = _cameras()[view].fit_depth(*ZarrLoader(d / "p.zarr").pyramid.volume_box())
    img = _render(ctx, d, cam, TF, MTF, "classified", store="m2.zarr")
    plateau = ref.tf_lookup(MTF.table, np.array([1.0]))[0, :3] * 255.0
    assert float(ref.tf_lookup(MTF.table, np.array([0.5]))[0, 3]) == 0.0  # the zeros are transparent
    seen = img[..., 3] > 25
    assert seen.sum() > 400 and (img[..., 3] > 250).sum() > 400  # the blob covers much of the image
    sat = _saturation(img)[seen]
    want = (plateau.max() - plateau.min()) / plateau.max()
    assert sat.min() >= want - 0.03, (sat.min(), want, int((sat < want - 0.03).sum()))
    assert _pale_lines(img) == 0
