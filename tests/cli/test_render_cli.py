"""``clipvol render``: writes the PNG the action renders, prints frame statistics, refuses bad input."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl


def test_render_writes_png_matching_the_action(tmp_path, capsys):
    out = tmp_path / "img.png"
    rc = main(["render", "procedural:fractal?size=40", "--brick", "16", "--out", str(out), "--size", "64x48",
               "--view", "front", "--ortho", "--mode", "mip", "--policy", "fixed", "--tf-points", "0:0,0,0,0;1:1,1,1,1"])
    assert rc == 0
    img = np.asarray(Image.open(out))
    assert img.shape == (48, 64, 4)
    err = capsys.readouterr().err
    assert "bricks drawn" in err and "converged True" in err
    # independent check: the front orthographic MIP of the procedural volume through the grey TF
    from clipvol.bricking.generators import parse_procedural

    vol = parse_procedural("procedural:fractal?size=40").region(0, (0, 0, 0), (40, 40, 40))
    mip = vol.max(axis=0)
    lo, hi = 0.0, 1.0  # the procedural generators' declared value range
    t = np.clip((mip - lo) / (hi - lo), 0, 1)
    # the 40x40 volume fills the central columns of the 64x48 image (framing is 1.05 x diagonal)
    drawn = img[..., 3] > 0
    assert drawn.any() and not drawn.all()
    # grey points from 0 to 1: alpha == t of the ray's maximum; pixel centres fall between voxel centres, so the
    # image's alphas lie within the MIP's range and come close to its maximum
    a = img[..., 3][drawn].astype(float)
    assert a.max() <= t.max() * 255 + 1 and a.min() >= t.min() * 255 - 1
    assert a.max() >= 0.95 * t.max() * 255


def test_render_refuses_bad_arguments(tmp_path, capsys):
    assert main(["render", "procedural:fractal?size=16", "--out", str(tmp_path / "x.jpg")]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["render", "procedural:fractal?size=16", "--out", str(tmp_path / "x.png"), "--tf", "nope"]) == 2
    assert "--tf" in capsys.readouterr().err
    assert main(["render", str(tmp_path / "missing.zarr"), "--out", str(tmp_path / "x.png")]) == 2


def test_render_a_time_point_and_hide_labels(tmp_path):
    """--t picks a time point of a (t, z, y, x) OME-Zarr; --hide-labels removes a label's voxels.
    References: the same render of a store holding only that time point / of the image with the
    hidden voxels set to NaN by numpy."""
    import zarr

    from clipvol.bricking.labels import brick_labels
    from clipvol.bricking.pipeline import brick_volume

    rng = np.random.default_rng(3)
    data = rng.random((2, 16, 16, 16), dtype=np.float32)
    data[1] *= 0.25
    g = zarr.open_group(str(tmp_path / "ts.zarr"), mode="w")
    g.create_array("0", shape=data.shape, chunks=(1, 8, 8, 8), dtype="float32")[...] = data
    axes = [{"name": "t", "type": "time"}] + [{"name": a, "type": "space"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1, 1]}]}]}],
        "omero": {"channels": [{"window": {"min": 0.0, "max": 1.0}}]}}})
    common = ["--size", "32x32", "--view", "front", "--ortho", "--mode", "mip", "--policy", "fixed", "--tf", "grey"]
    assert main(["render", str(tmp_path / "ts.zarr"), "--t", "1", "--out", str(tmp_path / "t1.png")] + common) == 0
    np.save(tmp_path / "t1.npy", data[1])
    assert main(["render", str(tmp_path / "t1.npy"), "--brick", "8", "--out", str(tmp_path / "ref.png"),
                 "--tf-range", "0,1"] + common) == 0
    a, b = np.asarray(Image.open(tmp_path / "t1.png")), np.asarray(Image.open(tmp_path / "ref.png"))
    assert np.abs(a.astype(int) - b).max() <= 1
    assert main(["render", str(tmp_path / "ts.zarr"), "--t", "2", "--out", str(tmp_path / "x.png")] + common) == 2

    img = data[0]
    lab = np.zeros(img.shape, np.uint8)
    lab[:, :, 8:] = 4
    np.save(tmp_path / "img.npy", img)
    np.save(tmp_path / "lab.npy", lab)
    brick_volume(tmp_path / "img.npy", tmp_path / "img.zarr", brick=8, progress=False)
    brick_labels(tmp_path / "img.zarr", tmp_path / "lab.npy", "seg", progress=False)
    assert main(["render", str(tmp_path / "img.zarr"), "--hide-labels", "seg:4", "--out", str(tmp_path / "h.png")]
                + common) == 0
    hidden = np.asarray(Image.open(tmp_path / "h.png"))
    shown = np.asarray(Image.open(tmp_path / "t1.png"))  # (a render of the whole cube, for its footprint)
    cols = np.nonzero(shown[..., 3].max(axis=0))[0]
    left, right = cols[: len(cols) // 2 - 1], cols[len(cols) // 2 + 1:]
    # the half with label 4 is gone (transparent), the other half is drawn
    assert hidden[:, right, 3].max() == 0 and hidden[:, left, 3].max(axis=0).min() > 0
    assert main(["render", str(tmp_path / "img.zarr"), "--hide-labels", "nope:1", "--out", str(tmp_path / "n.png")]
                + common) == 2


def test_render_shading_changes_colour_not_opacity(tmp_path, capsys):
    """--shading lights the colours (Blinn-Phong) and leaves every pixel's opacity as it was;
    --light with the wrong count of numbers is refused naming it."""
    base = ["render", "procedural:fractal?size=32", "--brick", "16", "--size", "48x48", "--policy", "fixed",
            "--tf", "bone"]
    assert main(base + ["--out", str(tmp_path / "u.png")]) == 0
    assert main(base + ["--out", str(tmp_path / "l.png"), "--shading", "--light", "0.1,0.9,0.5,10"]) == 0
    u = np.asarray(Image.open(tmp_path / "u.png")).astype(int)
    lit = np.asarray(Image.open(tmp_path / "l.png")).astype(int)
    assert np.abs(u[..., 3] - lit[..., 3]).max() <= 1
    assert np.abs(u[..., :3] - lit[..., :3])[u[..., 3] > 50].mean() > 5
    capsys.readouterr()
    assert main(base + ["--out", str(tmp_path / "x.png"), "--shading", "--light", "1,2"]) == 2
    assert "--light" in capsys.readouterr().err


@pytest.mark.slow
def test_render_max_error_uses_the_image_policy_and_prints_the_prediction(tmp_path, capsys):
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume

    store = tmp_path / "head.zarr"
    brick_volume(ct_head((48, 48, 48), seed=2), store, brick=8, progress=False)
    base = ["render", str(store), "--size", "64x64", "--tf", "bone", "--out", str(tmp_path / "h.png")]
    assert main(base + ["--max-error", "5%"]) == 0
    err = capsys.readouterr().err
    assert "image policy" in err and "error budget 5 %" in err
    pct = float(err.split("image policy")[1].split("estimated ")[1].split(" %")[0])
    assert 0.0 <= pct <= 5.0, err
    assert "not estimated" not in err  # every pixel cast: the estimate is the frame's
    assert main(base + ["--max-error", "5%", "--refine-tolerance", "0.1"]) == 0
    assert "adaptive image sampling adds an error of its own, not estimated" in capsys.readouterr().err
    assert main(base + ["--max-error", "five"]) == 2
    assert "max_error" in capsys.readouterr().err
    assert main(base + ["--max-error", "5%", "--policy", "distance"]) == 2
    assert "policy 'image'" in capsys.readouterr().err
