"""Read bricks from a zarr store: a clipvol store, or any plain OME-Zarr image.

Why not just ``arr[...]``: zarr-python 3.1 spends ~0.3-0.9 ms of fixed overhead per indexing call
and funnels every thread through one event loop, so chunk-aligned reads from several loader
threads reach only a few percent of memcpy speed. Because a brick *is* one chunk, this loader reads
the chunk's file itself (``<array>/c/<bz>/<by>/<bx>`` for zarr v3's default key encoding) and
decodes it with numcodecs, which releases the GIL, in the calling loader thread. The codec chains
``bytes`` (+ ``blosc`` | ``zstd`` | ``gzip`` | nothing) of zarr v3 and the plain compressors of
zarr v2 take this fast path; anything else (sharding, transpose, crc32c, filters) falls back to
zarr indexing, which gives the same values, only slower. A missing chunk file is an empty brick
(the array's fill value); a truncated or corrupt one raises :class:`InputFormatError` naming the
store, level and brick.

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

import json
import math
import threading
from collections import OrderedDict
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
from clipvol.bricking.store import (
    MAX_BRICK_VOXELS,
    MAX_VOXELS,
    STAT_ARRAYS,
    STATS_GROUP,
    parse_metadata,
)
from clipvol.errors import (
    InputFormatError,
    InputNotFoundError,
    ParameterError,
    StoreFormatError,
    StoreIncompleteError,
)
from clipvol.paging.loader import BrickKey

__all__ = ["ZarrLoader"]

#: bytes of derived (computed) bricks kept for plain OME-Zarr images missing coarse levels
DERIVED_CACHE_BYTES = 256 * 2**20

_V3_NUMERIC = {
    "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float16", "float32", "float64",
}


def _read_json(path: Path, where: str) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            doc = json.loads(f.read())
    except FileNotFoundError:
        raise
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

    @property
    def fast(self) -> bool:
        return self.decoder != "fallback"

    @property
    def blosc(self) -> bool:
        return type(self.decoder).__name__ == "Blosc"

    def chunk_path(self, cidx: tuple[int, ...]) -> Path:
        return self.path / (self.key_prefix + self.separator.join(str(i) for i in cidx))


def _fill(raw, dtype: np.dtype, where: str) -> float:
    if raw is None:
        return 0.0
    if isinstance(raw, str):
        try:
            return float({"NaN": "nan", "Infinity": "inf", "-Infinity": "-inf"}.get(raw, raw))
        except ValueError:
            raise InputFormatError(f"{where}: expected a numeric fill_value, got {raw!r}") from None
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise InputFormatError(f"{where}: expected a numeric fill_value, got {raw!r}")
    return float(raw)


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


def _array_meta(path: Path, where: str) -> _ArrayMeta:
    """Read and validate the metadata of the array at ``path`` (zarr v3 or v2) without opening it with zarr."""
    if (path / "zarr.json").is_file():
        m = _read_json(path / "zarr.json", where)
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
        return _ArrayMeta(path, shape, chunks, dtype, _fill(m.get("fill_value"), dtype, where), prefix, sep, decoder)
    if (path / ".zarray").is_file():
        m = _read_json(path / ".zarray", where)
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

    def __init__(self, path: str | Path, *, t: int | None = None, c: int | None = None) -> None:
        if isinstance(path, str) and path.startswith("zarr:"):
            path = path[len("zarr:"):]
        self.path = Path(path)
        self._where = str(self.path)
        if not self.path.exists():
            raise InputNotFoundError(f"{self._where}: no such store")
        if (self.path / "zarr.json").is_file():
            g = _read_json(self.path / "zarr.json", self._where)
            if g.get("node_type") != "group":
                raise InputFormatError(f"{self._where}: expected a zarr group, got node_type {g.get('node_type')!r}")
            attrs = g.get("attributes") or {}
        elif (self.path / ".zgroup").is_file():
            attrs = _read_json(self.path / ".zattrs", self._where) if (self.path / ".zattrs").is_file() else {}
        else:
            raise InputFormatError(f"{self._where}: expected a zarr group (zarr.json or .zgroup), found neither")
        self._lock = threading.Lock()
        self._zarr_arrays: dict[int, Any] = {}
        self._stats: dict[int, dict[str, np.ndarray] | None] = {}
        self._derived: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._derived_bytes = 0
        self._want = {"t": t, "c": c}
        self._select: tuple[int, ...] = ()  # index of the leading (t, c) axes
        self._chunk_lead: tuple[int, ...] = ()  # ... as chunk grid index
        self._within: tuple[int, ...] = ()  # ... inside that chunk
        self.axes: tuple[str, ...] = ()  # names of the leading axes ("t", "c")
        self.lead_shape: tuple[int, ...] = ()
        if "clipvol" in attrs:
            self._open_clipvol(attrs)
        else:
            self._open_ome(attrs)

    # -- opening ------------------------------------------------------------------------------
    def _open_clipvol(self, attrs: dict) -> None:
        meta = parse_metadata(attrs, self._where)
        if not meta.complete:
            raise StoreIncompleteError(
                f"{self._where}: the store is incomplete (attrs['clipvol']['complete'] is false): its build was "
                "interrupted; re-run `clipvol brick` with the same arguments to resume it"
            )
        pyr = meta.pyramid
        self.frame = meta.frame  # the source's voxel-to-world affine (NIfTI, DICOM, ...) or None
        self.is_clipvol_store = True
        self._lead = 0
        for name, v in self._want.items():
            if v is not None and v != 0:
                raise ParameterError(f"{name}: this store has no {name!r} axis (a 3-D clipvol store), got {name}={v}")
        self._arrays: list[_ArrayMeta] = []
        for L, lv in enumerate(pyr.levels):
            where = f"{self._where} level {L}"
            am = _array_meta(self.path / str(L), where)
            if am.shape != lv.shape or am.chunks != pyr.brick_shape:
                raise StoreFormatError(f"{where}: expected shape {list(lv.shape)} and chunks {list(pyr.brick_shape)}, "
                                       f"got {list(am.shape)} and {list(am.chunks)}")
            if am.dtype.newbyteorder("=") != pyr.dtype.newbyteorder("="):
                raise StoreFormatError(f"{where}: expected dtype {pyr.dtype}, got {am.dtype}")
            self._arrays.append(am)
        self._pyramid = replace(pyr, dtype=pyr.dtype.newbyteorder("="))
        self._stored = pyr.num_levels

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
        self.frame = None  # a plain OME-Zarr image: no affine beyond scale and translation
        first = _array_meta(self.path / datasets[0]["path"], f"{self._where} level 0")
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
            try:
                am = _array_meta(self.path / ds["path"], f"{self._where} level {L}")
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
        """Brick ``index`` ``(bz, by, bx)`` of ``level``: brick shape, native dtype, edge-replicated."""
        index = self._pyramid.check_key(level, index)
        if level >= self._stored:
            return self._derived_brick(level, index)
        am = self._arrays[level]
        start, stop = self._pyramid.brick_voxel_box(level, index)
        if am.fast:
            block = self._read_fast(am, level, index)
        else:
            block = self._read_zarr(level, start, stop)
        valid = tuple(e - s for s, e in zip(start, stop))
        if block.shape != valid:
            block = block[tuple(slice(0, v) for v in valid)]
        if block.dtype != self._pyramid.dtype:
            block = block.astype(self._pyramid.dtype)
        return pad_to_brick(block, self._pyramid.brick_shape)

    def read_brick_into(self, level: int, index: Int3, out: np.ndarray) -> None:
        """Write brick ``index`` of ``level`` into ``out`` (brick shape and dtype, C-contiguous).

        The clip-texture hands its slot here: an interior brick of a blosc (or uncompressed) level
        is decoded straight into it, saving a copy of every brick; anything else goes through
        :meth:`read_brick` and one copy. Same contract and errors as :meth:`read_brick`.
        """
        index = self._pyramid.check_key(level, index)
        pyr = self._pyramid
        if level < self._stored and out.flags.c_contiguous and out.shape == pyr.brick_shape and out.dtype == pyr.dtype:
            am = self._arrays[level]
            start, stop = pyr.brick_voxel_box(level, index)
            interior = all(e - s == b for s, e, b in zip(start, stop, pyr.brick_shape))
            if am.fast and interior and not self._lead and am.chunks == pyr.brick_shape and am.dtype == pyr.dtype \
                    and (am.decoder is None or am.blosc):
                if self._read_fast(am, level, index, out.reshape(-1).view(np.uint8)) is None:
                    out.fill(am.fill_value)  # missing chunk: an empty brick
                return
        out[...] = self.read_brick(level, index)

    def _read_fast(self, am: _ArrayMeta, level: int, index: Int3, buf: np.ndarray | None = None) -> np.ndarray | None:
        """Decode one chunk file; into ``buf`` (uint8, chunk bytes) when given, where a missing
        chunk returns None instead of a filled array."""
        cpath = am.chunk_path(self._chunk_lead + tuple(index))
        nbytes = math.prod(am.chunks) * am.dtype.itemsize
        out = np.empty(nbytes, dtype=np.uint8) if buf is None else buf
        try:
            with open(cpath, "rb") as f:
                if am.decoder is None:
                    n = f.readinto(memoryview(out))
                    if n != nbytes or f.read(1):
                        raise ValueError(f"expected {nbytes} bytes, got {n if n != nbytes else 'more'}")
                else:
                    data = f.read()
        except FileNotFoundError:
            if buf is not None:
                return None
            return np.full(self._pyramid.brick_shape, am.fill_value, dtype=self._pyramid.dtype)
        except ValueError as e:
            raise self._corrupt(level, index, cpath, e) from None
        if am.decoder is not None:
            try:
                if am.blosc:
                    # the header says the sizes: check them, then decode straight into `out`
                    n, cbytes = _blosc_sizes(data)
                    if n != nbytes or cbytes != len(data):
                        raise ValueError(f"blosc header: {n} bytes in {cbytes}, expected {nbytes} bytes in {len(data)}")
                    am.decoder.decode(data, out=out)
                else:
                    dec = np.frombuffer(am.decoder.decode(data), dtype=np.uint8)
                    if dec.size != nbytes:
                        raise ValueError(f"decoded {dec.size} bytes, expected {nbytes}")
                    out = dec
            except Exception as e:  # numcodecs raises RuntimeError/ValueError/TypeError for bad data
                raise self._corrupt(level, index, cpath, e) from None
        arr = out.view(am.dtype).reshape(am.chunks)
        if self._lead:
            arr = arr[self._within]
        return arr

    def _corrupt(self, level: int, index: Int3, cpath: Path, e: BaseException) -> InputFormatError:
        return InputFormatError(
            f"{self._where}: {BrickKey(level, index)}: chunk file {cpath.relative_to(self.path)} is truncated or "
            f"corrupt ({type(e).__name__}: {e})"
        )

    def _read_zarr(self, level: int, start, stop) -> np.ndarray:
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

            grid = self._pyramid.grid(level)
            for name in STAT_ARRAYS:
                p = base / name
                if not p.is_dir():
                    continue
                am = _array_meta(p, f"{self._where} {STATS_GROUP}/{level}/{name}") if name != "done" else None
                if am is not None and tuple(am.shape[:3]) != grid:
                    raise StoreFormatError(f"{self._where}: {STATS_GROUP}/{level}/{name}: expected shape starting "
                                           f"{list(grid)}, got {list(am.shape)}")
                a = np.asarray(zarr.open_array(str(p), mode="r")[...])
                a.setflags(write=False)
                stats[name] = a
        if not stats or "min" not in stats or "max" not in stats:
            stats = None
        with self._lock:
            self._stats[level] = stats
        return stats

    def brick_ranges(self, level: int, indices: np.ndarray) -> np.ndarray | None:
        """``(n, 2)`` ``[min, max]`` of each brick in ``indices`` (``(n, 3)``) from the store's
        statistics, or ``None`` (plain OME-Zarr, or no statistics)."""
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
