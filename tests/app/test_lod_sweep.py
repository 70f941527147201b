"""The block-budget sweep of the report (after Wang, Garcia & Shen 2007, Fig. 6): every policy is
held to each budget, the image policy's error falls with the budget, and a loader without summary
tables skips only the image-based curves."""

from __future__ import annotations

import numpy as np

from clipvol.app.lod_sweep import LOD_POLICIES, blocks_to_reach, lod_sweep, plot_lod_sweep
from clipvol.app.session import RenderSession
from clipvol.bricking.generators import ct_head
from clipvol.bricking.pipeline import brick_volume
from clipvol.paging.open import open_store
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction


def _views(pyr):
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    cam = Camera.perspective(tuple(c - np.array([0.2, 0.1, 1.0]) * 1.1 * float(np.linalg.norm(hi - lo))), tuple(c),
                             up=(0, -1, 0), fov_y=40, size=(64, 64))
    return [(cam, tuple(c))]


def _sweep(gl, loader, budgets, logs):
    tf = TransferFunction.preset("bone", value_range=loader.pyramid.value_range)
    views = _views(loader.pyramid)
    with RenderSession(loader, gl, memory_budget="64MB", texture_budget="64MB", tf=tf,
                       params=RenderParams(policy="fixed", level=0)) as sess:
        refs = [sess.render(c, coi, wait=True) for c, coi in views]
        sess.update(level=None)
        return lod_sweep(sess, views, refs, budgets, log=logs.append)


def test_sweep_rows_and_plot(gl, tmp_path):
    path = tmp_path / "h.zarr"
    brick_volume(ct_head((48, 48, 48), seed=2), path, brick=8, progress=False)
    budgets = (4, 16, 64)
    rows = _sweep(gl, open_store(path), budgets, [])
    assert {r["policy"] for r in rows} == set(LOD_POLICIES)
    for r in rows:
        assert r["blocks"] <= r["budget"] and r["converged"] == 1
    img = [r["pct_de6"] for r in rows if r["policy"] == "image"]
    assert img[0] > img[-1] and all(b <= a + 0.25 for a, b in zip(img, img[1:])), img
    best = blocks_to_reach(rows, "image", target=img[-1])
    assert best is not None and best["pct_de6"] <= img[-1]
    p = plot_lod_sweep(rows, tmp_path / "fig6.png")
    assert p is not None and p.stat().st_size > 0


def test_without_tables_only_image_curves_are_skipped(gl, tmp_path):
    from clipvol.loaders.procedural import ProceduralLoader

    logs: list = []
    rows = _sweep(gl, ProceduralLoader("procedural:fractal?size=24&seed=1", brick=8), (4, 16), logs)
    assert {r["policy"] for r in rows} == {"projected size", "distance"}
    assert sum("skipped" in m and "clipvol summarize" in m for m in logs) == 2
