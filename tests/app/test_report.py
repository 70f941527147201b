"""The error-against-run-time report on a tiny volume: files, columns, and error falling with the threshold."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("moderngl")


@pytest.fixture(scope="module")
def report(tmp_path_factory, ctx):
    from clipvol.loaders.procedural import ProceduralLoader
    from clipvol.app.report import run_report

    out = tmp_path_factory.mktemp("report")
    loader = ProceduralLoader("procedural:fractal?size=32&seed=1", brick=8)
    res = run_report(loader, out, views=2, size=(48, 48), thresholds=(0.5, 2.0, 8.0), memory_budgets=(),
                     texture_budgets=("40kB",), tf="grey", ctx=ctx, max_frames=3)
    return res, loader


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_files_and_columns(report):
    from clipvol.app.report import REPORT_COLUMNS

    res, _ = report
    for p in [res.csv, res.markdown, *res.plots, *res.images]:
        assert p.is_file() and p.stat().st_size > 0, p
    assert {p.name for p in res.plots} == {"error_vs_time.png", "error_vs_bytes.png", "lod_budget.png"}
    with open(res.csv, newline="") as fh:
        header = next(csv.reader(fh))
    assert tuple(header) == REPORT_COLUMNS
    rows = _rows(res.csv)
    assert {r["sweep"] for r in rows} == {"fixed", "lod_threshold", "texture_budget"}
    assert {r["kind"] for r in rows} == {"converged", "as-it-comes"}
    md = res.markdown.read_text()
    assert "error_vs_time.png" in md
    # papers cited by authors, title and year in a References section, never by a file number
    import re

    assert "## References" in md and "LaMar, B. Hamann and K. I. Joy" in md and "1999" in md
    assert not re.search(r"\bseed", md, re.I)


def test_converged_rows_are_consistent(report):
    res, loader = report
    pyr = loader.pyramid
    for r in _rows(res.csv):
        if r["kind"] != "converged":
            continue
        if r["sweep"] != "texture_budget":  # a tiny texture budget may not hold the wanted bricks
            assert r["converged"] == "1", r
        assert int(r["bytes_needed"]) == int(r["bricks_drawn"]) * pyr.brick_nbytes
        assert float(r["frame_s"]) > 0 and float(r["converge_s"]) >= 0
        if r["sweep"] == "fixed":
            # the reference is level 0 everywhere: every level-0 brick in view, no error
            assert float(r["pct_de6"]) == 0.0
            assert int(r["bricks_drawn"]) == pyr.num_bricks(0)


def test_error_falls_as_threshold_falls(report):
    res, _ = report
    conv = [r for r in _rows(res.csv) if r["kind"] == "converged" and r["sweep"] == "lod_threshold"]
    by_t = {}
    for r in conv:
        by_t.setdefault(float(r["lod_threshold"]), []).append(float(r["rmse"]))
    ts = sorted(by_t)
    err = [np.mean(by_t[t]) for t in ts]
    bricks = {}
    for r in conv:
        bricks.setdefault(float(r["lod_threshold"]), []).append(int(r["bricks_drawn"]))
    # finer threshold: never fewer bricks, never more error; the extremes differ
    assert all(np.mean(bricks[a]) >= np.mean(bricks[b]) for a, b in zip(ts, ts[1:]))
    assert all(e1 <= e2 + 1e-9 for e1, e2 in zip(err, err[1:])), err
    assert err[0] < err[-1]


def test_csv_errors_match_the_saved_images(report):
    """Recompute RMSE from the written PNGs with numpy (composited over black, 8-bit RGB)."""
    res, _ = report
    ref = np.asarray(Image.open(res.out_dir / "reference_view0.png"), dtype=np.float64)
    rows = {float(r["lod_threshold"]): r for r in _rows(res.csv)
            if r["kind"] == "converged" and r["sweep"] == "lod_threshold" and r["view"] == "0"}
    for t, r in rows.items():
        img = np.asarray(Image.open(res.out_dir / f"view0_lod{t:g}.png"), dtype=np.float64)
        a = img[..., :3] * img[..., 3:4] / 255.0
        b = ref[..., :3] * ref[..., 3:4] / 255.0
        rmse = np.sqrt(np.mean((a - b) ** 2))
        assert float(r["rmse"]) == pytest.approx(rmse, abs=0.6), (t, r["rmse"], rmse)
