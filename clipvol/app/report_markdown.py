"""The report's markdown: the answer, the tables per setting, and the papers they follow.

Part of ``clipvol report`` (:mod:`clipvol.app.report`).
"""

from __future__ import annotations

import numpy as np

from ..units import format_bytes
from .lod_sweep import blocks_to_reach
from .report_measure import ReportResult
from .report_summary import _converged, _fmt_bytes, _fmt_ms, nearer_than_full, summarise

__all__ = ["REFERENCES", "write_markdown"]

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


def _estimate_lines(summ: list[dict]) -> list[str]:
    """The settings whose policy predicts its own error (the image policy: ``--max-errors``), the
    prediction beside the measurement per view: how far ``--max-error`` can be trusted on this data
    and these views (the estimate is a model, ``docs/rendering.md``, "The visible-error budget")."""
    est = [s for s in summ if np.isfinite(s.get("predicted_pct_de6", float("nan")))]
    if not est:
        return []
    lines = ["", "## The image policy's estimate against the measurement", "",
             "The image policy predicts the % of pixels with ΔE ≥ 6 against the converged picture from the "
             "store's summary tables and the view, before it draws; `--max-error` stops refining when the "
             "prediction is within the budget. Per view: predicted / measured % (predicted ÷ measured).", "",
             "| setting | predicted % | measured % | per view |", "| --- | ---: | ---: | --- |"]
    for s in est:
        per = "; ".join(f"{p:.2f} / {m:.2f}" + (f" ({p / m:.2f})" if m > 0 else "")
                        for p, m in s["predicted_by_view"] if np.isfinite(p))
        lines.append(f"| {s['setting']} | {s['predicted_pct_de6']:.2f} | {s['pct_de6']:.2f} | {per} |")
    return lines


def write_markdown(result: ReportResult, pyr, *, size, path, tf, mode, step, cap, classify: str = "distribution") -> None:
    rows = result.rows
    summ = summarise(rows, result.lod_rows)
    ref_label = f"fixed L{result.reference_level}"
    full = next((s for s in summ if s["sweep"] == "fixed"), None)
    nearer = nearer_than_full(summ)
    fp = "-" if full is None else f"{full['pct_de6']:.2f}"
    lines = [
        "# clipvol report: image error against run time",
        "",
        f"**{result.headline[:1].upper() + result.headline[1:]}.**",
        "",
        f"Data: {' x '.join(map(str, pyr.shape))} voxels (z, y, x), {pyr.dtype}, brick {pyr.brick_shape[0]}, "
        f"{pyr.num_levels} levels. Views: {len({r['view'] for r in rows})} along the `{path}` path, "
        f"{size[0]}x{size[1]} pixels, `{mode}`, transfer function `{tf if isinstance(tf, str) else (getattr(tf, 'name', None) or 'custom')}`, step {step}, "
        f"coarse levels classified by {'the distribution beneath each voxel' if classify == 'distribution' else 'their mean'} "
        f"(`--classify {classify}`); "
        + ("framing the whole volume." if result.framed is None else
           "framing the voxels the transfer function makes visible (within "
           + " x ".join(f"{a:.4g}..{b:.4g}" for a, b in zip(*result.framed)) + ", x y z), from where they fill the views."),
        "",
        f"Error against the **converged picture** of each view: {result.converged or 'level 0, a fine step, supersampled'}"
        + (" (level 0 exceeds the reference cap of " + format_bytes(cap) + ")" if result.reference_level else "")
        + ", drawn once per view by the same renderer with the same transfer function, mode and lighting. "
          "Error: % of pixels with ΔE ≥ 6 in CIELUV (a difference people notice; the quality measure of [4]), "
          "RMSE and PSNR on 8-bit RGB. The full-resolution frame "
        f"`{ref_label}` (fixed level {result.reference_level} at step {step}, one ray per pixel) is measured "
        "against it like every setting: "
        + (f"{full['pct_de6']:.2f} % of pixels ΔE ≥ 6 (worst view {full['pct_de6_max']:.2f} %), the column "
           "`full res %` beside each setting." if full else "not measured.")
        + (" Nearer the converged picture than the full-resolution frame, and faster: "
           + ", ".join(f"{s['setting']} ({s['pct_de6']:.2f} %, {s['speedup']:.2f}x)" for s in nearer) + "."
           if nearer else ""),
        "",
        f"Speed-ups are against the full-resolution frame `{ref_label}`. "
        f"Timing: every setting and the full-resolution frame are warmed (their views loaded and drawn once), then "
        f"drawn over {result.rounds} interleaved rounds in this process (settings in forward order on even "
        "rounds, reverse on odd ones; each view drawn twice in a row, the second frame timed, so that what "
        "a change of setting or view costs once is not counted). `frame ms` is the median of the rounds "
        "(mean over views), `spread` "
        "their minimum and maximum. Each of the setting's frames is paired with a full-resolution frame "
        "drawn right before or after it; `speed-up` is the median over the pairs of the full-resolution frame's time "
        "over the setting's (geometric mean over views). `converge ms` is the time from a new, cold "
        "clip-texture (view 0; later views: from the previous view) until the frame is converged. "
        "Raw timings: `timing.csv`.",
        "",
        "## Converged frames per setting (means over views)",
        "",
        "| sweep | setting | frame ms | spread ms | speed-up | converge ms | bricks | bytes needed | bytes loaded "
        "| % ΔE≥6 | worst view | full res % | RMSE | PSNR dB |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for s in summ:
        rm = "-" if not np.isfinite(s["rmse"]) else f"{s['rmse']:.2f}"
        ps = "-" if not np.isfinite(s["psnr"]) else f"{s['psnr']:.1f}"
        lines.append(
            f"| {s['sweep']} | {s['setting']} | {_fmt_ms(s['frame_s'])} | {_fmt_ms(s['frame_min_s'])}-"
            f"{_fmt_ms(s['frame_max_s'])} | {s['speedup']:.2f}x | {_fmt_ms(s['converge_s'])} | {s['bricks_drawn']:.0f} | "
            f"{_fmt_bytes(s['bytes_needed'])} | {_fmt_bytes(s['bytes_loaded'])} | {s['pct_de6']:.2f} | "
            f"{s['pct_de6_max']:.2f} | {fp} | {rm} | {ps} |"
        )
    lines += _estimate_lines(summ)
    fixed = {r["view"]: r for r in _converged(rows, "fixed")}
    lods = sorted({float(r["lod_threshold"]) for r in _converged(rows, "lod_threshold")}, key=lambda t: (abs(np.log(t)), t))
    lod = lods[0] if lods else 1.0  # the threshold nearest 1 pixel
    multi = {r["view"]: r for r in _converged(rows, "lod_threshold") if float(r["lod_threshold"]) == lod}
    if fixed and multi:
        lines += [
            "",
            "## Bricks and time, fixed vs multiresolution (as tabulated in [2])",
            "",
            f"| view | {ref_label} bricks | {ref_label} ms | {ref_label} % ΔE≥6 | multires (lod={lod:g}) bricks | multires ms "
            "| speed-up | % ΔE≥6 |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for v in sorted(fixed):
            if v not in multi:
                continue
            f, m = fixed[v], multi[v]
            sp = float(m["speedup"])
            lines.append(f"| {v} | {f['bricks_drawn']} | {_fmt_ms(float(f['frame_s']))} | {float(f['pct_de6']):.2f} | "
                         f"{m['bricks_drawn']} | "
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
                  "converged picture, mean over views. Raw rows: `lod_budget.csv`.", "",
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

