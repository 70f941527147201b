"""Zarr metadata read as JSON and validated before zarr opens anything.

Why before zarr: zarr-python trusts what a store says; a reader of stores written by others must
not. Absurd shapes or chunk shapes, and object, string, structured or complex dtypes, are refused
here (nothing is ever unpickled), every metadata file is opened as what it claims to be (a regular
file inside the store, its size capped: :mod:`clipvol.bricking.store_files`), and dataset paths
of plain OME-Zarr metadata must resolve inside the store. What one array needs for the chunk fast
path (:mod:`clipvol.loaders.zarr_chunks`) is decided here once: its codec chain, key encoding and
byte order (:class:`ArrayMeta`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from clipvol.bricking.pyramid import validate_dtype
from clipvol.bricking.store import MAX_BRICK_VOXELS, MAX_VOXELS
from clipvol.bricking.store_files import MAX_METADATA_BYTES, read_file
from clipvol.errors import InputFormatError

from .zarr_shard_index import ShardLayout, sharding_layout

__all__ = ["ArrayMeta", "array_meta", "group_attributes", "inside", "read_json", "set_of"]


def inside(root: Path, rel: str, where: str) -> Path:
    """``root / rel`` resolved (symbolic links followed), which must stay inside ``root``: a metadata
    path that is absolute or climbs out (``../../other.zarr/0``) is an :class:`InputFormatError`."""
    if not isinstance(rel, str) or not rel or "\x00" in rel or os.path.isabs(rel) or rel.startswith(("/", "\\")):
        raise InputFormatError(f"{where}: dataset path {rel!r} must be a relative path inside the store")
    base = root.resolve()
    p = (base / rel).resolve()
    if p == base or not p.is_relative_to(base):
        raise InputFormatError(f"{where}: dataset path {rel!r} resolves to {p}, outside the store {base}")
    return p


#: the most voxels one shard of a sharded array may cover (its inner chunks are bounded like bricks)
MAX_SHARD_VOXELS = 2**36

_V3_NUMERIC = {
    "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float16", "float32", "float64",
}


def read_json(path: Path, where: str, root: Path | None = None) -> dict[str, Any]:
    """A metadata file as a JSON object: a regular file inside ``root`` (default: its own folder),
    at most :data:`~clipvol.bricking.store_files.MAX_METADATA_BYTES` (never a FIFO, a device, or a
    link out of the store)."""
    try:
        doc = json.loads(read_file(path, path.parent if root is None else root, MAX_METADATA_BYTES))
    except FileNotFoundError:
        raise
    except InputFormatError as e:  # StoreFileError stays one: callers must not skip such a file
        raise type(e)(f"{where}: {e}") from None
    except (OSError, ValueError) as e:
        raise InputFormatError(f"{where}: cannot read {path.name} as JSON ({type(e).__name__}: {e})") from None
    if not isinstance(doc, dict):
        raise InputFormatError(f"{where}: expected a JSON object in {path.name}, got {type(doc).__name__}")
    return doc


def _decoder(name: str):
    import numcodecs

    return {"blosc": numcodecs.Blosc, "zstd": numcodecs.Zstd, "gzip": numcodecs.GZip, "zlib": numcodecs.Zlib,
            "lz4": numcodecs.LZ4}[name]()


@dataclass(frozen=True, slots=True)
class ArrayMeta:
    """What the loader needs of one zarr array, validated from its JSON metadata."""

    path: Path
    shape: tuple[int, ...]
    chunks: tuple[int, ...]
    dtype: np.dtype  # as stored (byte order included)
    fill_value: float
    key_prefix: str  # "c/" (v3 default) or "" (v2 / v3 "v2" encoding)
    separator: str
    decoder: Any  # numcodecs codec, None = raw bytes, "fallback" = use zarr indexing
    checksum: bool = False  # a crc32c codec ends the chain: the last 4 bytes are the CRC-32C of the rest
    #: sharded (zarr v3 ``sharding_indexed`` read by the fast path): ``chunks``, ``decoder`` and
    #: ``checksum`` are then the inner chunk's, and chunk keys name shards (:meth:`shard_key`)
    shard: ShardLayout | None = None

    @property
    def fast(self) -> bool:
        return self.decoder != "fallback"

    @property
    def blosc(self) -> bool:
        return type(self.decoder).__name__ == "Blosc"

    @property
    def nbytes(self) -> int:
        return math.prod(self.chunks) * self.dtype.itemsize

    def chunk_root(self, lead: tuple[int, ...]) -> str:
        """The chunk key up to the last three indices (``lead``: the chunk index of the leading t/c
        axes), as a string (built once per level: no pathlib on the hot path)."""
        return str(self.path) + "/" + self.key_prefix + "".join(f"{v}{self.separator}" for v in lead)

    def shard_key(self, sidx: tuple[int, ...]) -> str:
        """The key of shard ``sidx`` relative to the array (``c/0/1/2``)."""
        return self.key_prefix + self.separator.join(str(i) for i in sidx)

    def chunk_path(self, cidx: tuple[int, ...]) -> Path:
        return self.path / (self.key_prefix + self.separator.join(str(i) for i in cidx))


def _fill(raw, dtype: np.dtype, where: str) -> float:
    if raw is None:
        return 0.0
    if isinstance(raw, str):
        try:
            v = float({"NaN": "nan", "Infinity": "inf", "-Infinity": "-inf"}.get(raw, raw))
        except ValueError:
            raise InputFormatError(f"{where}: expected a numeric fill_value, got {raw!r}") from None
    elif isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise InputFormatError(f"{where}: expected a numeric fill_value, got {raw!r}")
    else:
        try:
            v = float(raw)
        except OverflowError:
            raise InputFormatError(f"{where}: expected a fill_value within {dtype.name}, got {raw!r:.40}") from None
    if dtype.kind in "iu" and not (math.isfinite(v) and v.is_integer() and np.iinfo(dtype).min <= v <= np.iinfo(dtype).max):
        raise InputFormatError(f"{where}: expected an integer fill_value within {dtype.name}, got {raw!r:.40}")
    return v


def _check_sizes(shape, chunks, where: str, max_chunk: int = MAX_BRICK_VOXELS) -> tuple[tuple[int, ...], tuple[int, ...]]:
    def ints(v, what):
        if not isinstance(v, list) or not v or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
            raise InputFormatError(f"{where}: expected {what} as a list of integers, got {v!r:.80}")
        return tuple(v)

    shape, chunks = ints(shape, "shape"), ints(chunks, "chunk shape")
    if len(shape) != len(chunks):
        raise InputFormatError(f"{where}: expected a chunk shape of {len(shape)} dimensions, got {list(chunks)}")
    if any(s < 1 or s > 2**40 for s in shape) or math.prod(shape) > MAX_VOXELS:
        raise InputFormatError(f"{where}: expected a shape of at most 2**40 per axis and 2**62 voxels, got {list(shape)}")
    if any(c < 1 for c in chunks) or math.prod(chunks) > max_chunk:
        raise InputFormatError(f"{where}: expected a chunk shape of at most {max_chunk} voxels, got {list(chunks)}")
    return shape, chunks


def _v3_chain(codecs: list[dict], m: dict) -> tuple[Any, str, bool]:
    """``(decoder, endian, checksum)`` of a zarr v3 chunk's codec chain: ``bytes`` (+ ``blosc`` |
    ``zstd`` | ``gzip``) (+ ``crc32c``) takes the fast path, anything else is ``"fallback"``."""
    decoder: Any = "fallback"
    endian = "little"
    checksum = bool(codecs) and codecs[-1].get("name") == "crc32c"
    if checksum:
        codecs = codecs[:-1]
    if codecs and codecs[0].get("name") == "bytes" and len(codecs) <= 2 and not m.get("storage_transformers"):
        endian = (codecs[0].get("configuration") or {}).get("endian", "little")
        rest = [c.get("name") for c in codecs[1:]]
        if not rest:
            decoder = None
        elif rest[0] in ("blosc", "zstd", "gzip"):
            decoder = _decoder(rest[0])
    return decoder, endian, checksum


def array_meta(path: Path, where: str, root: Path | None = None) -> ArrayMeta:
    """Read and validate the metadata of the array at ``path`` (zarr v3 or v2) without opening it
    with zarr; ``root``: the store, which every metadata file must lie inside."""
    if (path / "zarr.json").exists():
        m = read_json(path / "zarr.json", where, root)
        if m.get("node_type") != "array":
            raise InputFormatError(f"{where}: expected an array, got node_type {m.get('node_type')!r}")
        dt = m.get("data_type")
        if not isinstance(dt, str) or dt not in _V3_NUMERIC:
            raise InputFormatError(f"{where}: expected an integer or float data_type, got {dt!r} (object, string, "
                                   "structured, bool and complex data are not supported)")
        grid = m.get("chunk_grid") or {}
        if grid.get("name") != "regular":
            raise InputFormatError(f"{where}: expected a regular chunk grid, got {grid.get('name')!r}")
        codecs = [c if isinstance(c, dict) else {"name": c} for c in m.get("codecs") or []]
        sharded = bool(codecs) and codecs[0].get("name") == "sharding_indexed"
        # a shard holds many chunks: its shape is bounded by the shard cap, its inner chunk's by the brick cap
        shape, chunks = _check_sizes(m.get("shape"), (grid.get("configuration") or {}).get("chunk_shape"), where,
                                     MAX_SHARD_VOXELS if sharded else MAX_BRICK_VOXELS)
        shard = None
        if sharded:
            found = sharding_layout(codecs[0], chunks, where) if len(codecs) == 1 else None
            if found is None:  # bytes-to-bytes codecs over whole shards, or an index zarr-python must read
                decoder, endian, checksum = "fallback", "little", False
                _check_sizes(list(shape), list(chunks), where)  # read whole by zarr-python: a brick's bound
            else:
                shard, chunks, inner = found
                _check_sizes(list(shape), list(chunks), where)
                decoder, endian, checksum = _v3_chain(inner, m)
        else:
            decoder, endian, checksum = _v3_chain(codecs, m)
        dtype = np.dtype(dt).newbyteorder(">" if endian == "big" else "<")
        cke = m.get("chunk_key_encoding") or {"name": "default"}
        sep = (cke.get("configuration") or {}).get("separator", "/" if cke.get("name") == "default" else ".")
        prefix = "c" + sep if cke.get("name") == "default" else ""
        if cke.get("name") not in ("default", "v2"):
            decoder = "fallback"
        if decoder == "fallback" and shard is not None:  # zarr-python reads it, a shard per brick as before
            shard, chunks = None, _check_sizes(m.get("shape"), grid["configuration"]["chunk_shape"], where)[1]
        return ArrayMeta(path, shape, chunks, dtype, _fill(m.get("fill_value"), dtype, where), prefix, sep, decoder,
                         checksum, shard)
    if (path / ".zarray").exists():
        m = read_json(path / ".zarray", where, root)
        raw_dt = m.get("dtype")
        try:
            if not isinstance(raw_dt, str):
                raise TypeError
            dtype = validate_dtype(raw_dt)
        except (TypeError, ValueError):
            raise InputFormatError(f"{where}: expected an integer or float dtype, got {raw_dt!r} (object, string, "
                                   "structured, bool and complex data are not supported)") from None
        shape, chunks = _check_sizes(m.get("shape"), m.get("chunks"), where)
        decoder = "fallback"
        comp = m.get("compressor")
        if not m.get("filters") and m.get("order", "C") == "C":
            if comp is None:
                decoder = None
            elif isinstance(comp, dict) and comp.get("id") in ("blosc", "zstd", "gzip", "zlib", "lz4"):
                decoder = _decoder(comp["id"])
        sep = m.get("dimension_separator") or "."
        return ArrayMeta(path, shape, chunks, dtype, _fill(m.get("fill_value"), dtype, where), "", sep, decoder)
    raise InputFormatError(f"{where}: expected a zarr array (zarr.json or .zarray) at {path}")


def group_attributes(path: Path, where: str) -> dict[str, Any]:
    """The attributes of the zarr group at ``path`` (v3 ``zarr.json`` or v2 ``.zgroup`` +
    ``.zattrs``), read through :func:`read_json`: where a loader learns whether it opens a clipvol
    store or a plain OME-Zarr image."""
    if (path / "zarr.json").exists():
        g = read_json(path / "zarr.json", where, path)
        if g.get("node_type") != "group":
            raise InputFormatError(f"{where}: expected a zarr group, got node_type {g.get('node_type')!r}")
        return g.get("attributes") or {}
    if (path / ".zgroup").exists():
        return read_json(path / ".zattrs", where, path) if (path / ".zattrs").exists() else {}
    raise InputFormatError(f"{where}: expected a zarr group (zarr.json or .zgroup), found neither")


def set_of(attrs: dict, where: str) -> tuple[str, int, int] | None:
    """``(axis, count, version)`` of the image set whose root group has ``attrs`` (what ``clipvol
    brick`` writes for a 4-D input, :mod:`clipvol.bricking.channels`), or None for any other group."""
    from clipvol.bricking.channels import set_attrs

    return set_attrs(attrs, where)
