"""What a kept cut's merge costs on the orbit frames that merge, against the merge from nothing of the
same cut on the same frame.

Along the orbit of ``bench_frame_cost.py --flat`` (the same warm-up, then ``--frames`` frames of 1
degree each, a 32^2 image, ``projected-size``), a render action draws each frame as usual. Where its
:class:`~clipvol.scene.selection.merge.KeptMerge` merges (the cut's leaves changed, or the camera
answers some of the merge's questions otherwise: a culled node moved beside the view or into it),
the same call's items, windows and ``may_cover`` are merged from nothing too
(:func:`~clipvol.scene.selection.merge.merge_items`, the baseline outside the kept path), the two
timed on the rendering thread's CPU (``time.thread_time``) one after the other, the order
alternating, and checked equal entry for entry. Per volume: the merges, the median CPU ms of each
and the median of the per-call ratios kept ÷ from nothing. It runs on an older tree too (it wraps
``KeptMerge.merge``), to measure a change alternately with the tree before it:

    python tools/bench/bench_kept_merge.py --store mni16.zarr --head 512 --frames 48
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_frame_cost  # noqa: E402  (beside this script)
import common  # noqa: E402


def _wrap(calls: list) -> None:
    """Wrap ``KeptMerge.merge`` to time each call and the merge from nothing of its arguments."""
    from clipvol.scene.selection import merge as M

    kept = M.KeptMerge.merge

    def timed(self, items, windows, may_cover=None):
        first = len(calls) % 2 == 0  # (which goes first alternates)
        if not first:
            c = time.thread_time()
            want = M.merge_items(items, self.pyramid, windows, may_cover)
            scratch = time.thread_time() - c
        c = time.thread_time()
        out = kept(self, items, windows, may_cover)
        own = time.thread_time() - c
        if first:
            c = time.thread_time()
            want = M.merge_items(items, self.pyramid, windows, may_cover)
            scratch = time.thread_time() - c
        same = all(np.array_equal(getattr(out, k), getattr(want, k)) for k in ("rows", "lo", "hi", "span"))
        if not same:
            raise RuntimeError("the kept merge differs from the merge from nothing")
        calls.append((own, scratch))
        return out

    M.KeptMerge.merge = timed


def main(argv: list[str] | None = None) -> int:
    ap = common.orbit_parser(__doc__, frames=48)
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_kept_merge.csv")
    a = ap.parse_args(argv)
    entries = common.orbit_stores(a)
    if not entries:
        ap.error("nothing to measure: give --store or --head")
    calls: list = []
    _wrap(calls)
    rows = []
    for store, label in entries:
        scene = common.WarmScene(store)
        try:
            act = scene.action(policy="projected-size", lod_threshold=a.lod, step=bench_frame_cost.STEP)
            cams = bench_frame_cost.cameras(scene.pyramid, a.image, "orbit", a.frames)
            for cam in (*cams, cams[0]):  # the benchmark's warm-up
                act.render(cam, scene.tf, wait=True, timeout=900)
            calls.clear()
            for cam in cams:
                act.render(cam, scene.tf)
            bricks = act.last_frame_stats.bricks_distinct
        finally:
            scene.close()
        row = {"date": time.strftime("%Y-%m-%d"), "volume": label, "image": a.image, "camera": "orbit",
               "frames": a.frames, "bricks": bricks, "merges": len(calls), "load": bench_frame_cost._load()}
        if calls:
            row.update(kept_ms=round(1e3 * statistics.median(c[0] for c in calls), 3),
                       scratch_ms=round(1e3 * statistics.median(c[1] for c in calls), 3),
                       kept_over_scratch=round(statistics.median(c[0] / c[1] for c in calls), 3))
        rows.append(row)
        print(f"{label}: {bricks} bricks, {len(calls)} merges in {a.frames} orbit frames; kept "
              f"{row.get('kept_ms', '-')} ms, from nothing {row.get('scratch_ms', '-')} ms (medians), "
              f"kept / from nothing {row.get('kept_over_scratch', '-')} (median of per-call ratios); "
              f"load {row['load']}")
    return common.save_rows(a.out, rows)


if __name__ == "__main__":
    sys.exit(main())
