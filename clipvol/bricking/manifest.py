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
* per level, the metadata of every array the manifest covers - the level's array ``<L>`` and
  every array under ``clipvol_stats/<L>/`` - as its ``zarr.json`` holds it, less the free-form
  ``attributes``: data type, byte order and codec chain, fill value, shape, chunk grid and key
  encoding. A level's ``zarr.json`` is what tells a reader how to decode its chunks; left outside
  the root of trust, an edited byte order, a codec chain without its compressor or another fill
  value makes verified bytes decode into wrong voxels, or unwritten bricks read back as something
  else. Arrays are found by walking those folders, so an array added later beside a level's
  statistics is pinned the same way without a change here;
* the multiscale list of the root attributes (``attrs["ome"]["multiscales"]``: each level's path,
  scale and translation), which places every level in the world (the rest of ``attrs["ome"]`` is
  free to change: a label image's ``image-label`` block is written after its build);
* ``manifest.json`` lists the tables with their SHA-256, and its own SHA-256 and length are
  recorded in the root attributes (``attrs["clipvol"]["manifest"]``).

A reader compares the pinned metadata with the store's files (:func:`metadata_problems`): the
levels' arrays and the multiscale list on opening, a level's other arrays when it first reads
them; it refuses a store whose metadata differs, naming the level (or array) and the field; ``clipvol repair`` puts the pinned metadata back (:func:`restore_metadata`). A manifest
written before metadata pins (no ``arrays`` in its levels) still verifies its chunks and
statistics; :attr:`Manifest.metadata_pinned` is then False and the reader says so.

Layout::

    clipvol_manifest/manifest.json   {"format": 1, "multiscales": [...],
                                      "levels": [{"grid", "table", "table_sha256", "stats", "arrays"}]}
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
from .store_files import MAX_METADATA_BYTES

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
    "read_manifest_doc",
    "pinned_metadata",
    "metadata_problems",
    "metadata_pins",
    "restore_metadata",
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
    #: per level, the pinned metadata of each array by its path in the store (None: a manifest
    #: written before metadata pins)
    arrays: tuple[dict[str, dict], ...] | None = None
    #: the pinned ``attrs["ome"]["multiscales"]`` list (None: not pinned)
    multiscales: list | None = None

    @property
    def metadata_pinned(self) -> bool:
        """True when the manifest pins the arrays' metadata and the multiscale transforms."""
        return self.arrays is not None

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


def _zarr_json(path: Path, root: Path) -> dict:
    """A ``zarr.json`` as a JSON object (a regular file inside the store, size-capped)."""
    from .store_files import read_file

    doc = json.loads(read_file(path, root, MAX_METADATA_BYTES))
    if not isinstance(doc, dict):
        raise ValueError(f"expected a JSON object, got {type(doc).__name__}")
    return doc


def _pinned_fields(doc: dict) -> dict:
    """What the manifest pins of an array's ``zarr.json``: everything but its free-form ``attributes``."""
    return {k: v for k, v in doc.items() if k != "attributes"}


def level_array_paths(path: Path, level: int) -> list[str]:
    """The arrays the manifest covers for ``level``, as paths inside the store: the level's own
    array, its spread array ``clipvol_spread/<level>`` (levels >= 1 of a store built with it,
    :mod:`clipvol.bricking.spread`), then every array under ``clipvol_stats/<level>/`` (found by
    walking: an array added there later is covered without a change here), sorted."""
    from .spread import SPREAD_GROUP

    out = [str(level)] if (path / str(level) / "zarr.json").is_file() else []
    if (path / SPREAD_GROUP / str(level) / "zarr.json").is_file():
        out.append(f"{SPREAD_GROUP}/{level}")
    base = path / STATS_GROUP / str(level)
    if base.is_dir():
        for entry in sorted(os.scandir(base), key=lambda e: e.name):
            if entry.is_dir(follow_symlinks=False) and os.path.isfile(os.path.join(entry.path, "zarr.json")):
                out.append(f"{STATS_GROUP}/{level}/{entry.name}")
    return out


def pinned_metadata(path: str | Path, levels: int) -> tuple[list[dict[str, dict]], list | None]:
    """Per level, ``{array path: its pinned zarr.json fields}``, and the root's multiscale list:
    what :func:`write_manifest` records so that a reader can hold the store's metadata to it."""
    path = Path(path)
    arrays = []
    for L in range(levels):
        arrays.append({rel: _pinned_fields(_zarr_json(path / rel / "zarr.json", path))
                       for rel in level_array_paths(path, L)})
    attrs = _zarr_json(path / "zarr.json", path).get("attributes") or {}
    ms = _multiscales_of(attrs)
    return arrays, ms if isinstance(ms, list) else None


def _short(v) -> str:
    text = json.dumps(v, sort_keys=True)
    return text if len(text) <= 240 else text[:237] + "..."


#: how a message names a zarr.json field (the words the rest of clipvol uses for it)
FIELD_WORDS = {"data_type": "dtype (data_type)", "chunk_grid": "chunks (chunk_grid)",
               "chunk_key_encoding": "chunk key encoding (chunk_key_encoding)"}


def _name(rel: str) -> str:
    return f"level {rel}" if rel.isdigit() else rel


def metadata_problems(root: str | Path, manifest: "Manifest", attrs: dict | None, *,
                      levels_only: bool = False, level: int | None = None) -> list[str]:
    """What differs between the metadata ``manifest`` pins and the store at ``root`` (``attrs``:
    its root attributes, already read; None: the multiscale list is not compared): one line per
    field, naming the level or array and the field, with both values ("level 1: codecs differ:
    manifest has [...], zarr.json has [...]"). Empty when they agree, or when the manifest pins no
    metadata (written before metadata pins). ``levels_only``: the levels' own arrays only (what a
    reader needs on opening); ``level``: only that level's other arrays (its statistics, compared
    when they are first read). An array whose ``zarr.json`` is absent or unreadable is left to the
    checks of its data (a deleted statistics array differs from its digest; a level without
    metadata cannot open)."""
    if not manifest.metadata_pinned:
        return []
    root = Path(root)
    out: list[str] = []
    for L, per_level in enumerate(manifest.arrays or ()):
        if level is not None and L != level:
            continue
        for rel, want in per_level.items():
            if (levels_only and not rel.isdigit()) or (level is not None and rel.isdigit()):
                continue
            out.extend(_array_problems(root, rel, want))
    want = manifest.multiscales
    have = _multiscales_of(attrs) if attrs is not None else None
    if attrs is not None and want is not None and have != want:
        out.extend(_multiscale_problems(want, have))
    return out


def _array_problems(root: Path, rel: str, want: dict) -> list[str]:
    """The fields of ``rel/zarr.json`` that differ from the pinned ``want``."""
    where = _name(rel)
    try:
        have = _pinned_fields(_zarr_json(root / rel / "zarr.json", root))
    except (OSError, ValueError):
        # absent or not a readable file: not a difference of metadata but of data, which the
        # reader refuses on its own terms (a level's array_meta, a statistics array's digest)
        return []
    out = []
    for key in sorted(set(want) | set(have)):
        word = FIELD_WORDS.get(key, key)
        if key not in have:
            out.append(f"{where}: {word} is missing from zarr.json (manifest has {_short(want[key])})")
        elif key not in want:
            out.append(f"{where}: {word} is in zarr.json ({_short(have[key])}) but not in the manifest")
        elif have[key] != want[key]:
            verb = "differ" if key in ("codecs", "chunk_grid") else "differs"
            out.append(f"{where}: {word} {verb}: manifest has {_short(want[key])}, zarr.json has "
                       f"{_short(have[key])}")
    return out


def _multiscales_of(attrs) -> list | None:
    ome = attrs.get("ome") if isinstance(attrs, dict) else None
    return ome.get("multiscales") if isinstance(ome, dict) else None


def _multiscale_problems(want: list, have) -> list[str]:
    """The differences of the root's multiscale list from the pinned one, per level where it can."""
    try:
        w_ds, h_ds = want[0]["datasets"], have[0]["datasets"]
        assert isinstance(w_ds, list) and isinstance(h_ds, list)
    except (TypeError, KeyError, IndexError, AssertionError):
        return [f"attrs['ome']['multiscales'] differs: manifest has {_short(want)}, zarr.json has {_short(have)}"]
    out = []
    for L in range(max(len(w_ds), len(h_ds))):
        if L >= len(h_ds):
            out.append(f"level {L}: missing from the multiscales list (attrs['ome']['multiscales'][0]['datasets'] "
                       f"has {len(h_ds)} entries, the manifest {len(w_ds)}: manifest has {_short(w_ds[L])})")
        elif L >= len(w_ds):
            out.append(f"level {L}: an extra multiscales entry {_short(h_ds[L])} (the manifest has {len(w_ds)})")
        elif h_ds[L] != w_ds[L]:
            out.append(f"level {L}: multiscale transform differs: manifest has {_short(w_ds[L])}, "
                       f"zarr.json has {_short(h_ds[L])}")
    w0 = [{k: v for k, v in m.items() if k != "datasets"} if isinstance(m, dict) else m for m in want]
    h0 = [{k: v for k, v in m.items() if k != "datasets"} if isinstance(m, dict) else m for m in have]
    if w0 != h0:
        out.append(f"attrs['ome']['multiscales'] differs outside the level transforms (axes, name, type): manifest "
                   f"has {_short(w0)}, zarr.json has {_short(h0)}")
    return out


def restore_metadata(root: str | Path) -> list[str]:
    """Put back the metadata the store's verified manifest pins: each array's ``zarr.json`` fields
    (its ``attributes`` kept) and the root's multiscale list, each file rewritten through a
    temporary name and an atomic rename (an absent one is left to the rebuild of its data). Returns
    what was restored, one entry per file (empty: nothing
    differed, or the manifest pins no metadata). Raises :class:`ManifestError` when the manifest
    does not verify: then nothing vouches for any metadata and nothing is written."""
    root = Path(root)
    top = _zarr_json(root / "zarr.json", root)
    attrs = top.get("attributes") if isinstance(top.get("attributes"), dict) else {}
    cv = attrs.get("clipvol") if isinstance(attrs.get("clipvol"), dict) else {}
    doc = read_manifest_doc(root, cv)
    manifest = metadata_pins(doc)
    if not manifest.metadata_pinned:
        return []
    done = []
    for per_level in manifest.arrays or ():
        for rel, want in per_level.items():
            p = root / rel / "zarr.json"
            try:
                old = _zarr_json(p, root)
            except (OSError, ValueError):
                continue  # absent or unreadable: rebuilt with its data (statistics), or refused on opening
            if _pinned_fields(old) == want:
                continue
            new = dict(want)
            new["attributes"] = old.get("attributes", {}) if isinstance(old.get("attributes", {}), dict) else {}
            p.parent.mkdir(parents=True, exist_ok=True)
            _atomic_write(p, json.dumps(new, indent=2).encode())
            done.append(f"{_name(rel)} ({rel}/zarr.json)")
    if manifest.multiscales is not None and _multiscales_of(attrs) != manifest.multiscales:
        attrs = dict(attrs)
        attrs["ome"] = {**(attrs.get("ome") if isinstance(attrs.get("ome"), dict) else {}),
                        "multiscales": manifest.multiscales}
        top = dict(top)
        top["attributes"] = attrs
        _atomic_write(root / "zarr.json", json.dumps(top, indent=2).encode())
        done.append("the multiscale transforms (attrs['ome']['multiscales'] in zarr.json)")
    return done


def metadata_pins(doc: dict) -> "Manifest":
    """A :class:`Manifest` holding only the metadata pins of a verified ``manifest.json`` document."""
    levels = doc.get("levels") or []
    arrays = []
    for lv in levels:
        a = lv.get("arrays") if isinstance(lv, dict) else None
        if not isinstance(a, dict) or not all(isinstance(v, dict) for v in a.values()):
            return Manifest((), (), "", None, None)
        arrays.append({str(k): v for k, v in a.items()})
    ms = doc.get("multiscales")
    return Manifest((), (), "", tuple(arrays), ms if isinstance(ms, list) else None)


def write_manifest(path: str | Path, grids: list[tuple[int, int, int]]) -> dict:
    """Write ``clipvol_manifest/`` for the store at ``path`` (level brick grids ``grids``) and return
    the entry for ``attrs["clipvol"]["manifest"]`` (``sha256`` and ``bytes`` of manifest.json).

    Files go through a temporary name and an atomic rename; the caller records the returned entry
    in the root attributes, which is what makes the new manifest the one a reader trusts.
    """
    path = Path(path)
    tables, digests = build_tables(path, grids)
    arrays, multiscales = pinned_metadata(path, len(grids))
    out = path / MANIFEST_DIR
    out.mkdir(exist_ok=True)
    levels = []
    for L, (t, d) in enumerate(zip(tables, digests)):
        data = t.tobytes()
        _atomic_write(out / f"{L}.bin", data)
        levels.append({"grid": list(t.shape), "table": f"{L}.bin", "table_sha256": hashlib.sha256(data).hexdigest(),
                       "stats": d, "arrays": arrays[L]})
    top = {"format": MANIFEST_FORMAT, "levels": levels}
    if multiscales is not None:
        top["multiscales"] = multiscales
    doc = json.dumps(top, indent=1, sort_keys=True).encode()
    _atomic_write(out / "manifest.json", doc)
    return {"sha256": hashlib.sha256(doc).hexdigest(), "bytes": len(doc)}


def _atomic_write(p: Path, data: bytes) -> None:
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, p)


def read_manifest_doc(root: str | Path, cv: dict) -> dict:
    """The store's ``manifest.json`` as a JSON object, once its SHA-256 and length match the entry
    recorded in the root attributes (``cv``: ``attrs["clipvol"]``); :class:`ManifestError` says why not."""
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
        if not isinstance(doc, dict) or doc.get("format") != MANIFEST_FORMAT or not isinstance(doc["levels"], list):
            raise ValueError("unknown format")
    except (ValueError, KeyError, TypeError) as e:
        raise ManifestError(f"{where} is malformed ({e})") from None
    doc["sha256"] = entry["sha256"]
    return doc


def load_manifest(root: str | Path, cv: dict, grids: list[tuple[int, int, int]], doc: dict | None = None) -> Manifest:
    """The verified manifest of the store at ``root`` (``cv``: its ``attrs["clipvol"]``; ``doc``:
    its :func:`read_manifest_doc` when already read).

    Raises :class:`ManifestError` saying why the store is unverified: no manifest recorded (a store
    written before manifests), a file missing, unreadable or not a regular file inside the store,
    a SHA-256 that differs, or a table whose records do not match the level's grid or their places.
    """
    from .store_files import read_file

    root = Path(root)
    if doc is None:
        doc = read_manifest_doc(root, cv)
    where = f"{MANIFEST_DIR}/manifest.json"
    levels = doc["levels"]
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
    pins = metadata_pins(doc)
    return Manifest(tuple(tables), tuple(stats), doc["sha256"], pins.arrays, pins.multiscales)
