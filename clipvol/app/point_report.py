"""The report of a point store: frame time and image error against the splat tolerance.

Meredith & Ma (2001) plot frames per second against the user's error tolerance (the largest
splat, a fraction of the screen): a coarser tolerance draws shallower nodes - fewer, larger splats
of representative points - and is faster. This module measures that trade on real frames and adds
what it costs in the picture. For a few views around the data it renders, per tolerance, a
**converged** frame (every wanted node drawn at its own depth) and times the median of three
renders once the cut is resident (select + gather + draw + read-back), then compares the frame
with the **every-point reference** of the same view: every input point, read straight from the
store's leaves (not through the selection), drawn as a splat of its leaf's size - the full-detail
picture. The error is the % of pixels with ΔE ≥ 6 in CIELUV (Wang, Garcia & Shen 2007), with RMSE
and PSNR. The reference's own frame time is the baseline of the speed-ups.

Outputs in ``out_dir``: ``point_report.csv`` (one row per view and tolerance, plus the reference
rows), ``tolerance.png`` (frame rate and error against tolerance), ``reference_view*.png`` and the
frames of the first view (``tolerance_*.png``), and ``point_report.md`` with the table and a
References section.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import ParameterError
from ..render.context import create_context
from ..scene.camera import Camera
from ..scene.metrics import percent_delta_e, psnr, rmse
from ..scene.splat_select import tolerance_pixels
from .point_session import PointSession, open_point_loader
from .report import ReportFiles

__all__ = ["PointReportResult", "run_point_report", "POINT_REPORT_COLUMNS", "DEFAULT_TOLERANCES", "POINT_REFERENCES",
           "footprint_blur"]

DEFAULT_TOLERANCES = ("1px", "2px", "4px", "0.02", "0.05", "0.1", "0.2")

POINT_REPORT_COLUMNS = ("view", "tolerance", "tolerance_px", "kind", "frame_s", "converged", "nodes", "points",
                        "speedup", "pct_de6", "rmse", "psnr", "blur_pct_de6")

POINT_REFERENCES = (
    "J. Meredith and K.-L. Ma. Multiresolution view-dependent splat based volume rendering of large "
    "irregular data. IEEE Symposium on Parallel and Large-Data Visualization and Graphics, 2001.",
    "C. Wang, A. Garcia and H.-W. Shen. Interactive level-of-detail selection using image-based quality "
    "metric for large volume visualization. IEEE Transactions on Visualization and Computer Graphics "
    "13(1), 2007.",
)


@dataclass
class PointReportResult(ReportFiles):
    """Files written by :func:`run_point_report` and its rows."""


def orbit_cameras(lo, hi, views: int, size, fov_y: float = 35.0, elevation: float = 25.0) -> list[Camera]:
    """``views`` perspective cameras around the box ``(lo, hi)``, the whole box in view."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    c = (lo + hi) / 2.0
    r = float(np.linalg.norm(hi - lo)) / 2.0
    w, h = size
    half = np.radians(fov_y) / 2.0
    half_min = min(half, np.arctan(np.tan(half) * w / h))
    dist = 1.05 * r / np.sin(half_min)
    el = np.radians(elevation)
    out = []
    for i in range(views):
        az = np.radians(30.0 + 360.0 * i / views)
        d = np.array([np.cos(el) * np.sin(az), -np.sin(el), -np.cos(el) * np.cos(az)])
        out.append(Camera.perspective(tuple(c + dist * d), tuple(c), fov_y=fov_y, size=(w, h)))
    return out


def footprint_blur(img: np.ndarray, sigma_px: float) -> np.ndarray:
    """``img`` (straight RGBA uint8) blurred by a Gaussian of ``sigma_px`` pixels, premultiplied, zero outside.

    The every-point frame seen through the footprint of one tolerance-sized splat (sigma = half
    the tolerance): the detail any picture made of splats that large cannot hold. Its error
    against the every-point frame (``blur_pct_de6``) is the yardstick the tolerance's own error
    is read against.
    """
    a = img.astype(np.float64) / 255.0
    prem = np.concatenate([a[..., :3] * a[..., 3:4], a[..., 3:4]], axis=-1)
    r = max(int(np.ceil(3.0 * sigma_px)), 1)
    x = np.arange(-r, r + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / max(sigma_px, 1e-6)) ** 2)
    k /= k.sum()
    for axis in (0, 1):
        pad = [(0, 0)] * 3
        pad[axis] = (r, r)
        p = np.pad(prem, pad)
        n = prem.shape[axis]
        prem = sum(k[i] * np.take(p, np.arange(i, i + n), axis=axis) for i in range(len(k)))
    al = prem[..., 3:4]
    rgb = np.where(al > 0, prem[..., :3] / np.maximum(al, 1e-12), 0.0)
    return np.round(np.clip(np.concatenate([rgb, al], axis=-1), 0.0, 1.0) * 255.0).astype(np.uint8)


def _metrics(img, ref) -> dict:
    p = float(psnr(img, ref, premultiplied=False))
    return {"pct_de6": round(float(percent_delta_e(img, ref, premultiplied=False)), 4),
            "rmse": round(float(rmse(img, ref, premultiplied=False)), 4), "psnr": round(p, 3) if np.isfinite(p) else p}


def _timed(fn, repeats: int) -> tuple[float, np.ndarray]:
    times, img = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        img = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), img


def run_point_report(source, out_dir, *, tolerances: Sequence = DEFAULT_TOLERANCES, size=(192, 192), views: int = 2,
                     tf=None, mode: str = "composite", memory_budget="1GB", threads=None, timeout: float = 120.0,
                     repeats: int = 3, reference_cap: int = 20_000_000, plots: bool = True) -> PointReportResult:
    """Frame time and image error against tolerance for a point store (see the module docstring).

    Parameters
    ----------
    source : path or PointStoreLoader
        A store written by ``clipvol brick-points``.
    out_dir : path
        Output folder (created).
    tolerances : sequence
        Tolerances (fractions of the screen, ``"5%"`` or ``"Npx"``), any order.
    size : (int, int)
        Image size.
    views : int
        Views around the data.
    tf : str or TransferFunction, optional
        Transfer function (default ``viridis`` over the value range).
    reference_cap : int
        Most points the every-point reference may hold in memory.
    """
    if int(views) < 1:
        raise ParameterError(f"views: expected >= 1, got {views!r}")
    if int(repeats) < 1:
        raise ParameterError(f"repeats: expected >= 1, got {repeats!r}")
    tols = list(tolerances)
    if not tols:
        raise ParameterError("tolerances: expected at least one tolerance")
    size = (int(size[0]), int(size[1]))
    order = sorted(range(len(tols)), key=lambda i: tolerance_pixels(tols[i], size))  # also validates each
    tols = [tols[i] for i in order]
    loader = open_point_loader(source)
    xyz, vals, h = loader.leaf_points(max_points=int(reference_cap))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = PointReportResult(out, out / "point_report.csv", out / "point_report.md")
    ctx = create_context()
    rows: list[dict] = []
    try:
        with PointSession(loader, ctx, memory_budget=memory_budget, threads=threads, tolerance=tols[0], mode=mode,
                          tf=tf) as sess:
            lo, hi = loader.world_box()
            value = vals[:, sess.action.value]
            for v, cam in enumerate(orbit_cameras(lo, hi, int(views), size)):
                draw_all = lambda: sess.action.draw_points(cam, sess.tf, xyz, value, h)  # noqa: E731
                draw_all()
                ref_s, ref = _timed(draw_all, repeats)
                p = out / f"reference_view{v}.png"
                _save(ref, p)
                result.images.append(p)
                rows.append({"view": v, "tolerance": "every point", "tolerance_px": 0.0, "kind": "reference",
                             "frame_s": ref_s, "converged": True, "nodes": 0, "points": len(value), "speedup": 1.0,
                             "pct_de6": 0.0, "rmse": 0.0, "psnr": float("inf"), "blur_pct_de6": 0.0})
                for i, tol in enumerate(tols):
                    sess.update(tolerance=tol)
                    sess.render(cam, (lo + hi) / 2.0, wait=True, timeout=timeout)
                    frame_s, img = _timed(lambda: sess.render(cam), repeats)
                    st = sess.frame_stats
                    rows.append({"view": v, "tolerance": str(tol), "tolerance_px": round(st.tolerance_px, 3),
                                 "kind": "splats", "frame_s": frame_s, "converged": st.converged,
                                 "nodes": st.nodes_drawn, "points": st.points_drawn,
                                 "speedup": ref_s / max(frame_s, 1e-9), **_metrics(img, ref),
                                 "blur_pct_de6": round(float(percent_delta_e(footprint_blur(ref, 0.5 * st.tolerance_px),
                                                                             ref, premultiplied=False)), 4)})
                    if v == 0:
                        p = out / f"tolerance_{i:02d}.png"
                        _save(img, p)
                        result.images.append(p)
    finally:
        ctx.release()
    result.rows = rows
    with open(result.csv, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=POINT_REPORT_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in POINT_REPORT_COLUMNS})
    if plots:
        result.plots.append(_plot(rows, out / "tolerance.png", loader.meta.num_points, size))
    _markdown(result, loader, size=size, mode=mode)
    return result


def summarise(rows: list[dict]) -> list[dict]:
    """Per tolerance (and the reference), the means over views, finest first."""
    out = []
    for tol in dict.fromkeys(r["tolerance"] for r in rows):
        rs = [r for r in rows if r["tolerance"] == tol]
        out.append({"tolerance": tol, "kind": rs[0]["kind"], "tolerance_px": float(np.mean([r["tolerance_px"] for r in rs])),
                    **{k: float(np.mean([float(r.get(k, 0.0)) for r in rs]))
                       for k in ("frame_s", "points", "nodes", "speedup", "pct_de6", "rmse", "blur_pct_de6")}})
    return out


def _save(img: np.ndarray, path: Path) -> None:
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(img), "RGBA").save(path)


def _plot(rows: list[dict], path: Path, n: int, size) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summ = summarise(rows)
    sp = [s for s in summ if s["kind"] == "splats"]
    ref = [s for s in summ if s["kind"] == "reference"][0]
    tol = [s["tolerance_px"] for s in sp]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4), dpi=90)
    ax[0].plot(tol, [1.0 / s["frame_s"] for s in sp], "o-", label="splats at the tolerance")
    ax[0].axhline(1.0 / ref["frame_s"], color="k", ls="--", label="every point (reference)")
    ax[0].set_xscale("log")
    ax[0].set_yscale("log")
    ax[0].set_xlabel(f"tolerance (largest splat, pixels of a {size[0]}x{size[1]} image)")
    ax[0].set_ylabel("frames per second (median of 3, cut resident)")
    ax[0].set_title(f"{n:,} points: frame rate against tolerance")
    ax[0].grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    ax[1].plot(tol, [s["pct_de6"] for s in sp], "o-", label="splats at the tolerance")
    ax[1].plot(tol, [s["blur_pct_de6"] for s in sp], "k:", label="every point blurred by one splat's footprint")
    ax[1].legend(fontsize=8)
    ax[1].set_xscale("log")
    ax[1].set_xlabel("tolerance (pixels)")
    ax[1].set_ylabel("% pixels with ΔE ≥ 6 vs every point")
    ax[1].set_title("image error against tolerance")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _markdown(result: PointReportResult, loader, *, size, mode) -> None:
    summ = summarise(result.rows)
    meta = loader.meta
    views = len({r["view"] for r in result.rows})
    lines = [
        "# clipvol report: frame time and image error against splat tolerance",
        "",
        f"Data: {meta.num_points:,} points, {len(loader.nodes):,} octree nodes (at most {meta.max_points} points each), "
        f"depth {loader.depth}. Views: {views} around the data, {size[0]}x{size[1]} pixels, `{mode}`.",
        "",
        "Tolerance: the largest splat any drawn node may have on screen [1]. Reference: every input point "
        "drawn as a splat of its leaf's size (read from the store's leaves, not through the selection). "
        "Error: % of pixels with ΔE ≥ 6 in CIELUV [2] and RMSE on 8-bit RGB; speed-up = reference frame time / "
        "frame time. Frame times: median of 3 renders once the cut is resident. `blur` = the error of the "
        "every-point frame blurred by the footprint of one tolerance-sized splat (Gaussian, sigma = half the "
        "tolerance): detail no picture of splats that large can hold, the yardstick for the tolerance's error.",
        "",
        "| tolerance | px | points drawn | nodes | frame ms | speed-up | % ΔE≥6 | blur % ΔE≥6 | RMSE |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for s in summ:
        lines.append(f"| {s['tolerance']} | {s['tolerance_px']:.1f} | {s['points']:,.0f} | {s['nodes']:,.0f} | "
                     f"{s['frame_s'] * 1e3:.1f} | {s['speedup']:.1f}x | {s['pct_de6']:.2f} | {s['blur_pct_de6']:.2f} | "
                     f"{s['rmse']:.2f} |")
    if result.plots:
        lines += ["", "## Plots", ""] + [f"![{p.stem}]({p.name})" for p in result.plots]
    lines += ["", "Raw numbers, one row per view and tolerance: `point_report.csv`.", "", "## References", ""]
    lines += [f"{i}. {ref}" for i, ref in enumerate(POINT_REFERENCES, 1)] + [""]
    result.markdown.write_text("\n".join(lines))
