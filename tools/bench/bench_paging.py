"""Paging benchmark: ClipTexture loader throughput against zarr-python and against the decode floor.

Why these references: a brick of a clipvol store is one zarr chunk, so the fastest anything can
page it in is "read the chunk file, decode it" (the *floor*, here with numcodecs in a tight loop
on the same number of threads), and the obvious alternative is zarr-python's own chunk-aligned
``arr[...]`` reads from the same threads. All three read the *same list of bricks* - the ones
the ClipTexture loaded while roaming - in one run, with the page cache warmed first, so the ratios
compare CPU paths (decode, copies, locking, per-call overhead), not the disk.

Measured, in a child process so its peak resident memory is the clip-texture's own:

* loader MB/s of a ClipTexture (``memory_budget``, default 256 MB) whose centre roams across the
  volume one level-0 brick per step, waiting until idle at each step;
* time to converge (every brick of every window resident) after a jump across the volume;
* peak RSS against the budget (target: at most budget + 200 MB).

Run ``python tools/bench/bench_paging.py`` (a >= 2 GiB procedural fractal store, cached under
``bench-data/``) or ``--quick`` for a small run. Results go to ``tools/bench/results/bench_paging.csv`` and a
summary is printed; ``docs/benchmarks.md`` discusses them.
"""

from __future__ import annotations

import argparse
import csv
import multiprocessing as mp
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from common import DATA, RESULTS, fractal_store  # noqa: E402  (tools/bench/common.py)
FULL = {"size": "512x1024x1024", "brick": 64, "budget": "256MB"}  # 2 GiB of float32
PASSES = 10
QUICK = {"size": "96x192x192", "brick": 32, "budget": "12MB"}


def _chunk_path(store: Path, level: int, idx) -> Path:
    return store / str(level) / "c" / str(idx[0]) / str(idx[1]) / str(idx[2])


def warm_cache(store: Path, keys) -> int:
    n = 0
    for L, idx in set(keys):
        p = _chunk_path(store, L, idx)
        if p.is_file():
            n += len(p.read_bytes())
    return n


class _Recording:
    """Loader proxy that records the bricks read (in call order)."""

    def __init__(self, loader):
        self._loader = loader
        self.pyramid = loader.pyramid
        self.keys: list[tuple[int, tuple[int, int, int]]] = []

        if hasattr(loader, "read_brick_into"):
            self.read_brick_into = self._read_brick_into

    def read_brick(self, level, index):
        self.keys.append((level, tuple(index)))  # list.append is atomic under the GIL
        return self._loader.read_brick(level, index)

    def _read_brick_into(self, level, index, out):
        self.keys.append((level, tuple(index)))
        self._loader.read_brick_into(level, index, out)


class _CopyOnly:
    """The zarr loader without its ``read_brick_into``: the clip-texture then copies each brick
    returned by ``read_brick`` into its slot (the 'copy' variant, to show what zero-copy gains)."""

    def __init__(self, loader) -> None:
        self._loader = loader
        self.pyramid = loader.pyramid

    def read_brick(self, level, index):
        return self._loader.read_brick(level, index)


def _rss_sampler(stop: threading.Event, peak: list[int]) -> None:
    import psutil

    proc = psutil.Process()
    while not stop.is_set():
        peak[0] = max(peak[0], proc.memory_info().rss)
        stop.wait(0.01)


def _vm_hwm() -> int:
    """Peak RSS of this process image (Linux ``VmHWM``; unlike ``ru_maxrss`` it does not carry the
    parent's size over the fork/exec that spawned us). 0 where unavailable."""
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _entering(ct, before: list) -> list:
    """Bricks ``(level, index)`` in the clip-texture's windows now that were not in ``before``."""
    from clipvol.paging.toroidal import window_diff

    keys = []
    for L, old in enumerate(before):
        new = ct.window(L)
        if new != old:
            keys += [(L, tuple(int(v) for v in b)) for b in window_diff(old, new)[0]]
    return keys


def roam_child(store: str, budget: str, threads: int, out_q, go_q, direct: bool = False, sync: bool = False) -> None:
    """Child process: roam a ClipTexture over the store; report MB/s, convergence, RSS, bricks.

    ``sync``: wait until idle after every step. Otherwise the roaming is pipelined like a viewer
    that keeps moving: before step ``k + 1`` it waits only for the bricks that entered at step
    ``k - 1`` (``wait_for``), so the loader threads always have the current step's bricks queued.
    """
    import numpy as np
    import psutil
    from clipvol.loaders.zarr_store import ZarrLoader

    from clipvol.paging.cliptexture import ClipTexture

    loader = _Recording(ZarrLoader(store) if direct else _CopyOnly(ZarrLoader(store)))
    pyr = loader.pyramid
    baseline = psutil.Process().memory_info().rss
    stop, peak = threading.Event(), [baseline]
    sampler = threading.Thread(target=_rss_sampler, args=(stop, peak), daemon=True)
    sampler.start()
    lo, hi = pyr.volume_box()
    mid = (lo + hi) / 2
    step = pyr.brick_shape[2] * pyr.spacing[2]
    xs = np.arange(lo[0] + step / 2, hi[0], step)
    path = [np.array([x, mid[1] + 0.25 * (hi[1] - lo[1]) * np.sin(i / 3), mid[2]]) for i, x in enumerate(xs)]
    ct = ClipTexture(loader, budget, threads, center=path[0])
    ct.wait_until_idle()
    for p in range(PASSES):  # across the volume and back: each pass timed on its own
        before, n_keys, t0 = ct.stats, len(loader.keys), time.perf_counter()
        prev: list = []
        for c in (path if p % 2 == 0 else path[::-1]):
            windows = [ct.window(L) for L in range(pyr.num_levels)]
            ct.set_center(c)
            if sync:
                ct.wait_until_idle()
            else:
                ct.wait_for(prev)
                prev = _entering(ct, windows)
        ct.wait_until_idle()
        seconds = time.perf_counter() - t0
        after = ct.stats
        out_q.put({"keys": loader.keys[n_keys:], "seconds": seconds,
                   "bytes": after.bytes_loaded - before.bytes_loaded, "loads": after.loads_total - before.loads_total})
        go_q.get()  # the parent runs the references on these bricks while we stay idle (interleaved)
    roam = ct.stats
    # jump across the volume: time until every window is resident again
    n_keys = len(loader.keys)
    t1 = time.perf_counter()
    ct.set_center(lo + 0.9 * (hi - lo))
    ct.wait_until_idle()
    converge_s = time.perf_counter() - t1
    jump_bricks = ct.stats.loads_total - roam.loads_total
    jump_bytes = ct.stats.bytes_loaded - roam.bytes_loaded
    jump_keys = loader.keys[n_keys:]
    resident = ct.stats.resident_bytes
    ok = ct.close()
    stop.set()
    sampler.join()
    peak_rss = max(peak[0], _vm_hwm())
    out_q.put(
        {
            "steps": len(path),
            "window": roam.window,
            "whole_levels": list(roam.whole_levels),
            "pool_bytes": roam.pool_bytes,
            "latency_p50": roam.latency_p50,
            "latency_p95": roam.latency_p95,
            "latency_p99": roam.latency_p99,
            "converge_s": converge_s,
            "jump_bricks": jump_bricks,
            "jump_bytes": jump_bytes,
            "jump_keys": jump_keys,
            "resident_bytes": resident,
            "baseline_rss": baseline,
            "peak_rss": peak_rss,
            "closed": ok,
            "budget": ct.memory_budget,
        }
    )


def zarr_reads(store: Path, keys, pool: ThreadPoolExecutor, brick_shape) -> float:
    """Seconds for zarr-python chunk-aligned ``arr[...]`` reads of ``keys`` on the pool's threads."""
    import zarr

    group = zarr.open_group(str(store), mode="r")
    arrays = {L: group[str(L)] for L in {k[0] for k in keys}}

    def one(key):
        L, idx = key
        sl = tuple(slice(i * b, (i + 1) * b) for i, b in zip(idx, brick_shape))
        return arrays[L][sl].nbytes

    list(pool.map(one, keys[: min(len(keys), 8)]))  # warm zarr's event loop and metadata
    t = time.perf_counter()
    list(pool.map(one, keys))
    return time.perf_counter() - t


def floor_reads(store: Path, keys, pool: ThreadPoolExecutor) -> float:
    """Seconds to read each brick's chunk file and decode it with numcodecs (the floor)."""
    import numcodecs

    codec = numcodecs.Blosc()

    def one(key):
        p = _chunk_path(store, *key)
        try:
            with open(p, "rb") as f:
                data = f.read()
        except FileNotFoundError:
            return 0
        return len(codec.decode(data))

    t = time.perf_counter()
    list(pool.map(one, keys))
    return time.perf_counter() - t


def _run_variant(ctx, store: Path, cfg: dict, threads: int, direct: bool, sync: bool = False) -> dict:
    """Run one roaming child; between its passes, time the two references on the same bricks."""
    import numpy as np

    q, go = ctx.Queue(), ctx.Queue()
    child = ctx.Process(target=roam_child, args=(str(store), cfg["budget"], threads, q, go, direct, sync))
    child.start()
    brick = (int(cfg["brick"]),) * 3
    mb = 1e6
    ct_r, zarr_r, floor_r, loads = [], [], [], 0
    import zarr

    zarr.config.set({"threading.max_workers": threads})  # zarr's own codec threads: the same count
    pool = ThreadPoolExecutor(threads)  # started once, like the clip-texture's threads
    list(pool.map(time.sleep, [0.01] * threads))
    for _ in range(PASSES):  # interleaved: pass k in the child, then the references on its bricks
        p = q.get()
        keys = [(int(L), tuple(idx)) for L, idx in p["keys"]]
        loads += p["loads"]
        ct_r.append(p["bytes"] / p["seconds"] / mb)
        zarr_r.append(p["bytes"] / zarr_reads(store, keys, pool, brick) / mb)
        floor_r.append(p["bytes"] / floor_reads(store, keys, pool) / mb)
        go.put(True)
    res = q.get()
    child.join()
    # the jump: every brick queued at once, no roaming in between - the loader threads' own speed
    jump_keys = [(int(L), tuple(idx)) for L, idx in res.pop("jump_keys")]
    jump_floor_s = min(floor_reads(store, jump_keys, pool) for _ in range(3))
    pool.shutdown()
    res.update(
        jump_mbs=res["jump_bytes"] / res["converge_s"] / mb,
        jump_floor_mbs=res["jump_bytes"] / jump_floor_s / mb,
        jump_vs_floor=jump_floor_s / res["converge_s"],
        loads=loads,
        ct_mbs=float(np.median(ct_r)),
        zarr_mbs=float(np.median(zarr_r)),
        floor_mbs=float(np.median(floor_r)),
        vs_zarr=float(np.median(np.array(ct_r) / np.array(zarr_r))),
        vs_floor=float(np.median(np.array(ct_r) / np.array(floor_r))),
    )
    return res


def plot_csv(csv_path: Path, png_path: Path) -> Path:
    """Bar chart of the clip-texture's MB/s against both references, per variant, from the CSV."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader(open(csv_path)))
    wanted = ("cliptexture_MB_s", "zarr_arr_MB_s", "floor_MB_s", "ratio_vs_zarr", "ratio_vs_floor")
    val = {(r["metric"], r["variant"]): float(r["value"]) for r in rows if r["metric"] in wanted}
    variants = list(dict.fromkeys(r["variant"] for r in rows if r["variant"]))
    series = [("cliptexture_MB_s", "ClipTexture", "tab:green"), ("zarr_arr_MB_s", "zarr-python arr[...]", "tab:gray"),
              ("floor_MB_s", "read + numcodecs (floor)", "tab:olive")]
    fig, ax = plt.subplots(figsize=(7, 3.2))
    for k, (metric, label, colour) in enumerate(series):
        xs = [i + (k - 1) * 0.27 for i in range(len(variants))]
        ax.bar(xs, [val.get((metric, v), 0) for v in variants], width=0.27, label=label, color=colour)
    ax.set_xticks(range(len(variants)), [f"{v}\nvs zarr {val.get(('ratio_vs_zarr', v), 0):.2f}x, "
                                         f"vs floor {val.get(('ratio_vs_floor', v), 0):.2f}" for v in variants])
    ax.set_ylabel("MB/s (2 threads)")
    ax.set_title("loading bricks while roaming (2 GiB store, 256 MB budget)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return png_path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small store and budget (seconds)")
    ap.add_argument("--size", help="ZxYxX of the fractal (default 512x1024x1024 float32 = 2 GiB)")
    ap.add_argument("--brick", type=int)
    ap.add_argument("--budget")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--data-dir", type=Path, default=DATA)
    ap.add_argument("--csv", type=Path, help="output (default tools/bench/results/bench_paging.csv; --quick: bench-data/bench_paging_quick.csv)")
    args = ap.parse_args(argv)
    if args.csv is None:
        args.csv = args.data_dir / "bench_paging_quick.csv" if args.quick else RESULTS / "bench_paging.csv"
    cfg = dict(QUICK if args.quick else FULL)
    for k in ("size", "brick", "budget"):
        if getattr(args, k) is not None:
            cfg[k] = getattr(args, k)
    from clipvol.units import parse_bytes

    store = fractal_store(cfg["size"], int(cfg["brick"]), args.data_dir)
    store_bytes = sum(p.stat().st_size for p in store.rglob("*") if p.is_file())
    # warm the page cache over the whole store so all paths read from memory
    warm_cache(store, [(int(p.parts[-5]), tuple(int(v) for v in p.parts[-3:])) for p in store.glob("[0-9]*/c/*/*/*")])
    ctx = mp.get_context("spawn")
    variants = {"copy": _run_variant(ctx, store, cfg, args.threads, False),
                "into": _run_variant(ctx, store, cfg, args.threads, True),
                "sync": _run_variant(ctx, store, cfg, args.threads, True, sync=True)}
    budget = parse_bytes(cfg["budget"])
    mb = 1e6
    first = variants["copy"]
    z, y, x = (int(v) for v in cfg["size"].split("x"))
    rows = [
        ("store", f"procedural:fractal size={cfg['size']} float32 brick={cfg['brick']} blosc-lz4", "", "", ""),
        ("store_bytes_on_disk", store_bytes, "bytes", "", ""),
        ("volume_bytes", 4 * z * y * x, "bytes", "", ""),
        ("threads", args.threads, "", "", ""),
        ("memory_budget", budget, "bytes", "", ""),
        ("window_W", first["window"], "bricks/axis", "", f"whole levels {first['whole_levels']}"),
        ("pool_bytes", first["pool_bytes"], "bytes", "", "slot pool, <= budget"),
        ("roam_steps", first["steps"], "", "", f"per pass, {PASSES} passes; one level-0 brick per step"),
    ]
    notes = {"copy": "ZarrLoader.read_brick copied into the slot; pipelined roaming",
             "into": "read_brick_into (decoded straight into the slot); pipelined roaming",
             "sync": "ZarrLoader.read_brick_into (the default); wait until idle after every step"}
    for name, r in variants.items():
        rows += [
            ("bricks_loaded", r["loads"], "", name, "over all passes"),
            ("cliptexture_MB_s", round(r["ct_mbs"], 1), "MB/s", name, notes[name] + "; median of passes"),
            ("zarr_arr_MB_s", round(r["zarr_mbs"], 1), "MB/s", name, "zarr-python arr[...] same bricks same threads; median"),
            ("floor_MB_s", round(r["floor_mbs"], 1), "MB/s", name, "file read + numcodecs decode, same threads; median"),
            ("ratio_vs_zarr", round(r["vs_zarr"], 2), "x", name, "median over passes; target >= 2"),
            ("ratio_vs_floor", round(r["vs_floor"], 2), "x", name, "median over passes; target >= 0.8"),
            ("latency_p50_ms", round(1e3 * r["latency_p50"], 2), "ms", name, "loader call"),
            ("latency_p95_ms", round(1e3 * r["latency_p95"], 2), "ms", name, ""),
            ("latency_p99_ms", round(1e3 * r["latency_p99"], 2), "ms", name, ""),
            ("converge_after_jump_s", round(r["converge_s"], 3), "s", name, f"{r['jump_bricks']} bricks loaded"),
            ("jump_MB_s", round(r["jump_mbs"], 1), "MB/s", name, "every window brick queued at once (a jump across the volume)"),
            ("jump_floor_MB_s", round(r["jump_floor_mbs"], 1), "MB/s", name, "file read + numcodecs decode of the same bricks, same threads; best of 3"),
            ("jump_ratio_vs_floor", round(r["jump_vs_floor"], 2), "x", name, "target >= 0.8"),
            ("baseline_rss_MB", round(r["baseline_rss"] / mb, 1), "MB", name, "child after imports + open"),
            ("peak_rss_MB", round(r["peak_rss"] / mb, 1), "MB", name, f"target <= budget + 200 MB = {(budget + 200e6) / mb:.0f} MB"),
            ("peak_rss_minus_budget_MB", round((r["peak_rss"] - budget) / mb, 1), "MB", name, "target <= 200"),
            ("close_joined_all_threads", r["closed"], "", name, ""),
        ]
    args.csv.parent.mkdir(parents=True, exist_ok=True)
    with open(args.csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["metric", "value", "unit", "variant", "note"])
        w.writerows(rows)
    for r in rows:
        print(f"{r[0]:>26} {r[3]:>4}: {r[1]} {r[2]}  {r[4]}")
    print(f"wrote {args.csv}")
    if not args.quick:
        print(f"wrote {plot_csv(args.csv, args.csv.with_suffix('.png'))}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
