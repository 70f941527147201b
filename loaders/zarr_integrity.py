"""Integrity of what the zarr loader reads: never wrong data as if right.

Why its own module: these checks are the reason a load can be trusted, and each has a cost paid on
every read, so they sit together where their reasoning can be read at once.

- The store's manifest (:mod:`clipvol.bricking.manifest`) is verified on opening
  (:meth:`IntegrityChecks._verify_manifest`): when it verifies (``loader.verified``), "the
  statistics" below are its per-brick records - each chunk's exact size and crc32c and the brick's
  bounds, keyed by brick index - so deleting or replacing the statistics arrays changes nothing a
  load trusts, and each statistics array is compared with its digest when read. A clipvol store
  without one, or whose manifest does not verify, or without checksums, opens *unverified*
  (``loader.trust`` says why) with an :class:`UnverifiedStoreWarning`, and the checks fall back
  to the statistics arrays.
- A ``crc32c`` codec is verified over every byte of the chunk before decoding, on every read
  (:meth:`IntegrityChecks._verify_chunk`; the function is :func:`clipvol.loaders.zarr_crc.crc32c_implementation`),
  and an intact chunk must carry the crc32c recorded for its brick (not another brick's).
- Decoded data is checked against the statistics for that brick
  (:meth:`IntegrityChecks._check_plausible`): on every load where the bytes are unproven; where the
  manifest verified and the chunk carries the crc32c it records for the brick, a sample of the
  decode is checked on the brick's first load in this process only
  (:meth:`IntegrityChecks._check_loaded` says why the per-load checks still catch every fault
  kind), which takes numpy's GIL-holding reductions off the per-load path. A missing chunk file
  is an empty brick only if the statistics say the brick is empty
  (:meth:`IntegrityChecks._check_absent`), on every load.

A truncated, corrupt, substituted or lost chunk raises :class:`~clipvol.errors.BrickIntegrityError`
naming the store, brick and chunk file. The per-brick statistics are also the loader's
``brick_statistics`` / ``brick_ranges`` (the ``HasBrickRanges`` extension of the loader contract).

A mixin of :class:`~clipvol.loaders.zarr_store.ZarrLoader`: the checks run inside the read path of
:mod:`clipvol.loaders.zarr_chunks`, on the loader's own attributes, without an extra object hop.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from clipvol.bricking.manifest import (ManifestError, load_manifest, metadata_pins, metadata_problems,
                                      read_manifest_doc)
from clipvol.bricking.pyramid import Int3
from clipvol.bricking.store import STAT_ARRAYS, STATS_GROUP
from clipvol.bricking.store_files import check_tree
from clipvol.errors import BrickIntegrityError, InputFormatError, ParameterError, StoreFormatError
from clipvol.paging.bytesource import is_remote_url
from clipvol.paging.loader import BrickKey

from .zarr_crc import _CRC32C_RESIDUE
from .zarr_meta import array_meta

__all__ = ["IntegrityChecks", "UnverifiedStoreWarning", "SAMPLE_STRIDE", "no_checksum_reason"]


def no_checksum_reason(checksummed: list[bool], clipvol_attrs: dict) -> str:
    """Why chunks go unchecked when some level's codec chain does not end with ``crc32c``
    (``checksummed[L]``), in the store's own terms: a store written before chunk checksums lacks
    it on every level and has no manifest; a level without it beside levels with it, or in a store
    with a manifest (a build writes the manifest with its checksummed chunks), is a codec list
    edited since the build, and saying "written before checksums" would send the user the wrong way."""
    missing = [L for L, ok in enumerate(checksummed) if not ok]
    where = (f"level{'s' if len(missing) > 1 else ''} {', '.join(map(str, missing))} "
             f"({', '.join(f'{L}/zarr.json' for L in missing)})")
    tail = "(corruption inside a chunk is caught only by the statistics check; `clipvol check --all` reads every brick)"
    if isinstance(clipvol_attrs.get("manifest"), dict):
        return (f"the codec list of {where} has no crc32c, but the store has a manifest, which clipvol "
                f"writes with chunk checksums: the metadata was edited since the build {tail}")
    if len(missing) < len(checksummed):
        return (f"the codec list of {where} has no crc32c while the other levels have it: the metadata "
                f"was edited since the build {tail}")
    return f"written before chunk checksums (no level's codec list has crc32c) {tail}"


class UnverifiedStoreWarning(UserWarning):
    """A clipvol store whose manifest is missing or does not verify (one written before manifests,
    or damaged), or one written before chunk checksums: its bricks load, but what the reader
    believes about unread bricks rests on statistics nothing vouches for."""


class _ChecksumError(ValueError):
    """A chunk whose crc32c does not match its bytes (turned into a BrickIntegrityError naming the file)."""


class _IdentityError(ValueError):
    """An intact chunk that is not the one written for its brick."""


#: "not looked up yet" (None means "no statistics")
_UNREAD = object()
#: the largest statistics array file read (a row of per-brick histograms of a very wide level)
MAX_STATS_FILE_BYTES = 256 * 2**20
#: a brick whose chunk checksum is proven checks the decode on every SAMPLE_STRIDE-th row of every
#: SAMPLE_STRIDE-th z-plane (1/64 of its voxels; see IntegrityChecks._check_plausible for why that is enough)
SAMPLE_STRIDE = 8


class IntegrityChecks:
    """The manifest, chunk checksums and statistics checks, and the statistics themselves."""

    #: check loads against the store's statistics (see _check_loaded; set False only to measure what it costs)
    check_plausibility: bool = True
    #: verify each chunk's crc32c (set False only to measure what it costs)
    verify_checksums: bool = True

    def _check_pinned_metadata(self, attrs: dict) -> None:
        """Refuse a store whose metadata differs from what its manifest pins
        (:func:`clipvol.bricking.manifest.metadata_problems`): a level's ``zarr.json`` with another
        byte order, codec chain, fill value, shape or chunk grid, or another multiscale list.

        Why on opening, before the levels are parsed: a level's metadata decides how every chunk
        decodes and where the level lies; a verified chunk decoded with an edited codec chain is
        wrong voxels, and an edited fill value turns unwritten bricks into other values. A
        manifest that does not verify leaves this to :meth:`_verify_manifest` (the store opens
        unverified); one written before metadata pins is marked by ``metadata_pinned``."""
        self._manifest_doc = None
        cv = attrs.get("clipvol")
        if not isinstance(cv, dict):
            return
        try:
            self._manifest_doc = read_manifest_doc(self.meta_path, cv)
        except ManifestError:
            return
        # the levels and the multiscale list now; each level's other arrays (its statistics) when
        # they are first read (brick_statistics): a reader that never reads them pays nothing
        # a set member's group holds no multiscale list of its own (the set's root does, 4-D)
        member = self.meta_path != self.path
        problems = metadata_problems(self.meta_path, metadata_pins(self._manifest_doc), None if member else attrs,
                                     levels_only=True)
        if problems:
            shown = "; ".join(problems[:6]) + (f"; and {len(problems) - 6} more" if len(problems) > 6 else "")
            fix = ("`clipvol repair STORE --source INPUT` on the store where it is written restores it from the manifest"
                   if is_remote_url(self._where) else
                   f"`clipvol repair {self._where} --source INPUT` restores it from the manifest")
            raise StoreFormatError(f"{self._where}: metadata differs from the store's manifest: {shown}. {fix}")

    def _verify_manifest(self, clipvol_attrs: dict, *, warn: bool) -> None:
        """Set ``verified``, ``trust`` and ``_manifest`` of a clipvol store whose levels are open;
        warn (:class:`UnverifiedStoreWarning`) when it is unverified and ``warn``."""
        if not all(am.checksum for am in self._arrays):
            self.trust = f"unverified: {no_checksum_reason([am.checksum for am in self._arrays], clipvol_attrs)}"
        else:
            try:
                self._manifest = load_manifest(self.meta_path, clipvol_attrs,
                                               [self._pyramid.grid(L) for L in range(self._pyramid.num_levels)],
                                               doc=getattr(self, "_manifest_doc", None))
                self.verified = True
                self.metadata_pinned = self._manifest.metadata_pinned
                if self.metadata_pinned:
                    self.trust = (f"verified: manifest sha256 {self._manifest.sha256[:16]}... pins every brick's chunk "
                                  "and statistics and every level's metadata")
                else:
                    self.trust = (f"verified: manifest sha256 {self._manifest.sha256[:16]}... pins every brick's chunk "
                                  "and statistics, not the arrays' metadata (a manifest written before metadata pins: "
                                  f"`clipvol repair {self._where} --source INPUT` adds them)")
            except ManifestError as e:
                self.trust = f"unverified: {e}"
        if not self.verified and warn:
            warnings.warn(f"{self._where}: {self.trust}", UnverifiedStoreWarning, stacklevel=4)

    def _verify_chunk(self, data: Any, level: int, index: Int3, st: Any) -> tuple[Any, int]:
        """``(body, proof)`` of a chunk ending in its crc32c: the bytes before the checksum, and 2
        when the checksum is intact *and* equals the one the statistics recorded for this brick (the
        bytes are exactly those written here), else 1. ``st``: the brick's :meth:`_brick_stats`, or
        ``_UNREAD`` to look them up. Raises ``_ChecksumError`` / ``_IdentityError`` (the read path
        names the file) or ValueError for a chunk too short to hold a checksum."""
        if len(data) < 4:
            raise ValueError(f"{len(data)} bytes cannot hold a crc32c checksum")
        # one pass, no copy: the CRC-32C of a message followed by its own CRC is a constant
        if self.verify_checksums and self._crc32c(data) != _CRC32C_RESIDUE:
            want, got = int.from_bytes(data[-4:], "little"), self._crc32c(bytes(data[:-4]))
            raise _ChecksumError(f"crc32c checksum mismatch (stored {want:#010x}, computed {got:#010x})")
        body = memoryview(data)[:-4]
        if not self.verify_checksums:
            st = None
        elif st is _UNREAD:
            st = self._brick_stats(level, index)
        if st is not None and st[4] == st[4]:  # the crc recorded for this brick (not NaN)
            have = int.from_bytes(data[-4:], "little")
            if st[4] < 0:
                raise _IdentityError("the statistics say no chunk was written for this brick")
            if have != int(st[4]):
                raise _IdentityError(f"it is an intact chunk (crc32c {have:#010x}) but not the one written "
                                     f"for this brick ({int(st[4]):#010x}): another brick's, or another build's")
            return body, 2
        return body, 1

    def _brick_stats(self, level: int, index: Int3) -> tuple[float, float, float, float, float] | None:
        """``(min, max, nan_count, inf_count, chunk_crc32c)`` the store recorded for the brick (NaN
        where not recorded: not compared; crc -1: no chunk written), or None (no statistics). One
        lookup in a per-level table of Python floats (nested lists, not an array: indexing a list
        costs a fraction of a numpy item lookup and its ``tolist``, on every load, under the GIL)."""
        tbl = self._checks.get(level, _UNREAD)
        if tbl is _UNREAD:
            if self._manifest is not None:  # a verified store: the manifest, never the statistics arrays
                self._checks[level] = tbl = self._manifest.checks(level).tolist()
                return tuple(tbl[index[0]][index[1]][index[2]])
            st = self.brick_statistics(level)
            tbl = None
            if st is not None:
                missing = np.full(st["min"].shape, np.nan)
                cols = [st["min"], st["max"]] + [st[n] if n in st else missing for n in ("nan_count", "inf_count", "chunk_crc32c")]
                tbl = np.stack(cols, axis=-1).astype(np.float64).tolist()  # a crc32c (< 2**32) is exact in float64
            self._checks[level] = tbl
        if tbl is None:
            return None
        return tuple(tbl[index[0]][index[1]][index[2]])

    def _check_loaded(self, level: int, index: Int3, block: np.ndarray, got: int, st: Any = _UNREAD) -> None:
        """The decode check of one load (:meth:`_check_plausible`), run once per brick per loader
        when the bytes are proven against a verified manifest, on every load otherwise.

        Why once is enough there: ``got == 2`` on a verified store means the chunk's crc32c is
        intact (every stored byte checked on this load) *and* equals the crc32c the manifest -
        whose digest verified on opening - records for this brick, so the bytes are the ones the
        build wrote for it. The same bytes through the same decoder give the same voxels, so a
        sampled decode check that passed on an earlier load of this brick in this process
        proves this one too. Each fault kind stays caught on every load by a check that does not
        depend on the skipped one: corrupt or truncated bytes by the crc32c (and the exact chunk
        size the manifest records, checked before the read), another brick's or another build's
        intact chunk by the recorded crc32c, a lost chunk by :meth:`_check_absent`, a wrong
        decoder by the first load's sample (the record names the level's codec chain it was made
        with, so a level whose decoder is set up anew is sampled anew). An
        unverified store, a chunk without a recorded crc32c (``got == 1``), or checks switched
        off and on again (``verify_checksums`` off makes ``got`` 1) are checked on every load.
        """
        if got == 2 and self._manifest is not None:
            am = self._arrays[level]  # the level's codec chain: a record holds for the decoder it was made with
            rec = self._decode_proven.get(level)
            if rec is None or rec[0] is not am:
                gz, gy, gx = self._grids[level]
                rec = self._decode_proven[level] = (am, bytearray(gz * gy * gx))  # one byte a brick
            _, gy, gx = self._grids[level]  # precomputed per level (ChunkReader._prepare_hot_path)
            i = (index[0] * gy + index[1]) * gx + index[2]
            if rec[1][i]:
                return
            self._check_plausible(level, index, block, True, st)
            if self.check_plausibility:
                rec[1][i] = 1  # a byte store: loader threads share the record (a lost race only checks again)
            return
        self._check_plausible(level, index, block, got == 2, st)

    def _decode_on_record(self, level: int, index: Int3) -> bool:
        """True when brick ``index`` of ``level`` has its sampled decode check on record
        (:meth:`_check_loaded` skips it on later loads)."""
        rec = self._decode_proven.get(level)
        if rec is None or rec[0] is not self._arrays[level]:
            return False
        _, gy, gx = self._grids[level]
        return bool(rec[1][(index[0] * gy + index[1]) * gx + index[2]])

    def _check_absent(self, level: int, index: Int3) -> None:
        """A missing chunk is an empty brick only if the statistics say so (min = max = fill, no NaN/Inf)."""
        if not self.check_plausibility:
            return
        st = self._brick_stats(level, index)
        if st is None:
            return
        lo, hi, nan, inf, crc = st
        fill = self._pyramid.fill_value
        if not (lo == fill and hi == fill and not nan > 0 and not inf > 0) or crc >= 0:
            raise BrickIntegrityError(
                f"{self._where}: {BrickKey(level, index)}: chunk {self._chunk_name(level, index)} is missing, but the "
                f"store's statistics say the brick holds data (min {lo:g}, max {hi:g}, {nan:g} NaN, {inf:g} Inf)")

    def _check_plausible(self, level: int, index: Int3, block: np.ndarray, proven: bool = False,
                         st: Any = _UNREAD) -> None:
        """Decoded data against the statistics written with the brick (``block``: exactly its valid
        voxels; an interior brick: all of them).

        Unproven bytes (no checksum, or none recorded for this brick): the decoded min and max (and
        NaN/Inf counts) must *equal* the statistics: one SIMD min and max while the brick is in
        cache; NaN/Inf are counted only when that pass meets one. ``proven`` bytes (their crc32c is
        intact and is the one recorded for this brick, so they are exactly what was written here):
        every eighth row of every eighth z-plane must lie inside the brick's bounds. That checks
        the decode, not the bytes: a wrong decoder (byte order, shuffle, type size) makes every
        voxel wrong, and a blosc block decoded wrong makes a contiguous run of kilobytes wrong -
        whole rows, so a bad block holding a sampled plane holds sampled rows too, as whole sampled
        planes would. A sixty-fourth of the voxels rather than every eighth plane: numpy holds the
        GIL over these small reductions, so with two loader threads sampling an eighth costs about
        30 us a float32 64^3 brick, and the sixty-fourth gives the loader 2-2.5 % of throughput
        (paired runs, float32 and uint16). ``st``: the brick's :meth:`_brick_stats` when the caller
        has looked them up already.
        """
        if not self.check_plausibility:
            return
        if st is _UNREAD:
            st = self._brick_stats(level, index)
        if st is None:
            return
        lo, hi, nan, inf, _ = st
        part = block[::SAMPLE_STRIDE, ::SAMPLE_STRIDE] if proven and block.ndim == 3 else block
        mn, mx = part.min(), part.max()
        if part.dtype.kind == "f" and not (math.isfinite(mn) and math.isfinite(mx)):
            fin = np.isfinite(part)
            got_nan = int(np.count_nonzero(np.isnan(part)))
            got_inf = int(part.size - np.count_nonzero(fin) - got_nan)
            vals = part[fin]
            mn, mx = (vals.min(), vals.max()) if vals.size else (math.nan, math.nan)
        else:
            got_nan = got_inf = 0
        mn, mx = float(mn), float(mx)
        if proven:
            inside = (lo <= mn and mx <= hi) or (math.isnan(mn) and math.isnan(mx))
            if inside and (got_nan == 0 or not nan == 0) and (got_inf == 0 or not inf == 0):
                return
        elif mn == lo and mx == hi and (got_nan == nan or nan != nan) and (got_inf == inf or inf != inf):
            return  # the common case: equal bounds, counts equal or not recorded (NaN)
        else:
            same = (mn == lo or (math.isnan(mn) and math.isnan(lo))) and (mx == hi or (math.isnan(mx) and math.isnan(hi)))
            if same and not (nan == nan and got_nan != nan) and not (inf == inf and got_inf != inf):
                return
        what = "a sample (every 8th row of every 8th plane) of the decoded data" if proven else "decoded data"
        raise BrickIntegrityError(
            f"{self._where}: {BrickKey(level, index)}: {what} (min {mn:g}, max {mx:g}, {got_nan} NaN, "
            f"{got_inf} Inf) disagrees with the store's statistics (min {lo:g}, max {hi:g}, {nan:g} NaN, {inf:g} Inf): "
            "the chunk is corrupt or belongs to another brick")

    def brick_statistics(self, level: int) -> dict[str, np.ndarray] | None:
        """The store's per-brick statistics of ``level`` (``min``, ``max``, ``mean``, ... over the
        brick grid, as written by ``clipvol brick``), or ``None`` for a plain OME-Zarr image.
        Read once per level and cached; do not modify the returned arrays."""
        self._pyramid.check_key(level, (0, 0, 0))
        if not self.is_clipvol_store:
            return None
        with self._lock:
            if level in self._stats:
                return self._stats[level]
        stats: dict[str, np.ndarray] | None = {}
        base = self.meta_path / STATS_GROUP / str(level)
        if base.is_dir():
            import zarr

            try:  # zarr-python opens these files itself: look at what they are first
                check_tree(base, self.path, MAX_STATS_FILE_BYTES)
            except InputFormatError as e:
                raise StoreFormatError(f"{self._where}: {STATS_GROUP}/{level}: {e}") from None
            if self._manifest is not None:
                changed = metadata_problems(self.meta_path, self._manifest, None, level=level)
                if changed:
                    raise StoreFormatError(f"{self._where}: metadata differs from the store's manifest: "
                                           f"{'; '.join(changed[:6])}: the statistics cannot be trusted "
                                           f"(`clipvol repair {self._where} --source INPUT` restores it)")
            grid = self._pyramid.grid(level)
            for name in STAT_ARRAYS:
                p = base / name
                if not p.is_dir():
                    continue
                am = array_meta(p, f"{self._where} {STATS_GROUP}/{level}/{name}", self.path) if name != "done" else None
                if am is not None and tuple(am.shape[:3]) != grid:
                    raise StoreFormatError(f"{self._where}: {STATS_GROUP}/{level}/{name}: expected shape starting "
                                           f"{list(grid)}, got {list(am.shape)}")
                a = np.asarray(zarr.open_array(str(p), mode="r")[...])
                a.setflags(write=False)
                stats[name] = a
        if self._manifest is not None:
            problems = self._manifest.stats_problems(level, stats)
            if problems:
                raise StoreFormatError(f"{self._where}: {'; '.join(problems)}: the statistics cannot be trusted "
                                       f"(`clipvol repair {self._where} --source INPUT` rewrites them)")
        if not stats or "min" not in stats or "max" not in stats:
            stats = None
        with self._lock:
            self._stats[level] = stats
        return stats

    def refresh_statistics(self) -> None:
        """Forget the cached statistics (after ``clipvol repair`` rewrote some): the next load re-reads them."""
        with self._lock:
            self._stats.clear()
            self._checks.clear()
            self._decode_proven.clear()

    def brick_ranges(self, level: int, indices: np.ndarray) -> np.ndarray | None:
        """``(n, 2)`` ``[min, max]`` of each brick in ``indices`` (``(n, 3)``) from the store's
        statistics, or ``None`` (plain OME-Zarr, or no statistics). A verified store answers from its
        manifest, so a deleted or replaced statistics array never makes a brick look empty."""
        if self._manifest is not None:
            self._pyramid.check_key(level, (0, 0, 0))
            t = self._manifest.tables[level]
            stats = {"min": t["min"], "max": t["max"], "nan_count": t["nan_count"], "inf_count": t["inf_count"]}
        else:
            stats = self.brick_statistics(level)
        if stats is None:
            return None
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        g = np.array(self._pyramid.grid(level))
        if np.any(idx < 0) or np.any(idx >= g):
            raise ParameterError(f"{self.path}: brick_ranges: expected indices inside level {level}'s grid {tuple(g)}, "
                                 f"got {idx[np.any((idx < 0) | (idx >= g), axis=1)][0].tolist()}")
        t = (idx[:, 0], idx[:, 1], idx[:, 2])
        out = np.stack([stats["min"][t], stats["max"][t]], axis=1).astype(np.float64)
        # Bounds must not hide non-finite voxels: a brick of fill value plus NaN is not "empty".
        if "inf_count" in stats:
            out[stats["inf_count"][t] > 0] = (-np.inf, np.inf)
        if "nan_count" in stats:
            out[stats["nan_count"][t] > 0] = np.nan
        return out
