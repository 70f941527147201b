"""Summary tables: per-brick value histograms and parent-child correspondence tables.

After Wang, Garcia & Shen (2007, section IV-D). Image-based level of detail needs, for every brick,
the error its coarse version makes *under the current transfer function*. Reading the voxels again
whenever the transfer function changes would take minutes for a large store; the summary tables
hold everything that error needs, so a change only re-evaluates small tables
(:mod:`clipvol.scene.lod_error`):

* **histogram** ``H`` per brick (every level): counts of the brick's valid voxels per quantised
  value (256 levels), NaN counted apart (``nan_count``).
* **correspondence** ``C`` per brick below the top level: counts of the pairs (parent's quantised
  value, this brick's quantised value) over this brick's valid voxels, where the parent value is the
  voxel of the parent brick that covers the child voxel (the 2x2x2 cell: ``parent[i // 2]``). Pairs
  with a NaN on either side are left out (NaN is drawn transparent).

Quantisation: 8-bit unsigned data is its own index (exact). Every other dtype is quantised
*uniformly* over the store's finite value range, ``q = clip(floor((v - lo) / (hi - lo) * 256), 0,
255)`` (``-inf``/``+inf`` land in the end bins). Uniform, not histogram-equalised, because the
transfer function is itself a uniform table over the value window: a uniform bin never hides more
of the transfer function than one table entry does, while equalised bins would be wide exactly
where the data is rare - where a CT's bone and contrast agent live.

Storage (zarr arrays in the store, under ``clipvol_summary/<level>/``): ``histogram`` (grid x 256,
uint32), ``nan_count`` (grid, int64) and, below the top level, the correspondence tables as a CSR
over the level's bricks in C order: ``pairs_offsets`` (n_bricks + 1, int64), ``pairs_code`` (uint16,
``parent * 256 + child``, ascending within a brick, stored as the difference from the brick's
previous code - the first one as is) and ``pairs_count`` (uint32). Only non-zero pairs
are kept; parent and child are strongly correlated, so a brick's table is a narrow band around the
diagonal (the observation behind the paper's zig-zag run-length code; the CSR form keeps the same
entries and is simpler to read with numpy). The group's attributes record the quantisation and the
levels finished; building is resumable per level and ``complete`` is written last.
"""

from __future__ import annotations

import json
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import StoreFormatError
from .pyramid import Pyramid
from .store import open_store_meta
from .store_files import chunk_cap, read_file

__all__ = ["SUMMARY_GROUP", "SUMMARY_BINS", "SummaryMissingError", "Quantiser", "SummaryTables",
           "build_summary", "summary_of", "open_summary", "summary_bytes", "tree_bytes"]

SUMMARY_GROUP = "clipvol_summary"
SUMMARY_BINS = 256
_FORMAT = 2


class SummaryMissingError(StoreFormatError):
    """A store has no (complete) summary tables; ``clipvol summarize STORE`` builds them."""


@dataclass(frozen=True, slots=True)
class Quantiser:
    """Maps data values to the 256 summary levels (see the module docstring)."""

    method: str  # "identity" (uint8) or "uniform"
    lo: float
    hi: float

    @classmethod
    def for_pyramid(cls, pyr: Pyramid) -> "Quantiser":
        if pyr.dtype == np.uint8:
            return cls("identity", 0.0, 255.0)
        lo, hi = (float(v) for v in pyr.value_range)
        return cls("uniform", lo, hi)

    def __call__(self, v: np.ndarray, dtype=np.int64) -> np.ndarray:
        """``(..)`` level of each value as ``dtype`` (NaN gives 0: mask NaN apart before use).

        The float64 steps run in place on one temporary (the tables quantise every voxel of every
        level twice: each pass over the data counts)."""
        if self.method == "identity":
            return v.astype(dtype)
        width = self.hi - self.lo
        with np.errstate(invalid="ignore", over="ignore"):
            if width > 0:
                t = np.subtract(v, self.lo, dtype=np.float64)
                t /= width
                t *= SUMMARY_BINS
            else:
                t = np.where(np.asarray(v, dtype=np.float64) > self.lo, SUMMARY_BINS - 1.0, 0.0)
        np.nan_to_num(t, copy=False, nan=0.0, posinf=SUMMARY_BINS - 1.0, neginf=0.0)
        np.floor(t, out=t)
        np.clip(t, 0, SUMMARY_BINS - 1, out=t)
        return t.astype(dtype)

    def centres(self) -> np.ndarray:
        """``(256,)`` float64 representative data value of each level (the value at the bin's centre)."""
        if self.method == "identity":
            return np.arange(SUMMARY_BINS, dtype=np.float64)
        width = self.hi - self.lo
        return self.lo + (np.arange(SUMMARY_BINS) + 0.5) / SUMMARY_BINS * width

    def to_attrs(self) -> dict:
        return {"method": self.method, "lo": self.lo, "hi": self.hi, "bins": SUMMARY_BINS}

    @classmethod
    def from_attrs(cls, a: dict, where: str) -> "Quantiser":
        try:
            q = cls(str(a["method"]), float(a["lo"]), float(a["hi"]))
        except (KeyError, TypeError, ValueError):
            raise StoreFormatError(f"{where}: malformed quantisation attributes {a!r}") from None
        if q.method not in ("identity", "uniform") or int(a.get("bins", SUMMARY_BINS)) != SUMMARY_BINS:
            raise StoreFormatError(f"{where}: expected quantisation 'identity' or 'uniform' with {SUMMARY_BINS} bins, got {a!r}")
        return q


@dataclass
class SummaryTables:
    """The summary tables of one store, in memory (per level, over the level's brick grid)."""

    pyramid: Pyramid
    quantiser: Quantiser
    histogram: list[np.ndarray]  # per level: grid + (256,) int64
    nan_count: list[np.ndarray]  # per level: grid int64
    pairs_offsets: list[np.ndarray | None]  # per level below top: (n_bricks + 1,) int64; None at the top
    pairs_code: list[np.ndarray | None]
    pairs_count: list[np.ndarray | None]

    def pairs(self, level: int, index) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(parent_level, child_level, count)`` of brick ``(level, index)``'s correspondence table."""
        g = self.pyramid.grid(level)
        flat = int(np.ravel_multi_index(tuple(int(i) for i in index), g))
        off = self.pairs_offsets[level]
        a, b = int(off[flat]), int(off[flat + 1])
        code = self.pairs_code[level][a:b].astype(np.int64)
        return code // SUMMARY_BINS, code % SUMMARY_BINS, self.pairs_count[level][a:b].astype(np.int64)


# -- building ------------------------------------------------------------------------------------
class _BrickReader:
    """The valid (unpadded) voxels of a brick of the store's levels, for the tables (``lead``: the
    member's index along the leading axis of an image set's 4-D arrays, :mod:`.channels`).

    Why not zarr-python: its per-brick read costs about ten times a file read plus one decode, and
    the tables read every brick of every level (most of them twice); that made ``clipvol summarize``
    slower than the bricking it follows. A level written by ``clipvol brick`` (chain ``bytes`` little
    endian, optional ``blosc``, ``crc32c``; default chunk keys) is read here as the inverse of
    :func:`~clipvol.bricking.pipeline.chunk_encoder`: the chunk file (a regular file inside the store,
    size-capped), its CRC-32C checked, one decode; a missing chunk is an empty brick (fill 0). Any
    other chain is read with zarr-python. (The loaders' reader, with the manifest and statistics
    checks, lies in a higher stage than bricking.)"""

    def __init__(self, path: Path, pyr: Pyramid, lead: tuple[int, ...] = ()) -> None:
        import zarr

        self.path, self.pyr, self.lead = Path(path), pyr, tuple(int(k) for k in lead)
        self.root = zarr.open_group(str(path), mode="r")
        self.fast: list = []
        for L in range(pyr.num_levels):
            meta = json.loads(read_file(self.path / str(L) / "zarr.json", self.path))
            names = [c.get("name") if isinstance(c, dict) else c for c in meta.get("codecs") or []]
            crc = bool(names) and names[-1] == "crc32c"
            chain = names[:-1] if crc else names
            endian = ((meta.get("codecs") or [{}])[0].get("configuration") or {}).get("endian", "little")
            cke = meta.get("chunk_key_encoding") or {}
            ok = (chain[:1] == ["bytes"] and chain[1:] in ([], ["blosc"]) and endian == "little"
                  and cke.get("name", "default") == "default"
                  and (cke.get("configuration") or {}).get("separator", "/") == "/")
            self.fast.append((crc, chain[1:] == ["blosc"]) if ok else None)

    def __call__(self, level: int, index) -> np.ndarray:
        s, e = self.pyr.brick_voxel_box(level, index)
        valid = tuple(slice(0, b - a) for a, b in zip(s, e))
        how = self.fast[level]
        if how is None:
            return np.asarray(self.root[str(level)][self.lead + tuple(slice(a, b) for a, b in zip(s, e))])
        from ..errors import BrickIntegrityError

        B, dtype = self.pyr.brick_shape, self.pyr.dtype
        name = f"{level}/c/" + "".join(f"{k}/" for k in self.lead) + f"{index[0]}/{index[1]}/{index[2]}"
        try:
            data = read_file(self.path / name, self.path, chunk_cap(int(np.prod(B)) * dtype.itemsize))
        except FileNotFoundError:
            return np.zeros(B, dtype)[valid]  # never written: all fill value
        crc, blosc = how
        if crc:
            import google_crc32c

            data, tail = data[:-4], data[-4:]
            if google_crc32c.value(data) != int.from_bytes(tail, "little"):
                raise BrickIntegrityError(f"{self.path}: chunk {name} fails its crc32c: the summary tables are "
                                          "not built from damaged data (`clipvol check` / `clipvol repair`)")
        if blosc:
            import numcodecs

            data = numcodecs.Blosc().decode(data)
        a = np.frombuffer(data, dtype=dtype.newbyteorder("<"))
        if a.size != int(np.prod(B)):
            raise BrickIntegrityError(f"{self.path}: chunk {name} decodes to {a.size} values, expected {int(np.prod(B))}")
        return a.reshape(B).astype(dtype, copy=False)[valid]


def _quantised(q: Quantiser, v: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """``(levels, nan_mask)`` of ``v``: levels as :class:`Quantiser` gives them, as uint8 (all 256
    fit: an eighth of the int64 memory to repeat and combine); mask None when ``v`` cannot hold NaN."""
    return q(v, np.uint8), (np.isnan(v) if v.dtype.kind == "f" else None)


def _up(a: np.ndarray, cut: tuple, shape: tuple) -> np.ndarray:
    """``a[cut]`` repeated 2x along each axis (one copy, by broadcasting), cropped to ``shape``."""
    b = a[cut]
    n0, n1, n2 = b.shape
    return np.broadcast_to(b[:, None, :, None, :, None], (n0, 2, n1, 2, n2, 2)).reshape(2 * n0, 2 * n1, 2 * n2)[
        : shape[0], : shape[1], : shape[2]]


def _tables_for_parent(loader: "_BrickReader", pyr: Pyramid, q: Quantiser, level: int, pidx, only=None) -> list:
    """Histograms of the children of parent ``(level, pidx)`` (level >= 1) and their correspondence
    tables (``only``: a set of child index tuples, the others skipped). The parent is quantised once,
    at its own resolution, and its levels repeated 2x per axis under each child (quantising is per
    voxel, so this equals quantising the repeated values, on an eighth of the voxels)."""
    qp, pnan = _quantised(q, loader(level, pidx))
    out = []
    grid_c = np.array(pyr.grid(level - 1))
    B = np.array(pyr.brick_shape)
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                c = np.array(pidx) * 2 + (dz, dy, dx)
                if np.any(c >= grid_c) or (only is not None and tuple(int(v) for v in c) not in only):
                    continue
                child = loader(level - 1, tuple(int(v) for v in c))
                off = (np.array((dz, dy, dx)) * B) // 2
                n = -(-np.array(child.shape) // 2)
                cut = (slice(off[0], off[0] + n[0]), slice(off[1], off[1] + n[1]), slice(off[2], off[2] + n[2]))
                out.append((tuple(int(v) for v in c),)
                           + _hist_and_pairs(q, child, _up(qp, cut, child.shape),
                                             None if pnan is None else _up(pnan, cut, child.shape)))
    return out


def _hist_and_pairs(q: Quantiser, child: np.ndarray, qp_up: np.ndarray | None, pnan_up: np.ndarray | None = None):
    """Histogram, NaN count and (with the parent's levels ``qp_up`` and NaN mask ``pnan_up`` under
    each child voxel) the non-zero correspondence pairs of one brick, in ascending code order.

    The pairs are counted by sorting the brick's 16-bit codes (numpy sorts 16-bit integers by radix)
    and cutting the runs: work in the brick's voxels, where a 65,536-bin count and its scan for
    non-zeros cost as much again for every brick, however small."""
    qc, nan = _quantised(q, child.reshape(-1))
    if nan is not None and nan.any():
        hist = np.bincount(qc[~nan], minlength=SUMMARY_BINS)
        nan_count = int(nan.sum())
    else:
        nan, hist, nan_count = None, np.bincount(qc, minlength=SUMMARY_BINS), 0
    if qp_up is None:
        return hist, nan_count, None, None
    code = (qp_up.reshape(-1).astype(np.uint16) << 8) | qc  # parent * 256 + child
    ok = None if pnan_up is None or not pnan_up.any() else ~pnan_up.reshape(-1)
    if nan is not None:
        ok = ~nan if ok is None else ok & ~nan
    if ok is not None:
        code = code[ok]
    if not code.size:
        return hist, nan_count, np.zeros(0, np.uint16), np.zeros(0, np.uint32)
    srt = np.sort(code, kind="stable")
    starts = np.flatnonzero(np.concatenate(([True], srt[1:] != srt[:-1])))
    counts = np.diff(np.append(starts, srt.size))
    return hist, nan_count, srt[starts], counts.astype(np.uint32)


def build_summary(path, *, workers: int | None = None, progress: bool = True, overwrite: bool = False,
                  data: tuple[Path, tuple[int, ...]] | None = None) -> None:
    """Build (or finish) the summary tables of the clipvol store at ``path``.

    ``data``: ``(root, (k,))`` for member ``k`` of an image set (``path`` its member group, its
    bricks the root's 4-D arrays at ``k``; :mod:`clipvol.bricking.channels`).

    Streams the store one parent brick (and its eight children) at a time, on ``workers``
    threads; memory holds one level's tables, never a level's voxels. Levels already finished by
    an interrupted run are kept (``overwrite`` rebuilds everything). ``complete`` is the last write.
    """
    import os

    import zarr
    from tqdm import tqdm

    path = Path(path)
    meta = open_store_meta(path, require_complete=True)
    pyr = meta.pyramid
    q = Quantiser.for_pyramid(pyr)
    root = zarr.open_group(str(path), mode="r+")
    loader = _BrickReader(path, pyr) if data is None else _BrickReader(Path(data[0]), pyr, data[1])
    attrs = None
    if SUMMARY_GROUP in root and not overwrite:
        attrs = dict(root[SUMMARY_GROUP].attrs)
        if attrs.get("quantisation") != q.to_attrs() or attrs.get("format") != _FORMAT:
            attrs = None  # another quantisation: rebuild
    if attrs is None:
        import shutil

        shutil.rmtree(path / SUMMARY_GROUP, ignore_errors=True)
        g = root.create_group(SUMMARY_GROUP)
        attrs = {"format": _FORMAT, "quantisation": q.to_attrs(), "levels_done": [], "complete": False}
        g.attrs.update(attrs)
    group = root[SUMMARY_GROUP]
    done = set(int(v) for v in attrs.get("levels_done", []))
    workers = workers or os.cpu_count() or 1
    total = sum(pyr.num_bricks(L) for L in range(pyr.num_levels) if L not in done)
    bar = tqdm(total=total, unit="brick", desc="summary tables", file=sys.stderr, disable=not progress,
               dynamic_ncols=True)
    try:
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="clipvol-summary") as pool:
            for L in range(pyr.num_levels):
                if L in done:
                    continue
                _build_level(group, loader, pyr, q, L, pool, bar)
                done.add(L)
                group.attrs.update({"levels_done": sorted(done)})
    finally:
        bar.close()
    group.attrs.update({"complete": True})  # the very last write


def summary_of(read, pyr: Pyramid, children, *, workers: int | None = None) -> SummaryTables:
    """In-memory summary tables of some bricks: for each level ``L`` below the top, the correspondence
    tables and histograms of the bricks ``children[L]`` (``(n, 3)``); every other brick has none (no
    pairs, an empty histogram). ``read(level, index)`` returns a brick's valid voxels.

    Why: a source that is not a store on disk (a benchmark's virtual 1024³ store, generated brick by
    brick) has no tables, and building them for every brick means generating the whole volume. The
    bricks a slice can touch are few; their tables come from the same code :func:`build_summary`
    runs over a store's bricks (:func:`_tables_for_parent`), so they equal a full build's there."""
    import os

    q = Quantiser.for_pyramid(pyr)
    top = pyr.num_levels - 1
    hist = [np.zeros(pyr.grid(L) + (SUMMARY_BINS,), dtype=np.int64) for L in range(pyr.num_levels)]
    nanc = [np.zeros(pyr.grid(L), dtype=np.int64) for L in range(pyr.num_levels)]
    offs, codes, counts = [], [], []
    with ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
        for L in range(top):
            want = {tuple(int(v) for v in c) for c in np.asarray(children[L], dtype=np.int64).reshape(-1, 3)}
            parents = sorted({(c[0] // 2, c[1] // 2, c[2] // 2) for c in want})
            n = pyr.num_bricks(L)
            cd: list = [np.zeros(0, np.uint16)] * n
            ct: list = [np.zeros(0, np.uint32)] * n
            for res in pool.map(lambda p: _tables_for_parent(read, pyr, q, L + 1, p, only=want), parents):
                for idx, h, nc, c, k in res:
                    hist[L][idx], nanc[L][idx] = h, nc
                    flat = int(np.ravel_multi_index(idx, pyr.grid(L)))
                    cd[flat], ct[flat] = c, k
            offs.append(np.concatenate([[0], np.cumsum([len(c) for c in cd])]).astype(np.int64))
            codes.append(np.concatenate(cd).astype(np.uint16))
            counts.append(np.concatenate(ct).astype(np.uint32))
    return SummaryTables(pyr, q, hist, nanc, offs + [None], codes + [None], counts + [None])


def _build_level(group, loader, pyr: Pyramid, q: Quantiser, L: int, pool, bar) -> None:
    """Tables of every brick of level ``L``: histograms, and (below the top) pairs with the parent."""
    grid = pyr.grid(L)
    n = int(np.prod(grid))
    hist = np.zeros(grid + (SUMMARY_BINS,), dtype=np.uint32)
    nanc = np.zeros(grid, dtype=np.int64)
    codes: list = [None] * n
    counts: list = [None] * n
    top = L == pyr.num_levels - 1
    if top:
        def one(idx):
            return [(idx,) + _hist_and_pairs(q, loader(L, idx), None)]
        jobs = [tuple(int(v) for v in i) for i in np.ndindex(*grid)]
    else:
        def one(pidx):
            return _tables_for_parent(loader, pyr, q, L + 1, pidx)
        jobs = [tuple(int(v) for v in i) for i in np.ndindex(*pyr.grid(L + 1))]
    for res in pool.map(one, jobs):
        for idx, h, nc, cd, ct in res:
            hist[idx] = h
            nanc[idx] = nc
            flat = int(np.ravel_multi_index(idx, grid))
            codes[flat], counts[flat] = cd, ct
            bar.update(1)
    lg = group.require_group(str(L))
    row = (1,) + tuple(grid[1:])
    lg.create_array("histogram", shape=hist.shape, chunks=row + (SUMMARY_BINS,), dtype="uint32", fill_value=0,
                    overwrite=True)[...] = hist
    lg.create_array("nan_count", shape=grid, chunks=row, dtype="int64", fill_value=0, overwrite=True)[...] = nanc
    if not top:
        lens = np.array([len(c) for c in codes], dtype=np.int64)
        off = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
        allc = np.concatenate(codes) if n else np.zeros(0, np.uint16)
        allk = np.concatenate(counts) if n else np.zeros(0, np.uint32)
        chunk = max(1, min(len(allc), 1 << 20))
        lg.create_array("pairs_offsets", shape=off.shape, chunks=(min(len(off), 1 << 20),), dtype="int64",
                        fill_value=0, overwrite=True)[...] = off
        lg.create_array("pairs_code", shape=allc.shape, chunks=(chunk,), dtype="uint16", fill_value=0,
                        overwrite=True)[...] = _delta(allc, off)
        lg.create_array("pairs_count", shape=allk.shape, chunks=(chunk,), dtype="uint32", fill_value=0,
                        overwrite=True)[...] = allk


def _delta(codes: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Codes stored as differences within each brick (the first one absolute): ascending codes near
    the table's diagonal become small numbers that compress several times better."""
    d = np.diff(codes.astype(np.int64), prepend=0)
    starts = off[:-1][np.diff(off) > 0]
    d[starts] = codes[starts]
    return d.astype(np.uint16)


def _undelta(d: np.ndarray, off: np.ndarray) -> np.ndarray:
    c = np.cumsum(d.astype(np.int64))
    starts = off[:-1][np.diff(off) > 0]
    base = np.zeros(len(d), np.int64)
    if len(starts):
        # subtract the running sum before each brick's first entry
        seg = np.repeat(np.arange(len(starts)), np.diff(np.append(starts, len(d))))
        before = c[starts] - d[starts].astype(np.int64)
        base = before[seg]
    return (c - base).astype(np.uint16)


# -- reading ---------------------------------------------------------------------------------------
def open_summary(path) -> SummaryTables:
    """Read the summary tables of the store at ``path``.

    Raises :class:`SummaryMissingError` (naming ``clipvol summarize``) when the store has none or
    their build was interrupted, :class:`StoreFormatError` naming the part when a level's table is
    missing from tables marked complete (deleted or damaged since).
    """
    try:
        return _read_summary(path)
    except KeyError as e:
        raise StoreFormatError(f"{path}/{SUMMARY_GROUP}: the table {e} is missing from summary tables marked "
                               f"complete; rebuild them with `clipvol summarize --overwrite {path}`") from None


def _read_summary(path) -> SummaryTables:
    import json

    import zarr

    path = Path(path)
    meta = open_store_meta(path)
    pyr = meta.pyramid
    zj = path / SUMMARY_GROUP / "zarr.json"
    try:
        attrs = json.loads(zj.read_text()).get("attributes", {})
    except FileNotFoundError:
        raise SummaryMissingError(f"{path}: no summary tables (image-based level of detail needs them); "
                                  f"build them with `clipvol summarize {path}`") from None
    except (OSError, ValueError) as e:
        raise StoreFormatError(f"{zj}: unreadable ({e})") from None
    if not attrs.get("complete"):
        raise SummaryMissingError(f"{path}: the summary tables are incomplete (an interrupted build); "
                                  f"finish them with `clipvol summarize {path}`")
    q = Quantiser.from_attrs(attrs.get("quantisation", {}), f"{path}/{SUMMARY_GROUP}")
    g = zarr.open_group(str(path / SUMMARY_GROUP), mode="r")
    hist, nanc, offs, codes, counts = [], [], [], [], []
    for L in range(pyr.num_levels):
        lg = g[str(L)]
        h = np.asarray(lg["histogram"][...]).astype(np.int64)
        if h.shape != pyr.grid(L) + (SUMMARY_BINS,):
            raise StoreFormatError(f"{path}/{SUMMARY_GROUP}/{L}/histogram: expected shape "
                                   f"{list(pyr.grid(L)) + [SUMMARY_BINS]}, got {list(h.shape)}")
        hist.append(h)
        nanc.append(np.asarray(lg["nan_count"][...]))
        if L < pyr.num_levels - 1:
            off = np.asarray(lg["pairs_offsets"][...])
            ct = np.asarray(lg["pairs_count"][...])
            cd = np.asarray(lg["pairs_code"][...])
            if off.shape != (pyr.num_bricks(L) + 1,) or off[-1] != len(cd) or len(cd) != len(ct) or np.any(np.diff(off) < 0):
                raise StoreFormatError(f"{path}/{SUMMARY_GROUP}/{L}: inconsistent correspondence tables "
                                       f"(offsets {off.shape}, {len(cd)} codes, {len(ct)} counts)")
            offs.append(off)
            codes.append(_undelta(cd, off))
            counts.append(ct)
        else:
            offs.append(None)
            codes.append(None)
            counts.append(None)
    return SummaryTables(pyr, q, hist, nanc, offs, codes, counts)


def tree_bytes(base) -> int:
    """Bytes on disk of every file under the folder ``base`` (a store's side group)."""
    import os

    size = 0
    for r, _d, files in os.walk(base):
        for f in files:
            size += os.path.getsize(os.path.join(r, f))
    return size


def summary_bytes(path) -> int | None:
    """Bytes on disk of the store's summary tables, or None when it has none."""
    base = Path(path) / SUMMARY_GROUP
    if not base.is_dir():
        return None
    return tree_bytes(base)
