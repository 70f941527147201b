"""Remote store benchmark: a view's bricks from an HTTP server at 0, 20 and 50 ms latency.

What it measures (one run, ratios only): the seconds a clip-texture over
:class:`~clipvol.loaders.zarr_remote.RemoteZarrLoader` takes to page the cube windows of a view
around the centre of a store (every brick of its windows loaded, the "view's bricks"), from a
static HTTP server on 127.0.0.1 (``tests/remote_servers.py``, in a process of its own so it does
not share this process's interpreter lock) that sleeps ``latency`` before every answer, keeps
connections alive and caps its bandwidth (``--bandwidth``, the same cap at every latency). The
reference is the same server at 0 ms read the same way: ``ratio = t(0 ms) / t(latency)`` (target
>= 0.8). Two ways are run, interleaved: requests in flight sized from the measured link (the
default, :mod:`clipvol.paging.link`) and a fixed ``--fixed`` (16, the size before any
measurement). Rounds are interleaved (every configuration once a round), each with a fresh
loader (no on-disk cache, its metadata fetched before the clock starts); medians of ``--rounds``. Run from the repository root::

    python tools/bench/bench_remote.py            # ~1-2 min on 2 shared cores
    python tools/bench/bench_remote.py --quick    # smoke run

    python tools/bench/bench_remote.py --bandwidth 20e6 --csv bench_remote_20MBs.csv   # a slow link

Writes ``tools/bench/results/bench_remote.csv`` (or ``--csv``).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1] / "tests"))  # the test servers


def view_seconds(url: str, budget: str, in_flight: int | None) -> tuple[float, int, int, int]:
    """Seconds until the clip-texture over ``url`` has paged its windows; with the bricks loaded,
    the requests sent and the requests in flight at the end."""
    from clipvol.loaders.zarr_remote import RemoteZarrLoader
    from clipvol.paging.cliptexture import ClipTexture

    kw = {} if in_flight is None else dict(max_in_flight=in_flight)
    ld = RemoteZarrLoader(f"{url}/s.zarr", **kw)
    lo, hi = ld.pyramid.volume_box()
    sent0 = ld.source.requests
    t = time.perf_counter()
    with ClipTexture(ld, budget, center=tuple(((lo + hi) / 2).tolist()), prefault=False) as ct:
        ok = ct.wait_until_idle(600)
        dt = time.perf_counter() - t
        n = ct.stats.loads_total
        threads = ld.source.max_in_flight  # the requests in flight the source settled on
    ld.close()
    if not ok:
        raise RuntimeError(f"{url}: the view did not finish paging within 600 s")
    return dt, n, ld.source.requests - sent0, threads


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", default="384")
    p.add_argument("--brick", type=int, default=32)
    p.add_argument("--budget", default="256MB", help="memory budget of the clip-texture (its windows are the view)")
    p.add_argument("--latencies", nargs="+", type=float, default=[0.0, 0.02, 0.05], help="seconds; the first is the reference")
    p.add_argument("--bandwidth", type=float, default=200e6, help="bytes a second the server sends, all answers together")
    p.add_argument("--in-flight", type=int, default=None, help="max_in_flight (default: sized from the link)")
    p.add_argument("--fixed", type=int, default=16,
                   help="also run with this fixed max_in_flight, interleaved, for comparison (0: not)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", type=Path, default=HERE / "results")
    p.add_argument("--csv", default="bench_remote.csv", help="file name of the rows under --out")
    args = p.parse_args(argv)
    args.fixed = args.fixed or None
    if args.quick:
        args.size, args.rounds, args.budget = "128", 1, "16MB"

    from common import fractal_store
    from remote_servers import serve_directory_process

    store = fractal_store(args.size, args.brick)
    site = store.parent / f"site-{store.name}"
    site.mkdir(exist_ok=True)
    link = site / "s.zarr"
    if not link.exists():
        link.symlink_to(store.resolve(), target_is_directory=True)
    modes = [args.in_flight, *([] if args.fixed is None else [args.fixed])]
    configs = [(lat, m) for m in modes for lat in args.latencies]
    times: dict[tuple, list[float]] = {c: [] for c in configs}
    info: dict[tuple, tuple] = {}
    with __import__("contextlib").ExitStack() as stack:
        urls = {lat: stack.enter_context(serve_directory_process(site, latency=lat, bandwidth=args.bandwidth,
                                                                 keep_alive=True))
                for lat in args.latencies}
        view_seconds(urls[args.latencies[0]], args.budget, args.in_flight)  # warm: page cache, imports
        for _ in range(args.rounds):
            for lat, m in configs:
                dt, n, sent, inflight = view_seconds(urls[lat], args.budget, m)
                times[(lat, m)].append(dt)
                info[(lat, m)] = (n, sent, inflight)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / args.csv, "w", newline="") as f:
        w = csv.DictWriter(f, ["store", "brick", "budget", "bandwidth_MB_s", "max_in_flight", "latency_ms", "bricks",
                               "requests", "in_flight_at_end", "median_s", "rounds_s", "ratio_to_0ms"])
        w.writeheader()
        for lat, m in configs:
            ref = statistics.median(times[(args.latencies[0], m)])
            med = statistics.median(times[(lat, m)])
            n, sent, inflight = info[(lat, m)]
            mode = "measured" if m is None else str(m)
            w.writerow(dict(store=f"fractal {args.size}^3 float32", brick=args.brick, budget=args.budget,
                            bandwidth_MB_s=round(args.bandwidth / 1e6, 1), max_in_flight=mode,
                            latency_ms=round(lat * 1e3), bricks=n, requests=sent, in_flight_at_end=inflight,
                            median_s=round(med, 3), rounds_s=" ".join(f"{t:.3f}" for t in times[(lat, m)]),
                            ratio_to_0ms=round(ref / med, 3)))
            print(f"in flight {mode:>8}, {lat * 1e3:4.0f} ms: {n} bricks, {sent} requests, {inflight} in flight "
                  f"at the end, median {med:.2f} s = {ref / med:.2f} of 0 ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
