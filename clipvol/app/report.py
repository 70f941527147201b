"""The report of image error against run time: what each quality setting costs and what it loses.

A multiresolution renderer trades image quality for time and bytes (Meredith & Ma 2001 plot
frame rate against error tolerance; Wang, Garcia & Shen 2007 plot image quality against block
budget). This module measures the trade on real frames. Along a camera path (a few views) it
renders, for a sweep of ``lod_threshold``, of memory / texture budgets and of block budgets per
selection policy:

* **cold** (each setting in a new session, so an empty clip-texture and GPU cache): the
  **as-it-comes** frames (``wait=False``, the viewer's default) a user sees while the bricks stream
  in, until the frame converges (or a frame limit), and the **time to converge**; the converged
  frame's distinct bricks and texels, the bytes those bricks hold (``bytes_needed``, the "bytes
  transmitted" of LaMar et al. 2000) and the bytes the clip-texture loaded (it pages whole windows,
  so usually more);
* **warm** (the way a benchmark times): every setting and the full-resolution reference are
  warmed, then drawn over ``rounds`` interleaved rounds in this one process, and the **frame time**
  is the median (with its minimum and maximum). A frame timed first in a process, or first after a
  load, carries costs no later frame has; one frame per setting timed in sequence charges them to
  whichever setting comes first, and can show two settings that draw the same bricks as 1.9x apart.

Every frame is compared with the **converged picture** of the same view (:mod:`.converged`:
level 0 at a quarter-voxel step, ``supersample`` x ``supersample`` rays per pixel box-filtered
down), drawn once per view by the same renderer with the same transfer function and mode. The
**full-resolution frame** (fixed level 0 at the report's step, converged, with budgets that hold
everything) is measured against it like every setting, and its own error is shown beside each:
a faster setting can be nearer the converged picture than the full-resolution frame, and the
report says so when one is. Every warm frame of a setting is paired with a full-resolution frame
drawn right before or after it, and the **speed-up** is the median over the pairs of the
full-resolution frame's time over the setting's: the load of a shared machine drifts over
seconds, and a pair sees the same load. When level 0 of a huge volume exceeds ``reference_cap``
bytes, both use the finest level that fits and the report says so. Errors are the "% of pixels
with ΔE ≥ 6 in CIELUV" of Wang, Garcia & Shen (2007) plus RMSE and PSNR
(:mod:`clipvol.scene.metrics`).

The answer in one line (:func:`headline`): at <= 5 % of pixels visibly different from the
converged picture on every view, how much faster frames are, and with which setting, or that no
setting gets there; and the full-resolution frame's own error.

Outputs in ``out_dir``: ``report.csv`` (one row per frame), ``timing.csv`` (one row per warm timed
frame), ``error_vs_time.png`` and ``error_vs_bytes.png`` (matplotlib, Agg; one curve per sweep /
setting), ``lod_budget.csv`` / ``.png``, ``reference_view*.png`` (the converged pictures),
``full_resolution_view*.png`` and a few example frames, and
``report.md`` with the answer, a table per setting, two tables - bricks and time, fixed vs
multiresolution (as LaMar, Hamann & Joy 1999 tabulate them), and bytes, fixed vs multiresolution
(as LaMar et al. 2000 do) - and a References section (:data:`REFERENCES`).

The work is split by job: :mod:`.report_measure` draws and measures (the cold sweep, the warm
paired rounds), :mod:`.report_summary` sums the rows up and words the answer,
:mod:`.report_plot` plots and :mod:`.report_markdown` writes ``report.md``; this module is the
entry that runs them in order and writes the CSV files. The policy comparison
(:mod:`.lod_sweep`), the converged picture (:mod:`.converged`) and the image metrics
(:mod:`clipvol.scene.metrics`) live apart.
"""


from __future__ import annotations

import csv
from typing import Callable, Sequence

from .converged import CONVERGED_STEP, CONVERGED_SUPERSAMPLE
from .report_markdown import REFERENCES, write_markdown
from .report_measure import (DEFAULT_MAX_ERRORS, DEFAULT_REFINES, DEFAULT_THRESHOLDS, FRAMES, REPORT_COLUMNS,
                             TIMING_COLUMNS, ReportFiles, ReportResult, measure)
from .report_plot import plots as _plots
from .report_summary import VISIBLE_TARGET, headline, summarise
from .lod_sweep import plot_lod_sweep

__all__ = ["ReportResult", "ReportFiles", "run_report", "summarise", "headline", "REPORT_COLUMNS", "TIMING_COLUMNS",
           "DEFAULT_THRESHOLDS", "DEFAULT_MAX_ERRORS", "DEFAULT_REFINES", "VISIBLE_TARGET", "REFERENCES", "FRAMES"]


def run_report(
    source,
    out_dir,
    *,
    path: str = "orbit",
    views: int = 3,
    size=(192, 192),
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
    memory_budgets: Sequence | None = None,
    texture_budgets: Sequence | None = None,
    tf="viridis",
    mode: str = "composite",
    iso_value: float | None = None,
    step: float = 0.5,
    threads: int | None = None,
    timeout: float = 120.0,
    max_frames: int = 8,
    reference_cap="1GB",
    ctx=None,
    log: Callable[[str], None] | None = None,
    plots: bool = True,
    block_budgets: Sequence[int] | None = None,
    rounds: int = 5,
    allow_partial: bool = False,
    max_errors: Sequence | None = None,
    refines: Sequence | None = None,
    frame: str = "visible",
    supersample: int = CONVERGED_SUPERSAMPLE,
    converged_step: float = CONVERGED_STEP,
    classify: str = "distribution",
) -> ReportResult:
    """Measure image error against frame time and bytes for a sweep of settings; write the report.

    Parameters
    ----------
    source : loader, path or URL
        The data (see :func:`clipvol.paging.open.open_store`).
    out_dir : str or Path
        Where ``report.csv``, the plots, images and ``report.md`` go (created).
    path : {'orbit', 'fly', 'zoom'}
        Camera path the views are taken from (:mod:`clipvol.scene.paths`).
    views : int
        Number of views along the path.
    size : (int, int)
        Image ``(width, height)``; it also caps the reference render's cost.
    thresholds : sequence of float
        ``lod_threshold`` values (pixels) swept with budgets that hold everything.
    memory_budgets, texture_budgets : sequence, optional
        Clip-texture and GPU cache budgets swept at ``lod_threshold`` 1 (bytes or strings like
        ``"16MB"``). Default: a half and an eighth of the whole pyramid (memory: no less than
        the smallest budget the clip-texture accepts). Pass ``()`` to skip a sweep.
    tf : str or TransferFunction
        Transfer-function preset name, or a transfer function.
    mode : {'composite', 'mip', 'minip', 'average', 'iso'}
        Render mode (:class:`~clipvol.scene.params.RenderParams`); the reference is drawn in it too.
    iso_value : float, optional
        ``mode="iso"``: the surface's data value.
    step : float
        Sample spacing in voxels of each level.
    threads : int, optional
        Loader threads.
    timeout : float
        Seconds to wait for a converged frame (per view and setting).
    max_frames : int
        As-it-comes frames rendered per view at most.
    reference_cap : int or str
        Bytes the reference may hold; above it the reference drops to a coarser level.
    ctx : moderngl.Context, optional
        GL context; default a standalone EGL context created (and released) here.
    log : callable, optional
        Progress lines go here (e.g. ``print``).
    plots : bool
        Write the PNG plots (needs matplotlib).
    block_budgets : sequence of int, optional
        Block budgets of the policy comparison after Wang, Garcia & Shen's Fig. 6
        (:mod:`clipvol.app.lod_sweep`: projected size, distance, image-based with and without
        visibility; ``lod_budget.csv`` / ``lod_budget.png``). Default
        :data:`~clipvol.app.lod_sweep.DEFAULT_BLOCK_BUDGETS`; ``()`` skips it. The image-based
        curves need the store's summary tables (else they are reported as skipped).
    rounds : int
        Warm interleaved rounds per setting and view; the frame time is their median, the spread
        their minimum and maximum, the speed-up the median of the paired ratios. Each round draws
        four frames per setting and view (the setting's and the reference's, each twice), so the
        warm half costs about ``4 * rounds`` frames per setting and view. The reference's session
        stays open while each memory / texture budget setting is timed beside it in a session of
        its own: up to twice the reference's budgets are held then.
    allow_partial : bool
        Go on (with a warning on stderr) when a converged frame has failed bricks that no verified
        ancestor stands in for; without it such a frame raises
        :class:`~clipvol.errors.FrameIncompleteError`.
    max_errors : sequence, optional
        Visible-error budgets of the image policy (``RenderParams.max_error``: fractions or strings
        like ``"5%"``), each a setting of the sweep ``"max_error"`` measured like the thresholds.
        Default :data:`DEFAULT_MAX_ERRORS`; ``()`` skips them. They need the store's summary tables
        (else they are reported as skipped).
    refines : sequence of (step, tolerance), optional
        Level 0 sampled at ``step`` voxels with adaptive image sampling at ``tolerance``
        (``RenderParams.step``, ``refine_tolerance``), each a setting of the sweep ``"refine"``
        (composite only). Default :data:`DEFAULT_REFINES`; ``()`` skips them.
    frame : {'visible', 'volume'}
        What the ``orbit`` views frame: ``"visible"`` (composite mode) the voxels the transfer
        function gives opacity (:func:`clipvol.scene.framing.visible_points`), from the distance where
        they fill the views; ``"volume"`` the sphere around the whole volume box. Other paths and
        modes frame the volume.
    supersample : int
        Rays per pixel along each axis of the converged picture every error is measured against
        (:mod:`clipvol.app.converged`; default 2, 4 where the time is there).
    converged_step : float
        Sample spacing in voxels of the converged picture (default 0.25).
    classify : {'distribution', 'mean'}
        How every frame's coarse samples are classified (``RenderParams.classify``): the transfer
        function applied to the distribution of the level-0 voxels beneath each coarse voxel where
        the store holds it (consistent coarse levels), or to their mean; a report run once with
        each compares the two on the same views.

    Returns
    -------
    ReportResult
    """

    kw = {k: v for k, v in locals().items() if k not in ("source", "out_dir")}
    result, pyr, cap = measure(source, out_dir, **kw)
    out = result.out_dir
    result.headline = headline(summarise(result.rows, result.lod_rows), rounds=rounds, views=int(views))
    with open(result.csv, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(REPORT_COLUMNS))
        w.writeheader()
        w.writerows(result.rows)
    with open(result.timing_csv, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(TIMING_COLUMNS))
        w.writeheader()
        w.writerows(result.timing_rows)
    if result.lod_rows:
        with open(out / "lod_budget.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(result.lod_rows[0]))
            w.writeheader()
            w.writerows(result.lod_rows)
    if plots:
        result.plots.extend(_plots(result.rows, out))
        if result.lod_rows:
            p = plot_lod_sweep(result.lod_rows, out / "lod_budget.png")
            if p is not None:
                result.plots.append(p)
    write_markdown(result, pyr, size=size, path=path, tf=tf, mode=mode, step=step, cap=cap, classify=classify)
    return result

