"""Benchmark the summary tables (``clipvol summarize``) against the bricking of the same store.

Usage::

    python tools/bench/bench_summary.py [--rounds 3] [--workers N] [--out tools/bench/results/bench_summary.csv]

The summary tables of image-based level of detail (C. Wang, A. Garcia and H.-W. Shen, *Interactive
level-of-detail selection using image-based quality metric for large volume visualization*, IEEE
TVCG 13(1), 2007, section IV-D; :mod:`clipvol.bricking.summary`) read every brick of every level
again after ``clipvol brick`` has written them. For each input, each round times, one after the other in this process:

1. ``brick_volume(..., summary=False, overwrite=True)``: the bricking alone (every level, the
   statistics, checksums and manifest);
2. ``build_summary(..., overwrite=True)`` on that store: the tables alone.

The ratio is ``summary time / bricking time`` (the medians over the rounds; target <= 1: the tables
cost no more than the bricking they follow). Inputs: the MNI ICBM152 2009a T1 template
(197x233x189 uint8, ``/work/data/mni_t1.nii.gz`` or ``--mni``) with 32^3 and 16^3 bricks (identity
quantisation), the procedural fractal, 192^3 float32 with 32^3 bricks, and 256^3 scaled to 12-bit
uint16 words with 64^3 bricks (uniform quantisation over the value range, as a microscope's or a
CT's 16-bit data). ``VARIANT`` names the code measured (a wrapper that patches something in says so).
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

from common import RESULTS  # noqa: E402  (tools/bench/common.py)

#: what is measured
VARIANT = "as shipped"


def _inputs(mni: Path):
    out = []
    if mni.is_file():
        out += [("mni_t1 uint8", str(mni), 32), ("mni_t1 uint8", str(mni), 16)]
    out.append(("fractal-192 float32", "procedural:fractal?size=192", 32))
    from clipvol.bricking.generators import parse_procedural

    frac = parse_procedural("procedural:fractal?size=256").region(0, (0, 0, 0), (256, 256, 256))
    out.append(("fractal-256 uint16 (12-bit)", (frac * 4095).astype("uint16"), 64))  # microscopy-like words
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--mni", type=Path, default=Path("/work/data/mni_t1.nii.gz"))
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_summary.csv")
    args = ap.parse_args(argv)

    from clipvol.bricking.pipeline import brick_volume
    from clipvol.bricking.summary import build_summary

    rows = []
    with tempfile.TemporaryDirectory(prefix="clipvol-bench-summary-") as tmp:
        for name, src, brick in _inputs(args.mni):
            store = Path(tmp) / f"s{brick}.zarr"
            bt, st = [], []
            for _ in range(args.rounds):  # interleaved: bricking, then the tables of what it wrote
                t = time.perf_counter()
                meta = brick_volume(src, store, brick=brick, summary=False, overwrite=True, progress=False,
                                    workers=args.workers)
                bt.append(time.perf_counter() - t)
                t = time.perf_counter()
                build_summary(store, workers=args.workers, progress=False, overwrite=True)
                st.append(time.perf_counter() - t)
            b, s = statistics.median(bt), statistics.median(st)
            row = {"input": name, "shape": "x".join(map(str, meta.pyramid.shape)), "brick": brick,
                   "levels": meta.pyramid.num_levels, "bricks": sum(meta.pyramid.num_bricks(L)
                                                                    for L in range(meta.pyramid.num_levels)),
                   "brick_s": round(b, 3), "summary_s": round(s, 3), "ratio_summary_to_brick": round(s / b, 3),
                   "rounds": args.rounds, "workers": args.workers or os.cpu_count(), "variant": VARIANT,
                   "loadavg": open("/proc/loadavg").read().split()[0], "machine": platform.machine(),
                   "cpus": os.cpu_count(), "date": time.strftime("%Y-%m-%d")}
            rows.append(row)
            print(f"{name} brick {brick}: bricking {b:.2f} s, summary tables {s:.2f} s, ratio {s / b:.2f} "
                  f"(medians of {args.rounds}; load {row['loadavg']})", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    new = not args.out.exists()
    with open(args.out, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        if new:
            w.writeheader()
        w.writerows(rows)
    print(f"rows appended to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
