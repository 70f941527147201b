"""Splat lighting from weighted least-squares gradients on unstructured points.

References: the coefficients of a linear field (the estimate must recover them exactly, whatever
the points' layout), and the independent numpy splatter (``tests/reference_splats.py``) lighting
every point with the field's exact gradient.
"""

from __future__ import annotations

import numpy as np
import pytest

from reference_splats import splat_every_point

from clipvol.scene.point_gradient import wls_gradients
from clipvol.scene.metrics import percent_delta_e

G = np.array([0.02, -0.012, 0.016])  # the linear field's gradient (per world unit): values in [0.11, 0.86]
N = 16  # a power of two: every leaf holds 2 x 2 x 2 lattice points, splat size 1


def test_wls_gradient_is_exact_for_a_linear_field_on_any_layout(rng):
    xyz = rng.random((6, 20, 3)) * rng.uniform(0.01, 100.0, (6, 1, 1))
    vals = xyz @ G + 0.3
    counts = np.array([20, 9, 4, 3, 20, 1])
    vals[4, 5] = np.nan  # a NaN value takes no part and gets no gradient
    g = wls_gradients(xyz, vals, counts)
    for j, c in enumerate(counts):
        rows = [i for i in range(c) if not (j == 4 and i == 5)]
        if c >= 4:
            np.testing.assert_allclose(g[j, rows], np.broadcast_to(G, (len(rows), 3)), rtol=1e-5, atol=1e-7)
    assert not g[4, 5].any() and not g[:, 20:].any() and not g[1, 9:].any()
    assert not g[5].any()  # a lone point has no neighbour: no gradient
    # a quadratic field: second-order accurate on a dense, symmetric neighbourhood
    q = np.stack(np.meshgrid(*(np.linspace(-0.1, 0.1, 3),) * 3, indexing="ij"), -1).reshape(1, -1, 3) + 0.5
    vq = (q**2).sum(-1)
    gq = wls_gradients(q, vq, np.array([27]))
    np.testing.assert_allclose(gq[0, 13], 2 * q[0, 13], atol=1e-6)  # the centre point


@pytest.fixture(scope="module")
def lattice(tmp_path_factory):
    from clipvol.bricking.point_sources import ArrayPointSource
    from clipvol.bricking.point_store import build_point_store

    z, y, x = np.meshgrid(*(np.arange(N),) * 3, indexing="ij")
    xyz = np.stack([x.ravel(), y.ravel(), z.ravel()], 1) + 0.5
    vals = (xyz @ G + 0.3).astype(np.float32)
    path = tmp_path_factory.mktemp("lit") / "p.zarr"
    build_point_store(ArrayPointSource(xyz, vals), path, max_points=8, progress=False, box=((0, 0, 0), (N, N, N)))
    return path, xyz, vals


def test_lit_splats_match_the_numpy_splatter_lit_with_the_exact_gradient(gl, lattice):
    from clipvol.loaders.point_store import PointStoreLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.splat import SplatRenderAction
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction

    path, xyz, vals = lattice
    tab = TransferFunction.preset("viridis", value_range=(0.0, 1.0)).table.copy()
    tab[:, 3] = 0.35
    tf = TransferFunction(tab, (0.0, 1.0))
    c = N / 2.0
    cam = Camera.perspective((c + 26, c - 18, c - 34), (c, c, c), fov_y=40, size=(96, 96))
    light = (0.3, 0.7, 0.3, 20.0)
    loader = PointStoreLoader(path)
    with ClipTexture(loader, "32MB", 2, center=loader.to_paging((c, c, c))) as ct, \
            SplatRenderAction(gl, ct, tolerance="1px", opacity_unit=1.0, shading=True, light=light) as action:
        lit = action.render(cam, tf, wait=True, timeout=60)
        assert action.last_frame_stats.points_drawn == N**3
        action.shading = False
        unlit = action.render(cam, tf, wait=True, timeout=60)
    ref = splat_every_point(xyz, vals, 1.0, cam, tf.table, (0.0, 1.0), unit=1.0,
                            gradients=np.broadcast_to(G, xyz.shape), light=light)
    ref_unlit = splat_every_point(xyz, vals, 1.0, cam, tf.table, (0.0, 1.0), unit=1.0)
    assert percent_delta_e(unlit, ref_unlit, premultiplied=False) < 1.0
    assert percent_delta_e(lit, ref, premultiplied=False) < 1.0
    assert percent_delta_e(lit, unlit, premultiplied=False) > 20.0  # the lighting shows
    with pytest.raises(Exception, match="light"):
        SplatRenderAction(gl, ct, light=(0.3, 0.7, 0.3, 0.0))


def test_render_cli_lights_a_point_store(lattice, tmp_path):
    from PIL import Image

    from clipvol.tools.cli import main

    path = lattice[0]
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    assert main(["render", str(path), "--out", str(a), "--size", "64x64", "--tolerance", "2px", "--tf", "viridis"]) == 0
    assert main(["render", str(path), "--out", str(b), "--size", "64x64", "--tolerance", "2px", "--tf", "viridis",
                 "--shading", "--light", "0.2,0.8,0.5,10"]) == 0
    ia, ib = (np.asarray(Image.open(p)).astype(int) for p in (a, b))
    assert np.array_equal(ia[..., 3], ib[..., 3])  # opacity unchanged: lighting changes colours only
    assert np.abs(ia[..., :3] - ib[..., :3]).max() > 20
    assert main(["render", str(path), "--out", str(b), "--shading", "--light", "0.2,0.8,0.5,0"]) == 2
