"""Sharded store benchmark: every brick of a level read over HTTP at 0, 20 and 50 ms latency, by
clipvol's loader and by zarr-python through its own fsspec store.

What it measures (one run, ratios only): an OME-Zarr 0.5 image written by zarr-python 3 with
``shards=`` (the procedural fractal, float32 by default, 256³, 32³ inner chunks, shards of 4 chunks
a side, blosc + crc32c inside), served by the static HTTP server of the tests
(``tests/remote_servers.py``, a process of its own: it does not share this process's interpreter
lock) that sleeps ``latency`` before every answer, keeps connections alive and caps its bandwidth.
Every brick of level 0 (or, ``--view slab``, one layer of bricks through its centre, as a slice
pages) is read with ``--threads`` threads (one brick a call) by

- ``clipvol``: :class:`~clipvol.loaders.zarr_remote.RemoteZarrLoader` ``read_brick`` (a shard's
  index once, neighbouring inner chunks in one ranged request: :mod:`clipvol.loaders.zarr_shards`),
  told the bricks first (``plan_reads``, as a clip-texture tells it its queue);
- ``clipvol_view``: the same loader under a :class:`~clipvol.paging.cliptexture.ClipTexture` of
  ``--threads`` loader threads whose region is exactly those bricks (nearest the centre first, the
  plan told by the clip-texture itself; its slot pool is built inside the timing);
- ``clipvol_per_chunk``: the same loader with ``shard_run_bytes=0`` (one request per inner chunk);
- ``zarr_per_brick`` (**the reference**): zarr-python 3 ``arr[box]`` per brick over its own
  ``FsspecStore`` of the same URL, same threads;
- ``zarr_whole``: zarr-python reading the bricks' bounding box in one ``arr[...]`` (its own
  concurrency; a paging viewer cannot read this way, it asks for bricks).

Configurations are interleaved within each round, each with a fresh loader / array (nothing
cached; opening - the metadata requests - is not timed), warm (one untimed pass first); medians of
``--rounds``. Requests sent and bytes are taken
from an in-process server's own request log in one extra, untimed pass per configuration. Run from
the repository root::

    python tools/bench/bench_shard.py           # ~1-2 min on 2 shared cores
    python tools/bench/bench_shard.py --quick   # smoke run

Writes ``tools/bench/results/bench_shard.csv`` (or ``--csv``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1] / "tests"))  # the test servers

#: clipvol's ``shard_run_bytes`` (``--run-bytes``)
RUN_BYTES = 8 * 2**20

MODES = ("clipvol", "clipvol_view", "clipvol_per_chunk", "zarr_per_brick", "zarr_whole")


def sharded_store(size: int, inner: int, per_shard: int, dtype: str, data_dir: Path) -> Path:
    """The fractal (seed 1) as a sharded OME-Zarr 0.5 image written by zarr-python (cached)."""
    import zarr
    from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec, ShardingCodec

    from clipvol.bricking.generators import parse_procedural

    path = data_dir / f"shard-site-{size}-c{inner}-s{per_shard}-{dtype}" / "s.zarr"
    if (path / "0" / "zarr.json").exists() and (path / "done").exists():
        return path
    gen = parse_procedural(f"procedural:fractal?size={size}&seed=1")
    vol = gen.region(0, (0, 0, 0), gen.shape)
    if dtype == "uint16":
        lo, hi = float(vol.min()), float(vol.max())
        vol = np.rint((vol - lo) / (hi - lo) * 4095).astype(np.uint16)
    vol = vol.astype(dtype)
    g = zarr.open_group(str(path), mode="w", zarr_format=3)
    codec = ShardingCodec(chunk_shape=(inner,) * 3, codecs=[BytesCodec(), BloscCodec(cname="lz4"), Crc32cCodec()])
    a = g.create_array("0", shape=vol.shape, dtype=vol.dtype, chunks=(inner * per_shard,) * 3, serializer=codec,
                       compressors=None, fill_value=0)
    a[...] = vol
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{
        "axes": [{"name": n, "type": "space", "unit": "micrometer"} for n in "zyx"],
        "datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1.0, 1.0, 1.0]}]}]}],
        "omero": {"channels": [{"window": {"min": float(vol.min()), "max": float(vol.max())}}]}}
    (path / "done").write_text("")
    return path


#: which bricks are read (``--view``): every brick of level 0, or one layer of bricks through its centre
VIEW = "level"


def bricks(shape, inner: int) -> list[tuple[int, int, int]]:
    """The bricks of level 0 (``shape``, ``inner``-voxel bricks) that :data:`VIEW` reads."""
    grid = [-(-s // inner) for s in shape]
    if VIEW == "slab":  # one z-layer of bricks through the centre: what a slice through it pages
        return [(grid[0] // 2, y, x) for y in range(grid[1]) for x in range(grid[2])]
    return [tuple(int(v) for v in idx) for idx in np.ndindex(*grid)]


def opened(mode: str, url: str, threads: int):
    """A function reading every brick of level 0 of ``url`` the way ``mode`` says (returning the
    bricks read), and one closing what it opened. Opening (metadata requests) is not timed: a viewer
    opens a store once and then reads bricks."""
    if mode.startswith("clipvol"):
        from clipvol.loaders.zarr_remote import RemoteZarrLoader

        kw = {"shard_run_bytes": 0 if mode == "clipvol_per_chunk" else RUN_BYTES}
        ld = RemoteZarrLoader(f"{url}/s.zarr", **kw)
        idx = bricks(ld.pyramid.levels[0].shape, ld.pyramid.brick_shape[0])
        ld.plan_reads(0, np.array(idx))  # what a clip-texture paging these bricks tells its loader

        def read() -> int:
            if mode == "clipvol_view":  # a clip-texture paging exactly these bricks, nearest the centre first
                from clipvol.paging.cliptexture import ClipTexture
                from clipvol.paging.region import Region

                pyr = ld.pyramid
                lo, hi = pyr.volume_box()
                none = np.zeros((0, 3), np.int64)
                region = Region(tuple(((lo + hi) / 2).tolist()), (np.array(idx),) + (none,) * (pyr.num_levels - 1))
                with ClipTexture(ld, "1GB", threads=threads, region=region, prefault=False) as ct:
                    if not ct.wait_until_idle(600) or ct.failures:
                        raise RuntimeError(f"{url}: the view did not page cleanly: {list(ct.failures.values())[:1]}")
                return len(idx)
            with ThreadPoolExecutor(threads) as pool:
                for b in pool.map(lambda i: ld.read_brick(0, i), idx):
                    assert b.shape == ld.pyramid.brick_shape
            return len(idx)

        return read, ld.close
    import zarr
    from zarr.storage import FsspecStore

    arr = zarr.open_array(FsspecStore.from_url(f"{url}/s.zarr", read_only=True), path="0", mode="r")
    c = arr.chunks[0]  # chunks: the inner chunk of a sharded array
    idx = bricks(arr.shape, c)

    def read() -> int:
        if mode == "zarr_whole":  # the bricks' bounding box in one call (the whole level, or the layer)
            lo, hi = np.min(idx, axis=0), np.max(idx, axis=0) + 1
            arr[tuple(slice(a * c, b * c) for a, b in zip(lo, hi))]
        else:
            with ThreadPoolExecutor(threads) as pool:
                list(pool.map(lambda i: arr[tuple(slice(v * c, (v + 1) * c) for v in i)], idx))
        return len(idx)

    return read, lambda: None


def read_level(mode: str, url: str, threads: int) -> tuple[int, float]:
    """``(bricks, seconds)`` of one read of every brick of level 0 by ``mode`` (opening not timed)."""
    read, close = opened(mode, url, threads)
    try:
        t = time.perf_counter()
        n = read()
        return n, time.perf_counter() - t
    finally:
        close()


def counted(mode: str, site: Path, threads: int, bandwidth: float) -> tuple[int, int]:
    """(requests, bytes) the server's own log shows for one read of the level by ``mode``."""
    from remote_servers import serve_directory

    with serve_directory(site, keep_alive=True, bandwidth=bandwidth) as (url, srv):
        read_level(mode, url, threads)  # metadata included: each mode reads its zarr.json files
        log = [e for e in srv.log if e[0].startswith("/s.zarr/0/c/")]
    return len(log), sum(e[3] for e in log)


def main(argv=None) -> int:
    global RUN_BYTES, VIEW
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--inner", type=int, default=32, help="inner chunk (= brick) edge")
    p.add_argument("--per-shard", type=int, default=4, help="inner chunks per shard per axis")
    p.add_argument("--dtype", default="float32", choices=["float32", "uint16"])
    p.add_argument("--latencies", nargs="+", type=float, default=[0.0, 0.02, 0.05], help="seconds")
    p.add_argument("--bandwidth", type=float, default=200e6, help="bytes a second the server sends, all answers together")
    p.add_argument("--threads", type=int, default=16)
    p.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    p.add_argument("--run-bytes", type=int, default=RUN_BYTES, help="clipvol's shard_run_bytes (default: its default)")
    p.add_argument("--view", default="level", choices=["level", "slab"],
                   help="every brick of level 0, or one z-layer of bricks through its centre")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", type=Path, default=HERE / "results")
    p.add_argument("--csv", default="bench_shard.csv")
    args = p.parse_args(argv)
    if args.quick:
        args.size, args.rounds, args.latencies = 128, 1, [0.0, 0.02]

    RUN_BYTES, VIEW = args.run_bytes, args.view
    from common import DATA, write_rows
    from remote_servers import serve_directory_process

    store = sharded_store(args.size, args.inner, args.per_shard, args.dtype, DATA)
    site = store.parent
    configs = [(lat, m) for lat in args.latencies for m in args.modes]
    times: dict[tuple, list[float]] = {c: [] for c in configs}
    nbricks = 0
    load = os.getloadavg()[0]
    with __import__("contextlib").ExitStack() as stack:
        urls = {lat: stack.enter_context(serve_directory_process(site, latency=lat, bandwidth=args.bandwidth,
                                                                 keep_alive=True))
                for lat in args.latencies}
        for m in args.modes:  # warm: page cache, imports, connections
            read_level(m, urls[args.latencies[0]], args.threads)
        for _ in range(args.rounds):
            for lat, m in configs:
                nbricks, dt = read_level(m, urls[lat], args.threads)
                times[(lat, m)].append(dt)
    load = max(load, os.getloadavg()[0])
    counts = {m: counted(m, site, args.threads, args.bandwidth) for m in args.modes}
    rows = []
    for lat, m in configs:
        med = statistics.median(times[(lat, m)])
        ref = statistics.median(times[(lat, "zarr_per_brick")]) if "zarr_per_brick" in args.modes else float("nan")
        reqs, nbytes = counts[m]
        rows.append(dict(store=f"fractal {args.size}^3 {args.dtype}, inner {args.inner}^3, {args.per_shard}^3 per shard",
                         view=args.view, mode=m, run_bytes=args.run_bytes if m == "clipvol" else "", latency_ms=round(lat * 1e3), bricks=nbricks, threads=args.threads,
                         bandwidth_MB_s=round(args.bandwidth / 1e6, 1), requests=reqs, bytes=nbytes,
                         median_s=round(med, 3), rounds_s=" ".join(f"{v:.3f}" for v in times[(lat, m)]),
                         speed_over_zarr_per_brick=round(ref / med, 2), load=round(load, 1)))
        print(f"{lat * 1e3:4.0f} ms {m:>18}: {reqs:5d} requests, {nbytes / 1e6:7.2f} MB, median {med:6.3f} s, "
              f"{ref / med:5.2f}x zarr-python per brick")
    args.out.mkdir(parents=True, exist_ok=True)
    write_rows(args.out / args.csv, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
