"""The report's plots: error against frame time and against bytes, converged and as-it-comes.

Part of ``clipvol report`` (:mod:`clipvol.app.report`); matplotlib with the Agg backend, imported
only here and only when plots are asked for.
"""

from __future__ import annotations

from pathlib import Path

from .report_summary import summarise

__all__ = ["plots"]


def plots(rows: list[dict], out: Path) -> list[Path]:
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
            a1.plot([s[xkey] * scale], [s["pct_de6"]], "k*", markersize=10, label=s["setting"] + " (full resolution)")
        xs = [s[xkey] * scale for s in summ if s[xkey] > 0]
        if xs and max(xs) / min(xs) > 20:
            a1.set_xscale("log")
        a1.set_xlabel(xlabel)
        a1.set_ylabel("% pixels with ΔE ≥ 6 (CIELUV)\nagainst the converged picture")
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


