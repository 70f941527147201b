"""The report's summaries: per-setting means over views, and the one-line answer.

Part of ``clipvol report`` (:mod:`clipvol.app.report`). Reads the rows :mod:`.report_measure`
writes; every error in them is against the converged picture of the view, the full-resolution
frame's (sweep ``"fixed"``) included.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..units import format_bytes

__all__ = ["summarise", "headline", "VISIBLE_TARGET", "nearer_than_full"]

#: the error the report's one-line answer is held to: % of pixels with CIELUV ΔE >= 6
VISIBLE_TARGET = 5.0


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
            "predicted_pct_de6": mean("predicted_pct_de6"),
            "predicted_by_view": [(_nan(r.get("predicted_pct_de6", "")), _nan(r["pct_de6"])) for r in rs],
        })
    return out


def _full_clause(ref: dict | None) -> str:
    """``"; the full-resolution frame itself: 2.10 % (worst view 3.00 %)"``, or nothing when unknown."""
    if ref is None or not np.isfinite(_nan(ref.get("pct_de6_max", ""))):
        return ""
    mean = _nan(ref.get("pct_de6", ref["pct_de6_max"]))
    return (f"; the full-resolution frame itself: {mean:.2f} % (worst view {float(ref['pct_de6_max']):.2f} %) "
            "against the converged picture")


def nearer_than_full(summary: Sequence[dict]) -> list[dict]:
    """The settings faster than the full-resolution frame (speed-up > 1) whose error against the
    converged picture is below the full-resolution frame's on every view and on average (by the
    worst view and the mean): nearer the truth and cheaper. Empty without a full-resolution row."""
    ref = next((s for s in summary if s["sweep"] == "fixed"), None)
    if ref is None:
        return []
    rm, rw = _nan(ref.get("pct_de6", "")), _nan(ref.get("pct_de6_max", ""))
    return [s for s in summary if s["sweep"] != "fixed" and np.isfinite(s["speedup"]) and s["speedup"] > 1.0
            and _nan(s.get("pct_de6", "")) < rm and _nan(s.get("pct_de6_max", "")) <= rw]


def headline(summary: Sequence[dict], *, rounds: int, views: int, target: float = VISIBLE_TARGET) -> str:
    """The report's answer in one sentence: how much faster frames are at <= ``target`` % of pixels
    visibly different (CIELUV ΔE >= 6) from the converged picture on every view, with the setting
    that gets there, or that no setting does; and the full-resolution frame's own error against the
    same picture. The speed-up is against the full-resolution frame drawn by the same path."""
    ref = next((s for s in summary if s["sweep"] == "fixed"), None)
    rest = [s for s in summary if s["sweep"] != "fixed" and np.isfinite(s["speedup"])]
    how = (f"warm frames, each paired with a full-resolution frame; medians of {rounds} interleaved rounds over "
           f"{views} view{'s' * (views != 1)}")
    if ref is None or not rest:
        return "no setting was timed against the full-resolution frame"
    full = _full_clause(ref)
    ok = [s for s in rest if s["pct_de6_max"] <= target]
    if not ok:
        best = min(rest, key=lambda s: s["pct_de6_max"])
        return (f"no setting reaches <= {target:g} % of pixels visibly different (CIELUV dE >= 6) from the converged "
                f"picture on every view; the closest, {best['setting']}, has {best['pct_de6_max']:.2f} % at "
                f"{best['speedup']:.2f}x the speed of the full-resolution frame{full} ({how})")
    best = max(ok, key=lambda s: s["speedup"])
    # the speed-up is the median of the per-round paired ratios, the times the medians of each side's
    # frames: the two can disagree near 1x, so the sentence says which is which
    times = (f"the median of its paired ratios; frame medians {_fmt_ms(best['frame_s'])} ms against "
             f"{_fmt_ms(best['ref_frame_s'])} ms for {ref['setting']}")
    if best["speedup"] < 1.0:
        return (f"at <= {target:g} % of pixels visibly different (CIELUV dE >= 6) from the converged picture no "
                f"setting is faster than the full-resolution frame: the fastest, {best['setting']}, takes "
                f"{1 / best['speedup']:.2f}x its time ({times}{full}; {how})")
    return (f"at <= {target:g} % of pixels visibly different (CIELUV dE >= 6) from the converged picture, frames are "
            f"{best['speedup']:.1f}x faster than the full-resolution frame (setting {best['setting']}, "
            f"{best['pct_de6_max']:.2f} % on its worst view; {times}{full}; {how})")


def _fmt_ms(s: float) -> str:
    return "-" if not np.isfinite(s) else f"{s * 1e3:.1f}"


def _fmt_bytes(b: float) -> str:
    return "-" if not np.isfinite(b) else format_bytes(b)


