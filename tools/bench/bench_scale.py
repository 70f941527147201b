"""Benchmark the beyond-one-machine paths against baselines in the same run.

Usage::

    python tools/bench/bench_scale.py [--size 256] [--quick]

Three parts, each a ratio measured in this run (results in ``tools/bench/results/bench_scale.csv``, a plot in
``tools/bench/results/bench_scale.png``, and the tables of ``docs/scale.md``):

1. **Bricking on Dask** - :func:`~clipvol.bricking.dask_build.brick_volume_dask` with a local
   cluster of 1 and 2 worker processes (and the in-process ``threads`` scheduler) against the local
   threaded :func:`~clipvol.bricking.pipeline.brick_volume` with 2 threads, and against zarr-python
   writing level 0 alone (the bricking baseline of ``docs/benchmarks.md``). Peak worker RSS is
   each worker's ``VmHWM`` read through ``client.run``.
2. **Remote reads** - every level-0 brick (32^3) read through :class:`~clipvol.loaders.zarr_remote.RemoteZarrLoader`
   from a local HTTP server (its own process) that sleeps 20 ms before each answer, with 64, 16
   and 2 requests in flight, against :class:`~clipvol.loaders.zarr_store.ZarrLoader` reading the same store from
   local disk with 2 threads, and against zarr-python reading the level through its own
   ``FsspecStore`` from the same slow server (one ``arr[...]``, zarr's own async concurrency).
3. **Sort-last** - frame time of :class:`~clipvol.app.sortlast.DistributedRenderer` with 2 worker
   processes against 1, against the single-process render action, and the share of the frame
   spent compositing on the client.

This machine has 2 cores shared with other work and no GPU (Mesa llvmpipe rasterises on the
CPU with its own threads), so two workers can at best halve a CPU-bound time and usually do not:
the figures say what the code costs, not what a cluster gains.
"""

from __future__ import annotations

import argparse
import csv
import functools
import http.server
import os
import shutil
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from common import REPO, RESULTS  # noqa: E402  (tools/bench/common.py)
ROOT = REPO


def _hwm_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def _warm_worker() -> None:
    import clipvol.bricking.dask_build  # noqa: F401
    import numcodecs  # noqa: F401
    import zarr  # noqa: F401


class _Slow(http.server.SimpleHTTPRequestHandler):
    latency = 0.02

    def log_message(self, *a):
        pass

    def do_GET(self):  # noqa: N802
        time.sleep(self.latency)
        super().do_GET()


def _serve_child(root: str, latency: float, q) -> None:
    handler = type("H", (_Slow,), {"latency": latency})
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(handler, directory=root))
    srv.daemon_threads = True
    srv.request_queue_size = 256
    q.put(srv.server_address[1])
    srv.serve_forever(poll_interval=0.05)


def _serve(root: Path, latency: float):
    """A slow static server in its own process (so it does not share this process's GIL)."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    q = ctx.Queue()
    proc = ctx.Process(target=_serve_child, args=(str(root), latency, q), daemon=True)
    proc.start()
    return proc, f"http://127.0.0.1:{q.get(timeout=30)}"


def bench_bricking(work: Path, size: int, rows: list) -> None:
    from distributed import Client, LocalCluster

    from clipvol.bricking.dask_build import brick_volume_dask
    from clipvol.bricking.generators import parse_procedural
    from clipvol.bricking.pipeline import brick_volume, store_codecs

    brick = 32
    vol = (parse_procedural(f"procedural:fractal?size={size}").region(0, (0, 0, 0), (size,) * 3) * 60000).astype(np.uint16)
    npy = work / "in.npy"
    np.save(npy, vol)
    mb = vol.nbytes / 2**20
    del vol

    def timed(fn) -> float:
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t

    import zarr

    def zarr_level0():
        src = np.load(npy, mmap_mode="r")
        arr = zarr.create_array(str(work / "z.zarr"), shape=src.shape, chunks=(brick,) * 3, dtype=src.dtype,
                                compressors=store_codecs("lz4", src.dtype), overwrite=True)
        with zarr.config.set({"threading.max_workers": 2}):
            for z in range(0, src.shape[0], brick):
                arr[z:z + brick] = src[z:z + brick]

    t_zarr = timed(zarr_level0)
    t_local = min(timed(lambda: brick_volume(npy, work / "local.zarr", brick=brick, workers=2, overwrite=True,
                                             progress=False)) for _ in range(2))
    t_thr = timed(lambda: brick_volume_dask(npy, work / "thr.zarr", brick=brick, workers=2, span=2, overwrite=True,
                                            progress=False, scheduler="threads"))
    rows += [("brick", "zarr_level0_s", round(t_zarr, 3), "s", f"zarr-python writes level 0 alone ({mb:.0f} MiB uint16, 2 threads)"),
             ("brick", "local_s", round(t_local, 3), "s", "brick_volume, 2 threads, all levels + statistics"),
             ("brick", "local_over_zarr", round(t_zarr / t_local, 3), "ratio", "throughput relative to zarr level-0 write"),
             ("brick", "dask_threads_s", round(t_thr, 3), "s", "brick_volume_dask, scheduler threads (2)"),
             ("brick", "dask_threads_over_local", round(t_local / t_thr, 3), "ratio", "throughput relative to the local path")]
    times = {}
    for n in (1, 2):
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0",
                          worker_dashboard_address="127.0.0.1:0") as cluster, Client(cluster) as client:
            client.run(_warm_worker)  # imports happen once per process, not inside the clock
            base = client.run(_rss_mb)
            t = min(timed(lambda: brick_volume_dask(npy, work / f"d{n}.zarr", brick=brick, span=2, overwrite=True,
                                                    progress=False, client=client)) for _ in range(2))
            peak = client.run(_hwm_mb)
        times[n] = t
        rows += [("brick", f"dask_{n}proc_s", round(t, 3), "s", f"brick_volume_dask on a local cluster of {n} process(es)"),
                 ("brick", f"dask_{n}proc_over_local", round(t_local / t, 3), "ratio", "throughput relative to the local path (2 threads)"),
                 ("brick", f"dask_{n}proc_peak_worker_rss_mb", round(max(peak.values()), 1), "MiB",
                  f"largest worker VmHWM (idle worker RSS {statistics.mean(base.values()):.0f} MiB)")]
    rows.append(("brick", "dask_2proc_over_1proc", round(times[1] / times[2], 3), "ratio", "2 worker processes vs 1 (best of 2 each)"))
    identical = all((work / "local.zarr" / p).read_bytes() == (work / "d2.zarr" / p).read_bytes()
                    for p in ("0/c/4/4/4", "1/c/2/2/2") if (work / "local.zarr" / p).exists())
    rows.append(("brick", "sample_chunks_identical", identical, "", "local vs 2-process Dask store"))


def bench_remote(work: Path, size: int, rows: list, latency: float = 0.02) -> None:
    import zarr
    from zarr.storage import FsspecStore

    from clipvol.bricking.pipeline import brick_volume
    from clipvol.loaders.zarr_remote import RemoteZarrLoader
    from clipvol.loaders.zarr_store import ZarrLoader

    store = work / "site" / "r.zarr"
    if not store.exists():
        brick_volume(work / "in.npy", store, brick=32, workers=2, progress=False)
    local = ZarrLoader(store)
    keys = [tuple(int(v) for v in k) for k in np.ndindex(local.pyramid.grid(0))]
    nbytes = len(keys) * local.pyramid.brick_nbytes

    def read_all(loader, threads: int) -> float:
        t = time.perf_counter()
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda k: loader.read_brick(0, k), keys))
        return time.perf_counter() - t

    read_all(local, 2)  # page cache warm
    t_local = min(read_all(local, 2) for _ in range(2))
    srv, url = _serve(work / "site", latency)
    try:
        res = {}
        for inflight in (64, 16, 2):
            remote = RemoteZarrLoader(f"{url}/r.zarr", max_in_flight=inflight)
            res[inflight] = read_all(remote, remote.preferred_threads)
        arr = zarr.open_array(FsspecStore.from_url(f"{url}/r.zarr", read_only=True), path="0", mode="r")
        t = time.perf_counter()
        arr[...]
        t_zarr = time.perf_counter() - t
    finally:
        srv.terminate()
        srv.join(5)
    srv, url = _serve(work / "site", 0.0)  # the same server without the sleep: its own ceiling
    try:
        remote = RemoteZarrLoader(f"{url}/r.zarr", max_in_flight=16)
        t_fast = read_all(remote, remote.preferred_threads)
    finally:
        srv.terminate()
        srv.join(5)
    mbs = lambda s: nbytes / 2**20 / s  # noqa: E731
    rows += [("remote", "local_loader_MB_s", round(mbs(t_local), 1), "MB/s", "ZarrLoader from local disk, 2 threads"),
             ("remote", "remote64_MB_s", round(mbs(res[64]), 1), "MB/s", f"RemoteZarrLoader over HTTP, {latency * 1000:.0f} ms per request, 64 in flight"),
             ("remote", "remote16_MB_s", round(mbs(res[16]), 1), "MB/s", "same, 16 in flight (the default)"),
             ("remote", "remote2_MB_s", round(mbs(res[2]), 1), "MB/s", "same, 2 in flight"),
             ("remote", "zarr_fsspec_MB_s", round(mbs(t_zarr), 1), "MB/s", "zarr-python arr[...] over its FsspecStore, same server"),
             ("remote", "remote64_over_local", round(t_local / res[64], 3), "ratio", "remote (64 in flight) / local read; target >= 0.5"),
             ("remote", "remote16_over_local", round(t_local / res[16], 3), "ratio", "remote (16 in flight) / local read"),
             ("remote", "remote2_over_local", round(t_local / res[2], 3), "ratio", "remote (2 in flight) / local read"),
             ("remote", "remote16_no_latency_MB_s", round(mbs(t_fast), 1), "MB/s", "RemoteZarrLoader, same server without the 20 ms, 16 in flight"),
             ("remote", "remote64_over_no_latency", round(t_fast / res[64], 3), "ratio",
              "20 ms server (64 in flight) / the same server at 0 ms: latency hidden"),
             ("remote", "remote64_over_zarr_fsspec", round(t_zarr / res[64], 3), "ratio", "remote loader (64) / zarr-python over the same server")]


def bench_sortlast(work: Path, rows: list, frames: int = 3) -> None:
    from clipvol.app.sortlast import DistributedRenderer
    from clipvol.bricking.generators import parse_procedural
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.open import open_store
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.params import RenderParams
    from clipvol.scene.transfer import TransferFunction
    from clipvol.scene.views import view_camera

    store = work / "sl.zarr"
    n = 128
    vol = parse_procedural(f"procedural:fractal?size={n}").region(0, (0, 0, 0), (n, n, n)).astype(np.float32)
    brick_volume(vol, store, brick=32, workers=2, progress=False, overwrite=True)
    pyr = open_store(store).pyramid
    tf = TransferFunction.preset("viridis")
    params = RenderParams(lod_threshold=0.5)
    cams = [view_camera(pyr, v, (256, 256)) for v in ("iso", "side", "front")][:frames]

    def steady(render) -> float:
        for c in cams:  # warm: loads, uploads, contexts
            render(c)
        ts = []
        for c in cams:
            t = time.perf_counter()
            render(c)
            ts.append(time.perf_counter() - t)
        return statistics.median(ts)

    ctx = create_context()
    with ClipTexture(open_store(store), "256MB") as clip, ClipRenderAction(ctx, clip, params) as act:
        t_single = steady(lambda c: act.render(c, tf, wait=True))
    ctx.release()
    res = {}
    for w in (1, 2):
        with DistributedRenderer(str(store), w, params, memory_budget="256MB") as dr:
            comp = []

            def one(c):
                dr.render(c, tf)
                comp.append(dr.last_stats.composite_seconds / dr.last_stats.frame_seconds)

            res[w] = (steady(one), statistics.median(comp))
    rows += [("sortlast", "single_process_frame_ms", round(t_single * 1000, 1), "ms", f"ClipRenderAction, {n}^3 float32, 256x256, converged"),
             ("sortlast", "workers1_frame_ms", round(res[1][0] * 1000, 1), "ms", "DistributedRenderer, 1 worker process"),
             ("sortlast", "workers2_frame_ms", round(res[2][0] * 1000, 1), "ms", "DistributedRenderer, 2 worker processes"),
             ("sortlast", "workers2_over_workers1", round(res[1][0] / res[2][0], 3), "ratio", "frame rate with 2 workers / with 1"),
             ("sortlast", "workers1_over_single", round(t_single / res[1][0], 3), "ratio", "frame rate of 1 Dask worker / the single-process action"),
             ("sortlast", "composite_share_2w", round(res[2][1], 4), "fraction", "client compositing time / frame time, 2 workers")]


def _plot(rows: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratios = [(f"{p}: {k}", v) for p, k, v, unit, _ in rows if unit == "ratio"]
    fig, ax = plt.subplots(figsize=(8, 0.4 * len(ratios) + 1.2))
    ax.barh([r[0] for r in ratios], [r[1] for r in ratios], color="tab:blue")
    ax.axvline(1.0, color="k", lw=0.8)
    ax.set_xlabel("ratio to the baseline named in bench_scale.csv (column what)")
    ax.invert_yaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256, help="edge of the bricking/remote volume (uint16)")
    ap.add_argument("--out", default=str(RESULTS), help="directory for bench_scale.csv/.png")
    ap.add_argument("--parts", default="brick,remote,sortlast")
    args = ap.parse_args(argv)
    rows: list = []
    work = Path(tempfile.mkdtemp(prefix="clipvol-bench-scale-"))
    try:
        parts = args.parts.split(",")
        if "brick" in parts or "remote" in parts:
            if "brick" in parts:
                bench_bricking(work, args.size, rows)
            else:
                from clipvol.bricking.generators import parse_procedural

                s = args.size
                np.save(work / "in.npy", (parse_procedural(f"procedural:fractal?size={s}").region(0, (0, 0, 0), (s,) * 3) * 60000).astype(np.uint16))
        if "remote" in parts:
            bench_remote(work, args.size, rows)
        if "sortlast" in parts:
            bench_sortlast(work, rows)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    out = Path(args.out)
    with open(out / "bench_scale.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["part", "metric", "value", "unit", "what"])
        w.writerows(rows)
    _plot(rows, out / "bench_scale.png")
    for r in rows:
        print(",".join(map(str, r)))
    print(f"cores {os.cpu_count()}; python {sys.version.split()[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
