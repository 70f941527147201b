"""``clipvol brick --scheduler``: build the pyramid as a Dask graph, on threads, processes or a cluster.

Why Dask: one machine bricks a terabyte in about a day; a cluster of them should not need a
home-made work queue. The graph follows the octree, so that every task reads its own input and
no level-0 voxel passes through the client:

* **Tier tasks.** The levels are cut into tiers of ``span`` levels. A tier-0 task owns the
  level-0 region under one brick of level ``span - 1`` (``2**(span-1)`` bricks per axis): it reads
  that region from the input itself (each worker opens the input by its path), and for each of
  its levels summarises, encodes and writes every brick (the chunk files, exactly as the local
  path writes them), then down-samples the region for the next level. What is left at the top, one
  brick of level ``span`` down-sampled (its *carry*, ``(B/2)^3`` voxels), goes to the tier-1 task
  above it, which assembles ``8**span`` carries into its own region, and so on up to the last
  level. Down-sampling a region whole equals down-sampling its bricks one by one because brick
  extents are even (the edge of the volume is the edge of its last brick), so the result is the
  local path's, brick for brick.
* **The client only keeps books.** It creates the store (the same function as the local path),
  submits the tasks in z order, writes each brick-row's statistics and then its ``done`` flags as
  soon as the row's bricks are all reported (the same arrays, values and chunking, hence the same
  bytes), and writes ``complete`` last. A build whose client or workers die leaves an incomplete
  store; re-running the same command resumes it from the ``done`` flags (Dask itself re-runs the
  tasks of a worker that died while the client lives).
* **Bounded memory.** A worker holds at most one tier region per thread: ``(B * 2**(span-1))^3``
  voxels (32 MiB for 64^3 uint16 bricks and ``span=3``) plus its ``8**span`` carries (the same
  size again); the client holds the statistics of the rows still in flight.

Output is a local directory (on a cluster: a file system every worker mounts at the same path).
Schedulers: ``threads`` (one in-process worker with ``workers`` threads), ``processes``
(``workers`` local processes, one thread each) or ``tcp://HOST:PORT`` (an existing
``dask.distributed`` scheduler). Needs the optional extra: ``pip install 'clipvol[dask]'``.
"""

from __future__ import annotations

import sys
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MissingExtraError, ParameterError
from .build_options import BuildOptions
from .pipeline import (_create_store, chunk_encoder, encode_brick, has_spread_arrays, mark_complete, output_lock,
                       plan_build, prepare_output, write_errors)
from .pyramid import Pyramid, downsample
from .spread import SPREAD_GROUP, moments_down, spread_dtype, spread_of
from .sources import check_source_unchanged, open_source
from .stats import StatsComputer, finite_range
from .store import STAT_ARRAYS, STATS_GROUP, StoreMeta, parse_metadata

__all__ = ["brick_volume_dask", "SCHEDULERS", "DEFAULT_SPAN"]

SCHEDULERS = ("threads", "processes")
#: levels per tier task: 3 gives regions of 4^3 level-0 bricks (32 MiB at 64^3 uint16)
DEFAULT_SPAN = 3


def _need_dask():
    try:
        import dask  # noqa: F401
        import distributed  # noqa: F401
    except ImportError:
        raise MissingExtraError("--scheduler: bricking on Dask needs the dask extra: pip install 'clipvol[dask]'") from None


# -- worker side ------------------------------------------------------------------------------------
_SOURCES: dict[Any, Any] = {}


def _worker_source(spec):
    """The input, opened once per worker process from its path (or the array itself)."""
    source, raw_shape, raw_dtype, byte_order = spec
    if isinstance(source, np.ndarray):
        return open_source(source)
    key = (str(source), raw_shape, str(raw_dtype), byte_order)
    try:  # a long-lived worker must not keep a handle on an input replaced since
        st = Path(source).stat()
        key += (st.st_mtime_ns, st.st_size)
    except (OSError, TypeError, ValueError):
        pass
    src = _SOURCES.get(key)
    if src is None:
        src = _SOURCES[key] = open_source(source, raw_shape=raw_shape, raw_dtype=raw_dtype, byte_order=byte_order)
    return src


def _scan_task(spec, z0: int, z1: int):
    src = _worker_source(spec)
    Z, Y, X = src.shape
    return finite_range(src.read((z0, 0, 0), (z1, Y, X)))


def _region_box(pyr: Pyramid, L0: int, L1: int, top: tuple[int, int, int]):
    """Voxel box at level ``L0`` under brick ``top`` of level ``L1``."""
    B, f = pyr.brick_shape, 2 ** (L1 - L0)
    shape = pyr.levels[L0].shape
    start = tuple(t * f * b for t, b in zip(top, B))
    stop = tuple(min(s + f * b, n) for s, b, n in zip(start, B, shape))
    return start, stop


def _tier_task(spec, out: str, pyr: Pyramid, codec: str, checksum: bool, spread: bool, L0: int, L1: int, top, done,
               *carries):
    """Build levels ``L0..L1`` under brick ``top`` of level ``L1`` (see the module docstring).

    ``done[L - L0]`` is the region's ``done`` mask at level ``L``; ``carries`` (tier > 0) are
    ``(child_top, block, m1, m2)`` of the tier below (``m1``, ``m2``: the block's level-0 moments
    when ``spread``, else None; :mod:`clipvol.bricking.spread`). Returns ``(stats, carry)``; ``stats`` holds
    ``(level, index, BrickStats, chunk crc32c or -1)`` per brick written.
    """
    B = pyr.brick_shape
    start, stop = _region_box(pyr, L0, L1, top)
    m1 = m2 = None
    if L0 == 0:
        data = _worker_source(spec).read(start, stop)
    else:
        shape = tuple(b - a for a, b in zip(start, stop))
        data = np.empty(shape, dtype=pyr.dtype)
        if spread:
            m1, m2 = np.empty(shape, dtype=np.float64), np.empty(shape, dtype=np.float64)
        for child, block, c1, c2 in carries:
            o = tuple(c * (b // 2) - s for c, b, s in zip(child, B, start))
            at = tuple(slice(a, a + n) for a, n in zip(o, block.shape))
            data[at] = block
            if spread:
                m1[at], m2[at] = c1, c2
    encode = chunk_encoder(codec, pyr.dtype, checksum)
    encode_sp = chunk_encoder(codec, spread_dtype(pyr.dtype), checksum) if spread else None
    stats = StatsComputer(pyr.dtype, pyr.value_range)
    results = []
    for L in range(L0, L1 + 1):
        f = 2 ** (L1 - L)
        first = tuple(t * f for t in top)
        grid = pyr.grid(L)
        for rel in product(*(range(min(f, g - a)) for a, g in zip(first, grid))):
            if done[L - L0][rel]:
                continue
            idx = tuple(a + r for a, r in zip(first, rel))
            at = tuple(slice(r * b, (r + 1) * b) for r, b in zip(rel, B))
            block = data[at]
            st = stats.compute(block)
            payload = encode_brick(block, B, encode)
            results.append((L, idx, st, int.from_bytes(payload[-4:], "little") if payload is not None and checksum else -1))
            if payload is not None:
                d = Path(out) / str(L) / "c" / str(idx[0]) / str(idx[1])
                d.mkdir(parents=True, exist_ok=True)
                with open(d / str(idx[2]), "wb") as fh:
                    fh.write(payload)
            if spread and L >= 1:  # the same bytes as the local build's (pipeline._Builder._brick)
                sp = encode_brick(spread_of(m1[at], m2[at], pyr.dtype), B, encode_sp)
                if sp is not None:
                    d = Path(out) / SPREAD_GROUP / str(L) / "c" / str(idx[0]) / str(idx[1])
                    d.mkdir(parents=True, exist_ok=True)
                    with open(d / str(idx[2]), "wb") as fh:
                        fh.write(sp)
        if L + 1 < pyr.num_levels:
            if spread:
                m1, m2 = moments_down(data, m1, m2)
            data = downsample(data, pyr.filter)
    return results, ((tuple(top), data, m1, m2) if L1 + 1 < pyr.num_levels else None)


def _carry_of(result):
    return result[1]


def _stats_of(result):
    return result[0]


# -- client side ------------------------------------------------------------------------------------
def _client(scheduler: str, workers: int):
    """A ``distributed.Client`` for ``scheduler`` and the cluster to close with it (or None)."""
    from distributed import Client, LocalCluster

    if scheduler == "threads":
        # in-process: the scheduler and the worker talk over Dask's inproc transport, no socket
        cluster = LocalCluster(n_workers=1, threads_per_worker=workers, processes=False, dashboard_address="127.0.0.1:0",
                               worker_dashboard_address="127.0.0.1:0")
    elif scheduler == "processes":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                               worker_dashboard_address="127.0.0.1:0", host="127.0.0.1")
    elif scheduler.startswith(("tcp://", "tls://", "ucx://")) or "://" not in scheduler and ":" in scheduler:
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as e:
            raise ParameterError(f"--scheduler: cannot reach the Dask scheduler at {scheduler} ({type(e).__name__})") from None
    else:
        raise ParameterError(f"--scheduler: expected threads, processes or a scheduler address tcp://HOST:PORT, got {scheduler!r}")
    return Client(cluster), cluster


class _RowBook:
    """Statistics of the brick-rows in flight; a row is written (stats, then done) once whole."""

    def __init__(self, group, pyr: Pyramid, done: list[np.ndarray]) -> None:
        self.pyr = pyr
        self.arrays = [{n: group[f"{STATS_GROUP}/{L}/{n}"] for n in STAT_ARRAYS if n in group[f"{STATS_GROUP}/{L}"]}
                       for L in range(pyr.num_levels)]
        self.missing = {(L, k): int(np.count_nonzero(~done[L][k])) for L in range(pyr.num_levels)
                        for k in range(pyr.grid(L)[0]) if not done[L][k].all()}
        self.rows: dict[tuple[int, int], dict[tuple[int, int], Any]] = {}

    def add(self, stats) -> None:
        for L, (k, by, bx), st, crc in stats:
            self.rows.setdefault((L, k), {})[(by, bx)] = (st, crc)
            self.missing[(L, k)] -= 1
            if self.missing[(L, k)] == 0:
                self._write(L, k, self.rows.pop((L, k)))

    def _write(self, L: int, k: int, row: dict) -> None:
        _, gy, gx = self.pyr.grid(L)
        order = [row[(y, x)][0] for y in range(gy) for x in range(gx)]
        arrs = self.arrays[L]
        if "chunk_crc32c" in arrs:  # the same arrays, in the same order of writes, as the local sweep
            arrs["chunk_crc32c"][k] = np.array([row[(y, x)][1] for y in range(gy) for x in range(gx)],
                                               dtype=np.int64).reshape(gy, gx)
        for name in ("min", "max", "mean", "std"):
            arrs[name][k] = np.array([getattr(r, name) for r in order], dtype=np.float64).reshape(gy, gx)
        for name in ("nan_count", "inf_count"):
            arrs[name][k] = np.array([getattr(r, name) for r in order], dtype=np.int64).reshape(gy, gx)
        arrs["histogram"][k] = np.stack([r.histogram for r in order]).reshape(gy, gx, -1)
        arrs["done"][k] = np.ones((gy, gx), dtype=bool)  # last: the row is finished

    @property
    def finished(self) -> bool:
        return not self.rows and all(v == 0 for v in self.missing.values())


def brick_volume_dask(
    source,
    output,
    options: BuildOptions | None = None,
    *,
    scheduler: str = "threads",
    span: int = DEFAULT_SPAN,
    client=None,
    **kwargs,
) -> StoreMeta:
    """Brick ``source`` into ``output`` on Dask; the store is byte-identical to
    :func:`clipvol.bricking.pipeline.brick_volume`'s with the same options.

    Parameters
    ----------
    options : BuildOptions, optional
        How to build the store (:class:`~clipvol.bricking.build_options.BuildOptions`, the same
        value the local build takes); ``**kwargs`` are any of its options, over ``options``.
        ``workers`` is the number of threads (``threads``) or processes (``processes``); it is
        ignored for a cluster address.
    scheduler : str
        ``threads``, ``processes`` or the address of a ``dask.distributed`` scheduler.
    span : int
        Levels per tier task (>= 1); see the module docstring for the memory it implies.
    client : distributed.Client, optional
        Use this client instead of making one from ``scheduler``.

    The summary tables of image-based level of detail (``summary``) are built on the client, from
    the finished store (:func:`clipvol.bricking.summary.build_summary`), as the local path does.
    """
    _need_dask()
    opts = BuildOptions.from_kwargs(options, **kwargs)
    workers, progress, overwrite = opts.workers, opts.progress, opts.overwrite
    bshape, filter, codec = opts.brick, opts.filter, opts.codec
    raw_shape, raw_dtype, byte_order = opts.raw_shape, opts.raw_dtype, opts.byte_order
    if isinstance(span, bool) or not isinstance(span, int) or not 1 <= span <= 6:
        raise ParameterError(f"span: expected an integer in 1..6, got {span!r}")
    output = Path(output).absolute()
    src = open_source(source, raw_shape=raw_shape, raw_dtype=raw_dtype, byte_order=byte_order)
    try:
        sp, unit, frame, job, inodes = plan_build(src, source, output, opts)  # as the local build decides them
        shape, dtype = src.shape, src.dtype
    finally:
        src.close()
    spec = (source, tuple(raw_shape) if raw_shape is not None else None, raw_dtype, byte_order)
    own = None
    if client is None:
        client, own = _client(scheduler, workers)
        own = (client, own)
    try:
        if progress and own is not None and own[1] is None:  # an existing cluster: say where to watch it
            print(f"clipvol brick: Dask dashboard {client.dashboard_link}", file=sys.stderr)
        with write_errors(output), output_lock(output):
            attrs = prepare_output(output, job, overwrite)
            if isinstance(source, np.ndarray):
                spec = (client.scatter(source, broadcast=True), None, None, byte_order)
            if attrs is None:
                vr = _scan(client, spec, shape, dtype)
                pyramid = Pyramid.build(shape, bshape, sp, filter, dtype, vr, 0.0)
                group = _create_store(output, pyramid, codec, unit, job["source"], frame, job.get("source_identity"))
            else:
                import zarr

                pyramid = parse_metadata(attrs, str(output)).pyramid
                group = zarr.open_group(str(output), mode="r+")
            _build(client, spec, group, pyramid, output, codec, span, progress)
            again = open_source(source, raw_shape=raw_shape, raw_dtype=raw_dtype, byte_order=byte_order)
            try:
                check_source_unchanged(again, job["source_identity"], inodes, output)
            finally:
                again.close()
            mark_complete(group)  # the very last write, by the client
        if opts.summary:  # the same tables as the local path, with their own completion marker
            from .summary import build_summary

            build_summary(output, workers=workers, progress=progress)
        return parse_metadata(dict(group.attrs), str(output))
    finally:
        if own is not None:
            own[0].close()
            if own[1] is not None:
                own[1].close()


def _scan(client, spec, shape, dtype, chunk_bytes: int = 64 << 20) -> tuple[float, float]:
    """Finite (min, max) of level 0 from z-slabs read by the workers."""
    Z, Y, X = shape
    slab = max(1, chunk_bytes // max(1, Y * X * np.dtype(dtype).itemsize))
    futs = [client.submit(_scan_task, spec, z0, min(z0 + slab, Z), pure=False) for z0 in range(0, Z, slab)]
    lo, hi = np.inf, -np.inf
    for r in client.gather(futs):
        if r is not None:
            lo, hi = min(lo, r[0]), max(hi, r[1])
    return (0.0, 0.0) if not np.isfinite(lo) else (float(lo), float(hi))


def _build(client, spec, group, pyr: Pyramid, output: Path, codec: str, span: int, progress: bool) -> None:
    from distributed import as_completed
    from tqdm import tqdm

    nlev = pyr.num_levels
    # a resumed build of a store written before checksums keeps that store's codec chain (as the local path)
    checksum = any(type(c).__name__ == "Crc32cCodec" for c in group["0"].metadata.codecs)
    done = [np.asarray(group[f"{STATS_GROUP}/{L}/done"][...], dtype=bool) for L in range(nlev)]
    spread = has_spread_arrays(group, nlev)  # a resumed build of a store created without them writes none
    book = _RowBook(group, pyr, done)
    total = sum(book.missing.values())
    bar = tqdm(total=total, unit="brick", desc="bricking (dask)", file=sys.stderr, disable=not progress,
               dynamic_ncols=True)
    below: dict[tuple, Any] = {}  # top brick of the tier below -> its future
    stat_futs = []
    try:
        for L0 in range(0, nlev, span):
            L1 = min(L0 + span - 1, nlev - 1)
            here: dict[tuple, Any] = {}
            for top in np.ndindex(pyr.grid(L1)):
                masks = []
                for L in range(L0, L1 + 1):
                    f = 2 ** (L1 - L)
                    first = [t * f for t in top]
                    masks.append(done[L][tuple(slice(a, a + f) for a in first)])
                carries = []
                if L0 > 0:
                    f = 2 ** (L1 - L0 + 1)  # children: bricks of level L0 - 1 under `top`
                    g = pyr.grid(L0 - 1)
                    for rel in product(*(range(min(f, n - t * f)) for t, n in zip(top, g))):
                        child = tuple(t * f + r for t, r in zip(top, rel))
                        carries.append(client.submit(_carry_of, below[child], pure=False))
                fut = client.submit(_tier_task, spec, str(output), pyr, codec, checksum, spread, L0, L1, top, masks,
                                    *carries, pure=False, priority=-L0)
                here[top] = fut
                stat_futs.append(client.submit(_stats_of, fut, pure=False))
            below = here
        del below, here
        error: BaseException | None = None
        for fut in as_completed(stat_futs):
            if fut.status == "error":
                if error is None:
                    error = fut.exception()
                    client.cancel([f for f in stat_futs if not f.done()])
            elif fut.status == "finished" or (fut.status != "cancelled" and error is None):
                # finished - or being recomputed because the worker holding it died: result() waits
                stats = fut.result()
                book.add(stats)  # rows finished before a failure are kept: a re-run skips them
                bar.update(len(stats))
            fut.release()
        if error is not None:
            raise error
    finally:
        bar.close()
    if not book.finished:  # pragma: no cover - every task reported: a bookkeeping bug, never a complete store
        raise RuntimeError(f"{output}: Dask build finished with rows unaccounted for")
