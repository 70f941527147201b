"""Benchmark ``clipvol brick`` against a plain zarr write of level 0, in the same run.

Usage::

    python tools/bench/bench_brick.py [--size 1024] [--workers N] [--brick 64] [--codec lz4]

It builds (once, cached under ``bench-data/``) a uint16 ``.npy`` input of ``size``^3 voxels - the
procedural fractal scaled to the uint16 range, 2 GiB at the default 1024 - then, each in its own
child process so that peak resident memory is that run's alone (its ``VmHWM``):

1. bricks it with :func:`clipvol.bricking.pipeline.brick_volume` (all levels, statistics, ``workers`` threads);
2. writes the same level 0 with zarr-python alone: same chunks and codec, ``arr[z0:z1] = slab``
   slab by slab with ``zarr.config.set({'threading.max_workers': workers})``.

Both read the input from the page cache (it was just written or read). The ratio is
``zarr time / brick time`` (bricking throughput relative to zarr's; target >= 0.7) although the
bricker does more work (every level, 8/7 of the voxels, plus statistics). Results go to
``tools/bench/results/bench_brick.csv`` and the bricking section of ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from common import REPO, RESULTS  # noqa: E402  (tools/bench/common.py)
ROOT = REPO
#: what is measured (a wrapper that patches something in names it here)
VARIANT = "as shipped"

_HWM = r"""
def _hwm_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
"""

_BRICK_CHILD = _HWM + r"""
import json, sys, time
import numcodecs, tqdm, zarr  # imported before the clock starts, as in the zarr child
from clipvol.bricking.pipeline import brick_volume
a = json.loads(sys.argv[1])
t, c = time.perf_counter(), time.process_time()
brick_volume(a["input"], a["output"], brick=a["brick"], codec=a["codec"], workers=a["workers"], overwrite=True, progress=False,
             summary=False)  # the pyramid and statistics only; summary tables: tools/bench_lod.py
print(json.dumps({"seconds": time.perf_counter() - t, "cpu": time.process_time() - c, "rss_mb": _hwm_mb()}))
"""

_ZARR_CHILD = _HWM + r"""
import json, sys, time
import numpy as np, zarr
from clipvol.bricking.pipeline import store_codecs
a = json.loads(sys.argv[1])
src = np.load(a["input"], mmap_mode="r")
b = a["brick"]
t, c = time.perf_counter(), time.process_time()
with zarr.config.set({"threading.max_workers": a["workers"]}):
    arr = zarr.create_array(a["output"], shape=src.shape, chunks=(b, b, b), dtype=src.dtype, fill_value=0,
                            compressors=store_codecs(a["codec"], src.dtype), dimension_names=["z", "y", "x"],
                            config={"write_empty_chunks": False}, overwrite=True)
    for z0 in range(0, src.shape[0], b):
        slab = np.array(src[z0:z0 + b])  # a copy, as the bricker reads one
        arr[z0:z0 + b] = slab
        del slab
print(json.dumps({"seconds": time.perf_counter() - t, "cpu": time.process_time() - c, "rss_mb": _hwm_mb()}))
"""


def make_input(size: int, data_dir: Path) -> Path:
    """The cached uint16 input of ``size``^3 voxels (procedural fractal scaled to 0..65535)."""
    from clipvol.bricking.generators import parse_procedural

    path = data_dir / f"fractal_{size}_uint16.npy"
    if path.exists():
        return path
    data_dir.mkdir(parents=True, exist_ok=True)
    gen = parse_procedural(f"procedural:fractal?size={size}&seed=1")
    tmp = path.with_suffix(".partial")
    out = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint16, shape=(size,) * 3)
    step = max(1, (32 << 20) // (size * size * 4))
    for z0 in range(0, size, step):
        z1 = min(z0 + step, size)
        v = gen.region(0, (z0, 0, 0), (z1, size, size))
        out[z0:z1] = np.clip(np.rint(v * 65535.0), 0, 65535).astype(np.uint16)
        out.flush()
    del out
    os.replace(tmp, path)
    return path


def _child(code: str, args: dict) -> tuple[float, float, float]:
    """Run ``code`` in a fresh interpreter; return (seconds, CPU seconds, peak RSS in MB) it reports.

    The peak is the child's own ``VmHWM`` (the high-water mark of its address space since
    ``exec``); ``ru_maxrss`` would include the parent's resident set at ``fork`` time.
    """
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(args)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"child failed ({proc.returncode}):\n{proc.stderr}")
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    return res["seconds"], res["cpu"], res["rss_mb"]


def _du(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=1024, help="edge of the cubic uint16 input (1024 = 2 GiB)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--brick", type=int, default=64)
    p.add_argument("--codec", default="lz4")
    p.add_argument("--data-dir", type=Path, default=ROOT / "bench-data")
    p.add_argument("--docs", type=Path, default=RESULTS)
    p.add_argument("--repeat", type=int, default=1, help="runs of each; the best time is kept")
    args = p.parse_args(argv)

    t = time.perf_counter()
    src = make_input(args.size, args.data_dir)
    print(f"input {src} ready in {time.perf_counter() - t:.1f} s", flush=True)
    nbytes = src.stat().st_size
    with open(src, "rb") as f:  # warm the page cache for both runs alike
        while f.read(64 << 20):
            pass
    work = args.data_dir / "out"
    work.mkdir(parents=True, exist_ok=True)
    common = {"input": str(src), "brick": args.brick, "codec": args.codec, "workers": args.workers}
    brick_s, brick_rss, zarr_s, zarr_rss, brick_cpu, zarr_cpu = [], [], [], [], [], []
    for _ in range(args.repeat):
        for d in ("plain.zarr", "bricked.zarr"):  # deleting is not part of either timing
            shutil.rmtree(work / d, ignore_errors=True)
        s, c, r = _child(_ZARR_CHILD, {**common, "output": str(work / "plain.zarr")})
        zarr_s.append(s)
        zarr_cpu.append(c)
        zarr_rss.append(r)
        print(f"zarr level-0 write: {s:.2f} s ({c:.2f} s CPU), peak RSS {r:.0f} MB", flush=True)
        s, c, r = _child(_BRICK_CHILD, {**common, "output": str(work / "bricked.zarr")})
        brick_s.append(s)
        brick_cpu.append(c)
        brick_rss.append(r)
        print(f"clipvol brick:      {s:.2f} s ({c:.2f} s CPU), peak RSS {r:.0f} MB", flush=True)
    bs, zs = min(brick_s), min(zarr_s)
    mb = nbytes / 1e6
    bricked_bytes = _du(work / "bricked.zarr")
    plain_bytes = _du(work / "plain.zarr")
    row = {
        "date": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "machine": f"{platform.machine()} {os.cpu_count()} cores",
        "variant": VARIANT,
        "shape": f"{args.size}^3",
        "dtype": "uint16",
        "input_MB": round(mb, 1),
        "brick": args.brick,
        "codec": args.codec,
        "workers": args.workers,
        "brick_s": round(bs, 2),
        "brick_MBps": round(mb / bs, 1),
        "zarr_level0_s": round(zs, 2),
        "zarr_level0_MBps": round(mb / zs, 1),
        "ratio": round(zs / bs, 3),
        "brick_cpu_s": round(min(brick_cpu), 2),
        "zarr_cpu_s": round(min(zarr_cpu), 2),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "brick_peak_rss_MB": round(max(brick_rss), 0),
        "zarr_peak_rss_MB": round(max(zarr_rss), 0),
        "store_MB": round(bricked_bytes / 1e6, 1),
        "zarr_level0_MB": round(plain_bytes / 1e6, 1),
    }
    shutil.rmtree(work, ignore_errors=True)
    print(f"bricking: {row['brick_MBps']} MB/s of input; zarr level 0 alone: {row['zarr_level0_MBps']} MB/s; "
          f"ratio {row['ratio']} (target >= 0.7); peak RSS {row['brick_peak_rss_MB']:.0f} MB (target < 600 MB)")
    args.docs.mkdir(parents=True, exist_ok=True)
    csv_path = args.docs / "bench_brick.csv"
    new = not csv_path.exists()
    with open(csv_path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(row))
        if new:
            w.writeheader()
        w.writerow(row)
    print(f"appended to {csv_path}")
    print(f"wrote {plot_csv(csv_path, csv_path.with_suffix('.png'))}")
    return 0


def plot_csv(csv_path: Path, png_path: Path) -> Path:
    """Time and peak RSS of the last run, bricking against zarr's level-0 write, from the CSV."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    row = list(csv.DictReader(open(csv_path)))[-1]
    fig, (a, b) = plt.subplots(1, 2, figsize=(7, 3))
    names = ["clipvol brick\n(all levels + stats)", "zarr write\n(level 0 only)"]
    a.bar(names, [float(row["brick_s"]), float(row["zarr_level0_s"])], color=["tab:green", "tab:gray"])
    a.set_ylabel("seconds")
    a.set_title(f"{row['shape']} {row['dtype']}: ratio {float(row['ratio']):.2f} (target >= 0.7)", fontsize=9)
    b.bar(names, [float(row["brick_peak_rss_MB"]), float(row["zarr_peak_rss_MB"])], color=["tab:green", "tab:gray"])
    b.axhline(600, color="tab:red", ls="--", lw=1, label="600 MB target")
    b.set_ylabel("peak RSS (MB)")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return png_path


if __name__ == "__main__":
    sys.exit(main())
