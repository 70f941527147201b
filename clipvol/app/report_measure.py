"""The report's measuring: cold and warm frames of every setting, each against the converged picture.

Part of ``clipvol report`` (:mod:`clipvol.app.report` is the entry; :mod:`.report_summary` sums the
rows up, :mod:`.report_plot` and :mod:`.report_markdown` write them out). Per setting and view it
draws, cold (a new session: an empty clip-texture and GPU cache), the **as-it-comes** frames until
the frame converges and the converged frame's bricks, bytes and error; then, warm, every setting
and the full-resolution frame in interleaved rounds, each frame of a setting paired with a
full-resolution frame drawn right before or after it (:func:`_time_block`).

What an error is measured against: the **converged picture** of the view
(:class:`~clipvol.app.converged.ConvergedPictures`: level 0 at a quarter-voxel step, supersampled
and box-filtered), drawn once per view. The full-resolution frame (fixed level 0 at the report's
step) is measured against it like every setting - its own error is the floor that every setting
drawn at that step shares - and it stays the frame the speed-ups are taken against.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..bricking.spread import spread_dtype
from ..errors import ClipvolError, FrameIncompleteError, ParameterError
from ..paging.toroidal import minimum_budget
from ..render.context import create_context
from ..scene.framing import visible_points
from ..scene.metrics import percent_delta_e, psnr, rmse
from ..scene.params import RenderParams
from ..scene.paths import make_path
from ..units import format_bytes, parse_bytes
from .converged import CONVERGED_STEP, CONVERGED_SUPERSAMPLE, ConvergedPictures
from .lod_sweep import DEFAULT_BLOCK_BUDGETS, lod_sweep, policy_changes
from .report_summary import summarise
from .session import RenderSession, open_loader, resolve_tf

__all__ = ["ReportFiles", "ReportResult", "measure", "REPORT_COLUMNS", "TIMING_COLUMNS", "DEFAULT_THRESHOLDS",
           "DEFAULT_MAX_ERRORS", "DEFAULT_REFINES", "FRAMES"]

DEFAULT_THRESHOLDS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
#: the image policy's visible-error budgets (RenderParams.max_error) the report sweeps by default
DEFAULT_MAX_ERRORS = (0.10, 0.05, 0.02)
#: one level sampled at ``step`` voxels with adaptive image sampling at ``refine_tolerance``
#: (:mod:`clipvol.render.refine`), the settings of the sweep "refine" by default: ``(step,
#: tolerance)`` at the reference level, ``(step, tolerance, level)`` at a coarser one. Level 1 is in
#: it for stores with consistent coarse levels (:mod:`clipvol.bricking.spread`): classified as the
#: distribution of the voxels beneath, level 1 at step 1 with adaptive sampling was the fastest
#: setting within 5 % on close views of the MNI template (9.3-11.3x the full-resolution frame;
#: docs/benchmarks.md, "Multi-level cuts, consistent level 1 at speed"). Level 0 at step 2.5 with
#: tolerance 0.25 is the setting that reaches >= 5x at <= 5 % in the report on the template's
#: overviews at 512² (6.4x at 4.83 % on the worst of three views, where 0.3 is at 4.99-5.04 % and
#: 0.2 slower; docs/benchmarks.md, "`clipvol report` on the template: >= 5x at <= 5 %")
DEFAULT_REFINES = ((2.0, 0.16), (2.0, 0.25), (2.5, 0.2), (2.5, 0.25), (2.5, 0.3), (1.0, 0.08, 1), (1.0, 0.16, 1))
#: what the orbit's views frame (run_report's ``frame``)
FRAMES = ("visible", "volume")

REPORT_COLUMNS = (
    "sweep", "setting", "lod_threshold", "memory_budget", "texture_budget", "selection", "level",
    "view", "kind", "frame", "elapsed_s", "frame_s", "converge_s", "converged", "bricks_drawn",
    "texels_drawn", "bytes_needed", "bytes_loaded", "bytes_uploaded", "resident_mb",
    "pct_de6", "rmse", "psnr", "frame_min_s", "frame_max_s", "rounds", "ref_frame_s", "speedup",
    "predicted_pct_de6",
)

#: the raw timings, one row per warm frame (``timing.csv``): block 0 holds every setting drawn by the
#: session that holds everything, block k > 0 one budget setting beside the reference; the two
#: frames of a ``pair`` (the reference's and a setting's) were drawn one right after the other
TIMING_COLUMNS = ("block", "pair", "round", "sweep", "setting", "view", "frame_s", "host_s")


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
    #: what every error is measured against (:meth:`ConvergedPictures.describe`)
    converged: str = ""

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


def _refine_setting(spec) -> tuple[float, float, int | None]:
    """``(step, tolerance[, level])`` checked (RenderParams names ``step`` or ``refine_tolerance``;
    a level must be a whole number >= 0): ``(step, tolerance, level or None)``, None meaning the
    reference level."""
    spec = tuple(spec)
    if len(spec) not in (2, 3):
        raise ParameterError(f"refines: expected (step, tolerance) or (step, tolerance, level), got {spec!r}")
    p = RenderParams(step=spec[0], refine_tolerance=spec[1])
    level = None
    if len(spec) == 3:
        lv = spec[2]
        if isinstance(lv, bool) or int(lv) != lv or int(lv) < 0:
            raise ParameterError(f"refines: expected a level >= 0 as the third value, got {lv!r}")
        level = int(lv)
    return p.step, p.refine_tolerance, level


def _level_bytes(pyr, level: int) -> int:
    return pyr.num_bricks(level) * pyr.brick_nbytes


def _reference_level(pyr, cap: int) -> int:
    """Finest level whose bricks, with all coarser levels, fit in ``cap`` bytes."""
    for L in range(pyr.num_levels):
        if sum(_level_bytes(pyr, l) for l in range(L, pyr.num_levels)) <= cap:
            return L
    return pyr.num_levels - 1


def _holding_budgets(loader, level: int) -> tuple[int, int]:
    """Memory and texture budgets that hold ``level`` and every coarser level whole, plus 2x2x2
    windows below.

    A store with consistent coarse levels (:mod:`clipvol.bricking.spread`) holds each coarse
    brick's spread beside it: the clip-texture keeps the spread in its memory budget, and the GPU
    cache counts every level at two channels (:class:`~clipvol.render.gpu_cache.GpuBrickCache`).
    A budget sized for the means alone holds half the pyramid on the GPU, and every change between
    the reference and a coarse setting evicts and uploads again (what the report used to time).
    """
    pyr = loader.pyramid
    spread = set(getattr(loader, "spread_levels", ()) or ())
    sp = spread_dtype(pyr.dtype).itemsize * int(np.prod(pyr.brick_shape)) if spread else 0
    levels = range(level, pyr.num_levels)
    mem = sum(_level_bytes(pyr, L) + (pyr.num_bricks(L) * sp if L in spread else 0) for L in levels)
    channels = 2 if spread else 1
    tex = sum(_level_bytes(pyr, L) for L in levels) * channels
    windows = (8 * level + 8) * pyr.brick_nbytes
    return int(mem * 1.25) + windows + (8 * level + 8) * sp, int(tex * 1.25) + windows * channels


def _metrics(img: np.ndarray, ref: np.ndarray) -> dict:

    # the render action returns straight (non-premultiplied) RGBA: composite it over black as such
    p = float(psnr(img, ref, premultiplied=False))
    return {
        "pct_de6": round(float(percent_delta_e(img, ref, threshold=6.0, premultiplied=False)), 4),
        "rmse": round(float(rmse(img, ref, premultiplied=False)), 4),
        "psnr": round(p, 3) if np.isfinite(p) else p,
    }


def _predicted_pct(sess) -> float | None:
    """The image policy's own estimate of the frame's % of pixels with Delta E >= 6 against the converged
    picture (:attr:`~clipvol.scene.selection.policies.image_based.ImageBased.estimated_error`), or None
    for a policy that makes none: the report prints it beside the measurement, so a reader sees how far
    the budget ``--max-error`` can be trusted on this data."""
    est = getattr(getattr(sess.action, "last_policy", None), "estimated_error", None)
    if est is None or not np.isfinite(est):
        return None
    return round(100.0 * float(est), 4)


def _row(s: _Setting, view: int, kind: str, frame: int, **values) -> dict:
    row = {
        "sweep": s.sweep, "setting": s.label, "lod_threshold": s.lod_threshold, "memory_budget": s.memory_budget,
        "texture_budget": s.texture_budget, "selection": s.selection, "level": "" if s.level is None else s.level,
        "view": view, "kind": kind, "frame": frame,
    }
    row.update(values)
    return {k: row.get(k, "") for k in REPORT_COLUMNS}


def _settle(sess, cam, coi, timeout: float) -> int:
    """Bring the view to its converged state; returns the bytes uploaded meanwhile.

    Waits until the clip-texture is idle (every brick of its windows loaded or failed), then draws
    one frame that waits (:meth:`~clipvol.render.frame_loop.FrameLoop.run` with ``wait=True``: it
    selects and uploads pass after pass without drawing until the cut is converged, the texture
    budget cannot hold the view at once, or ``timeout`` runs out). A frame drawn per upload pass
    instead - as this did before - drew up to 32 frames where one is needed: on a 192^3 store at
    160^2 that was most of the report's time.
    """
    t_end = time.perf_counter() + float(timeout)
    sess.set_center(coi)
    sess.clip_texture.wait_until_idle(timeout=timeout)
    sess.render(cam, coi, wait=True, timeout=max(t_end - time.perf_counter(), 0.0))
    return int(sess.frame_stats.bytes_uploaded)


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


#: untimed frames drawn after a change of setting or view before the timed one: the frame loop
#: selects the new cut from nothing, and keeps a projected-size cut for the frames after it, built
#: from nothing the next frame (:mod:`clipvol.render.frame_loop`, "Coherence"); timing the second
#: frame charged that build to every projected-size setting (the demo's ``lod=1``, the same bricks as
#: the full-resolution frame: 0.87-0.94x its speed, 1.0x when the third is timed)
SETTLING_FRAMES = 2


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
    third of three drawn in a row for its setting and view (:data:`SETTLING_FRAMES`): the first two
    take what a change of setting or view costs once (a new cut and the image policy's visibility
    estimate; then a projected-size cut kept for the next frames, built from nothing in the frame
    after the new cut), so the time is that of the frames a user gets while holding or slowly
    turning a view. Returns
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
                    for _ in range(SETTLING_FRAMES):  # what a change of setting or view costs once
                        sess.render(cam, coi, wait=False)
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
            predicted = _predicted_pct(sess)
            if predicted is not None:
                values["predicted_pct_de6"] = predicted
            rows.append(_row(s, v, "converged", 0, **values))
            if keep_frames is not None:
                keep_frames[(s.label, v)] = img
            if log:
                log(f"  {s.label:>14} view {v}: converged in {converge_s * 1e3:7.1f} ms, {values['bricks_drawn']:4d} bricks, "
                    f"{values['pct_de6']:.2f} % pixels dE>=6"
                    + ("" if predicted is None else f" (predicted {predicted:.2f} %)"))
    return rows




def _converged_pictures(loader, ctx, cams, base: RenderParams, tf, *, level: int, supersample: int, step: float,
                        memory_budget: int, threads, timeout: float, allow_partial: bool, log) -> list[np.ndarray]:
    """The converged picture of every view (:class:`~clipvol.app.converged.ConvergedPictures`), drawn
    by a session of its own that holds ``level`` whole; a frame with failed bricks is refused as in
    :func:`_check_failed`."""
    pics = ConvergedPictures(None, base, supersample=supersample, step=step, level=level)
    with RenderSession(loader, ctx, memory_budget=memory_budget, texture_budget=memory_budget, threads=threads,
                       params=pics.params, tf=tf) as sess:
        at: list = []  # the view being drawn: (index, centre of interest)

        def render(cam, params):
            v, coi = at[-1]
            img = sess.render(cam, coi, wait=True, timeout=timeout)
            if not sess.frame_stats.converged:
                _settle(sess, cam, coi, timeout)
                img = sess.render(cam, coi, wait=False)
            _check_failed("converged picture", v, sess.frame_stats, allow_partial, log)
            return img

        pics.render = render
        out = []
        for v, (cam, coi) in enumerate(cams):
            at.append((v, coi))
            out.append(pics.get(cam, key=v))
    return out


def measure(
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
    """The measuring half of :func:`clipvol.app.report.run_report` (same parameters): draws every
    frame and fills a :class:`ReportResult` (rows, timing rows, block-budget rows, images);
    returns it with the pyramid and the reference cap in bytes, for the summaries and the
    markdown. Nothing but the images is written."""
    # checked before anything is opened or written
    conv_desc = ConvergedPictures(None, RenderParams(), supersample=supersample, step=converged_step).describe()
    RenderParams(classify=classify)  # names classify when it is not one RenderParams knows
    out = Path(out_dir)
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
    refines = [_refine_setting(r) for r in (DEFAULT_REFINES if refines is None else refines)]
    loader = open_loader(source)
    out.mkdir(parents=True, exist_ok=True)
    pyr = loader.pyramid
    cap = parse_bytes(reference_cap, "reference_cap")
    ref_level = _reference_level(pyr, cap)
    full_mem, full_tex = _holding_budgets(loader, ref_level)
    from ..scene.views import patient_path

    path_name, path_kwargs = patient_path(path, getattr(loader, "frame", None))  # head-up for a patient
    framed = None
    if frame == "visible" and mode == "composite" and path_name in ("orbit", "turntable"):
        pts = visible_points(loader, resolve_tf(tf, loader))  # None: nothing visible, frame the volume
        if pts is not None:
            path_kwargs["fit"] = pts
            framed = (pts.min(axis=0), pts.max(axis=0))
    cams = list(make_path(path_name, pyr, int(views), size=size, **path_kwargs))
    conv_desc = ConvergedPictures(None, RenderParams(), supersample=supersample, step=converged_step,
                                  level=ref_level).describe()
    result = ReportResult(out_dir=out, csv=out / "report.csv", markdown=out / "report.md", reference_level=ref_level,
                          rounds=rounds, framed=framed, converged=conv_desc)
    base = RenderParams(mode=mode, iso_value=iso_value, step=step, texture_budget=full_tex, classify=classify)
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
        # 1. the converged picture of every view (what every error is measured against), then,
        #    cold, the full-resolution frame of every view and each setting from a new session
        if log:
            log(f"converged picture: {conv_desc}; {len(cams)} views at {size[0]}x{size[1]}, framing "
                + ("the volume" if framed is None else "the visible voxels within " + " x ".join(
                    f"{a:.4g}..{b:.4g}" for a, b in zip(*framed))))
        refs = _converged_pictures(loader, ctx, cams, base, tf, level=ref_level, supersample=supersample,
                                   step=converged_step, memory_budget=full_mem, threads=threads, timeout=timeout,
                                   allow_partial=allow_partial, log=log)
        fixed = _Setting("fixed", f"fixed L{ref_level}", 1.0, full_mem, full_tex, "fixed", ref_level)
        frames: dict = {}
        rows = _cold_setting(fixed, loader, ctx, cams, refs, keep_frames=frames, **kw)
        result.rows.extend(rows)
        from PIL import Image

        from .annotate import present

        frame = getattr(loader, "frame", None)  # a patient-frame store's images: un-mirrored and lettered
        for v, ref in enumerate(refs):
            for name, img in ((f"reference_view{v}.png", ref), (f"full_resolution_view{v}.png", frames[(fixed.label, v)])):
                p = out / name
                Image.fromarray(present(img, cams[v][0], frame), "RGBA").save(p)
                result.images.append(p)
        settings = [_Setting("lod_threshold", f"lod={t:g}", t, full_mem, full_tex) for t in thresholds]
        total_mem, total_tex = _holding_budgets(loader, 0)
        if memory_budgets is None:
            mmin = minimum_budget(pyr)
            memory_budgets = sorted({max(total_mem // 2, mmin), max(total_mem // 8, mmin)}, reverse=True)
        for m in memory_budgets:
            m = parse_bytes(m, "memory_budgets")
            settings.append(_Setting("memory_budget", f"mem={format_bytes(m)}", 1.0, m, full_tex))
        if texture_budgets is None:
            texture_budgets = [total_tex // 2, total_tex // 8]
        for t in texture_budgets:
            t = parse_bytes(t, "texture_budgets")
            settings.append(_Setting("texture_budget", f"tex={format_bytes(t)}", 1.0, full_mem, t))
        for e in max_errors:
            settings.append(_Setting("max_error", f"max-error={100 * e:g}%", 1.0, full_mem, full_tex, "image", None,
                                     (("max_error", e),)))
        for st, tol, lvl in refines if mode == "composite" else ():
            level = ref_level if lvl is None else lvl
            if level >= pyr.num_levels or level < ref_level:
                result.skipped.append(f"step={st:g} refine={tol:g} at level {level}: the store's levels are "
                                      f"{ref_level}..{pyr.num_levels - 1}")
                continue
            label = f"step={st:g} refine={tol:g}" if level == ref_level else f"L{level} step={st:g} refine={tol:g}"
            settings.append(_Setting("refine", label, 1.0, full_mem, full_tex, "fixed", level,
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
    return result, pyr, cap
