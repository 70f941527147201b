"""Read bricks from a zarr store: a clipvol store, or any plain OME-Zarr image.

Why not just ``arr[...]``: zarr-python 3.1 spends ~0.3-0.9 ms of fixed overhead per indexing call
and funnels every thread through one event loop, so chunk-aligned reads from several loader
threads reach only a few percent of memcpy speed. Because a brick *is* one chunk, this loader reads
the chunk's file itself (``<array>/c/<bz>/<by>/<bx>`` for zarr v3's default key encoding) and
decodes it with numcodecs, which releases the GIL, in the calling loader thread. The codec chains
``bytes`` (+ ``blosc`` | ``zstd`` | ``gzip`` | nothing) (+ ``crc32c``) of zarr v3 and the plain
compressors of zarr v2 take this fast path; anything else (sharding, transpose, filters) falls back
to zarr indexing, which gives the same values, only slower. Every raw chunk fetch goes through one
method, :meth:`ZarrLoader._chunk_bytes`, so a loader for remote storage overrides only that (local
files take :meth:`ZarrLoader._chunk_into_buffer`, the same bytes read into a per-thread buffer,
unless a subclass overrides ``_chunk_bytes``).

Integrity (never wrong data as if right): a ``crc32c`` codec is verified over every byte of the
chunk before decoding, on every read (clipvol stores carry it on every array; the fastest CRC-32C
package installed computes it: :func:`crc32c_implementation`); every load's decoded data is checked
against the store's statistics for that brick (min/max and NaN/Inf counts equal; for bytes whose
checksum is the one recorded for the brick, every 8th row of every 8th plane inside the bounds); a
missing chunk file is an empty brick (the fill value) only if the statistics say the brick is empty. A truncated, corrupt, substituted or lost chunk raises
:class:`~clipvol.errors.BrickIntegrityError` naming the store, brick and chunk file. Dataset paths
of plain OME-Zarr metadata must resolve inside the store.

The store's manifest (:mod:`clipvol.bricking.manifest`) is verified first, on opening: when it
verifies (:attr:`ZarrLoader.verified`), "the statistics" above are its per-brick records - each
chunk's exact size and crc32c and the brick's bounds, keyed by brick index - so deleting or
replacing the statistics arrays changes nothing a load trusts, and each statistics array is
compared with its digest when read. A clipvol store without one, or whose manifest does not
verify, or without checksums, opens *unverified* (:attr:`ZarrLoader.trust` says why) with an
:class:`UnverifiedStoreWarning`, and the checks fall back to the statistics arrays. Every file is
opened as what it claims to be (:mod:`clipvol.bricking.store_files`): a regular file inside the
store, never a FIFO, device or link out, its size capped before it is read.

Metadata is read as JSON and validated *before* zarr opens anything: absurd shapes or chunk
shapes, and object, string, structured or complex dtypes, are refused (nothing is ever unpickled).

Plain OME-Zarr (0.4: ``multiscales`` at the top level of the attributes, usually zarr v2; 0.5:
under ``"ome"``): the level-0 chunk shape is the brick shape; leading (time / channel) axes must
have size 1. A stored level is used only if it is the 2x (ceil) down-sample of the previous one
with the same chunk shape; from the first level that does not conform, coarser levels are
computed on demand, each brick from its (up to 8) children with the image's filter (its
``multiscales`` ``type`` if it is ``mean``, ``max`` or ``subsample``, else ``mean``), and kept in a
bounded cache. The value range comes from ``omero.window`` (``min``/``max``), else the dtype's
range for integers, else the finite range of the coarsest stored level (sampled).

Bricks are returned in native byte order (a big-endian store gives native arrays).
"""

from __future__ import annotations

import functools
import json
import math
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from clipvol.bricking.pyramid import (
    FILTERS,
    Int3,
    LevelInfo,
    Pyramid,
    downsample,
    level_shapes,
    level_transform,
    pad_to_brick,
    validate_dtype,
)
from clipvol.bricking.manifest import Manifest, ManifestError, load_manifest
from clipvol.bricking.store import (
    MAX_BRICK_VOXELS,
    MAX_VOXELS,
    STAT_ARRAYS,
    STATS_GROUP,
    parse_metadata,
)
from clipvol.bricking.store_files import (
    MAX_METADATA_BYTES,
    StoreFileError,
    check_opened,
    check_tree,
    chunk_cap,
    open_inside,
    read_capped,
    read_file,
)
from clipvol.errors import (
    BrickIntegrityError,
    InputFormatError,
    InputNotFoundError,
    ParameterError,
    StoreFormatError,
    StoreIncompleteError,
)
from clipvol.paging.loader import BrickKey
from clipvol.paging.readcount import ReadCounter

__all__ = ["ZarrLoader", "UnverifiedStoreWarning", "crc32c_implementation"]


class UnverifiedStoreWarning(UserWarning):
    """A clipvol store whose manifest is missing or does not verify (one written before manifests,
    or damaged), or one written before chunk checksums: its bricks load, but what the reader
    believes about unread bricks rests on statistics nothing vouches for."""


class _ChecksumError(ValueError):
    pass


class _IdentityError(ValueError):
    pass


_UNREAD = object()
#: the largest statistics array file read (a row of per-brick histograms of a very wide level)
MAX_STATS_FILE_BYTES = 256 * 2**20
#: a brick whose chunk checksum is proven checks the decode on every SAMPLE_STRIDE-th row of every
#: SAMPLE_STRIDE-th z-plane (1/64 of its voxels; see ZarrLoader._check_plausible for why that is enough)
SAMPLE_STRIDE = 8
#: CRC-32C of any byte string followed by its own CRC-32C (little-endian), the codec's layout
_CRC32C_RESIDUE = 0x48674BC7


#: CRC-32C packages, fastest first on the CPUs we measured (``docs/benchmarks.md``, integrity):
#: fastcrc folds with VPCLMULQDQ / PMULL (57 GB/s on our AVX-512 machine) and releases the GIL;
#: crc32c uses the SSE4.2 / ARMv8 CRC instruction (28 GB/s) and releases the GIL; google-crc32c
#: (zarr's own dependency, so always installed) is as fast as crc32c but holds the GIL.
CRC32C_PACKAGES = ("fastcrc", "crc32c", "google-crc32c")
#: CRC-32C of b"123456789", the check value of the iSCSI CRC (RFC 3720)
_CRC32C_CHECK = 0xE3069283


def _crc32c_function(package: str) -> Callable[[Any], int] | None:
    """The CRC-32C function of ``package`` (one of :data:`CRC32C_PACKAGES`), or None when it is not installed."""
    try:
        if package == "fastcrc":
            from fastcrc.crc32 import iscsi as fn
        elif package == "crc32c":
            from crc32c import crc32c as fn
        elif package == "google-crc32c":
            from google_crc32c import value

            def fn(data, _value=value):  # it refuses memoryviews (the loader's read buffer), not arrays
                return _value(np.frombuffer(data, dtype=np.uint8))
        else:
            raise ValueError(f"expected one of {CRC32C_PACKAGES}, got {package!r}")
    except ImportError:
        return None
    return fn


def _computes_crc32c(fn: Callable[[Any], int]) -> bool:
    """True when ``fn`` gives the standard check value, on bytes and on a memoryview of a bytearray
    (the loader hands it both), and the codec's residue: a package that computes another CRC, or
    a build that mishandles buffers, is never used to vouch for data."""
    msg = bytearray(b"123456789")
    try:
        return (fn(bytes(msg)) == _CRC32C_CHECK and fn(memoryview(msg)) == _CRC32C_CHECK
                and fn(bytes(msg) + _CRC32C_CHECK.to_bytes(4, "little")) == _CRC32C_RESIDUE)
    except Exception:  # noqa: BLE001  anything a broken build raises disqualifies it
        return False


@functools.cache
def crc32c_implementation() -> tuple[str, Callable[[Any], int]]:
    """``(package, function)``: the first of :data:`CRC32C_PACKAGES` that is installed and passes
    :func:`_computes_crc32c`. Chosen once per process; ``verify_checksums`` stays a full check of
    every byte whichever is used, only its speed differs."""
    for package in CRC32C_PACKAGES:
        fn = _crc32c_function(package)
        if fn is not None and _computes_crc32c(fn):
            return package, fn
    raise ImportError(f"no working CRC-32C among {CRC32C_PACKAGES} (google-crc32c is a dependency of zarr: "
                      "reinstall it)")



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

#: bytes of derived (computed) bricks kept for plain OME-Zarr images missing coarse levels
DERIVED_CACHE_BYTES = 256 * 2**20

_V3_NUMERIC = {
    "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float16", "float32", "float64",
}


def _read_json(path: Path, where: str, root: Path | None = None) -> dict[str, Any]:
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


def _blosc_sizes(data: bytes) -> tuple[int, int]:
    """``(nbytes, cbytes)`` from a blosc frame's 16-byte header (little-endian uint32s at 4 and 12)."""
    if len(data) < 16:
        raise ValueError(f"blosc frame of {len(data)} bytes is shorter than its 16-byte header")
    return int.from_bytes(data[4:8], "little"), int.from_bytes(data[12:16], "little")


def _decoder(name: str):
    import numcodecs

    return {"blosc": numcodecs.Blosc, "zstd": numcodecs.Zstd, "gzip": numcodecs.GZip, "zlib": numcodecs.Zlib,
            "lz4": numcodecs.LZ4}[name]()


@dataclass(frozen=True, slots=True)
class _ArrayMeta:
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


def _check_sizes(shape, chunks, where: str) -> tuple[tuple[int, ...], tuple[int, ...]]:
    def ints(v, what):
        if not isinstance(v, list) or not v or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
            raise InputFormatError(f"{where}: expected {what} as a list of integers, got {v!r:.80}")
        return tuple(v)

    shape, chunks = ints(shape, "shape"), ints(chunks, "chunk shape")
    if len(shape) != len(chunks):
        raise InputFormatError(f"{where}: expected a chunk shape of {len(shape)} dimensions, got {list(chunks)}")
    if any(s < 1 or s > 2**40 for s in shape) or math.prod(shape) > MAX_VOXELS:
        raise InputFormatError(f"{where}: expected a shape of at most 2**40 per axis and 2**62 voxels, got {list(shape)}")
    if any(c < 1 for c in chunks) or math.prod(chunks) > MAX_BRICK_VOXELS:
        raise InputFormatError(f"{where}: expected a chunk shape of at most {MAX_BRICK_VOXELS} voxels, got {list(chunks)}")
    return shape, chunks


def _array_meta(path: Path, where: str, root: Path | None = None) -> _ArrayMeta:
    """Read and validate the metadata of the array at ``path`` (zarr v3 or v2) without opening it
    with zarr; ``root``: the store, which every metadata file must lie inside."""
    if (path / "zarr.json").exists():
        m = _read_json(path / "zarr.json", where, root)
        if m.get("node_type") != "array":
            raise InputFormatError(f"{where}: expected an array, got node_type {m.get('node_type')!r}")
        dt = m.get("data_type")
        if not isinstance(dt, str) or dt not in _V3_NUMERIC:
            raise InputFormatError(f"{where}: expected an integer or float data_type, got {dt!r} (object, string, "
                                   "structured, bool and complex data are not supported)")
        grid = m.get("chunk_grid") or {}
        if grid.get("name") != "regular":
            raise InputFormatError(f"{where}: expected a regular chunk grid, got {grid.get('name')!r}")
        shape, chunks = _check_sizes(m.get("shape"), (grid.get("configuration") or {}).get("chunk_shape"), where)
        codecs = [c if isinstance(c, dict) else {"name": c} for c in m.get("codecs") or []]
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
        dtype = np.dtype(dt).newbyteorder(">" if endian == "big" else "<")
        cke = m.get("chunk_key_encoding") or {"name": "default"}
        sep = (cke.get("configuration") or {}).get("separator", "/" if cke.get("name") == "default" else ".")
        prefix = "c" + sep if cke.get("name") == "default" else ""
        if cke.get("name") not in ("default", "v2"):
            decoder = "fallback"
        return _ArrayMeta(path, shape, chunks, dtype, _fill(m.get("fill_value"), dtype, where), prefix, sep, decoder,
                          checksum)
    if (path / ".zarray").exists():
        m = _read_json(path / ".zarray", where, root)
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
        return _ArrayMeta(path, shape, chunks, dtype, _fill(m.get("fill_value"), dtype, where), "", sep, decoder)
    raise InputFormatError(f"{where}: expected a zarr array (zarr.json or .zarray) at {path}")


class ZarrLoader:
    """Loader for a clipvol store or a plain OME-Zarr image on the local file system.

    Parameters
    ----------
    path : str or Path
        The store's directory (a ``zarr:`` prefix is accepted, for :func:`clipvol.open_store`
        plug-in URLs).
    t, c : int, optional
        For an OME-Zarr image with time and/or channel axes (``t, c, z, y, x``, as microscopes
        write them): the time point and channel to read (default 0). The loader is then the 3-D
        volume at that ``(t, c)``; open one loader per time point or channel.

    Raises
    ------
    InputNotFoundError
        ``path`` does not exist.
    StoreIncompleteError
        A clipvol store whose build was interrupted (``complete: false``).
    StoreFormatError, InputFormatError
        Metadata that is inconsistent, absurd, or describes unsupported data.
    """

    #: check every load against the store's statistics (set False only to measure what it costs)
    check_plausibility: bool = True
    #: verify each chunk's crc32c (set False only to measure what it costs)
    verify_checksums: bool = True

    def __init__(self, path: str | Path, *, t: int | None = None, c: int | None = None,
                 allow_incomplete: bool = False) -> None:
        self._allow_incomplete = bool(allow_incomplete)
        if isinstance(path, str) and path.startswith("zarr:"):
            path = path[len("zarr:"):]
        self.path = Path(path)
        self._where = str(self.path)
        if not self.path.exists():
            raise InputNotFoundError(f"{self._where}: no such store")
        self._root_real = os.path.realpath(self.path)
        self._dirs_ok: set[str] = set()  # chunk folders already resolved inside the store
        self._manifest: Manifest | None = None
        #: True when the store's manifest verified (every brick's chunk size, crc32c and bounds are pinned)
        self.verified = False
        #: one line saying why the store is (un)verified
        self.trust = ""
        if (self.path / "zarr.json").exists():
            g = _read_json(self.path / "zarr.json", self._where, self.path)
            if g.get("node_type") != "group":
                raise InputFormatError(f"{self._where}: expected a zarr group, got node_type {g.get('node_type')!r}")
            attrs = g.get("attributes") or {}
        elif (self.path / ".zgroup").exists():
            attrs = _read_json(self.path / ".zattrs", self._where, self.path) if (self.path / ".zattrs").exists() else {}
        else:
            raise InputFormatError(f"{self._where}: expected a zarr group (zarr.json or .zgroup), found neither")
        self._lock = threading.Lock()
        #: bytes of chunk files read (counted in ``_load_chunk``, where they are read)
        self.read_counter = ReadCounter()
        self._zarr_arrays: dict[int, Any] = {}
        self._stats: dict[int, dict[str, np.ndarray] | None] = {}
        self._checks: dict[int, np.ndarray | None] = {}  # per level: (grid..., 5) min, max, nan, inf, crc
        self._derived: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._derived_bytes = 0
        self._want = {"t": t, "c": c}
        self._select: tuple[int, ...] = ()  # index of the leading (t, c) axes
        self._chunk_lead: tuple[int, ...] = ()  # ... as chunk grid index
        self._within: tuple[int, ...] = ()  # ... inside that chunk
        self.axes: tuple[str, ...] = ()  # names of the leading axes ("t", "c")
        self.lead_shape: tuple[int, ...] = ()
        self.origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world z, y, x of voxel 0 beyond the translations
        self.unit: str | None = None  # spatial unit, when the store says
        if "clipvol" in attrs:
            self._open_clipvol(attrs)
        else:
            self._open_ome(attrs)
        self._prepare_hot_path()

    def _prepare_hot_path(self) -> None:
        """Per level, what :meth:`read_brick_into` needs without building anything per call: the
        chunk key's root as a string, the separator, the grid, whether edge bricks are whole, and
        whether the level can be decoded straight into a slot."""
        pyr = self._pyramid
        self._roots = [am.chunk_root(self._chunk_lead) for am in self._arrays]
        self._seps = [am.separator for am in self._arrays]
        self._grids = [pyr.grid(L) for L in range(pyr.num_levels)]
        self._full_last = [tuple(n % b == 0 for n, b in zip(pyr.levels[L].shape, pyr.brick_shape))
                           for L in range(pyr.num_levels)]
        self._direct = [L < self._stored and am.fast and not self._lead and am.chunks == pyr.brick_shape
                        and am.dtype == pyr.dtype and (am.decoder is None or am.blosc)
                        for L, am in enumerate(self._arrays)]
        self._crc32c = crc32c_implementation()[1]
        # per level: each chunk's exact size from the manifest, else one cap from the chunk shape
        self._sizes = [self._manifest.sizes(L) if self._manifest is not None and L < self._stored else None
                       for L in range(len(self._arrays))]
        self._caps = [chunk_cap(am.nbytes) for am in self._arrays]
        self._tls = threading.local()  # per loader thread: the read buffer of _chunk_into_buffer
        # a subclass that fetches chunks elsewhere (remote stores) overrides _chunk_bytes: use it
        local = type(self)._chunk_bytes is ZarrLoader._chunk_bytes and hasattr(os, "readv")
        self._fetch = self._chunk_into_buffer if local else self._chunk_bytes

    @property
    def manifest(self) -> Manifest | None:
        """The store's verified manifest (:mod:`clipvol.bricking.manifest`), or None (unverified or foreign)."""
        return self._manifest

    @property
    def checksummed(self) -> bool:
        """True when every stored level carries zarr v3's ``crc32c`` codec (each chunk is verified on read)."""
        return all(am.checksum for am in self._arrays)

    # -- opening ------------------------------------------------------------------------------
    def _open_clipvol(self, attrs: dict) -> None:
        meta = parse_metadata(attrs, self._where)
        if not meta.complete and not self._allow_incomplete:
            raise StoreIncompleteError(
                f"{self._where}: the store is incomplete (attrs['clipvol']['complete'] is false): its build was "
                "interrupted; re-run `clipvol brick` with the same arguments to resume it"
            )
        pyr = meta.pyramid
        self.frame = meta.frame  # the source's voxel-to-world affine (NIfTI, DICOM, ...) or None
        self.origin, self.unit = tuple(float(v) for v in meta.origin), meta.unit
        self.is_clipvol_store = True
        self._lead = 0
        for name, v in self._want.items():
            if v is not None and v != 0:
                raise ParameterError(f"{name}: this store has no {name!r} axis (a 3-D clipvol store), got {name}={v}")
        self._arrays: list[_ArrayMeta] = []
        for L, lv in enumerate(pyr.levels):
            where = f"{self._where} level {L}"
            am = _array_meta(self.path / str(L), where, self.path)
            if am.shape != lv.shape or am.chunks != pyr.brick_shape:
                raise StoreFormatError(f"{where}: expected shape {list(lv.shape)} and chunks {list(pyr.brick_shape)}, "
                                       f"got {list(am.shape)} and {list(am.chunks)}")
            if am.dtype.newbyteorder("=") != pyr.dtype.newbyteorder("="):
                raise StoreFormatError(f"{where}: expected dtype {pyr.dtype}, got {am.dtype}")
            self._arrays.append(am)
        self._pyramid = replace(pyr, dtype=pyr.dtype.newbyteorder("="))
        self._stored = pyr.num_levels
        if not all(am.checksum for am in self._arrays):
            self.trust = ("unverified: written before chunk checksums (corruption inside a chunk is caught only by the "
                          "statistics check; `clipvol check --all` reads every brick)")
        else:
            try:
                self._manifest = load_manifest(self.path, attrs["clipvol"],
                                               [pyr.grid(L) for L in range(pyr.num_levels)])
                self.verified = True
                self.trust = f"verified: manifest sha256 {self._manifest.sha256[:16]}... pins every brick's chunk and statistics"
            except ManifestError as e:
                self.trust = f"unverified: {e}"
        if not self.verified and (meta.complete or not self._allow_incomplete):
            warnings.warn(f"{self._where}: {self.trust}", UnverifiedStoreWarning, stacklevel=3)

    def _open_ome(self, attrs: dict) -> None:
        ome = attrs.get("ome") if isinstance(attrs.get("ome"), dict) else attrs
        ms_list = ome.get("multiscales")
        if not isinstance(ms_list, list) or not ms_list or not isinstance(ms_list[0], dict):
            raise InputFormatError(f"{self._where}: neither a clipvol store nor an OME-Zarr image "
                                   "(no 'clipvol' attributes and no 'multiscales' metadata)")
        ms = ms_list[0]
        datasets = ms.get("datasets")
        if not isinstance(datasets, list) or not datasets or not all(isinstance(d, dict) and isinstance(d.get("path"), str) for d in datasets):
            raise InputFormatError(f"{self._where}: OME-Zarr 'multiscales'[0]['datasets'] is malformed")
        self.is_clipvol_store = False
        self.trust = "unverified, foreign: an OME-Zarr image not written by clipvol brick (no manifest)"
        self.frame = None  # a plain OME-Zarr image: no affine beyond scale and translation
        first = _array_meta(inside(self.path, datasets[0]["path"], f"{self._where} level 0"), f"{self._where} level 0",
                            self.path)
        nd = len(first.shape)
        if nd < 3 or nd > 5:
            raise InputFormatError(f"{self._where}: expected an image (t, c, z, y, x) with 3 to 5 axes, got shape "
                                   f"{list(first.shape)}")
        self._lead = nd - 3
        self._choose_lead(ms, first)
        brick: Int3 = tuple(first.chunks[-3:])  # type: ignore[assignment]
        expect = level_shapes(first.shape[-3:], brick)
        arrays = [first]
        for L, ds in enumerate(datasets[1:len(expect)], start=1):
            lpath = inside(self.path, ds["path"], f"{self._where} level {L}")  # outside the store: an error, not a skip
            try:
                am = _array_meta(lpath, f"{self._where} level {L}", self.path)
            except StoreFileError:
                raise  # a level file that is not what it claims is refused, never skipped
            except (InputFormatError, FileNotFoundError):
                break
            if am.shape[-3:] != expect[L] or am.chunks[-3:] != brick or am.dtype != first.dtype or len(am.shape) != nd:
                break
            arrays.append(am)
        self._arrays = arrays
        self._stored = len(arrays)
        shapes = [a.shape[-3:] for a in arrays]
        filt = ms.get("type") if ms.get("type") in FILTERS else "mean"
        infos = self._ome_levels(ms, shapes)
        for L in range(len(infos), len(expect)):  # derived levels: transform of the filter from level 0
            scale, shift = level_transform(L, infos[0].scale, filt)
            infos.append(LevelInfo(expect[L], scale, tuple(t + d for t, d in zip(infos[0].translation, shift))))
        dtype = first.dtype.newbyteorder("=")
        vr = self._ome_value_range(ome, dtype)
        fill = first.fill_value if math.isfinite(first.fill_value) else 0.0
        self._pyramid = Pyramid(tuple(infos), brick, dtype, vr or (0.0, 0.0), fill, filt)
        if vr is None:
            self._prepare_hot_path()  # _coarsest_range reads bricks
            self._pyramid = replace(self._pyramid, value_range=self._coarsest_range())

    def _choose_lead(self, ms: dict, first: "_ArrayMeta") -> None:
        """Resolve the requested ``t``/``c`` against the leading axes named in the metadata."""
        axes = ms.get("axes")
        names = []
        if isinstance(axes, list) and len(axes) == len(first.shape):
            names = [a.get("name") if isinstance(a, dict) else a for a in axes][: self._lead]
        if len(names) != self._lead or not all(isinstance(n, str) for n in names):
            names = ["t", "c"][2 - self._lead:] if self._lead else []  # OME order: t before c
        for name, v in self._want.items():
            if v is not None and name not in names and v != 0:
                raise ParameterError(f"{name}: {self._where} has no {name!r} axis (axes {names + ['z', 'y', 'x']}), "
                                     f"got {name}={v}")
        sel = []
        for name, size in zip(names, first.shape[: self._lead]):
            v = self._want.get(name) or 0
            if isinstance(v, bool) or int(v) != v or not 0 <= v < size:
                raise ParameterError(f"{name}: expected 0..{size - 1} for {self._where}, got {v!r}")
            sel.append(int(v))
        self._select = tuple(sel)
        lead_chunks = first.chunks[: self._lead]
        self._chunk_lead = tuple(v // ch for v, ch in zip(sel, lead_chunks))
        self._within = tuple(v % ch for v, ch in zip(sel, lead_chunks))
        self.axes = tuple(names)
        self.lead_shape = tuple(first.shape[: self._lead])

    def _ome_levels(self, ms: dict, shapes: list) -> list[LevelInfo]:
        out = []
        try:
            for ds, shape in zip(ms["datasets"], shapes):
                tr = {t["type"]: t for t in ds.get("coordinateTransformations", [])}
                sc = [float(v) for v in tr["scale"]["scale"]][-3:] if "scale" in tr else [1.0, 1.0, 1.0]
                tl = [float(v) for v in tr["translation"]["translation"]][-3:] if "translation" in tr else [0.0] * 3
                out.append(LevelInfo(shape, tuple(sc), tuple(tl)))
        except (KeyError, TypeError, ValueError) as e:
            raise InputFormatError(f"{self._where}: OME-Zarr coordinateTransformations are malformed ({type(e).__name__}: {e})") from None
        return out

    def _ome_value_range(self, ome: dict, dtype: np.dtype) -> tuple[float, float] | None:
        omero = ome.get("omero")
        chans = omero.get("channels") if isinstance(omero, dict) else None
        ci = self._select[self.axes.index("c")] if "c" in self.axes else 0
        first = chans[ci] if isinstance(chans, list) and len(chans) > ci else None
        win = first.get("window") if isinstance(first, dict) else None  # written by other tools: trust nothing
        if isinstance(win, dict):
            try:
                lo, hi = float(win["min"]), float(win["max"])
                if math.isfinite(lo) and math.isfinite(hi) and lo <= hi:
                    return lo, hi
            except (KeyError, TypeError, ValueError):
                pass
        if dtype.kind in "iu":
            info = np.iinfo(dtype)
            return float(info.min), float(info.max)
        return None

    def _coarsest_range(self, max_bricks: int = 64) -> tuple[float, float]:
        """Finite range of the coarsest *stored* level (levels derived on demand would read the
        whole volume), from at most ``max_bricks`` bricks spread evenly over it: an estimate, good
        enough to normalise a transfer function, that never makes opening a large image slow."""
        L = self._stored - 1
        lo, hi = math.inf, -math.inf
        g = self._pyramid.grid(L)
        n = math.prod(g)
        picks = np.unique(np.linspace(0, n - 1, min(n, max_bricks)).round().astype(np.int64))
        for idx in zip(*np.unravel_index(picks, g)):
            start, stop = self._pyramid.brick_voxel_box(L, idx)
            b = self.read_brick(L, idx)[tuple(slice(0, e - s) for s, e in zip(start, stop))]
            f = b[np.isfinite(b)]
            if f.size:
                lo, hi = min(lo, float(f.min())), max(hi, float(f.max()))
        return (lo, hi) if lo <= hi else (0.0, 0.0)

    # -- the Loader protocol ------------------------------------------------------------------
    @property
    def pyramid(self) -> Pyramid:
        return self._pyramid

    @property
    def stored_levels(self) -> int:
        """How many levels are read from the store (the rest are computed on demand)."""
        return self._stored

    def read_brick(self, level: int, index: Int3) -> np.ndarray:
        """Brick ``index`` ``(bz, by, bx)`` of ``level``: brick shape, native dtype, edge-replicated.

        Raises :class:`~clipvol.errors.BrickIntegrityError` when the chunk fails its checksum, when
        its decoded bounds disagree with the store's statistics, or when it is missing although the
        statistics say it holds data: wrong data is never returned as if right.
        """
        index = self._pyramid.check_key(level, index)
        if level >= self._stored:
            return self._derived_brick(level, index)
        am = self._arrays[level]
        start, stop = self._pyramid.brick_voxel_box(level, index)
        valid = tuple(e - s for s, e in zip(start, stop))
        if am.fast:
            buf = np.empty(am.nbytes, dtype=np.uint8)
            got = self._load_chunk(am, level, index, buf)
            if not got:
                self._check_absent(level, index)
                return np.full(self._pyramid.brick_shape, am.fill_value, dtype=self._pyramid.dtype)
            block = buf.view(am.dtype).reshape(am.chunks)
            if self._lead:
                block = block[self._within]
        else:
            got = 1
            block = self._read_zarr(level, start, stop)
        if block.shape != valid:
            block = block[tuple(slice(0, v) for v in valid)]
        if block.dtype != self._pyramid.dtype:
            block = block.astype(self._pyramid.dtype)
        self._check_plausible(level, index, block, got == 2)
        return pad_to_brick(block, self._pyramid.brick_shape)

    def read_brick_into(self, level: int, index: Int3, out: np.ndarray) -> None:
        """Write brick ``index`` of ``level`` into ``out`` (brick shape and dtype, C-contiguous).

        The clip-texture hands its slot here: an interior brick of a blosc (or uncompressed) level
        is decoded straight into it, saving a copy of every brick; anything else goes through
        :meth:`read_brick` and one copy. Same contract and errors as :meth:`read_brick`; on an
        error ``out`` holds garbage (the caller marks the brick failed, it never shows it).
        """
        direct = self._direct
        if 0 <= level < len(direct) and direct[level] and out.shape == self._pyramid.brick_shape \
                and out.dtype == self._pyramid.dtype and out.flags.c_contiguous:
            grid = self._grids[level]
            bz, by, bx = index
            # interior bricks only (the hot path: no key object, no pathlib, one bounds test)
            if 0 <= bz < grid[0] - 1 or (bz == grid[0] - 1 and self._full_last[level][0]):
                if 0 <= by < grid[1] - 1 or (by == grid[1] - 1 and self._full_last[level][1]):
                    if 0 <= bx < grid[2] - 1 or (bx == grid[2] - 1 and self._full_last[level][2]):
                        am = self._arrays[level]
                        st = self._brick_stats(level, index) if self.verify_checksums or self.check_plausibility \
                            else None  # looked up once for both checks
                        got = self._load_chunk(am, level, index, out.reshape(-1).view(np.uint8), st)
                        if not got:
                            self._check_absent(level, index)
                            out.fill(am.fill_value)  # missing chunk the statistics call empty
                            return
                        self._check_plausible(level, index, out, got == 2, st)
                        return
        out[...] = self.read_brick(level, index)

    # -- the raw fetch (the one method a remote store overrides) -------------------------------
    def _open_chunk(self, level: int, index: Int3) -> tuple[int, int] | None:
        """``(fd, size)``: a read-only descriptor of brick ``index``'s chunk file at ``level`` (the
        path from precomputed per-level parts: no pathlib, no key object) and its size, or None
        when it is absent.

        The file must be what it claims (:mod:`clipvol.bricking.store_files`): opened without
        blocking and without following a link out of the store, its folder resolved inside the
        store (once per folder), a regular file, exactly the size the manifest records (or at
        most the cap for the chunk shape). Anything else is a :class:`BrickIntegrityError`
        naming the file; no byte of it is read.
        """
        bz, by, bx = index
        sep = self._seps[level]
        path = f"{self._roots[level]}{bz}{sep}{by}{sep}{bx}"
        folder = path.rpartition("/")[0]
        try:
            if folder not in self._dirs_ok:
                real = os.path.realpath(folder)
                if real != self._root_real and not real.startswith(self._root_real.rstrip(os.sep) + os.sep):
                    raise InputFormatError(f"{folder}: resolves to {real}, outside the store {self._root_real}")
                self._dirs_ok.add(folder)
            fd = open_inside(path, self._root_real)
            if fd is None:
                return None
            try:
                sizes = self._sizes[level]
                size = check_opened(fd, path, self._caps[level], None if sizes is None else int(sizes[bz, by, bx]) or None)
            except BaseException:
                os.close(fd)
                raise
        except InputFormatError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file "
                                      f"{self._chunk_name(level, index)}: {str(e).split(': ', 1)[-1]}") from None
        return fd, size

    def _chunk_bytes(self, level: int, index: Int3) -> bytes | None:
        """The stored bytes of brick ``index``'s chunk at ``level``, or ``None`` when it is absent.

        Every raw chunk read of this loader goes through here, so a loader for another storage
        (object store, HTTP) overrides only this; decoding, checksum and plausibility stay above.
        Other ``OSError``\\ s propagate (transient: the clip-texture retries them).
        """
        opened = self._open_chunk(level, index)
        if opened is None:
            return None
        fd, size = opened
        try:  # one fstat and (for a regular file) one read: no buffered-reader object per chunk
            return read_capped(fd, size, max(size, self._caps[level]) if self._sizes[level] is None else size,
                               self._chunk_name(level, index))
        except InputFormatError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file {e}") from None
        finally:
            os.close(fd)

    def _chunk_into_buffer(self, level: int, index: Int3) -> memoryview | bytes | None:
        """:meth:`_chunk_bytes` of a local file, read into this thread's reused buffer: a memoryview
        valid until the same thread's next read through this loader (``_load_chunk`` is done with
        it by then), or None when the chunk is absent.

        Why: a fresh ``bytes`` per ~1 MB chunk costs an allocation and, whenever the allocator has
        handed the memory back to the kernel, a page fault per 4 KiB on the next read; one buffer
        per thread stays mapped and in the CPU cache, so the read is cheaper and the checksum and
        the decode that follow read the bytes from cache. It holds the largest chunk read so far,
        per loader thread. A short read, or a file whose size changed since ``fstat``, is read
        again whole by :meth:`_chunk_bytes`.
        """
        opened = self._open_chunk(level, index)
        if opened is None:
            return None
        fd, size = opened
        try:
            buf = getattr(self._tls, "buf", None)
            if buf is None or len(buf) <= size:  # one byte spare: a file that grew reads long
                buf = self._tls.buf = bytearray(size + 1 + (size >> 4))
            n = os.readv(fd, [buf])
        finally:
            os.close(fd)
        if n != size:
            return self._chunk_bytes(level, index)
        return memoryview(buf)[:n]

    def _load_chunk(self, am: _ArrayMeta, level: int, index: Int3, out: np.ndarray, st: Any = _UNREAD) -> int:
        """Fetch, verify and decode one chunk into ``out`` (uint8, the chunk's bytes). ``st``: the
        brick's :meth:`_brick_stats` when the caller has looked them up already.

        Returns 0 when the chunk is absent, 2 when its checksum is intact *and* equals the one the
        statistics recorded for this brick (the bytes are exactly those written here), else 1.
        """
        data = self._fetch(level, index)
        if data is None:
            return 0
        self.read_counter.add(len(data))
        nbytes = out.size
        loaded = 1
        try:
            if am.checksum:
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
                    loaded = 2
            else:
                body = data
            if am.decoder is None:
                if len(body) != nbytes:
                    raise ValueError(f"expected {nbytes} bytes, got {len(body)}")
                out[:] = np.frombuffer(body, dtype=np.uint8)
            elif am.blosc:
                # the header says the sizes: check them, then decode straight into `out`
                n, cbytes = _blosc_sizes(body)
                if n != nbytes or cbytes != len(body):
                    raise ValueError(f"blosc header: {n} bytes in {cbytes}, expected {nbytes} bytes in {len(body)}")
                am.decoder.decode(body, out=out)
            else:
                dec = np.frombuffer(am.decoder.decode(body), dtype=np.uint8)
                if dec.size != nbytes:
                    raise ValueError(f"decoded {dec.size} bytes, expected {nbytes}")
                out[:] = dec
        except _IdentityError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file "
                                      f"{self._chunk_name(level, index)}: {e}") from None
        except _ChecksumError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file "
                                      f"{self._chunk_name(level, index)} is truncated or corrupt ({e})") from None
        except Exception as e:  # numcodecs raises RuntimeError/ValueError/TypeError for bad data
            raise self._corrupt(level, index, e) from None
        return loaded

    def _chunk_name(self, level: int, index: Int3) -> str:
        am = self._arrays[level]
        root = self.path.resolve()
        rel = am.path.relative_to(root) if am.path.is_relative_to(root) else am.path.relative_to(self.path) \
            if am.path.is_relative_to(self.path) else am.path
        key = am.key_prefix + "".join(f"{v}{am.separator}" for v in self._chunk_lead) + am.separator.join(str(i) for i in index)
        return f"{rel}/{key}"

    def _corrupt(self, level: int, index: Int3, e: BaseException) -> InputFormatError:
        return BrickIntegrityError(
            f"{self._where}: {BrickKey(level, index)}: chunk file {self._chunk_name(level, index)} is truncated or "
            f"corrupt ({type(e).__name__}: {e})"
        )

    # -- plausibility: every load against the store's own statistics -----------------------------
    def _brick_stats(self, level: int, index: Int3) -> tuple[float, float, float, float, float] | None:
        """``(min, max, nan_count, inf_count, chunk_crc32c)`` the store recorded for the brick (NaN
        where not recorded: not compared; crc -1: no chunk written), or None (no statistics). One
        lookup in a per-level table."""
        tbl = self._checks.get(level, _UNREAD)
        if tbl is _UNREAD:
            if self._manifest is not None:  # a verified store: the manifest, never the statistics arrays
                self._checks[level] = tbl = self._manifest.checks(level)
                return tuple(tbl[index[0], index[1], index[2]].tolist())
            st = self.brick_statistics(level)
            tbl = None
            if st is not None:
                missing = np.full(st["min"].shape, np.nan)
                cols = [st["min"], st["max"]] + [st[n] if n in st else missing for n in ("nan_count", "inf_count", "chunk_crc32c")]
                tbl = np.stack(cols, axis=-1).astype(np.float64)  # a crc32c (< 2**32) is exact in float64
            self._checks[level] = tbl
        if tbl is None:
            return None
        return tuple(tbl[index[0], index[1], index[2]].tolist())

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

    def _read_zarr(self, level: int, start, stop) -> np.ndarray:
        """Codec chains off the fast path, through zarr-python (which verifies a crc32c itself). Anything
        zarr raises for metadata or data it cannot use becomes an :class:`InputFormatError`."""
        try:
            arr = self._zarr_arrays.get(level)
            if arr is None:
                import zarr

                with self._lock:
                    arr = self._zarr_arrays.get(level)
                    if arr is None:
                        arr = zarr.open_array(str(self._arrays[level].path), mode="r")
                        self._zarr_arrays[level] = arr
            sl = self._select + tuple(slice(a, b) for a, b in zip(start, stop))
            return np.asarray(arr[sl])
        except (OSError, MemoryError):
            raise
        except Exception as e:
            raise InputFormatError(f"{self._where} level {level}: zarr cannot read the array ({type(e).__name__}: "
                                   f"{str(e)[:200]})") from None

    def _derived_brick(self, level: int, index: Int3) -> np.ndarray:
        """A brick of a level the OME-Zarr image does not store: the filter over its 8 children."""
        key = (level, index)
        with self._lock:
            hit = self._derived.get(key)
            if hit is not None:
                self._derived.move_to_end(key)
                return hit.copy()
        pyr = self._pyramid
        B = pyr.brick_shape
        fine = level - 1
        fshape = pyr.levels[fine].shape
        start = [2 * i * b for i, b in zip(index, B)]
        stop = [min(s + 2 * b, n) for s, b, n in zip(start, B, fshape)]
        region = np.empty(tuple(e - s for s, e in zip(start, stop)), dtype=pyr.dtype)
        for child in pyr.children(level, index):
            cs, ce = pyr.brick_voxel_box(fine, child)
            data = self.read_brick(fine, child)
            region[tuple(slice(a - o, b - o) for a, b, o in zip(cs, ce, start))] = data[tuple(slice(0, b - a) for a, b in zip(cs, ce))]
        out = pad_to_brick(downsample(region, pyr.filter), B)
        with self._lock:
            if key not in self._derived:
                self._derived[key] = out
                self._derived_bytes += out.nbytes
                while self._derived_bytes > DERIVED_CACHE_BYTES and len(self._derived) > 1:
                    _, old = self._derived.popitem(last=False)
                    self._derived_bytes -= old.nbytes
        return out.copy()

    # -- statistics (HasBrickRanges) ----------------------------------------------------------
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
        base = self.path / STATS_GROUP / str(level)
        if base.is_dir():
            import zarr

            try:  # zarr-python opens these files itself: look at what they are first
                check_tree(base, self.path, MAX_STATS_FILE_BYTES)
            except InputFormatError as e:
                raise StoreFormatError(f"{self._where}: {STATS_GROUP}/{level}: {e}") from None
            grid = self._pyramid.grid(level)
            for name in STAT_ARRAYS:
                p = base / name
                if not p.is_dir():
                    continue
                am = _array_meta(p, f"{self._where} {STATS_GROUP}/{level}/{name}", self.path) if name != "done" else None
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

    def __repr__(self) -> str:
        kind = "clipvol store" if self.is_clipvol_store else "OME-Zarr"
        return f"ZarrLoader({self._where!r}, {kind}, {self._pyramid.num_levels} levels, brick {self._pyramid.brick_shape})"
