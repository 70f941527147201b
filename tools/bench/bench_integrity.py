"""Integrity benchmark: what the crc32c checksum and the statistics check cost per brick, and where
the zarr loader's time goes against the decode floor.

Why these references: a brick of a clipvol store is one zarr chunk, so the fastest anything can
load it is "read the chunk file, decode it with numcodecs" (the *floor*, outside our code path:
``open().read()`` then ``numcodecs.Blosc().decode``, as ``tools/bench/bench_paging.py`` defines it).
The loader is measured on the same bricks, on the same number of threads, in one run, page cache
warm, rounds interleaved, median of rounds:

* ``floor``: file read + numcodecs decode;
* ``loader, no checks``: ``ZarrLoader.read_brick_into`` with ``verify_checksums`` and
  ``check_plausibility`` off (the bare read path);
* ``loader, checksum``: crc32c verified;
* ``loader, checksum + statistics``: the default. On a verified store the sampled decode check
  runs on a brick's first load only (``IntegrityChecks._check_loaded``), so the medians of warm
  rounds leave it out; ``cost checksum + statistics, first round`` is round 1 alone.

Reported: MB/s (decoded bytes) of each, the cost of the checks as a fraction of the bare loader's
throughput (target <= 5 %), the loader against the floor (target >= 0.9 with 2 threads), and a
single-thread breakdown in microseconds per brick (file open+read, crc32c, blosc decode into the
slot, sampled statistics check, the whole call) and a ClipTexture filled by its own loader threads
against the floor on the same bricks (target >= 0.8).

Two kinds of data, because the checksum's cost scales with the *compressed* bytes and the decode's
with the *decoded* ones. ``--data fractal`` (the default): the procedural fractal, float32 or
(``--dtype uint16``) quantised to 12 bits; it has detail down to 2 voxels and compresses only
1.3-1.5x, the worst case for the checksum. ``--data ct``: the CT-like head of
:func:`clipvol.bricking.generators.ct_head` (air, skin, bone, brain) at 512^3 as 12-bit values in
uint16 words (256 MiB), which compresses like real CT (mostly air and smooth tissue).

Run ``python tools/bench/bench_integrity.py [--data ct | --dtype uint16]`` (stores cached under
``bench-data/``) or ``--quick``. Results: ``tools/bench/results/bench_integrity.csv`` (``_uint16``, ``_ct``) and
a summary on stdout; ``--summarize CSV...`` writes the median and range of several runs
(``tools/bench/results/bench_integrity_runs.csv``); ``docs/benchmarks.md`` discusses them.
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from common import DATA, RESULTS, ct_store, fractal_store  # noqa: E402  (tools/bench/common.py)
FULL = {"size": "256x512x512", "brick": 64}  # 256 MiB of float32
QUICK = {"size": "128x128x128", "brick": 32}
CT_FULL = {"size": "512x512x512", "brick": 64}  # 256 MiB of uint16


def chunk_keys(store: Path, levels: int) -> list[tuple[int, tuple[int, int, int]]]:
    """Every written chunk (non-empty brick) of every level, interior bricks only (the slot path)."""
    from clipvol.loaders.zarr_store import ZarrLoader

    pyr = ZarrLoader(store).pyramid
    keys = []
    for L in range(levels):
        for p in sorted((store / str(L) / "c").glob("*/*/*")):
            idx = tuple(int(v) for v in p.parts[-3:])
            s, e = pyr.brick_voxel_box(L, idx)
            if all(b - a == n for a, b, n in zip(s, e, pyr.brick_shape)):
                keys.append((L, idx))
    return keys


def _chunk_path(store: Path, level: int, idx) -> str:
    return f"{store}/{level}/c/{idx[0]}/{idx[1]}/{idx[2]}"


def floor_run(store: Path, keys, pool: ThreadPoolExecutor) -> tuple[float, float]:
    """``(wall, cpu)`` seconds: read each chunk file and decode it with numcodecs (the floor,
    outside our code); ``cpu`` sums the loader threads' CPU time (user + system) over the bricks."""
    import numcodecs

    codec = numcodecs.Blosc()

    def one(key):
        c = time.thread_time()
        with open(_chunk_path(store, *key), "rb") as f:
            data = f.read()
        codec.decode(data)
        return time.thread_time() - c

    t = time.perf_counter()
    cpu = sum(pool.map(one, keys))
    return time.perf_counter() - t, cpu


def loader_run(loader, keys, pool: ThreadPoolExecutor) -> tuple[float, float]:
    """``(wall, cpu)`` seconds: ``read_brick_into`` of every key into a per-thread slot (as the
    clip-texture does)."""
    import numpy as np

    local = threading.local()
    pyr = loader.pyramid

    def one(key):
        slot = getattr(local, "slot", None)
        if slot is None:
            slot = local.slot = np.empty(pyr.brick_shape, dtype=pyr.dtype)
        c = time.thread_time()
        loader.read_brick_into(key[0], key[1], slot)
        return time.thread_time() - c

    t = time.perf_counter()
    cpu = sum(pool.map(one, keys))
    return time.perf_counter() - t, cpu


def interleaved_loads(store: Path, keys, loaders: dict, rounds: int, pool: ThreadPoolExecutor) -> tuple[dict, dict]:
    """``(wall, cpu)``: per name, the seconds of each of ``rounds`` interleaved rounds of the floor
    (``"floor"``, :func:`floor_run`) and of each loader of ``loaders`` (:func:`loader_run`), all
    on the same keys and pool: the machine's load hits every variant alike."""
    wall: dict[str, list[float]] = {"floor": [], **{k: [] for k in loaders}}
    cpu: dict[str, list[float]] = {k: [] for k in wall}
    for _ in range(rounds):
        for name in wall:
            w, c = floor_run(store, keys, pool) if name == "floor" else loader_run(loaders[name], keys, pool)
            wall[name].append(w)
            cpu[name].append(c)
    return wall, cpu


def floor_kept_run(store: Path, keys, pool: ThreadPoolExecutor, dest) -> tuple[float, float]:
    """``(wall, cpu)``: the floor, but each brick decoded by numcodecs into its own row of ``dest``
    (a pre-faulted array of one row per brick), as any cache that keeps the bricks must: the plain
    floor decodes every brick into the same freed-and-reused buffer, which stays in the CPU cache."""
    import numcodecs

    codec = numcodecs.Blosc()

    def one(i):
        c = time.thread_time()
        with open(_chunk_path(store, *keys[i]), "rb") as f:
            data = f.read()
        codec.decode(memoryview(data)[:-4], out=dest[i])  # the last 4 bytes are the crc32c codec's
        return time.thread_time() - c

    t = time.perf_counter()
    cpu = sum(pool.map(one, range(len(keys))))
    return time.perf_counter() - t, cpu


def cliptexture_fill(store: Path, threads: int, rounds: int, pool: ThreadPoolExecutor,
                     prefault: bool = True) -> dict[str, float]:
    """A ClipTexture filled by its own loader threads (budget large enough to hold the whole store,
    so it loads every brick once) against the floor on the same bricks, interleaved rounds.

    Wall: best round of each, from the end of construction (its loader threads start there) until
    idle; the construction (pool allocation and pre-fault) is reported beside it, and a ratio that
    includes it. CPU: the process's CPU time (all threads) during the fill, against the floor
    threads' CPU time, median of rounds; the clip-texture's own bookkeeping (queue, locks,
    generation checks) shows up here, the machine's other load does not.
    """
    import numpy as np

    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.paging.cliptexture import ClipTexture

    class Recording:
        def __init__(self, loader):
            self.loader, self.pyramid, self.keys = loader, loader.pyramid, []
            self.brick_ranges = loader.brick_ranges

        def read_brick(self, level, index):
            return self.loader.read_brick(level, index)

        def read_brick_into(self, level, index, out):
            self.keys.append((level, tuple(index)))
            self.loader.read_brick_into(level, index, out)

    walls, cpus, fwalls, fcpus, kwalls, kcpus, builds, nbytes = [], [], [], [], [], [], [], 0
    budget = sum(p.stat().st_size for p in store.rglob("*") if p.is_file()) * 3 + (64 << 20)
    for _ in range(rounds):
        rec = Recording(ZarrLoader(store))
        rec.loader.brick_statistics(0)  # opening zarr for the statistics is a one-off, not paging
        t0 = time.perf_counter()
        ct = ClipTexture(rec, budget, threads=threads, prefault=prefault)
        c, t = time.process_time(), time.perf_counter()  # the loader threads start as __init__ ends
        ct.wait_until_idle()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
        builds.append(t - t0)
        nbytes = ct.stats.bytes_loaded
        ct.close()
        del ct
        fw, fc = floor_run(store, rec.keys, pool)
        fwalls.append(fw)
        fcpus.append(fc)
        shape = rec.pyramid.brick_shape
        dest = np.empty((len(rec.keys), int(np.prod(shape)) * rec.pyramid.dtype.itemsize), np.uint8)
        dest[:, ::4096] = 0  # pre-faulted, like the clip-texture's pool
        kw, kc = floor_kept_run(store, rec.keys, pool, dest)
        del dest
        kwalls.append(kw)
        kcpus.append(kc)
    best = walls.index(min(walls))
    return {"bricks": len(rec.keys), "MB_s": nbytes / min(walls) / 1e6, "floor_MB_s": nbytes / min(fwalls) / 1e6,
            "wall_ratio": min(fwalls) / min(walls), "cpu_ratio": statistics.median(fcpus) / statistics.median(cpus),
            "build_s": statistics.median(builds),
            "wall_ratio_with_build": min(fwalls) / min(w + b for w, b in zip(walls, builds)),
            "kept_wall_ratio": min(kwalls) / min(walls), "kept_cpu_ratio": statistics.median(kcpus) / statistics.median(cpus),
            "best_round": best}


def breakdown(keys, loader, reps: int = 5) -> dict[str, float]:
    """Single-thread CPU microseconds per brick of each step of the loader's read path, in situ:
    for each brick in turn, the steps run one after another on the same bytes, as in a load (so
    the checksum reads bytes just read, from cache), each timed alone; median over bricks and
    ``reps`` passes. The checksum is timed with every CRC-32C package installed (the loader uses
    the first of :data:`~clipvol.loaders.zarr_store.CRC32C_PACKAGES`). Whole loads are not timed
    here (the steps before them leave the brick in cache): the interleaved rounds measure those."""
    import numpy as np

    from clipvol.loaders.zarr_store import CRC32C_PACKAGES, _crc32c_function

    pyr = loader.pyramid
    slot = np.empty(pyr.brick_shape, dtype=pyr.dtype)
    u8 = slot.reshape(-1).view(np.uint8)
    dec = loader._arrays[0].decoder
    crcs = {p: fn for p in CRC32C_PACKAGES if (fn := _crc32c_function(p)) is not None}
    clock = time.thread_time_ns
    steps: dict[str, list[int]] = {"file read (fresh bytes, as the floor)": [], "file read (loader's buffer)": [],
                                   **{f"crc32c {p}": [] for p in crcs}, "blosc decode into slot": [],
                                   "statistics lookup + sampled check": []}
    for _ in range(reps):
        for L, idx in keys:
            t = [clock()]
            loader._chunk_bytes(L, idx)
            t.append(clock())
            data = loader._fetch(L, idx)
            t.append(clock())
            for fn in crcs.values():
                fn(data)
                t.append(clock())
            dec.decode(memoryview(data)[:-4], out=u8)
            t.append(clock())
            loader._check_plausible(L, idx, slot, True)
            t.append(clock())
            for name, a, b in zip(steps, t, t[1:]):
                steps[name].append(b - a)
    return {k: statistics.median(v) / 1e3 for k, v in steps.items()}


#: the figures a summary over several runs keeps (median and range of each)
SUMMARY_METRICS = (
    "compression_ratio", "load_average_1min",
    "cost checksum", "cost checksum + statistics", "cost checksum + statistics, first round", "cost checksum, wall", "cost checksum + statistics, wall",
    "cost checksum + statistics with google-crc32c", "cost checksum + statistics with google-crc32c, wall",
    "loader (default) / floor, CPU", "loader (default) / floor, wall",
    "loader (no checks) / floor, CPU", "loader (no checks) / floor, wall",
    "us/brick crc32c fastcrc", "us/brick crc32c google-crc32c", "us/brick blosc decode into slot",
    "us/brick statistics lookup + sampled check",
)


def summarize(paths: list[Path], out: Path) -> list[tuple]:
    """Median, min and max over several runs' CSVs of each data set's :data:`SUMMARY_METRICS`: one
    run's ratios move by several points on a shared machine, the median of runs far less."""
    runs: dict[str, dict[str, list[float]]] = {}
    for p in paths:
        with open(p, newline="") as f:
            vals = {row[0]: row[1] for row in csv.reader(f)}
        per = runs.setdefault(vals["store"], {})
        for m in SUMMARY_METRICS:
            if m in vals:
                per.setdefault(m, []).append(float(vals[m]))
    rows = [("store", "metric", "median", "min", "max", "runs")]
    for store, per in runs.items():
        rows += [(store, m, round(statistics.median(v), 2), min(v), max(v), len(v)) for m, v in per.items()]
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    return rows


def main(argv: list[str] | None = None) -> int:

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small store (seconds)")
    ap.add_argument("--size", help="ZxYxX of the fractal (default 256x512x512 float32)")
    ap.add_argument("--brick", type=int)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--data", choices=("fractal", "ct"), default="fractal",
                    help="fractal (compresses 1.3-1.5x) or the CT-like head as 12-bit uint16 (compresses like CT)")
    ap.add_argument("--dtype", choices=("float32", "uint16"), default="float32", help="of the fractal")
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--data-dir", type=Path, default=DATA)
    ap.add_argument("--csv", type=Path, help="output (default tools/bench/results/bench_integrity.csv; --quick: bench-data/...)")
    ap.add_argument("--summarize", nargs="+", type=Path, metavar="CSV",
                    help="no run: median and range over these runs' CSVs, into --csv (default tools/bench/results/bench_integrity_runs.csv)")
    args = ap.parse_args(argv)
    if args.summarize:
        rows = summarize(args.summarize, args.csv or RESULTS / "bench_integrity_runs.csv")
        for row in rows:
            print(*row, sep=", ")
        return 0
    load_start = os.getloadavg()[0]
    suffix = "_ct" if args.data == "ct" else "_uint16" if args.dtype == "uint16" else ""
    if args.csv is None:
        args.csv = args.data_dir / f"bench_integrity{suffix}_quick.csv" if args.quick \
            else RESULTS / f"bench_integrity{suffix}.csv"
    cfg = dict(QUICK if args.quick else CT_FULL if args.data == "ct" else FULL)
    for k in ("size", "brick"):
        if getattr(args, k) is not None:
            cfg[k] = getattr(args, k)
    from clipvol.loaders.zarr_store import CRC32C_PACKAGES, ZarrLoader, crc32c_implementation

    if args.data == "ct":
        store = ct_store(cfg["size"], int(cfg["brick"]), args.data_dir)
        what = f"ct_head as 12-bit uint16 size={cfg['size']}"
    else:
        store = fractal_store(cfg["size"], int(cfg["brick"]), args.data_dir, args.dtype)
        what = f"procedural:fractal size={cfg['size']} {args.dtype}"
    probe = ZarrLoader(store)
    keys = chunk_keys(store, probe.pyramid.num_levels)
    for k in keys:  # warm the page cache: every path reads from memory
        Path(_chunk_path(store, *k)).read_bytes()
    nbytes = len(keys) * probe.pyramid.brick_nbytes
    variants = {}
    for name, crc, stats in (("no checks", False, False), ("checksum", True, False), ("checksum + statistics", True, True)):
        ld = ZarrLoader(store)
        ld.verify_checksums, ld.check_plausibility = crc, stats
        ld.brick_statistics(0)
        variants[name] = ld
    from clipvol.loaders.zarr_store import _crc32c_function

    google = ZarrLoader(store)  # the same checks with the fallback CRC-32C (zarr's own): the gain, in this run
    google._crc32c = _crc32c_function("google-crc32c")
    google.brick_statistics(0)
    variants["checksum + statistics, google-crc32c"] = google
    pool = ThreadPoolExecutor(args.threads)
    list(pool.map(time.sleep, [0.01] * args.threads))
    times, cpus = interleaved_loads(store, keys, variants, args.rounds, pool)
    fill = cliptexture_fill(store, args.threads, args.rounds, pool)
    fill_np = cliptexture_fill(store, args.threads, args.rounds, pool, prefault=False)
    pool.shutdown()
    # Two measures. Wall time, best round of each: other processes only ever add time, so the
    # fastest round is the closest to the variant's own speed. CPU time (user + system) of the
    # loader threads, median of rounds: what each brick costs, nearly blind to a crowded machine
    # (waiting for a core is not counted). Both are ratios of the same bricks in the same run.
    best = {k: min(v) for k, v in times.items()}
    cpu = {k: statistics.median(v) for k, v in cpus.items()}
    mbs = {k: nbytes / best[k] / 1e6 for k in times}
    med = {k: nbytes / statistics.median(v) / 1e6 for k, v in times.items()}
    r = lambda a, b: best[b] / best[a]  # noqa: E731  wall throughput of a / of b
    rc = lambda a, b: cpu[b] / cpu[a]  # noqa: E731  CPU throughput of a / of b
    cost_crc = 1 - rc("checksum", "no checks")
    cost_all = 1 - rc("checksum + statistics", "no checks")
    with ThreadPoolExecutor(1) as one:  # a worker thread, like the loader's: numcodecs runs blosc's own
        # threads only when called from the main thread, and thread CPU time would not count them
        bd = one.submit(breakdown, keys[: min(len(keys), 400)], variants["checksum + statistics"]).result()
    comp = sum(os.path.getsize(_chunk_path(store, *k)) for k in keys)
    package = crc32c_implementation()[0]
    rows = [
        ("store", f"{what} brick={cfg['brick']} blosc-lz4 + crc32c", "", ""),
        ("bricks", len(keys), "", "interior written bricks of every level, page cache warm"),
        ("compression_ratio", round(nbytes / comp, 2), "x", "decoded / stored bytes"),
        ("stored_kB_per_brick", round(comp / len(keys) / 1e3, 1), "kB", "what the checksum reads per brick"),
        ("crc32c package", package, "", "the loader's CRC-32C (the first installed of fastcrc, crc32c, google-crc32c)"),
        ("threads", args.threads, "", ""),
        ("rounds", args.rounds, "", "interleaved; best round of each (median in the note)"),
        ("load_average_1min", round(os.getloadavg()[0], 2), "", f"other processes on the machine; at the start {load_start:.2f}"),
    ]
    for k, v in mbs.items():
        what = "floor = file read + numcodecs decode" if k == "floor" else f"ZarrLoader.read_brick_into, {k}"
        rows.append((f"MB_s {k}", round(v, 1), "MB/s", f"{what}; wall, best round (median {med[k]:.0f})"))
        rows.append((f"cpu_us_per_brick {k}", round(1e6 * cpu[k] / len(keys), 1), "us", "CPU time of the threads, median round"))
    rows += [
        ("cost checksum", round(100 * cost_crc, 1), "% of throughput", "CPU time vs the loader with no checks"),
        ("cost checksum + statistics", round(100 * cost_all, 1), "% of throughput", "CPU time vs the loader with no checks; target <= 5"),
        ("cost checksum + statistics, first round", round(100 * (1 - cpus["no checks"][0] / cpus["checksum + statistics"][0]), 1),
         "% of throughput", "CPU, round 1 alone: each brick's first load, which also runs its sampled decode check"),
        ("cost checksum, wall", round(100 * (1 - r("checksum", "no checks")), 1), "% of throughput",
         f"{args.threads} threads, best rounds, vs the loader with no checks"),
        ("cost checksum + statistics, wall", round(100 * (1 - r("checksum + statistics", "no checks")), 1),
         "% of throughput", f"{args.threads} threads, best rounds, vs the loader with no checks"),
        ("loader (default) / floor, CPU", round(rc("checksum + statistics", "floor"), 2), "x", "throughput ratio; target >= 0.9"),
        ("loader (no checks) / floor, CPU", round(rc("no checks", "floor"), 2), "x", "throughput ratio"),
        ("loader (default) / floor, wall", round(r("checksum + statistics", "floor"), 2), "x", f"{args.threads} threads, best rounds; target >= 0.9"),
        ("loader (no checks) / floor, wall", round(r("no checks", "floor"), 2), "x", f"{args.threads} threads, best rounds"),
        ("cost checksum + statistics with google-crc32c", round(100 * (1 - rc("checksum + statistics, google-crc32c", "no checks")), 1),
         "% of throughput", "CPU; the fallback CRC-32C (holds the GIL), same rounds"),
        ("cost checksum + statistics with google-crc32c, wall",
         round(100 * (1 - r("checksum + statistics, google-crc32c", "no checks")), 1), "% of throughput",
         f"{args.threads} threads, best rounds"),
    ]
    rows += [
        ("ClipTexture fill MB_s", round(fill["MB_s"], 1), "MB/s", f"{fill['bricks']} bricks loaded by its own threads; best round"),
        ("ClipTexture fill floor MB_s", round(fill["floor_MB_s"], 1), "MB/s", "file read + numcodecs decode of the same bricks; best round"),
        ("ClipTexture fill / floor, wall", round(fill["wall_ratio"], 2), "x", "target >= 0.8; from the end of construction to idle"),
        ("ClipTexture fill / floor, CPU", round(fill["cpu_ratio"], 2), "x", "process CPU during the fill vs the floor threads' CPU"),
        ("ClipTexture construction", round(1e3 * fill["build_s"], 1), "ms", "pool allocation + pre-fault, median; once per clip-texture"),
        ("ClipTexture (construction + fill) / floor, wall", round(fill["wall_ratio_with_build"], 2), "x", "best round"),
        ("ClipTexture fill / floor keeping the bricks, wall", round(fill["kept_wall_ratio"], 2), "x",
         "floor decoding each brick into its own pre-faulted row (as a cache must) instead of one reused buffer"),
        ("ClipTexture fill / floor keeping the bricks, CPU", round(fill["kept_cpu_ratio"], 2), "x", ""),
        ("ClipTexture fill / floor, wall, prefault=False", round(fill_np["wall_ratio"], 2), "x",
         "the pool's pages faulted in by the loader threads during the fill"),
        ("ClipTexture fill / floor, CPU, prefault=False", round(fill_np["cpu_ratio"], 2), "x", ""),
    ]
    rows += [(f"us/brick {k}", round(v, 1), "us", "one thread, CPU time, median; steps in turn on the same brick")
             for k, v in bd.items()]
    for p in CRC32C_PACKAGES:
        if f"crc32c {p}" in bd:
            rows.append((f"GB/s crc32c {p}", round(comp / len(keys) / bd[f"crc32c {p}"] / 1e3, 1), "GB/s",
                         "stored bytes / the in-situ time above"))
    args.csv.parent.mkdir(parents=True, exist_ok=True)
    with open(args.csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["metric", "value", "unit", "note"])
        w.writerows(rows)
    for row in rows:
        print(f"{row[0]:>36}: {row[1]} {row[2]}  {row[3]}")
    print(f"wrote {args.csv}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
