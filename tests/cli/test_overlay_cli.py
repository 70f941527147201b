"""``clipvol brick --origin`` and ``clipvol render A --overlay B[:tf]``: the PNG equals the independent numpy
two-volume reference (``reference_raycast.raycast_overlays``); the same frame from Python
(``RenderSession(overlays=...)``); bad overlays exit 2 naming them.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import reference_raycast as ref
from PIL import Image
from scipy.ndimage import gaussian_filter

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl

P_SHAPE, P_SPACING, P_ORIGIN = (24, 28, 26), (1.0, 1.2, 1.1), (-4.0, 2.0, 3.0)
Z_SHAPE, Z_SPACING, Z_ORIGIN = (12, 10, 14), (2.0, 2.5, 1.6), (4.0, 8.0, 7.0)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    d = tmp_path_factory.mktemp("ovcli")
    rng = np.random.default_rng(5)
    t1 = gaussian_filter(rng.random(P_SHAPE), 2.0).astype(np.float32)
    t1 = (t1 - t1.min()) / (t1.max() - t1.min())
    zmap = gaussian_filter(rng.standard_normal(Z_SHAPE), 1.5)
    zmap = (6.0 * zmap / np.abs(zmap).max()).astype(np.float32)
    np.save(d / "t1.npy", t1)
    np.save(d / "zmap.npy", zmap)
    for name, sp, org in (("t1", P_SPACING, P_ORIGIN), ("zmap", Z_SPACING, Z_ORIGIN)):
        assert main(["brick", str(d / f"{name}.npy"), str(d / f"{name}.zarr"), "--brick", "8", "--quiet", "--no-summary",
                     "--spacing", ",".join(map(str, sp[::-1])), "--origin=" + ",".join(map(str, org[::-1]))]) == 0  # x,y,z
    return d, t1, zmap


def test_brick_origin_is_the_ome_translation(stores):
    d, _, _ = stores
    attrs = json.loads((d / "zmap.zarr" / "zarr.json").read_text())["attributes"]
    tr = attrs["ome"]["multiscales"][0]["datasets"][0]["coordinateTransformations"][1]["translation"]
    assert tr == pytest.approx(list(Z_ORIGIN))


@pytest.mark.parametrize("sampling", [None, "interpolated"])
def test_render_overlay_equals_the_reference_and_python(stores, tmp_path, ctx, sampling):
    """The default (classified: the map's voxels classified, then interpolated) and
    ``--overlay-sampling interpolated`` (the value interpolated, then classified)."""
    d, t1, zmap = stores
    out = tmp_path / "o.png"
    args = ["render", str(d / "t1.zarr"), "--out", str(out), "--size", "64x56", "--policy", "fixed", "--level", "0",
            "--tf", "grey", "--tf-range", "0.35,1", "--overlay", f"{d / 'zmap.zarr'}:diverging@-5,5"]
    args += ["--overlay-sampling", sampling] if sampling else []
    assert main(args) == 0
    img = np.asarray(Image.open(out)).astype(int)
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.transfer import TransferFunction
    from clipvol.scene.views import view_camera

    pyr = ZarrLoader(d / "t1.zarr").pyramid
    cam = view_camera(pyr, "iso", (64, 56)).fit_depth(*pyr.volume_box())
    tf = TransferFunction.preset("grey", value_range=(0.35, 1.0))
    ztf = TransferFunction.preset("diverging", value_range=(-5.0, 5.0))
    shift = tuple(np.subtract(Z_ORIGIN, P_ORIGIN))
    layer = (zmap, Z_SPACING, shift, ztf.table, (-5.0, 5.0))
    r = ref.to_uint8(ref.raycast_overlays(t1, P_SPACING, cam, tf.table, (0.35, 1.0),
                                          [layer if sampling == "interpolated" else ref.classified_overlay(*layer)]))
    other = ref.to_uint8(ref.raycast_overlays(t1, P_SPACING, cam, tf.table, (0.35, 1.0),
                                              [ref.classified_overlay(*layer) if sampling == "interpolated" else layer]))
    assert np.abs(r.astype(int) - other.astype(int)).max() > 10  # the two samplings differ visibly here
    plain = ref.to_uint8(ref.raycast(t1, P_SPACING, cam, tf.table, (0.35, 1.0), 0.5))
    assert np.abs(r.astype(int) - plain.astype(int))[..., :3].max() > 80  # the map shows
    diff = np.abs(img - r.astype(int))
    # classified (8 table lookups a sample in float32 against float64): one pixel of the 3584 here is 4/255 off
    assert diff.max() <= 4 and (diff > 3).sum() <= 8 and (diff > 1).mean() < 0.01, (diff.max(), (diff > 1).mean())
    # the same frame from Python: a session with the overlay
    from clipvol.app.session import RenderSession
    from clipvol.scene.overlay import Overlay
    from clipvol.scene.params import RenderParams

    with RenderSession(str(d / "t1.zarr"), ctx, params=RenderParams(policy="fixed", level=0), tf=tf,
                       overlays=[(str(d / "zmap.zarr"), ztf) if sampling is None else
                                 Overlay(ZarrLoader(d / "zmap.zarr"), ztf, sampling=sampling)]) as s:
        py = s.render(view_camera(pyr, "iso", (64, 56)), wait=True, timeout=30)
    assert np.abs(py.astype(int) - img).max() <= 1


def test_render_refuses_bad_overlays(stores, tmp_path, capsys):
    d, _, zmap = stores
    base = ["render", str(d / "t1.zarr"), "--out", str(tmp_path / "x.png"), "--size", "32x32"]
    capsys.readouterr()
    assert main(base + ["--overlay", f"{d / 'zmap.zarr'}:rainbow@-1,1"]) == 2
    assert "rainbow" in capsys.readouterr().err
    far = tmp_path / "far.zarr"
    assert main(["brick", str(d / "zmap.npy"), str(far), "--brick", "8", "--quiet", "--no-summary",
                 "--origin", "0,0,900"]) == 0
    assert main(base + ["--overlay", str(far)]) == 2
    err = capsys.readouterr().err
    assert "far.zarr" in err and "overlap" in err
    mm = tmp_path / "mm.zarr"
    assert main(["brick", str(d / "zmap.npy"), str(mm), "--brick", "8", "--quiet", "--no-summary", "--unit", "millimeter"]) == 0
    assert main(base + ["--overlay", str(mm)]) == 2
    err = capsys.readouterr().err
    assert "mm.zarr" in err and "millimeter" in err
    assert main(base + ["--overlay", str(d / "zmap.zarr"), "--mode", "mip"]) == 2
    assert "composite" in capsys.readouterr().err
