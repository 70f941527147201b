"""The store manifest: what each brick's chunk and statistics must be, pinned by one checksum.

Why: a reader believes things about bricks it has not read - this one is empty, that one holds
values in ``[lo, hi]``, this chunk's crc32c is the one written here - and all of it comes from the
per-brick statistics arrays. Those are zarr arrays of small chunks: one can be deleted, or replaced
by another chunk that is intact on its own (a row of another level or another build), and nothing
inside the array notices. The manifest makes them answerable to one number in the root metadata:

* per level, a table with **one record per brick, keyed by its index**: the brick index itself,
  the size in bytes and the crc32c of its stored chunk (``-1`` and 0 bytes: no chunk written),
  and its ``min``, ``max``, ``nan_count`` and ``inf_count``; a record cannot move to another brick
  without its index field disagreeing with its place, or the table's digest changing;
* per level, the SHA-256 of every statistics array's values (``clipvol_stats/<L>/<name>``), so a
  statistics chunk swapped for another valid one is caught when the array is read;
* ``manifest.json`` lists the tables with their SHA-256, and its own SHA-256 and length are
  recorded in the root attributes (``attrs["clipvol"]["manifest"]``).

Layout::

    clipvol_manifest/manifest.json   {"format": 1, "levels": [{"grid", "table", "table_sha256", "stats"}]}
    clipvol_manifest/<L>.bin         records of TABLE_DTYPE, C order over level L's brick grid

Loading (:func:`load_manifest`) verifies the whole chain first; any break - no manifest recorded,
a file missing, a digest that differs, a record in the wrong place - raises
:class:`ManifestError` with the reason, and the reader treats the store as *unverified*.

The manifest is written once, as the last step of a build (:func:`write_manifest`, called by
``mark_complete``) and again by ``clipvol repair``; it is derived from the statistics the build
recorded while it wrote each chunk (crc32c of the encoded bytes) and the chunk files' sizes.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .store import STAT_ARRAYS, STATS_GROUP

__all__ = [
    "MANIFEST_DIR",
    "MANIFEST_FORMAT",
    "TABLE_DTYPE",
    "Manifest",
    "ManifestError",
    "stats_digest",
    "build_tables",
    "write_manifest",
    "load_manifest",
]

MANIFEST_DIR = "clipvol_manifest"
MANIFEST_FORMAT = 1
#: one record per brick (little-endian, 60 bytes)
TABLE_DTYPE = np.dtype([("index", "<i4", (3,)), ("nbytes", "<i8"), ("crc32c", "<i8"), ("min", "<f8"), ("max", "<f8"),
                        ("nan_count", "<i8"), ("inf_count", "<i8")])
#: the statistics arrays whose values the manifest pins (``done`` included: a finished store is all true)
PINNED_STATS = tuple(n for n in STAT_ARRAYS)


class ManifestError(ValueError):
    """The manifest is missing or does not verify; the message says why (the store is then unverified)."""


def stats_digest(a: np.ndarray) -> str:
    """SHA-256 of a statistics array's values: its dtype kind and size, shape and little-endian C-order
    bytes (independent of how zarr chunked or compressed them)."""
    a = np.asarray(a)
    le = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
    h = hashlib.sha256(f"{a.dtype.kind}{a.dtype.itemsize}:{list(a.shape)}:".encode())
    h.update(le.tobytes())
    return h.hexdigest()


@dataclass(frozen=True, slots=True)
class Manifest:
    """A verified manifest: per level, the brick table (shaped as the grid) and the statistics digests."""

    tables: tuple[np.ndarray, ...]
    stats: tuple[dict[str, str], ...]
    sha256: str

    def checks(self, level: int) -> np.ndarray:
        """``(gz, gy, gx, 5)`` float64: min, max, nan_count, inf_count, chunk crc32c (``-1``: none)."""
        t = self.tables[level]
        return np.stack([t["min"], t["max"], t["nan_count"].astype(np.float64), t["inf_count"].astype(np.float64),
                         t["crc32c"].astype(np.float64)], axis=-1)

    def sizes(self, level: int) -> np.ndarray:
        """``(gz, gy, gx)`` int64: each brick's chunk size in bytes (0: no chunk)."""
        return self.tables[level]["nbytes"]

    def stats_problems(self, level: int, stats: dict[str, np.ndarray] | None) -> list[str]:
        """What differs between the statistics arrays read for ``level`` and the manifest (empty: they agree)."""
        want = self.stats[level]
        have = stats or {}
        if want and not any(name in have for name in want):
            return [f"{STATS_GROUP}/{level} is missing (all {len(want)} statistics arrays)"]
        out = []
        for name, digest in want.items():
            if name not in have:
                out.append(f"{STATS_GROUP}/{level}/{name} is missing")
            elif stats_digest(have[name]) != digest:
                out.append(f"{STATS_GROUP}/{level}/{name} differs from the manifest (a replaced, swapped or damaged "
                           "statistics chunk)")
        return out


def build_tables(path: Path, grids: list[tuple[int, int, int]]) -> tuple[list[np.ndarray], list[dict[str, str]]]:
    """The brick tables and statistics digests of the store at ``path``, from its statistics arrays
    (as the build recorded them) and the sizes of its chunk files."""
    tables, digests = [], []
    all_stats = _read_stats(path, len(grids))
    for L, grid in enumerate(grids):
        stats = all_stats[L]
        for need in ("min", "max", "chunk_crc32c"):
            if need not in stats:
                raise ManifestError(f"{path}: {STATS_GROUP}/{L}/{need} is missing: no manifest can be derived")
        t = np.zeros(grid, dtype=TABLE_DTYPE)
        t["index"] = np.stack(np.indices(grid), axis=-1)
        t["crc32c"] = stats["chunk_crc32c"]
        t["min"], t["max"] = stats["min"], stats["max"]
        for name in ("nan_count", "inf_count"):
            if name in stats:
                t[name] = stats[name]
        level_dir = f"{path}{os.sep}{L}{os.sep}c{os.sep}"
        nbytes = t["nbytes"]
        for bz, by, bx in np.argwhere(t["crc32c"] >= 0).tolist():  # plain strings: no pathlib per brick
            p = f"{level_dir}{bz}{os.sep}{by}{os.sep}{bx}"
            try:
                nbytes[bz, by, bx] = os.lstat(p).st_size
            except FileNotFoundError:
                raise ManifestError(f"{p}: the statistics record a chunk for this brick but there is no file") from None
        tables.append(t)
        digests.append({name: stats_digest(a) for name, a in stats.items()})
    return tables, digests


def _read_stats(path: Path, levels: int) -> list[dict[str, np.ndarray]]:
    """Every level's statistics arrays, read concurrently in one pass of zarr's event loop (one
    array at a time costs a round trip through it per array: most of a manifest's write time)."""
    import asyncio

    import zarr
    from zarr.core.sync import sync

    names = [(L, n) for L in range(levels) for n in PINNED_STATS if (path / STATS_GROUP / str(L) / n).is_dir()]

    async def one(L: int, name: str) -> np.ndarray:
        arr = await zarr.api.asynchronous.open_array(store=str(path / STATS_GROUP / str(L) / name), mode="r")
        return np.asarray(await arr.getitem(...))

    async def every() -> list[np.ndarray]:
        return await asyncio.gather(*(one(L, n) for L, n in names))

    out: list[dict[str, np.ndarray]] = [{} for _ in range(levels)]
    for (L, n), a in zip(names, sync(every())):
        out[L][n] = a
    return out


def write_manifest(path: str | Path, grids: list[tuple[int, int, int]]) -> dict:
    """Write ``clipvol_manifest/`` for the store at ``path`` (level brick grids ``grids``) and return
    the entry for ``attrs["clipvol"]["manifest"]`` (``sha256`` and ``bytes`` of manifest.json).

    Files go through a temporary name and an atomic rename; the caller records the returned entry
    in the root attributes, which is what makes the new manifest the one a reader trusts.
    """
    path = Path(path)
    tables, digests = build_tables(path, grids)
    out = path / MANIFEST_DIR
    out.mkdir(exist_ok=True)
    levels = []
    for L, (t, d) in enumerate(zip(tables, digests)):
        data = t.tobytes()
        _atomic_write(out / f"{L}.bin", data)
        levels.append({"grid": list(t.shape), "table": f"{L}.bin", "table_sha256": hashlib.sha256(data).hexdigest(),
                       "stats": d})
    doc = json.dumps({"format": MANIFEST_FORMAT, "levels": levels}, indent=1, sort_keys=True).encode()
    _atomic_write(out / "manifest.json", doc)
    return {"sha256": hashlib.sha256(doc).hexdigest(), "bytes": len(doc)}


def _atomic_write(p: Path, data: bytes) -> None:
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, p)


def load_manifest(root: str | Path, cv: dict, grids: list[tuple[int, int, int]]) -> Manifest:
    """The verified manifest of the store at ``root`` (``cv``: its ``attrs["clipvol"]``).

    Raises :class:`ManifestError` saying why the store is unverified: no manifest recorded (a store
    written before manifests), a file missing, unreadable or not a regular file inside the store,
    a SHA-256 that differs, or a table whose records do not match the level's grid or their places.
    """
    from .store_files import read_file

    root = Path(root)
    entry = cv.get("manifest")
    if entry is None:
        raise ManifestError("no manifest (a store written before manifests): "
                            f"`clipvol repair {root} --source INPUT` checks every brick and writes one")
    if not (isinstance(entry, dict) and isinstance(entry.get("sha256"), str) and isinstance(entry.get("bytes"), int)
            and 0 < entry["bytes"] <= 2**20):
        raise ManifestError(f"attrs['clipvol']['manifest'] is malformed: {entry!r:.120}")
    where = f"{MANIFEST_DIR}/manifest.json"
    try:  # its length first: a manifest of another length was changed, which a size cap would not say
        size = (root / MANIFEST_DIR / "manifest.json").stat().st_size
    except OSError:
        size = None  # missing or unreadable: said below
    if size is not None and size != entry["bytes"]:
        raise ManifestError(f"{where} is {size} bytes, but the root metadata records {entry['bytes']}: the manifest "
                            "was changed since the build")
    try:
        doc_bytes = read_file(root / MANIFEST_DIR / "manifest.json", root, cap=entry["bytes"])
    except FileNotFoundError:
        raise ManifestError(f"{where} is missing") from None
    except (OSError, ValueError) as e:
        raise ManifestError(f"{where}: {e}") from None
    if hashlib.sha256(doc_bytes).hexdigest() != entry["sha256"]:
        raise ManifestError(f"{where} does not match the checksum recorded in the root metadata")
    try:
        doc = json.loads(doc_bytes)
        levels = doc["levels"]
        if doc.get("format") != MANIFEST_FORMAT or not isinstance(levels, list):
            raise ValueError("unknown format")
    except (ValueError, KeyError, TypeError) as e:
        raise ManifestError(f"{where} is malformed ({e})") from None
    if len(levels) != len(grids):
        raise ManifestError(f"{where} lists {len(levels)} levels, the store has {len(grids)}")
    tables, stats = [], []
    for L, (lv, grid) in enumerate(zip(levels, grids)):
        if not isinstance(lv, dict) or lv.get("grid") != list(grid) or lv.get("table") != f"{L}.bin" \
                or not isinstance(lv.get("stats"), dict):
            raise ManifestError(f"{where}: level {L} entry is malformed or not for grid {list(grid)}")
        n = int(np.prod(grid)) * TABLE_DTYPE.itemsize
        tpath = root / MANIFEST_DIR / f"{L}.bin"
        try:
            data = read_file(tpath, root, cap=n)
        except FileNotFoundError:
            raise ManifestError(f"{MANIFEST_DIR}/{L}.bin is missing") from None
        except (OSError, ValueError) as e:
            raise ManifestError(f"{MANIFEST_DIR}/{L}.bin: {e}") from None
        if len(data) != n or hashlib.sha256(data).hexdigest() != lv.get("table_sha256"):
            raise ManifestError(f"{MANIFEST_DIR}/{L}.bin does not match its checksum in the manifest")
        t = np.frombuffer(data, dtype=TABLE_DTYPE).reshape(grid)
        if not np.array_equal(t["index"], np.stack(np.indices(grid), axis=-1)):
            raise ManifestError(f"{MANIFEST_DIR}/{L}.bin: a record is not at its brick's place")
        tables.append(t)
        stats.append({str(k): str(v) for k, v in lv["stats"].items()})
    return Manifest(tuple(tables), tuple(stats), entry["sha256"])
