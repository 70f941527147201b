"""Per-label colour and opacity (label overlays, ``OVERLAYk_LABELS``): an image with its segmentation
drawn over it, each label in its own colour, one hidden, equals the independent numpy reference
(``reference_raycast.raycast_overlays`` with a label layer: the id of the voxel holding each sample
point, its colour from a plain dict); from the CLI (``--label-overlay``, ``--label-colors``) and
from Python with a separate, coarser label store. Ids are never interpolated.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from PIL import Image
from scipy.ndimage import gaussian_filter

from clipvol.scene.label_colors import palette_color
from clipvol.tools.cli import main

pytestmark = pytest.mark.gl

SHAPE, SPACING, ORIGIN = (26, 30, 28), (1.3, 1.0, 1.1), (2.0, -3.0, 4.0)
BIG = 70000  # an id far beyond a table row: the ids present are numbered on the CPU


def _labels(shape, scale=1.0):
    z, y, x = np.mgrid[0:shape[0], 0:shape[1], 0:shape[2]].astype(float) * scale
    lab = np.zeros(shape, dtype=np.uint32)
    for lid, c, r in ((3, (8, 10, 9), 6), (7, (16, 18, 16), 7), (12, (12, 20, 8), 5), (BIG, (18, 9, 19), 5)):
        lab[(z - c[0]) ** 2 + (y - c[1]) ** 2 + (x - c[2]) ** 2 < r * r] = lid
    return lab


COLORS = {0: (0, 0, 0, 0), 3: (1.0, 0.0, 0.0, 0.6), 7: (0, 0, 0, 0), 12: (0.0, 0.2, 1.0, 0.4)}


def _rgba(ids):
    return np.array([COLORS[i] if i in COLORS else (*palette_color(i), 0.3) for i in ids.tolist()], dtype=float).reshape(-1, 4)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("labov")
    img = gaussian_filter(np.random.default_rng(4).random(SHAPE), 2.0).astype(np.float32)
    img = (img - img.min()) / (img.max() - img.min())
    np.save(d / "img.npy", img)
    np.save(d / "seg.npy", _labels(SHAPE))
    assert main(["brick", str(d / "img.npy"), str(d / "img.zarr"), "--brick", "16", "--quiet", "--no-summary",
                 "--spacing", ",".join(map(str, SPACING[::-1])), "--origin", ",".join(map(str, ORIGIN[::-1])),  # x,y,z
                 "--labels", f"{d / 'seg.npy'}:seg"]) == 0
    return d, img


def test_label_overlay_from_the_cli_equals_the_reference(store, tmp_path):
    d, img = store
    out = tmp_path / "l.png"
    assert main(["render", str(d / "img.zarr"), "--out", str(out), "--size", "64x60", "--policy", "fixed",
                 "--level", "0", "--tf", "grey", "--tf-range", "0.4,1", "--label-overlay", "seg",
                 "--label-colors", "3=#ff0000:0.6,7=hide,12=#0033ff:0.4"]) == 0
    got = np.asarray(Image.open(out)).astype(int)
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.transfer import TransferFunction
    from clipvol.scene.views import view_camera

    pyr = ZarrLoader(d / "img.zarr").pyramid
    cam = view_camera(pyr, "iso", (64, 60)).fit_depth(*pyr.volume_box())
    tf = TransferFunction.preset("grey", value_range=(0.4, 1.0))
    colors = {**COLORS, 12: (0.0, 0x33 / 255, 1.0, 0.4)}

    def rgba(ids):
        return np.array([colors[i] if i in colors else (*palette_color(i), 0.3) for i in ids.tolist()],
                        dtype=float).reshape(-1, 4)

    layers = [("labels", _labels(SHAPE), SPACING, (0.0, 0.0, 0.0), rgba)]
    r = ref.to_uint8(ref.raycast_overlays(img, SPACING, cam, tf.table, (0.4, 1.0), layers))
    shown = ref.to_uint8(ref.raycast_overlays(img, SPACING, cam, tf.table, (0.4, 1.0),
                                              [("labels", _labels(SHAPE), SPACING, (0.0, 0.0, 0.0),
                                                lambda ids: rgba(np.where(ids == 7, 12, ids)))]))
    assert np.abs(r.astype(int) - shown.astype(int)).max() > 60  # hiding 7 is visible
    assert ((r[..., 0].astype(int) - r[..., 2] > 80) & (r[..., 3] > 100)).sum() > 20  # label 3 red
    diff = np.abs(got - r.astype(int))
    # within 1 of 255 here; a sample a float32 hair from a cell face may take the neighbour's id
    assert (diff > 1).mean() < 0.005 and diff.max() <= 40, (diff.max(), (diff > 1).mean())


def test_coarser_separate_label_store_from_python(store, ctx, tmp_path):
    """A label store of its own at twice the voxel size, another origin, drawn through a session."""
    d, img = store
    from clipvol.app.session import RenderSession
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.camera import Camera
    from clipvol.scene.label_colors import LabelColors
    from clipvol.scene.overlay import Overlay
    from clipvol.scene.params import RenderParams
    from clipvol.scene.transfer import TransferFunction

    coarse = _labels((13, 15, 14), scale=2.0)
    sp2, org2 = (2.6, 2.0, 2.2), (ORIGIN[0] + 1.0, ORIGIN[1] - 0.5, ORIGIN[2] + 0.7)
    brick_volume(coarse, tmp_path / "seg2.zarr", brick=8, spacing=sp2, origin=org2, filter="mode", progress=False,
                 workers=1, summary=False)
    ov = Overlay(ZarrLoader(tmp_path / "seg2.zarr"), LabelColors({3: (1.0, 0.0, 0.0, 0.6), 7: None, 12: (0.0, 0.2, 1.0, 0.4)}))
    tf = TransferFunction.preset("grey", value_range=(0.4, 1.0))
    pyr = ZarrLoader(d / "img.zarr").pyramid
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    cam = Camera.perspective(tuple(c + np.array([-1.0, 0.8, 1.4]) * 30), tuple(c), size=(60, 56), fov_y=45)
    with RenderSession(str(d / "img.zarr"), ctx, tf=tf, params=RenderParams(policy="fixed", level=0, overlays=(ov,))) as s:
        got = s.render(cam, wait=True).astype(int)
    fc = cam.fit_depth(lo, hi)
    shift = tuple(np.subtract(org2, ORIGIN))
    r = ref.to_uint8(ref.raycast_overlays(img, SPACING, fc, tf.table, (0.4, 1.0), [("labels", coarse, sp2, shift, _rgba)]))
    plain = ref.to_uint8(ref.raycast(img, SPACING, fc, tf.table, (0.4, 1.0), 0.5))
    assert np.abs(r.astype(int) - plain.astype(int)).max() > 60
    diff = np.abs(got - r.astype(int))
    assert (diff > 1).mean() < 0.005 and diff.max() <= 40, (diff.max(), (diff > 1).mean())
