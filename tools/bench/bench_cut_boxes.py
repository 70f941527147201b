"""What a multi-level cut costs to draw: the same bricks as one box, as a few boxes, as one node each.

Why this exists: projected-size cuts that mix levels (``lod_threshold`` 4 / 8 on the MNI template:
44 level-1 bricks and one level-2 brick) drew slower than the full-resolution frame, while fixed
level 1 (48 bricks, one merged box) drew 1.1-1.6x faster. Every frame here is warm and converged and
timed in the same interleaved rounds (forward order on even rounds, reverse on odd), median of
``--repeat``; the raw one-texture caster of level 0 (:class:`common.RawCaster`, at clipvol's stop)
is the reference outside clipvol's render path. Configurations (``RenderParams`` changes):

* ``L1 one box`` - fixed level 1, merged into one box, the per-brick path (``path="auto"``);
* ``L1 one box, single pass`` - the same through the page table (one node);
* ``L1 48 nodes, single pass`` - the same bricks unmerged (``merge_boxes=False``): one page-table
  node per brick, one level;
* ``L2 one box, single pass`` - fixed level 2 (8 bricks, one node);
* ``mixed, single pass`` / ``mixed, bricks`` - the projected-size cut at ``--threshold`` (default
  4) with evening out turned off (the paper's rule alone: levels 1 and 2, merged into 8 boxes),
  drawn by either path;
* ``mixed unmerged, single pass`` - that cut one node per brick;
* ``evened`` - the same threshold with evening out (the policy as it is).

Run ``python tools/bench/bench_cut_boxes.py --store mni32.zarr`` (a store with summary tables is
not needed); rows go to ``tools/bench/results/bench_cut_boxes.csv``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_mission  # noqa: E402  (its views)
import common  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, required=True)
    ap.add_argument("--image", type=int, default=256)
    ap.add_argument("--views", default="iso,face")
    ap.add_argument("--threshold", type=float, default=4.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_cut_boxes.csv")
    a = ap.parse_args(argv)

    import clipvol.scene.selection.policies.projected_size as ps
    from clipvol.render.paths.setup import OPAQUE

    scene = common.WarmScene(a.store)
    pyr, tf = scene.pyramid, scene.tf
    raw = scene.raw_caster()
    mixed = dict(policy="projected-size", lod_threshold=a.threshold)
    conf = {"L1 one box": dict(policy="fixed", level=1),
            "L1 one box, single pass": dict(policy="fixed", level=1, path="single-pass"),
            "L1 48 nodes, single pass": dict(policy="fixed", level=1, path="single-pass", merge_boxes=False),
            "L2 one box, single pass": dict(policy="fixed", level=2, path="single-pass"),
            "mixed, single pass": dict(mixed, path="single-pass"),
            "mixed, bricks": dict(mixed, path="bricks"),
            "mixed unmerged, single pass": dict(mixed, path="single-pass", merge_boxes=False),
            "evened": dict(mixed)}
    unevened = {"mixed, single pass", "mixed, bricks", "mixed unmerged, single pass"}
    acts = {k: scene.action(step=0.5, **kw) for k, kw in conf.items()}
    even_out = ps.even_out

    def render(k, cam, **kw):
        ps.even_out = (lambda r, *x, **y: np.asarray(r, dtype=bool)) if k in unevened else even_out
        try:
            return acts[k].render(cam, tf, **kw)
        finally:
            ps.even_out = even_out

    rows = []
    try:
        for view, cam in bench_mission.views(pyr, a.image).items():
            if view not in a.views.split(","):
                continue
            for k in acts:
                render(k, cam, wait=True, timeout=600)
            fc = acts["L1 one box"]._selection_camera(cam)
            names = ["raw", *acts]
            times = {k: [] for k in names}
            for r in range(a.repeat):
                for k in (names if r % 2 == 0 else names[::-1]):
                    t0 = time.perf_counter()
                    if k == "raw":
                        raw.render(fc, tf, 0.5, OPAQUE)
                    else:
                        render(k, cam)
                    times[k].append(time.perf_counter() - t0)
            base = times["L1 one box"]
            for k in acts:
                act = acts[k]
                sel = act.last_selection
                levels = sorted({int(it.level) for it in sel.items})
                row = dict(date=time.strftime("%Y-%m-%d"), store=a.store.name, image=a.image, view=view, config=k,
                           bricks=len(sel.items), levels="/".join(map(str, levels)), path=act.path_drawn,
                           boxes=act.boxes_drawn, nodes=act.page_table_nodes, rounds=a.repeat,
                           ms=round(1e3 * statistics.median(times[k]), 1),
                           over_one_box=round(statistics.median(t / b for t, b in zip(times[k], base)), 3),
                           over_raw=round(statistics.median(t / w for t, w in zip(times[k], times["raw"])), 3))
                rows.append(row)
                print(f"{a.image}^2 {view:5} {k:28} {row['bricks']:3d} bricks L{row['levels']:5} {row['path']:11} "
                      f"boxes {row['boxes']} nodes {row['nodes']:3d}: {row['ms']:7.1f} ms, {row['over_one_box']:.2f}x "
                      f"L1 one box, {row['over_raw']:.2f}x raw", flush=True)
    finally:
        scene.close()
    return common.save_rows(a.out, rows)


if __name__ == "__main__":
    sys.exit(main())
