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

Every frame is compared with the **full-resolution reference** of the same view (fixed level 0,
converged, with budgets that hold everything), drawn by the same renderer with the same parameters.
Every warm frame of a setting is paired with a frame of the reference drawn right before or after
it, and the **speed-up** is the median over the pairs of the reference's time over the setting's:
the load of a shared machine drifts over seconds, and a pair sees the same load. When level 0 of a
huge volume exceeds ``reference_cap`` bytes, the reference uses the finest level that fits and the
report says so. Errors are the "% of pixels with ΔE ≥ 6 in CIELUV" of Wang, Garcia & Shen (2007)
plus RMSE and PSNR (:mod:`clipvol.scene.metrics`).

The answer in one line (:func:`headline`): at <= 5 % of pixels visibly different on every view,
how much faster frames are, and with which setting, or that no setting gets there.

Outputs in ``out_dir``: ``report.csv`` (one row per frame), ``timing.csv`` (one row per warm timed
frame), ``error_vs_time.png`` and ``error_vs_bytes.png`` (matplotlib, Agg; one curve per sweep /
setting), ``lod_budget.csv`` / ``.png``, ``reference_view*.png`` and a few example frames, and
``report.md`` with the answer, a table per setting, two tables - bricks and time, fixed vs
multiresolution (as LaMar, Hamann & Joy 1999 tabulate them), and bytes, fixed vs multiresolution
(as LaMar et al. 2000 do) - and a References section (:data:`REFERENCES`).

Why one module of this size: the cold sweep, the warm paired rounds, the tables and the plots
read and write the same rows; the policy comparison (:mod:`.lod_sweep`) and the image metrics
(:mod:`clipvol.scene.metrics`) live apart.
"""

from __future__ import annotations

import csv
import sys
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import ClipvolError, FrameIncompleteError, ParameterError
from ..paging.toroidal import minimum_budget
from ..render.context import create_context
from ..scene.framing import visible_points
from ..scene.metrics import percent_delta_e, psnr, rmse
from ..scene.params import RenderParams
from ..scene.paths import make_path
from ..units import format_bytes, parse_bytes
from .lod_sweep import DEFAULT_BLOCK_BUDGETS, blocks_to_reach, lod_sweep, plot_lod_sweep, policy_changes
from .session import RenderSession, open_loader, resolve_tf

#: the papers the report's measures and tables come from, numbered as the report cites them
REFERENCES = (
    "P. Bhaniramka and Y. Demange. OpenGL Volumizer: a toolkit for high quality volume rendering of large "
    "data sets. IEEE/ACM Symposium on Volume Visualization and Graphics (VolVis), 2002.",
    "E. LaMar, B. Hamann and K. I. Joy. Multiresolution techniques for interactive texture-based volume "
    "visualization. IEEE Visualization, 1999.",
    "E. LaMar, M. A. Duchaineau, B. Hamann and K. I. Joy. Multiresolution techniques for interactive "
    "texture-based rendering of arbitrarily oriented cutting planes. Joint Eurographics - IEEE TCVG "
    "Symposium on Visualization (VisSym), 2000.",
    "C. Wang, A. Garcia and H.-W. Shen. Interactive level-of-detail selection using image-based quality "
    "metric for large volume visualization. IEEE Transactions on Visualization and Computer Graphics "
    "13(1), 2007.",
    "J. Meredith and K.-L. Ma. Multiresolution view-dependent splat based volume rendering of large "
    "irregular data. IEEE Symposium on Parallel and Large-Data Visualization and Graphics, 2001.",
    "M. Levoy. Volume rendering by adaptive refinement. The Visual Computer 6(1), 1990.",
)

__all__ = ["ReportResult", "run_report", "summarise", "headline", "REPORT_COLUMNS", "TIMING_COLUMNS", "DEFAULT_THRESHOLDS",
           "DEFAULT_MAX_ERRORS", "DEFAULT_REFINES", "VISIBLE_TARGET"]

DEFAULT_THRESHOLDS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
#: the image policy's visible-error budgets (RenderParams.max_error) the report sweeps by default
DEFAULT_MAX_ERRORS = (0.10, 0.05, 0.02)
#: full resolution sampled at ``step`` voxels with adaptive image sampling at ``refine_tolerance``
#: (:mod:`clipvol.render.refine`), the settings of the sweep "refine" by default
DEFAULT_REFINES = ((2.0, 0.16), (2.0, 0.25), (2.5, 0.2), (2.5, 0.3))
#: what the orbit's views frame (run_report's ``frame``)
FRAMES = ("visible", "volume")

REPORT_COLUMNS = (
    "sweep", "setting", "lod_threshold", "memory_budget", "texture_budget", "selection", "level",
    "view", "kind", "frame", "elapsed_s", "frame_s", "converge_s", "converged", "bricks_drawn",
    "texels_drawn", "bytes_needed", "bytes_loaded", "bytes_uploaded", "resident_mb",
    "pct_de6", "rmse", "psnr", "frame_min_s", "frame_max_s", "rounds", "ref_frame_s", "speedup",
)

#: the raw timings, one row per warm frame (``timing.csv``): block 0 holds every setting drawn by the
#: session that holds everything, block k > 0 one budget setting beside the reference; the two
#: frames of a ``pair`` (the reference's and a setting's) were drawn one right after the other
TIMING_COLUMNS = ("block", "pair", "round", "sweep", "setting", "view", "frame_s", "host_s")

#: the error the report's one-line answer is held to: % of pixels with CIELUV ΔE >= 6
VISIBLE_TARGET = 5.0


@dataclass
class ReportFiles:
    """What every report writes: its folder, CSV, markdown, plots, images, and its rows."""

    out_dir: Path
    csv: Path
    markdown: Path
    plots: list[Path] = field(default_factory=list)
    images: list[Path] = field(default_factory=list)
    rows: list[dict] = field(default_factory=list)


@dataclass
class ReportResult(ReportFiles):
    """Files written by :func:`run_report` and its rows."""

    reference_level: int = 0
    skipped: list[str] = field(default_factory=list)
    #: rows of the block-budget sweep (:mod:`clipvol.app.lod_sweep`, Fig. 6 of Wang, Garcia & Shen 2007)
    lod_rows: list[dict] = field(default_factory=list)
    #: warm interleaved rounds per setting and view
    rounds: int = 5
    #: the world box ``(lo, hi)`` of the points the views frame (``frame="visible"``), or None: the whole volume
    framed: tuple | None = None
    #: one row per timed warm frame (:data:`TIMING_COLUMNS`)
    timing_rows: list[dict] = field(default_factory=list)
    #: the one-line answer (:func:`headline`)
    headline: str = ""

    @property
    def timing_csv(self) -> Path:
        return self.out_dir / "timing.csv"


@dataclass(frozen=True)
class _Setting:
    sweep: str
    label: str
    lod_threshold: float
    memory_budget: int
    texture_budget: int
    selection: str = "projected-size"
    level: int | None = None
    #: further RenderParams changes, as ``(name, value)`` pairs (the block-budget policies)
    changes: tuple = ()

    def params(self, base: RenderParams) -> RenderParams:
        """``base`` with this setting's selection; every selection field is set, so that switching
        a shared session from one setting to another leaves nothing of the previous one behind."""
        ch = dict(policy=self.selection, level=self.level, lod_threshold=self.lod_threshold, block_budget=None,
                  max_error=None, max_texels_drawn=None, visibility=True, distance_factor=1.0)
        ch.update(dict(self.changes))
        return replace(base, **ch)


def _level_bytes(pyr, level: int) -> int:
    return pyr.num_bricks(level) * pyr.brick_nbytes


def _reference_level(pyr, cap: int) -> int:
    """Finest level whose bricks, with all coarser levels, fit in ``cap`` bytes."""
    for L in range(pyr.num_levels):
        if sum(_level_bytes(pyr, l) for l in range(L, pyr.num_levels)) <= cap:
            return L
    return pyr.num_levels - 1


def _holding_budget(pyr, level: int) -> int:
    """A budget that holds ``level`` and every coarser level whole, plus 2x2x2 windows below."""
    whole = sum(_level_bytes(pyr, l) for l in range(level, pyr.num_levels))
    return int(whole * 1.25) + (8 * level + 8) * pyr.brick_nbytes


def _metrics(img: np.ndarray, ref: np.ndarray) -> dict:

    # the render action returns straight (non-premultiplied) RGBA: composite it over black as such
    p = float(psnr(img, ref, premultiplied=False))
    return {
        "pct_de6": round(float(percent_delta_e(img, ref, threshold=6.0, premultiplied=False)), 4),
        "rmse": round(float(rmse(img, ref, premultiplied=False)), 4),
        "psnr": round(p, 3) if np.isfinite(p) else p,
    }


def _row(s: _Setting, view: int, kind: str, frame: int, **values) -> dict:
    row = {
        "sweep": s.sweep, "setting": s.label, "lod_threshold": s.lod_threshold, "memory_budget": s.memory_budget,
        "texture_budget": s.texture_budget, "selection": s.selection, "level": "" if s.level is None else s.level,
        "view": view, "kind": kind, "frame": frame,
    }
    row.update(values)
    return {k: row.get(k, "") for k in REPORT_COLUMNS}


def _settle(sess, cam, coi, timeout: float, max_passes: int = 32) -> int:
    """Bring the view to its converged state; returns the bytes uploaded meanwhile.

    Waits until the clip-texture is idle (every brick of its windows loaded or failed), then renders
    without waiting until the frame is converged or a pass uploads nothing more. Bounded by
    ``timeout`` and ``max_passes``, so a texture budget too small for the wanted bricks (uploads
    that keep evicting each other) ends the loop instead of spinning.
    """
    t_end = time.perf_counter() + float(timeout)
    sess.set_center(coi)
    sess.clip_texture.wait_until_idle(timeout=timeout)
    uploaded = 0
    for _ in range(max_passes):
        sess.render(cam, coi, wait=False)
        fs = sess.frame_stats
        up = fs.bytes_uploaded
        uploaded += up
        if fs.converged or up == 0 or time.perf_counter() > t_end:
            break
    return uploaded


def _check_failed(label: str, view: int, fs, allow_partial: bool, log) -> None:
    """A converged frame with failed bricks that no verified ancestor stands in for measures the
    error of a hole: refuse (:class:`~clipvol.errors.FrameIncompleteError`), or with
    ``allow_partial`` say so and go on."""
    from ..render.failures import describe_failed

    if not fs.unreplaced:
        return
    text = (f"{label} view {view}: {len(fs.unreplaced)} brick(s) failed and no verified ancestor stands in for them: "
            f"{describe_failed(fs.unreplaced)}")
    if not allow_partial:
        raise FrameIncompleteError(f"{text}; the report would measure a hole as data (allow_partial / --allow-partial "
                                   "writes it anyway)")
    print(f"clipvol report: warning: {text}; its numbers include the missing regions", file=sys.stderr)


def _apply(sess, base: RenderParams, s: _Setting) -> None:
    """Switch ``sess`` to setting ``s`` (only the fields that differ, so the GPU cache is kept)."""
    target = s.params(base)
    ch = {f.name: getattr(target, f.name) for f in fields(target)
          if f.name != "overlays" and getattr(target, f.name) != getattr(sess.params, f.name)}
    if ch:
        sess.update(**ch)


def _warm_frame_s(sess, cam, coi, timeout: float) -> float:
    """Wall time of one converged frame drawn from resident data (what a user waits for per frame
    once the view is loaded). A frame that still had to upload or was not converged is settled and
    timed again, so loading never counts as drawing; a texture budget too small to hold the view
    keeps uploading, and its second timing is the frame that budget gives."""
    _, dt = sess.timed_render(cam, coi, wait=False)
    fs = sess.frame_stats
    if fs.converged and fs.bytes_uploaded == 0:
        return dt
    _settle(sess, cam, coi, timeout)
    return sess.timed_render(cam, coi, wait=False)[1]


def _time_block(ref, entries, views, rounds: int, base: RenderParams, timeout: float, block: int,
                raw: list[dict]) -> dict:
    """Time every ``(session, setting)`` entry on every view against the reference ``ref`` (a
    ``(session, setting)`` too), warm, interleaved and paired.

    Every entry and the reference are first warmed (their views converged and drawn once,
    untimed). Then each of ``rounds`` rounds goes through the entries (forward on even rounds,
    backward on odd ones) and, per view, draws a **pair**: the reference frame and the setting's
    frame one right after the other (which comes first alternates), so that the load of a shared
    machine, which drifts over seconds, weighs on both frames of a pair alike. Each frame is the
    second of two drawn in a row for its setting and view: the first takes what a change of
    setting or view costs once (a new cut, the image policy's visibility estimate), so the time is
    that of the frames a user gets while holding or slowly turning a view. Returns
    ``{"times": {(label, view): [s, ...]}, "ratios": {(label, view): [reference s / setting s per
    pair]}}`` and appends one raw row per timed frame to ``raw`` (its ``pair`` column joins the
    two frames of a pair).
    """
    for sess, s in [ref, *entries]:
        _apply(sess, base, s)
        for cam, coi in views:
            sess.render(cam, coi, wait=True, timeout=timeout)
            _settle(sess, cam, coi, timeout)
            _warm_frame_s(sess, cam, coi, timeout)
    times: dict = {}
    ratios: dict = {}
    pair = 0
    for r in range(rounds):
        for entry in (entries if r % 2 == 0 else entries[::-1]):
            for v, (cam, coi) in enumerate(views):
                got = {}
                for sess, s in ((ref, entry) if (r + v) % 2 == 0 else (entry, ref)):
                    _apply(sess, base, s)
                    sess.render(cam, coi, wait=False)  # what a change of setting or view costs once
                    dt = _warm_frame_s(sess, cam, coi, timeout)
                    got[s.label] = dt
                    times.setdefault((s.label, v), []).append(dt)
                    raw.append({"block": block, "pair": pair, "round": r, "sweep": s.sweep, "setting": s.label,
                                "view": v, "frame_s": round(dt, 6),
                                "host_s": round(sess.frame_stats.host_ms / 1e3, 6)})  # the host's share (FrameStats)
                label = entry[1].label
                ratios.setdefault((label, v), []).append(got[ref[1].label] / max(got[label], 1e-9))
                pair += 1
    return {"times": times, "ratios": ratios}


def _timing_values(block: dict, ref_label: str, label: str, view: int) -> dict:
    """Median, spread and speed-up of one setting on one view: the speed-up is the median over its
    pairs of the reference's frame time over its own (:func:`_time_block`)."""
    t = np.asarray(block["times"][(label, view)], dtype=np.float64)
    ref = float(np.median(block["times"][(ref_label, view)]))
    med = float(np.median(t))
    return dict(frame_s=round(med, 6), frame_min_s=round(float(t.min()), 6), frame_max_s=round(float(t.max()), 6),
                rounds=len(t), ref_frame_s=round(ref, 6),
                speedup=round(float(np.median(block["ratios"][(label, view)])), 4))


def _cold_setting(s: _Setting, loader, ctx, views, refs, *, base: RenderParams, tf, threads, timeout, max_frames,
                  log, keep_frames: dict | None, allow_partial: bool = False) -> list[dict]:
    """The cold half of one setting: a new session (empty clip-texture and GPU cache) per setting.

    Per view: the frames a user sees as the bricks stream in (``as-it-comes`` rows, until the frame
    is converged or ``max_frames``), then the time until the view is converged (``converge_s``:
    view 0 from the new, cold clip-texture; later views from the previous view's state) and the
    converged frame's bricks, bytes and error. Its warm frame time is measured afterwards by
    :func:`_time_block`, interleaved with the reference.
    """
    rows: list[dict] = []
    brick_bytes = loader.pyramid.brick_nbytes
    with RenderSession(loader, ctx, memory_budget=s.memory_budget, texture_budget=s.texture_budget,
                       threads=threads, params=s.params(base), tf=tf) as sess:
        for v, (cam, coi) in enumerate(views):
            ref = refs[v] if refs is not None else None
            t_view = time.perf_counter()
            # the loader threads start at construction: the first view counts from there
            loaded0 = int(sess.texture_stats.bytes_loaded) if v else 0
            uploaded = 0
            conv = False
            # frames as they come, until the frame is converged (or the frame limit)
            for k in range(max_frames):
                img, dt = sess.timed_render(cam, coi, wait=False)
                fs = sess.frame_stats
                uploaded += fs.bytes_uploaded
                conv = fs.converged
                if ref is not None:
                    rows.append(_row(
                        s, v, "as-it-comes", k, elapsed_s=round(time.perf_counter() - t_view, 6), frame_s=round(dt, 6),
                        converged=int(conv), bricks_drawn=fs.bricks_distinct, texels_drawn=fs.texels_drawn,
                        bytes_needed=fs.bricks_distinct * brick_bytes, bytes_loaded=int(sess.texture_stats.bytes_loaded) - loaded0,
                        bytes_uploaded=uploaded, resident_mb=round(sess.texture_stats.resident_bytes / 1e6, 3),
                        **_metrics(img, ref),
                    ))
                if conv:
                    break
            uploaded += _settle(sess, cam, coi, timeout)
            converge_s = time.perf_counter() - t_view
            img = sess.render(cam, coi, wait=False)
            fs = sess.frame_stats
            _check_failed(s.label, v, fs, allow_partial, log)
            values = dict(
                elapsed_s=round(time.perf_counter() - t_view, 6), converge_s=round(converge_s, 6),
                converged=int(fs.converged), bricks_drawn=fs.bricks_distinct,
                texels_drawn=fs.texels_drawn, bytes_needed=fs.bricks_distinct * brick_bytes,
                bytes_loaded=int(sess.texture_stats.bytes_loaded) - loaded0, bytes_uploaded=uploaded,
                resident_mb=round(sess.texture_stats.resident_bytes / 1e6, 3),
            )
            if ref is not None:
                values.update(_metrics(img, ref))
            else:
                values.update(pct_de6=0.0, rmse=0.0, psnr=float("inf"))
            rows.append(_row(s, v, "converged", 0, **values))
            if keep_frames is not None:
                keep_frames[(s.label, v)] = img
            if log:
                log(f"  {s.label:>14} view {v}: converged in {converge_s * 1e3:7.1f} ms, {values['bricks_drawn']:4d} bricks, "
                    f"{values['pct_de6']:.2f} % pixels dE>=6")
    return rows


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

    Returns
    -------
    ReportResult
    """

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    thresholds = [float(t) for t in thresholds]
    if any(not (np.isfinite(t) and t > 0) for t in thresholds):
        raise ParameterError(f"thresholds: expected values > 0 pixels, got {thresholds}")
    if int(views) < 1:
        raise ParameterError(f"views: expected >= 1, got {views!r}")
    if frame not in FRAMES:
        raise ParameterError(f"frame: expected one of {', '.join(FRAMES)}, got {frame!r}")
    if int(max_frames) < 1:
        raise ParameterError(f"max_frames: expected >= 1, got {max_frames!r}")
    if isinstance(rounds, bool) or int(rounds) != rounds or int(rounds) < 1:
        raise ParameterError(f"rounds: expected an integer >= 1, got {rounds!r}")
    rounds = int(rounds)
    # validated before anything is drawn: fractions in (0, 1] (RenderParams names max_error when not)
    max_errors = [RenderParams(policy="image", max_error=e).max_error
                  for e in (DEFAULT_MAX_ERRORS if max_errors is None else max_errors)]
    refines = [(p.step, p.refine_tolerance) for p in (RenderParams(step=st, refine_tolerance=tol)
                                                      for st, tol in (DEFAULT_REFINES if refines is None else refines))]
    loader = open_loader(source)
    pyr = loader.pyramid
    cap = parse_bytes(reference_cap, "reference_cap")
    ref_level = _reference_level(pyr, cap)
    full_mem = _holding_budget(pyr, ref_level)
    full_tex = full_mem
    from ..scene.views import patient_path

    path_name, path_kwargs = patient_path(path, getattr(loader, "frame", None))  # head-up for a patient
    framed = None
    if frame == "visible" and mode == "composite" and path_name in ("orbit", "turntable"):
        pts = visible_points(loader, resolve_tf(tf, loader))  # None: nothing visible, frame the volume
        if pts is not None:
            path_kwargs["fit"] = pts
            framed = (pts.min(axis=0), pts.max(axis=0))
    cams = list(make_path(path_name, pyr, int(views), size=size, **path_kwargs))
    result = ReportResult(out_dir=out, csv=out / "report.csv", markdown=out / "report.md", reference_level=ref_level,
                          rounds=rounds, framed=framed)
    base = RenderParams(mode=mode, iso_value=iso_value, step=step, texture_budget=full_tex)
    own_ctx = ctx is None
    if own_ctx:
        ctx = create_context()
    kw = dict(base=base, tf=tf, threads=threads, timeout=timeout, max_frames=int(max_frames), log=log,
              allow_partial=bool(allow_partial))
    try:
        # 0. one throwaway frame, so that what the process does once (shader compilation, driver
        #    set-up) is not charged to the first setting's cold time
        with RenderSession(loader, ctx, memory_budget=full_mem, texture_budget=full_tex, threads=threads,
                           params=replace(base, policy="fixed", level=pyr.num_levels - 1), tf=tf) as sess:
            sess.render(*cams[0], wait=True, timeout=timeout)
        # 1. cold: the full-resolution reference of every view, then each setting from a new session
        if log:
            log(f"reference: fixed level {ref_level}, converged, {len(cams)} views at {size[0]}x{size[1]}, framing "
                + ("the volume" if framed is None else "the visible voxels within " + " x ".join(
                    f"{a:.4g}..{b:.4g}" for a, b in zip(*framed))))
        fixed = _Setting("fixed", f"fixed L{ref_level}", 1.0, full_mem, full_tex, "fixed", ref_level)
        frames: dict = {}
        rows = _cold_setting(fixed, loader, ctx, cams, None, keep_frames=frames, **kw)
        refs = [frames[(fixed.label, v)] for v in range(len(cams))]
        result.rows.extend(rows)
        from PIL import Image

        from .annotate import present

        frame = getattr(loader, "frame", None)  # a patient-frame store's images: un-mirrored and lettered
        for v, ref in enumerate(refs):
            p = out / f"reference_view{v}.png"
            Image.fromarray(present(ref, cams[v][0], frame), "RGBA").save(p)
            result.images.append(p)
        settings = [_Setting("lod_threshold", f"lod={t:g}", t, full_mem, full_tex) for t in thresholds]
        total = _holding_budget(pyr, 0)
        if memory_budgets is None:
            mmin = minimum_budget(pyr)
            memory_budgets = sorted({max(total // 2, mmin), max(total // 8, mmin)}, reverse=True)
        for m in memory_budgets:
            m = parse_bytes(m, "memory_budgets")
            settings.append(_Setting("memory_budget", f"mem={format_bytes(m)}", 1.0, m, full_tex))
        if texture_budgets is None:
            texture_budgets = [total // 2, total // 8]
        for t in texture_budgets:
            t = parse_bytes(t, "texture_budgets")
            settings.append(_Setting("texture_budget", f"tex={format_bytes(t)}", 1.0, full_mem, t))
        for e in max_errors:
            settings.append(_Setting("max_error", f"max-error={100 * e:g}%", 1.0, full_mem, full_tex, "image", None,
                                     (("max_error", e),)))
        for st, tol in refines if mode == "composite" else ():
            settings.append(_Setting("refine", f"step={st:g} refine={tol:g}", 1.0, full_mem, full_tex, "fixed", 0,
                                     (("step", st), ("refine_tolerance", tol))))
        measured = [fixed]
        for s in settings:
            try:
                result.rows.extend(_cold_setting(s, loader, ctx, cams, refs,
                                                 keep_frames=frames if s.sweep == "lod_threshold" else None, **kw))
                measured.append(s)
            except FrameIncompleteError:
                raise
            except ClipvolError as e:  # a budget too small for this pyramid: say so, go on
                result.skipped.append(f"{s.label}: {e}")
                if log:
                    log(f"  {s.label}: skipped ({e})")
        # 2. warm: every setting drawn by one session that holds everything is timed in one block,
        #    each frame paired with a reference frame; each budget setting has its own session,
        #    timed in a block of its own paired with the reference session again
        budgets = DEFAULT_BLOCK_BUDGETS if block_budgets is None else tuple(int(b) for b in block_budgets)
        shared = [s for s in measured if s.memory_budget == full_mem and s.texture_budget == full_tex]
        own = [s for s in measured if s not in shared]
        timing: dict = {}  # label -> its block's times and paired ratios
        with RenderSession(loader, ctx, memory_budget=full_mem, texture_budget=full_tex, threads=threads,
                           params=fixed.params(base), tf=tf) as main:
            # error against block budget per policy (Wang, Garcia & Shen 2007, Fig. 6), same views
            if budgets:
                if log:
                    log(f"block budgets {list(budgets)}: projected size, distance, image-based")
                lsk = []
                result.lod_rows = lod_sweep(main, cams, refs, budgets, timeout=timeout,
                                            log=lambda m: (lsk.append(m) if "skipped" in m else None, log and log(m)),
                                            check=lambda label, v, fs: _check_failed(label, v, fs, allow_partial, log))
                result.skipped += [m.strip() for m in lsk]
                texels = int(np.prod(pyr.brick_shape))
                for pol, b in dict.fromkeys((r["policy"], r["budget"]) for r in result.lod_rows):
                    ch = policy_changes(pol, b, texels)
                    shared.append(_Setting("block_budget", f"{pol} b={b}", float(ch.pop("lod_threshold", 1.0)),
                                           full_mem, full_tex, ch.pop("policy"), None, tuple(sorted(ch.items()))))
            if log:
                log(f"timing: {len(shared)} settings x {len(cams)} views, warm, {rounds} interleaved rounds")
            others = [s for s in shared if s is not fixed]
            blk = _time_block((main, fixed), [(main, s) for s in others], cams, rounds, base, timeout, 0,
                              result.timing_rows)
            timing.update({s.label: blk for s in others})
            for k, s in enumerate(own, 1):
                with RenderSession(loader, ctx, memory_budget=s.memory_budget, texture_budget=s.texture_budget,
                                   threads=threads, params=s.params(base), tf=tf) as sess:
                    timing[s.label] = _time_block((main, fixed), [(sess, s)], cams, rounds, base, timeout, k,
                                                  result.timing_rows)
        for r in result.rows:
            if r["kind"] != "converged":
                continue
            if r["setting"] == fixed.label:  # the reference against itself: its own frames, speed-up 1
                key = (fixed.label, int(r["view"]))
                t = next((b["times"][key] for b in (blk, *timing.values()) if b["times"].get(key)), None)
                if t is None:  # no setting was timed: nothing was paired with it
                    continue
                r.update(_timing_values({"times": {(fixed.label, 0): t}, "ratios": {(fixed.label, 0): [1.0]}},
                                        fixed.label, fixed.label, 0))
            elif r["setting"] in timing:
                r.update(_timing_values(timing[r["setting"]], fixed.label, r["setting"], int(r["view"])))
        for r in result.lod_rows:
            label = f"{r['policy']} b={r['budget']}"
            r.update(_timing_values(timing[label], fixed.label, label, int(r["view"])))
        if log:
            for s in summarise(result.rows, result.lod_rows):
                log(f"  {s['setting']:>24}: {s['frame_s'] * 1e3:8.1f} ms [{s['frame_min_s'] * 1e3:.1f}-"
                    f"{s['frame_max_s'] * 1e3:.1f}], {s['speedup']:5.2f}x, {s['pct_de6']:6.2f} % pixels dE>=6")
        for t in thresholds:
            img = frames.get((f"lod={t:g}", 0))
            if img is not None:
                p = out / f"view0_lod{t:g}.png"
                Image.fromarray(present(img, cams[0][0], frame), "RGBA").save(p)
                result.images.append(p)
    finally:
        if own_ctx:
            ctx.release()
    result.headline = headline(summarise(result.rows, result.lod_rows), rounds=rounds, views=len(cams))
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
    _markdown(result, pyr, size=size, path=path, tf=tf, mode=mode, step=step, cap=cap)
    return result


# -- summaries -----------------------------------------------------------------------------------
def _converged(rows: list[dict], sweep: str | None = None) -> list[dict]:
    return [r for r in rows if r["kind"] == "converged" and (sweep is None or r["sweep"] == sweep)]


def _by_setting(rows: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in rows:
        out.setdefault(r["setting"], []).append(r)
    return out


def _nan(v) -> float:
    return float("nan") if v in ("", None) else float(v)


def summarise(rows: list[dict], lod_rows: Sequence[dict] = ()) -> list[dict]:
    """Per setting, over views: the warm frame time (mean of the per-view medians, and of their
    minima and maxima), the speed-up against the full-resolution reference (the geometric mean over
    views of each view's speed-up, itself the median over its pairs of the reference's frame time
    over the setting's), time to converge, bricks, bytes and errors (mean, and the worst view's
    ``% ΔE ≥ 6``). ``lod_rows`` adds the block-budget policies (sweep ``"block_budget"``)."""
    groups = [(rs[0]["sweep"], label, rs) for label, rs in _by_setting(_converged(rows)).items()]
    by_pb: dict = {}
    for r in lod_rows:
        by_pb.setdefault(f"{r['policy']} b={r['budget']}", []).append(
            dict(r, bricks_drawn=r["blocks"], lod_threshold="", converge_s="", bytes_needed="", bytes_loaded="",
                 rmse="", psnr=""))
    groups += [("block_budget", label, rs) for label, rs in by_pb.items()]
    out = []
    for sweep, label, rs in groups:
        def mean(k):
            return float(np.mean([_nan(r.get(k, "")) for r in rs]))

        sp = np.array([_nan(r.get("speedup", "")) for r in rs])
        out.append({
            "sweep": sweep, "setting": label, "lod_threshold": rs[0]["lod_threshold"],
            "frame_s": mean("frame_s"), "frame_min_s": mean("frame_min_s"), "frame_max_s": mean("frame_max_s"),
            "ref_frame_s": mean("ref_frame_s"),
            "speedup": float(np.exp(np.mean(np.log(sp)))) if np.all(sp > 0) else float("nan"),
            "converge_s": mean("converge_s"), "bricks_drawn": mean("bricks_drawn"),
            "bytes_needed": mean("bytes_needed"), "bytes_loaded": mean("bytes_loaded"), "pct_de6": mean("pct_de6"),
            "pct_de6_max": max(_nan(r["pct_de6"]) for r in rs),
            "rmse": mean("rmse"), "psnr": float(np.mean([min(_nan(r["psnr"]), 99.0) for r in rs])),
        })
    return out


def headline(summary: Sequence[dict], *, rounds: int, views: int, target: float = VISIBLE_TARGET) -> str:
    """The report's answer in one sentence: how much faster frames are at <= ``target`` % of pixels
    visibly different (CIELUV ΔE >= 6) on every view, with the setting that gets there, or that no
    setting does. The speed-up is against the full-resolution frame drawn by the same path."""
    ref = next((s for s in summary if s["sweep"] == "fixed"), None)
    rest = [s for s in summary if s["sweep"] != "fixed" and np.isfinite(s["speedup"])]
    how = (f"warm frames, each paired with a reference frame; medians of {rounds} interleaved rounds over "
           f"{views} view{'s' * (views != 1)}")
    if ref is None or not rest:
        return "no setting was timed against the full-resolution reference"
    ok = [s for s in rest if s["pct_de6_max"] <= target]
    if not ok:
        best = min(rest, key=lambda s: s["pct_de6_max"])
        return (f"no setting reaches <= {target:g} % of pixels visibly different (CIELUV dE >= 6) on every view; "
                f"the closest, {best['setting']}, has {best['pct_de6_max']:.2f} % at {best['speedup']:.2f}x the "
                f"speed of the full-resolution frame ({how})")
    best = max(ok, key=lambda s: s["speedup"])
    times = f"{_fmt_ms(best['frame_s'])} ms against {_fmt_ms(best['ref_frame_s'])} ms for {ref['setting']}"
    if best["speedup"] < 1.0:
        return (f"at <= {target:g} % of pixels visibly different (CIELUV dE >= 6) no setting is faster than the "
                f"full-resolution frame: the fastest, {best['setting']}, takes {1 / best['speedup']:.2f}x its time "
                f"({times}; {how})")
    return (f"at <= {target:g} % of pixels visibly different (CIELUV dE >= 6), frames are {best['speedup']:.1f}x "
            f"faster than the full-resolution frame (setting {best['setting']}, {best['pct_de6_max']:.2f} % on its "
            f"worst view: {times}; {how})")


def _plots(rows: list[dict], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summ = summarise(rows)
    fixed = [s for s in summ if s["sweep"] == "fixed"]
    sweeps = [("lod_threshold", "LOD threshold sweep", "o-"), ("memory_budget", "memory budget (lod=1)", "s--"),
              ("texture_budget", "texture budget (lod=1)", "^:"), ("max_error", "image policy, error budget", "d-."),
              ("refine", "adaptive image sampling", "v-")]
    files = []
    for xkey, aic_key, xlabel, aic_label, name in (
        ("frame_s", "elapsed_s", "converged frame time (s, mean over views)", "time since the view changed (s)", "error_vs_time.png"),
        ("bytes_needed", "bytes_loaded", "bytes of the bricks drawn (MB, mean over views)", "bytes loaded since the view changed (MB)", "error_vs_bytes.png"),
    ):
        scale = 1e-6 if "bytes" in xkey else 1.0
        ascale = 1e-6 if "bytes" in aic_key else 1.0
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4), dpi=90)
        for sweep, label, style in sweeps:
            pts = sorted((s for s in summ if s["sweep"] == sweep), key=lambda s: s[xkey])
            if not pts:
                continue
            a1.plot([s[xkey] * scale for s in pts], [s["pct_de6"] for s in pts], style, label=label)
            for s in pts:
                a1.annotate(s["setting"].split("=")[-1], (s[xkey] * scale, s["pct_de6"]), textcoords="offset points", xytext=(4, 3), fontsize=7)
        for s in fixed:
            a1.plot([s[xkey] * scale], [s["pct_de6"]], "k*", markersize=10, label=s["setting"] + " (reference)")
        xs = [s[xkey] * scale for s in summ if s[xkey] > 0]
        if xs and max(xs) / min(xs) > 20:
            a1.set_xscale("log")
        a1.set_xlabel(xlabel)
        a1.set_ylabel("% pixels with ΔE ≥ 6 (CIELUV)")
        a1.set_title("converged frames")
        a1.grid(alpha=0.3)
        a1.legend(fontsize=7)
        aic = [r for r in rows if r["kind"] == "as-it-comes" and r["view"] == 0]
        cmap = plt.get_cmap("viridis")
        labels = list(dict.fromkeys(r["setting"] for r in aic))
        for i, lab in enumerate(labels):
            rs = [r for r in aic if r["setting"] == lab]
            a2.plot([float(r[aic_key]) * ascale for r in rs], [float(r["pct_de6"]) for r in rs], ".-",
                    color=cmap(i / max(len(labels) - 1, 1)), label=lab)
        a2.set_xlabel(aic_label)
        a2.set_ylabel("% pixels with ΔE ≥ 6 (CIELUV)")
        a2.set_title("as-it-comes frames (first view, cold start)")
        a2.grid(alpha=0.3)
        if labels:
            a2.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        p = out / name
        fig.savefig(p)
        plt.close(fig)
        files.append(p)
    return files


def _fmt_ms(s: float) -> str:
    return "-" if not np.isfinite(s) else f"{s * 1e3:.1f}"


def _fmt_bytes(b: float) -> str:
    return "-" if not np.isfinite(b) else format_bytes(b)


def _markdown(result: ReportResult, pyr, *, size, path, tf, mode, step, cap) -> None:
    rows = result.rows
    summ = summarise(rows, result.lod_rows)
    ref_label = f"fixed L{result.reference_level}"
    lines = [
        "# clipvol report: image error against run time",
        "",
        f"**{result.headline[:1].upper() + result.headline[1:]}.**",
        "",
        f"Data: {' x '.join(map(str, pyr.shape))} voxels (z, y, x), {pyr.dtype}, brick {pyr.brick_shape[0]}, "
        f"{pyr.num_levels} levels. Views: {len({r['view'] for r in rows})} along the `{path}` path, "
        f"{size[0]}x{size[1]} pixels, `{mode}`, transfer function `{tf if isinstance(tf, str) else (getattr(tf, 'name', None) or 'custom')}`, step {step}; "
        + ("framing the whole volume." if result.framed is None else
           "framing the voxels the transfer function makes visible (within "
           + " x ".join(f"{a:.4g}..{b:.4g}" for a, b in zip(*result.framed)) + ", x y z), from where they fill the views."),
        "",
        f"Reference: `{ref_label}` (fixed level {result.reference_level}, converged"
        + (", level 0 exceeds the reference cap of " + format_bytes(cap) if result.reference_level else "")
        + "), drawn by the same renderer with the same parameters as every setting. Error: % of pixels with ΔE ≥ 6 in CIELUV "
          "(a difference people notice; the quality measure of [4]), RMSE and PSNR on 8-bit RGB.",
        "",
        f"Timing: every setting and the reference are warmed (their views loaded and drawn once), then "
        f"drawn over {result.rounds} interleaved rounds in this process (settings in forward order on even "
        "rounds, reverse on odd ones; each view drawn twice in a row, the second frame timed, so that what "
        "a change of setting or view costs once is not counted). `frame ms` is the median of the rounds "
        "(mean over views), `spread` "
        "their minimum and maximum. Each of the setting's frames is paired with a frame of the reference "
        "drawn right before or after it; `speed-up` is the median over the pairs of the reference's time "
        "over the setting's (geometric mean over views). `converge ms` is the time from a new, cold "
        "clip-texture (view 0; later views: from the previous view) until the frame is converged. "
        "Raw timings: `timing.csv`.",
        "",
        "## Converged frames per setting (means over views)",
        "",
        "| sweep | setting | frame ms | spread ms | speed-up | converge ms | bricks | bytes needed | bytes loaded "
        "| % ΔE≥6 | worst view | RMSE | PSNR dB |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for s in summ:
        rm = "-" if not np.isfinite(s["rmse"]) else f"{s['rmse']:.2f}"
        ps = "-" if not np.isfinite(s["psnr"]) else f"{s['psnr']:.1f}"
        lines.append(
            f"| {s['sweep']} | {s['setting']} | {_fmt_ms(s['frame_s'])} | {_fmt_ms(s['frame_min_s'])}-"
            f"{_fmt_ms(s['frame_max_s'])} | {s['speedup']:.2f}x | {_fmt_ms(s['converge_s'])} | {s['bricks_drawn']:.0f} | "
            f"{_fmt_bytes(s['bytes_needed'])} | {_fmt_bytes(s['bytes_loaded'])} | {s['pct_de6']:.2f} | "
            f"{s['pct_de6_max']:.2f} | {rm} | {ps} |"
        )
    fixed = {r["view"]: r for r in _converged(rows, "fixed")}
    lods = sorted({float(r["lod_threshold"]) for r in _converged(rows, "lod_threshold")}, key=lambda t: (abs(np.log(t)), t))
    lod = lods[0] if lods else 1.0  # the threshold nearest 1 pixel
    multi = {r["view"]: r for r in _converged(rows, "lod_threshold") if float(r["lod_threshold"]) == lod}
    if fixed and multi:
        lines += [
            "",
            "## Bricks and time, fixed vs multiresolution (as tabulated in [2])",
            "",
            f"| view | {ref_label} bricks | {ref_label} ms | multires (lod={lod:g}) bricks | multires ms | speed-up | % ΔE≥6 |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for v in sorted(fixed):
            if v not in multi:
                continue
            f, m = fixed[v], multi[v]
            sp = float(m["speedup"])
            lines.append(f"| {v} | {f['bricks_drawn']} | {_fmt_ms(float(f['frame_s']))} | {m['bricks_drawn']} | "
                         f"{_fmt_ms(float(m['frame_s']))} | {sp:.2f}x | {float(m['pct_de6']):.2f} |")
        lines += [
            "",
            "## Bytes, fixed vs multiresolution (as tabulated in [3])",
            "",
            "`needed` = bytes of the bricks the converged frame draws; `loaded` = what the clip-texture read "
            "while the view converged (it pages whole windows around the centre of interest, warm from the "
            "previous view).",
            "",
            f"| view | {ref_label} needed | multires (lod={lod:g}) needed | ratio | {ref_label} loaded | multires loaded |",
            "| --- | ---: | ---: | ---: | ---: | ---: |",
        ]
        for v in sorted(fixed):
            if v not in multi:
                continue
            f, m = fixed[v], multi[v]
            ratio = float(f["bytes_needed"]) / max(float(m["bytes_needed"]), 1.0)
            lines.append(f"| {v} | {format_bytes(float(f['bytes_needed']))} | {format_bytes(float(m['bytes_needed']))} | {ratio:.1f}x | "
                         f"{format_bytes(float(f['bytes_loaded']))} | {format_bytes(float(m['bytes_loaded']))} |")
    if result.lod_rows:
        lines += ["", "## Error against block budget (after Wang, Garcia & Shen 2007, Fig. 6)", "",
                  "Bricks drawn (distinct) for each policy at the same block budgets; `% dE>=6` against the "
                  "full-resolution frame, mean over views. Raw rows: `lod_budget.csv`.", "",
                  "| policy | budget | bricks | % px dE>=6 |", "| --- | ---: | ---: | ---: |"]
        seen: dict = {}
        for r in result.lod_rows:
            seen.setdefault((r["policy"], r["budget"]), []).append(r)
        for (pol, b), rs in seen.items():
            lines.append(f"| {pol} | {b} | {np.mean([r['blocks'] for r in rs]):.0f} | "
                         f"{np.mean([r['pct_de6'] for r in rs]):.2f} |")
        for pol in dict.fromkeys(r["policy"] for r in result.lod_rows):
            best = blocks_to_reach(result.lod_rows, pol, 5.0)
            lines.append(f"\n{pol}: fewest bricks at <= 5 % pixels dE>=6 on some view: "
                         + (f"{best['blocks']} (view {best['view']})" if best else "not reached"))
    if result.plots:
        lines += ["", "## Plots", ""]
        for p in result.plots:
            lines.append(f"![{p.stem}]({p.name})")
            lines.append("")
    if result.skipped:
        lines += ["", "## Skipped settings", ""] + [f"- {s}" for s in result.skipped]
    lines += ["", "Raw numbers, one row per frame: `report.csv`.", "", "## References", ""]
    lines += [f"{i}. {ref}" for i, ref in enumerate(REFERENCES, 1)] + [""]
    result.markdown.write_text("\n".join(lines))
