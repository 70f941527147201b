"""``clipvol report --mode minip|average|iso``: the error of each setting is measured against a
converged picture drawn in the same mode (so the full-resolution frame is near it, and coarser
settings are farther), and the pictures really are that mode's."""

from __future__ import annotations

import csv

import numpy as np
import pytest

pytest.importorskip("moderngl")


def _sphere(n=32):
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    return (20.0 - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)


@pytest.mark.parametrize("mode", ["minip", "average", "iso"])
def test_report_measures_each_mode_against_its_own_reference(tmp_path, ctx, mode):
    from PIL import Image

    from clipvol.app.report import run_report
    from clipvol.loaders.numpy_array import NumpyLoader

    res = run_report(NumpyLoader(_sphere(), brick=8), tmp_path, views=1, size=(40, 40), thresholds=(0.5, 8.0),
                     memory_budgets=(), texture_budgets=(), block_budgets=(), tf="grey", ctx=ctx, max_frames=2,
                     rounds=1, plots=False, mode=mode, iso_value=10.0)
    with open(res.csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    full = [float(r["rmse"]) for r in rows if r["setting"] == "fixed L0" and r["kind"] == "converged"]
    coarse = [float(r["rmse"]) for r in rows if r["kind"] == "converged" and r["lod_threshold"] == "8.0"]
    assert full and coarse and max(coarse) > max(full)  # a coarser cut is farther from the converged picture
    for name in ("full_resolution_view0.png", "reference_view0.png"):
        alpha = np.asarray(Image.open(tmp_path / name))[..., 3]
        if mode == "iso":  # an opaque disc and nothing else (the converged picture's edge averaged over 2x2 rays)
            edge = (alpha > 0) & (alpha < 255)
            assert (alpha == 255).sum() > 50 and (edge.sum() == 0 if name.startswith("full") else edge.sum() < 0.5 * (alpha == 255).sum())
        else:  # a projection: the whole box's footprint, partly transparent under the grey ramp
            assert (alpha > 0).sum() > 200 and (alpha < 255).any()
    assert f"`{mode}`" in res.markdown.read_text()
