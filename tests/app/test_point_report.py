"""``clipvol report POINTS.zarr``: frame time and image error against tolerance, checked against an
independent every-point reference.

Points on a 16^3 lattice (spacing 1, aligned with the octree's cells, at most 8 points per node,
so every leaf splat is exactly one spacing wide) carry a smooth field. The report's frames at each
tolerance are compared here with ``tests/reference_splats.py``, a numpy splatter that draws every
input point (not read from the store, not through the selection): the finest tolerance draws
the leaves and must match it closely, and the error must not fall as the tolerance grows (it
falls as the tolerance shrinks) - the data of the report's error-against-tolerance plot.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest
from PIL import Image

from reference_splats import splat_every_point

from clipvol.scene.metrics import percent_delta_e

N = 16
TOLS = ["1px", "5px", "10px", "20px", "60px"]


@pytest.fixture(scope="module")
def lattice(tmp_path_factory):
    from clipvol.bricking.point_sources import ArrayPointSource
    from clipvol.bricking.point_store import build_point_store

    z, y, x = np.meshgrid(*(np.arange(N),) * 3, indexing="ij")
    vals = (0.5 + 0.5 * np.sin(x / 2.5) * np.cos(y / 3.0) * np.cos(z / 2.0)).astype(np.float32).ravel()
    xyz = np.stack([x.ravel(), y.ravel(), z.ravel()], 1) + 0.5
    path = tmp_path_factory.mktemp("prep") / "lat.zarr"
    build_point_store(ArrayPointSource(xyz, vals), path, max_points=8, progress=False, box=((0, 0, 0), (N, N, N)))
    return path, xyz, vals


def _tf():
    from clipvol.scene.transfer import TransferFunction

    tf = TransferFunction.preset("viridis", value_range=(0.0, 1.0))
    tab = tf.table.copy()
    tab[:, 3] *= 0.3
    return TransferFunction(tab, (0.0, 1.0))


def test_error_falls_as_tolerance_shrinks_against_every_point(gl, lattice, tmp_path):
    from clipvol.app.point_report import orbit_cameras, run_point_report

    path, xyz, vals = lattice
    tf = _tf()
    res = run_point_report(path, tmp_path / "rep", tolerances=TOLS[::-1], size=(96, 96), views=1, tf=tf,
                           memory_budget="64MB", threads=2, repeats=1)
    cam = orbit_cameras((0, 0, 0), (N, N, N), 1, (96, 96))[0]
    ref = splat_every_point(xyz, vals, 1.0, cam, tf.table, (0.0, 1.0), unit=1.0)
    assert (ref[..., 3] > 0).mean() > 0.2  # the reference shows the cube
    # the report's own every-point frame is the independent one
    own_ref = np.asarray(Image.open(tmp_path / "rep" / "reference_view0.png"))
    assert percent_delta_e(own_ref, ref, premultiplied=False) < 1.0
    rows = [r for r in csv.DictReader(open(res.csv)) if r["kind"] == "splats"]
    assert [r["tolerance"] for r in rows] == TOLS  # finest first
    points = [int(r["points"]) for r in rows]
    assert points[0] == N**3 and all(a >= b for a, b in zip(points, points[1:])) and points[-1] < points[0] / 8
    # each frame against the numpy reference: error does not fall as the tolerance grows
    err = [percent_delta_e(np.asarray(Image.open(tmp_path / "rep" / f"tolerance_{i:02d}.png")), ref, premultiplied=False)
           for i in range(len(TOLS))]
    assert err[0] < 1.0, err
    assert all(b >= a - 0.5 for a, b in zip(err, err[1:])), err
    assert err[-1] > err[0] + 5.0, err
    # the report's error column says the same (its reference is every point too)
    rep_err = [float(r["pct_de6"]) for r in rows]
    assert np.allclose(rep_err, err, atol=1.5), (rep_err, err)
    assert (tmp_path / "rep" / "tolerance.png").stat().st_size > 1000
    md = res.markdown.read_text()
    assert "Meredith" in md and "every point" in md and "seed" not in md.lower()


def test_report_cli_on_a_point_store_and_bad_tolerance(lattice, tmp_path):
    from clipvol.tools.cli import main

    path = lattice[0]
    assert main(["report", str(path), "--out", str(tmp_path / "r"), "--size", "48x48", "--views", "1",
                 "--tolerances", "2px,0.2", "--no-plots"]) == 0
    rows = list(csv.DictReader(open(tmp_path / "r" / "point_report.csv")))
    assert [r["tolerance"] for r in rows] == ["every point", "2px", "0.2"]
    assert main(["report", str(path), "--out", str(tmp_path / "s"), "--tolerances", "0.05,wide"]) == 2


def test_footprint_blur_against_scipy():
    """The yardstick's blur equals scipy's Gaussian filter of the premultiplied image (zero outside)."""
    ndimage = pytest.importorskip("scipy.ndimage")
    from clipvol.app.point_report import footprint_blur

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (40, 50, 4)).astype(np.uint8)
    img[..., 3] = np.where(rng.random((40, 50)) < 0.3, 0, img[..., 3])
    got = footprint_blur(img, 2.0)
    a = img / 255.0
    prem = np.concatenate([a[..., :3] * a[..., 3:4], a[..., 3:4]], -1)
    b = np.stack([ndimage.gaussian_filter(prem[..., c], 2.0, mode="constant", truncate=3.0) for c in range(4)], -1)
    want_a = b[..., 3]
    assert np.abs(got[..., 3] / 255.0 - want_a).max() <= 1 / 255 + 1e-9
    m = want_a > 0.2
    want_rgb = b[..., :3][m] / want_a[m][:, None]
    assert np.abs(got[..., :3][m] / 255.0 - want_rgb).max() <= 1.5 / 255


def test_reference_cap_and_bad_points_option_are_clear_errors(lattice, tmp_path):
    from clipvol.app.point_report import run_point_report
    from clipvol.errors import ParameterError
    from clipvol.tools.cli import main

    with pytest.raises(ParameterError, match="cap of 100"):
        run_point_report(lattice[0], tmp_path / "r", reference_cap=100)
    with pytest.raises(ParameterError, match="views"):
        run_point_report(lattice[0], tmp_path / "r", views=0)
    assert main(["report", "procedural:fractal?size=16", "--out", str(tmp_path / "v"), "--points",
                 str(tmp_path / "missing.zarr")]) == 2
