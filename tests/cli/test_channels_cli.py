"""``clipvol render STORE --channels 0:green,1:magenta,2:#ffaa00 --blend additive|over``: every channel
its own colour and window in one ray cast, equal to the independent numpy reference
(``reference_raycast.raycast_overlays`` with ``blend``); channels the image lacks exit 2 naming them."""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
import zarr
from PIL import Image
from scipy.ndimage import gaussian_filter

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl

SHAPE = (20, 24, 22)
WINDOWS = [(0.2, 1.0), (0.3, 1.0), (0.25, 0.9)]


@pytest.fixture(scope="module")
def image(tmp_path_factory):
    d = tmp_path_factory.mktemp("chan")
    rng = np.random.default_rng(8)
    data = np.stack([gaussian_filter(rng.random(SHAPE), 2.0) for _ in range(3)]).astype(np.float32)
    data = (data - data.min(axis=(1, 2, 3), keepdims=True)) / np.ptp(data, axis=(1, 2, 3), keepdims=True)
    g = zarr.open_group(str(d / "cells.zarr"), mode="w")
    g.create_array("0", shape=data.shape, chunks=(1, 16, 16, 16), dtype="float32")[...] = data
    axes = [{"name": "c", "type": "channel"}] + [{"name": a, "type": "space", "unit": "micrometer"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1.2, 1.0, 0.9]}]}]}],
        "omero": {"channels": [{"window": {"min": lo, "max": hi}} for lo, hi in WINDOWS]}}})
    return d / "cells.zarr", data


@pytest.mark.parametrize("blend", ["additive", "over"])
def test_channels_equal_the_reference(image, tmp_path, blend):
    path, data = image
    out = tmp_path / f"{blend}.png"
    spec = "0:green,1:magenta,2:#ffaa00"
    assert main(["render", str(path), "--out", str(out), "--size", "60x56", "--policy", "fixed", "--level", "0",
                 "--channels", spec, "--blend", blend]) == 0
    got = np.asarray(Image.open(out)).astype(int)
    from clipvol.app.channels import channel_tf
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.views import view_camera

    pyr = ZarrLoader(path, c=0).pyramid
    cam = view_camera(pyr, "iso", (60, 56)).fit_depth(*pyr.volume_box())
    sp = (1.2, 1.0, 0.9)
    tfs = [channel_tf(col, w) for col, w in zip(("green", "magenta", "#ffaa00"), WINDOWS)]
    layers = [(data[c], sp, (0.0, 0.0, 0.0), tfs[c].table, WINDOWS[c]) for c in (1, 2)]
    r = ref.to_uint8(ref.raycast_overlays(data[0], sp, cam, tfs[0].table, WINDOWS[0], layers, blend=blend))
    alone = ref.to_uint8(ref.raycast(data[0], sp, cam, tfs[0].table, WINDOWS[0], 0.5))
    assert np.abs(r.astype(int) - alone.astype(int))[..., :3].max() > 80  # the other channels show
    diff = np.abs(got - r.astype(int))
    assert diff.max() <= 3 and (diff > 1).mean() < 0.01, (diff.max(), (diff > 1).mean())


def test_additive_and_over_differ(image, tmp_path):
    path, _ = image
    imgs = []
    for blend in ("additive", "over"):
        out = tmp_path / f"{blend}.png"
        assert main(["render", str(path), "--out", str(out), "--size", "40x40", "--channels", "0:green,1:magenta",
                     "--blend", blend]) == 0
        imgs.append(np.asarray(Image.open(out)).astype(int))
    assert np.abs(imgs[0] - imgs[1]).max() > 20


def test_channels_the_image_lacks_are_refused(image, tmp_path, capsys):
    path, _ = image
    base = ["render", "--out", str(tmp_path / "x.png"), "--size", "32x32"]
    capsys.readouterr()
    assert main(base[:1] + [str(path)] + base[1:] + ["--channels", "0:green,5:magenta"]) == 2
    err = capsys.readouterr().err
    assert "c" in err and "0..2" in err and "5" in err
    assert main(base[:1] + ["procedural:fractal?size=32"] + base[1:] + ["--channels", "0:green,1:red"]) == 2
    assert "c axis" in capsys.readouterr().err
    assert main(base[:1] + [str(path)] + base[1:] + ["--channels", "0:green,1:chartreuse"]) == 2
    assert "chartreuse" in capsys.readouterr().err
    assert main(base[:1] + [str(path)] + base[1:] + ["--channels", "0:green,1:red", "--shading", "--blend", "additive"]) == 2
    assert "additive" in capsys.readouterr().err


def test_brick_a_4d_input_and_render_its_channels(image, tmp_path, capsys):
    """``clipvol brick cells.npy`` of shape (c, z, y, x): one store per channel; open_store(c=k) reads
    channel k's bytes; --channels renders the set exactly as the OME-Zarr image of the same data."""
    path, data = image
    np.save(tmp_path / "cells.npy", data)
    assert main(["brick", str(tmp_path / "cells.npy"), str(tmp_path / "set.zarr"), "--brick", "16",
                 "--spacing", "0.9,1.0,1.2", "--no-summary"]) == 0
    assert "3 channels" in capsys.readouterr().out
    from clipvol.paging.open import open_store

    for c in range(3):
        ld = open_store(tmp_path / "set.zarr", c=c)
        assert ld.axes == ("c",) and ld.lead_shape == (3,)
        np.testing.assert_array_equal(ld.read_brick(0, (0, 0, 0))[:16, :16, :16], data[c, :16, :16, :16])
    with pytest.raises(Exception, match=r"c: expected 0\.\.2"):
        open_store(tmp_path / "set.zarr", c=3)
    common = ["--size", "40x40", "--policy", "fixed", "--level", "0", "--channels", "0:green,1:magenta,2:cyan",
              "--tf-range", "0.2,1"]
    assert main(["render", str(tmp_path / "set.zarr"), "--out", str(tmp_path / "a.png")] + common) == 0
    assert main(["render", str(path), "--out", str(tmp_path / "b.png")] + common) == 0
    a = np.asarray(Image.open(tmp_path / "a.png")).astype(int)
    b = np.asarray(Image.open(tmp_path / "b.png")).astype(int)
    assert a[..., 3].max() > 100 and np.abs(a - b).max() <= 1


def test_view_offscreen_draws_the_channels_like_the_reference(image, tmp_path):
    """``clipvol view --channels`` (offscreen) draws the first orbit frame as the numpy reference of the
    same camera; with --play, or with --c, it is refused (exit 2)."""
    path, data = image
    out = tmp_path / "frames"
    assert main(["view", str(path), "--offscreen", "--frames", "1", "--size", "60x56", "--out", str(out),
                 "--converged", "--no-jitter", "--policy", "fixed", "--level", "0",
                 "--channels", "0:green,1:magenta", "--blend", "additive"]) == 0
    got = np.asarray(Image.open(sorted(out.glob("frame_*.png"))[0]).convert("RGBA")).astype(int)
    from clipvol.app.channels import channel_tf
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.paths import orbit

    pyr = ZarrLoader(path, c=0).pyramid
    cam, _ = next(iter(orbit(pyr, 1, size=(60, 56))))
    sp = (1.2, 1.0, 0.9)
    tfs = [channel_tf(col, w) for col, w in zip(("green", "magenta"), WINDOWS)]
    r = ref.to_uint8(ref.raycast_overlays(data[0], sp, cam, tfs[0].table, WINDOWS[0],
                                          [(data[1], sp, (0.0, 0.0, 0.0), tfs[1].table, WINDOWS[1])], blend="additive"))
    diff = np.abs(got - r.astype(int))
    assert r[..., 0].max() > 60 and r[..., 1].max() > 60  # both colours show in the reference
    assert diff.max() <= 3 and (diff > 1).mean() < 0.01, (diff.max(), (diff > 1).mean())
    assert main(["view", str(path), "--offscreen", "--frames", "1", "--out", str(tmp_path / "x"),
                 "--channels", "0:green", "--c", "1"]) == 2
