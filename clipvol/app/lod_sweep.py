"""Image error against block budget for several selection policies on the same views (seed Fig. 6).

After Wang, Garcia & Shen (2007), Fig. 6: the percentage of pixels with CIELUV Delta E >= 6 against
the converged picture (the report passes its references; :mod:`clipvol.app.converged`), as a
function of the number of bricks drawn. Every policy gets the same
budgets: the ``"image"`` policy through ``block_budget``, the others (projected size, distance)
through their greedy form under ``max_texels_drawn = budget * texels per brick`` - the same
traversal, refining the node their own rule ranks first. Each point is a converged frame; the
x value is the distinct bricks actually drawn.

Used by ``clipvol report`` (its ``lod_budget.png``) and ``tools/bench/bench_lod.py``.

References
----------
C. Wang, A. Garcia, H.-W. Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality
Metric for Large Volume Visualization", IEEE TVCG 13(1), 2007.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..scene.metrics import percent_delta_e

__all__ = ["LOD_POLICIES", "DEFAULT_BLOCK_BUDGETS", "policy_changes", "lod_sweep", "blocks_to_reach", "plot_lod_sweep",
           "scan_crossing"]

#: label -> RenderParams changes of the compared policies (budget applied by :func:`policy_changes`)
#: (the refine predicates of projected size and distance are opened wide so that the budget, not
#: their threshold, decides how far they refine; their rule still decides the order)
LOD_POLICIES = {
    "projected size": dict(policy="projected-size", lod_threshold=1.0 / 64.0),
    "distance": dict(policy="distance", distance_factor=1e9),
    "image (no visibility)": dict(policy="image", visibility=False),
    "image": dict(policy="image", visibility=True),
}
DEFAULT_BLOCK_BUDGETS = (8, 16, 32, 64, 128, 256)


def policy_changes(label: str, budget: int, texels_per_brick: int) -> dict:
    """The :class:`~clipvol.scene.params.RenderParams` changes of policy ``label`` at ``budget`` bricks."""
    ch = dict(LOD_POLICIES[label])
    if ch["policy"] == "image":
        ch.update(block_budget=int(budget), max_texels_drawn=None)
    else:
        ch.update(max_texels_drawn=int(budget) * int(texels_per_brick), block_budget=None)
    return ch


def lod_sweep(session, views, refs, budgets: Sequence[int] = DEFAULT_BLOCK_BUDGETS,
              policies: Sequence[str] = tuple(LOD_POLICIES), *, timeout: float = 120.0, repeats: int = 1,
              log: Callable[[str], None] | None = None, check: Callable | None = None) -> list[dict]:
    """Converged frames of every policy and budget on every view, compared with ``refs``.

    ``session`` is a :class:`~clipvol.app.session.RenderSession` whose budgets hold the views;
    ``views`` a list of ``(camera, centre)``; ``refs`` the full-resolution images. Returns rows with
    ``policy``, ``budget``, ``view``, ``blocks`` (distinct bricks drawn), ``pct_de6`` and ``frame_s``
    (the best of ``repeats`` warm frames). A policy the data cannot serve (no summary tables) is
    reported once through ``log`` and left out. ``check(label, view, frame_stats)``, optional, sees
    every converged frame before it is measured (the report refuses one with failed bricks that no
    ancestor stands in for, :class:`~clipvol.errors.FrameIncompleteError`, which is never skipped).
    """
    from ..errors import ClipvolError, FrameIncompleteError

    texels = int(np.prod(session.pyramid.brick_shape))
    rows: list[dict] = []
    for label in policies:
        try:
            for b in budgets:
                session.update(**policy_changes(label, b, texels))
                for v, (cam, coi) in enumerate(views):
                    session.render(cam, coi, wait=True, timeout=timeout)
                    best, img = float("inf"), None
                    for _ in range(max(1, repeats)):
                        t0 = time.perf_counter()
                        img = session.render(cam, coi, wait=False)
                        best = min(best, time.perf_counter() - t0)
                    fs = session.frame_stats
                    if check is not None:
                        check(f"{label} b={b}", v, fs)
                    rows.append(dict(policy=label, budget=int(b), view=v, blocks=int(fs.bricks_distinct),
                                     pct_de6=round(percent_delta_e(img, refs[v]), 4), frame_s=round(best, 6),
                                     converged=int(fs.converged)))
                    if log:
                        log(f"  {label:>22} budget {b:5d} view {v}: {fs.bricks_distinct:5d} bricks, "
                            f"{rows[-1]['pct_de6']:6.2f} % pixels dE>=6, {best * 1e3:7.1f} ms")
        except FrameIncompleteError:
            raise
        except ClipvolError as e:
            rows = [r for r in rows if r["policy"] != label]
            if log:
                log(f"  {label}: skipped ({e})")
    return rows


def blocks_to_reach(rows: list[dict], policy: str, target: float = 5.0, view: int | None = None) -> dict | None:
    """The row with the fewest bricks drawn whose error is at most ``target`` % (None: none reached it)."""
    ok = [r for r in rows if r["policy"] == policy and r["pct_de6"] <= target and (view is None or r["view"] == view)]
    return min(ok, key=lambda r: (r["blocks"], r["pct_de6"])) if ok else None


def scan_crossing(measure: Callable[[float], tuple[int, float]], points: dict, *, integer: bool, target: float = 5.0,
                  step: int = 2, margin: float = 1.0, max_points: int = 96) -> dict:
    """Refine a coarse sweep around its crossing of ``target`` until neighbours differ by <= ``step`` bricks.

    ``points`` maps a parameter value (a block budget, or a ``lod_threshold``) to ``(blocks, pct)``
    of the coarse sweep; ``measure(value)`` renders one more point. The error is not monotone in the
    bricks drawn, so nothing is bisected: every interval between two points adjacent in bricks drawn,
    at or below the fewest-bricks point reaching ``target`` and with an end within ``margin``
    percentage points of it, is *scanned* - integer parameters (budgets) every ``step``, real ones
    (thresholds) at geometric steps, as many as the interval's bricks over ``step`` - and the
    scan repeats on the new neighbours (a threshold's bricks jump) until every such interval is at
    most ``step`` bricks wide, cannot be split further, or ``max_points`` new points were measured.
    Returns the new points ``{value: (blocks, pct)}`` (``points`` is updated in place).
    """
    new: dict = {}
    tried: set = set(points)
    while len(new) < max_points:
        ok = [(b, v) for v, (b, e) in points.items() if e <= target]
        if not ok:
            break
        p_blocks = min(ok)[0]
        by_blocks = sorted((b, v, e) for v, (b, e) in points.items() if b <= p_blocks)
        todo: list = []
        for (b0, v0, e0), (b1, v1, e1) in zip(by_blocks, by_blocks[1:]):
            if b1 - b0 <= step or min(e0, e1) > target + margin:
                continue
            lo, hi = sorted((v0, v1))
            n = int(np.ceil((b1 - b0) / step)) - 1
            if integer:
                cand = range(int(lo) + step, int(hi), step) if hi - lo > step else range(int(lo) + 1, int(hi))
            elif hi / lo > 1.0 + 1e-3:
                cand = np.geomspace(lo, hi, n + 2)[1:-1].round(4).tolist()
            else:
                cand = []
            todo += [c for c in cand if c not in tried]
        if not todo:
            break
        for c in todo[: max_points - len(new)]:
            tried.add(c)
            new[c] = points[c] = measure(c)
    return new


def plot_lod_sweep(rows: list[dict], path: Path, title: str = "", target: float = 5.0) -> Path | None:
    """``% pixels dE >= 6`` against bricks drawn, one curve per policy (mean over views); None
    without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import matplotlib.ticker
    except ImportError:  # pragma: no cover
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for label in dict.fromkeys(r["policy"] for r in rows):
        pts: dict[int, list] = {}
        for r in rows:
            if r["policy"] == label:
                pts.setdefault(r["budget"], []).append((r["blocks"], r["pct_de6"]))
        xs = [np.mean([p[0] for p in v]) for _, v in sorted(pts.items())]
        ys = [np.mean([p[1] for p in v]) for _, v in sorted(pts.items())]
        ax.plot(xs, ys, marker="o", label=label)
    ax.axhline(target, color="grey", lw=0.8, ls="--")
    ax.set_xscale("log")
    xs_all = [r["blocks"] for r in rows] or [1]
    ticks = [b for b in (8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096) if min(xs_all) / 1.5 <= b <= max(xs_all) * 1.5]
    ax.set_xticks(ticks, [str(b) for b in ticks])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("bricks drawn (distinct, mean over views)")
    ax.set_ylabel("% of pixels with CIELUV ΔE ≥ 6\nagainst the converged picture")
    ax.set_title(title or "error against block budget (after Wang, Garcia & Shen 2007, Fig. 6)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
