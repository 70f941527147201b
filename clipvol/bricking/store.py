"""The clipvol store format: metadata written by ``clipvol brick``, read by every reader.

A store is a zarr v3 group (full description in ``docs/format.md``)::

    store.zarr/
      zarr.json            attributes: "ome" (OME-Zarr 0.5 multiscales) and "clipvol" (below)
      0/ 1/ ... N-1/       one array per level, one chunk per brick, dimension_names z, y, x;
                           fill_value = background; empty bricks are not written
      clipvol_stats/L/     per level, arrays over the brick grid: min, max, mean, std (float64),
                           nan_count, inf_count (int64), histogram (grid + (64,), int64), done (bool),
                           chunk_crc32c (int64: each chunk's crc32c, -1 where none was written)

``attrs["clipvol"]`` holds ``format_version``, ``brick_shape``, ``filter``, ``dtype``,
``value_range`` (finite min/max of level 0), ``fill_value``, ``spacing``, ``unit``, ``codec``,
``histogram_bins``, ``levels`` (shapes) and ``complete``; stores built from a file that records
its geometry (NIfTI, DICOM, MRC, ...) add ``origin`` (level-0 translation, z, y, x, also added to
every OME ``translation``), ``affine`` and ``world_frame`` (:mod:`clipvol.bricking.worldframe`). ``complete`` becomes ``true`` in the very
last write of a build, so a reader can tell an interrupted build from a finished one.

This module only builds and validates metadata dictionaries (pure Python); it never reads data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputNotFoundError, StoreFormatError, StoreIncompleteError
from .pyramid import FILTERS, LevelInfo, Pyramid, validate_dtype
from .worldframe import WorldFrame

__all__ = [
    "FORMAT_VERSION",
    "STATS_GROUP",
    "HIST_BINS",
    "STAT_ARRAYS",
    "MAX_VOXELS",
    "StoreMeta",
    "ome_metadata",
    "clipvol_metadata",
    "parse_metadata",
    "open_store_meta",
]

FORMAT_VERSION = 1
STATS_GROUP = "clipvol_stats"
HIST_BINS = 64
#: per-level statistics arrays under ``clipvol_stats/<level>/``
STAT_ARRAYS = ("min", "max", "mean", "std", "nan_count", "inf_count", "histogram", "done", "chunk_crc32c")
#: refuse metadata claiming more voxels than this (2**63 bytes would not fit any index anyway)
MAX_VOXELS = 2**62
MAX_BRICK_VOXELS = 512**3


@dataclass(frozen=True, slots=True)
class StoreMeta:
    """Validated metadata of a clipvol store."""

    pyramid: Pyramid
    unit: str
    codec: str
    complete: bool
    format_version: int
    histogram_bins: int = HIST_BINS
    #: world position of voxel 0 along the array axes (z, y, x); added to every OME translation
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: the source's voxel-to-world affine and frame, when it recorded one
    frame: WorldFrame | None = None


def ome_metadata(pyramid: Pyramid, name: str = "image", unit: str = "micrometer", origin=(0.0, 0.0, 0.0)) -> dict[str, Any]:
    """The OME-Zarr 0.5 ``attrs["ome"]`` block for ``pyramid`` (axes z, y, x of type space).

    ``origin`` (z, y, x) shifts every level's translation: the world position of voxel 0.
    """
    datasets = []
    for L, lv in enumerate(pyramid.levels):
        datasets.append(
            {
                "path": str(L),
                "coordinateTransformations": [
                    {"type": "scale", "scale": list(lv.scale)},
                    {"type": "translation", "translation": [t + float(o) for t, o in zip(lv.translation, origin)]},
                ],
            }
        )
    return {
        "version": "0.5",
        "multiscales": [
            {
                "name": name,
                "axes": [{"name": a, "type": "space", "unit": unit} for a in ("z", "y", "x")],
                "datasets": datasets,
                "type": {"mean": "mean", "max": "max", "subsample": "subsample", "mode": "mode"}[pyramid.filter],
                "metadata": {"method": f"clipvol.bricking.pyramid.downsample(filter={pyramid.filter!r})"},
            }
        ],
    }


def clipvol_metadata(
    pyramid: Pyramid, *, unit: str, codec: str, complete: bool, source: str = "", frame: WorldFrame | None = None
) -> dict[str, Any]:
    """The ``attrs["clipvol"]`` block (with ``origin``, ``affine``, ``world_frame`` when ``frame`` is given)."""
    geometry = {} if frame is None else {"origin": list(frame.origin), **frame.to_attrs()}
    return {
        "format_version": FORMAT_VERSION,
        "brick_shape": list(pyramid.brick_shape),
        "filter": pyramid.filter,
        "dtype": pyramid.dtype.str if pyramid.dtype.byteorder not in "=|" else pyramid.dtype.name,
        "value_range": list(pyramid.value_range),
        "fill_value": pyramid.fill_value,
        "spacing": list(pyramid.spacing),
        "unit": unit,
        "codec": codec,
        "histogram_bins": HIST_BINS,
        "levels": [list(lv.shape) for lv in pyramid.levels],
        "source": source,
        "complete": bool(complete),
        **geometry,
    }


def _get(d: dict, key: str, where: str):
    if key not in d:
        raise StoreFormatError(f"{where}: missing key {key!r}")
    return d[key]


def _int_list(v, n: int, where: str, lo: int = 1, hi: int = 2**40) -> tuple[int, ...]:
    if not isinstance(v, (list, tuple)) or len(v) != n or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
        raise StoreFormatError(f"{where}: expected {n} integers, got {v!r}")
    if any(x < lo or x > hi for x in v):
        raise StoreFormatError(f"{where}: expected integers in {lo}..{hi}, got {v!r}")
    return tuple(v)


def _float_list(v, n: int, where: str) -> tuple[float, ...]:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise StoreFormatError(f"{where}: expected {n} numbers, got {v!r}")
    try:
        out = tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise StoreFormatError(f"{where}: expected {n} numbers, got {v!r}") from None
    if not all(math.isfinite(x) for x in out):
        raise StoreFormatError(f"{where}: expected finite numbers, got {v!r}")
    return out


def parse_metadata(attrs: dict[str, Any], where: str) -> StoreMeta:
    """Validate a store's group attributes and return its :class:`StoreMeta`.

    Everything is checked *before* any array is touched or allocated: absurd shapes, brick shapes
    or level counts, unsupported dtypes (object, structured, complex, bool - nothing is ever
    unpickled) and inconsistent OME transforms raise :class:`StoreFormatError` naming ``where``
    (the store path) and the key.
    """
    if not isinstance(attrs, dict) or "clipvol" not in attrs:
        raise StoreFormatError(f"{where}: not a clipvol store (no 'clipvol' attributes in zarr.json)")
    cv = attrs["clipvol"]
    w = f"{where}: attrs['clipvol']"
    version = _get(cv, "format_version", w)
    if version != FORMAT_VERSION:
        raise StoreFormatError(f"{w}['format_version']: expected {FORMAT_VERSION}, got {version!r}")
    brick = _int_list(_get(cv, "brick_shape", w), 3, f"{w}['brick_shape']", 1, 4096)
    if math.prod(brick) > MAX_BRICK_VOXELS:
        raise StoreFormatError(f"{w}['brick_shape']: {brick} has more than {MAX_BRICK_VOXELS} voxels")
    filt = _get(cv, "filter", w)
    if filt not in FILTERS:
        raise StoreFormatError(f"{w}['filter']: expected one of {FILTERS}, got {filt!r}")
    try:
        dtype = validate_dtype(_get(cv, "dtype", w), f"{w}['dtype']")
    except ValueError as e:
        raise StoreFormatError(str(e)) from None
    vr = _float_list(_get(cv, "value_range", w), 2, f"{w}['value_range']")
    if vr[1] < vr[0]:
        raise StoreFormatError(f"{w}['value_range']: expected min <= max, got {vr}")
    fill = cv.get("fill_value", 0.0)
    if not isinstance(fill, (int, float)) or isinstance(fill, bool):
        raise StoreFormatError(f"{w}['fill_value']: expected a number, got {fill!r}")
    spacing = _float_list(_get(cv, "spacing", w), 3, f"{w}['spacing']")
    if any(s <= 0 for s in spacing):
        raise StoreFormatError(f"{w}['spacing']: expected values > 0, got {spacing}")
    levels_raw = _get(cv, "levels", w)
    if not isinstance(levels_raw, list) or not (1 <= len(levels_raw) <= 64):
        raise StoreFormatError(f"{w}['levels']: expected a list of 1..64 level shapes, got {levels_raw!r:.80}")
    shapes = [_int_list(s, 3, f"{w}['levels'][{i}]") for i, s in enumerate(levels_raw)]
    if math.prod(shapes[0]) > MAX_VOXELS:
        raise StoreFormatError(f"{w}['levels'][0]: {shapes[0]} claims more than 2**62 voxels")
    expect = Pyramid.build(shapes[0], brick, spacing, filt, dtype, vr, float(fill))
    if [lv.shape for lv in expect.levels] != list(shapes):
        raise StoreFormatError(
            f"{w}['levels']: expected the halving sequence {[list(lv.shape) for lv in expect.levels]} "
            f"for level 0 {list(shapes[0])} and brick {list(brick)}, got {levels_raw}"
        )
    origin = _float_list(cv.get("origin", [0.0, 0.0, 0.0]), 3, f"{w}['origin']")
    frame = WorldFrame.from_attrs(cv, where)
    # The OME block must agree with what we derive (other tools read it, we must not contradict it).
    ome = attrs.get("ome")
    if ome is not None:
        try:
            datasets = ome["multiscales"][0]["datasets"]
            if len(datasets) != len(expect.levels):
                raise StoreFormatError(f"{where}: attrs['ome']['multiscales'][0]['datasets'] lists {len(datasets)} "
                                       f"level(s), expected {len(expect.levels)} (one per level of attrs['clipvol']"
                                       f"['levels'])")
            for L, (ds, lv) in enumerate(zip(datasets, expect.levels, strict=True)):
                tr = {t["type"]: t for t in ds["coordinateTransformations"]}
                sc = tuple(float(v) for v in tr["scale"]["scale"])
                tl = tuple(float(v) for v in tr.get("translation", {"translation": [0, 0, 0]})["translation"])
                want = tuple(t + o for t, o in zip(lv.translation, origin))
                if not (np.allclose(sc, lv.scale) and np.allclose(tl, want)):
                    raise StoreFormatError(f"{where}: attrs['ome'] level {L}: scale/translation {sc}/{tl} disagree with clipvol's {lv.scale}/{want}")
        except StoreFormatError:
            raise
        except (KeyError, IndexError, TypeError, ValueError) as e:
            raise StoreFormatError(f"{where}: attrs['ome']['multiscales'] is malformed ({type(e).__name__}: {e})") from None
    unit = cv.get("unit", "micrometer")
    codec = cv.get("codec", "unknown")
    bins = cv.get("histogram_bins", HIST_BINS)
    return StoreMeta(expect, str(unit), str(codec), bool(cv.get("complete", False)), int(version), int(bins), origin, frame)


def level_info_from_ome(attrs: dict[str, Any], shapes: list[tuple[int, int, int]], where: str) -> list[LevelInfo]:
    """LevelInfo for each dataset of a plain OME-Zarr image (first multiscale; z, y, x axes last)."""
    try:
        ms = (attrs.get("ome") or attrs)["multiscales"][0]
        if len(ms["datasets"]) != len(shapes):
            raise StoreFormatError(f"{where}: OME-Zarr 'multiscales'[0]['datasets'] lists {len(ms['datasets'])} "
                                   f"level(s), expected {len(shapes)} (one per level array)")
        out = []
        for ds, shape in zip(ms["datasets"], shapes, strict=True):
            tr = {t["type"]: t for t in ds["coordinateTransformations"]}
            sc = [float(v) for v in tr["scale"]["scale"]][-3:]
            tl = [float(v) for v in tr.get("translation", {"translation": [0.0] * 3})["translation"]][-3:]
            out.append(LevelInfo(shape, tuple(sc), tuple(tl)))
        return out
    except StoreFormatError:
        raise
    except (KeyError, IndexError, TypeError, ValueError) as e:
        raise StoreFormatError(f"{where}: OME-Zarr 'multiscales' metadata is malformed ({type(e).__name__}: {e})") from None


def open_store_meta(path, *, require_complete: bool = False) -> StoreMeta:
    """Read and validate the metadata of the store at ``path`` (a directory) without touching data.

    Raises :class:`~clipvol.errors.InputNotFoundError` when ``path`` does not exist,
    :class:`StoreFormatError` when it is not a clipvol store, and, with ``require_complete``,
    :class:`~clipvol.errors.StoreIncompleteError` for an interrupted build.
    """
    import json
    from pathlib import Path

    from .store_files import read_file

    p = Path(path)
    if not p.exists():
        raise InputNotFoundError(f"{p}: no such store")
    try:  # a regular file inside the store, size-capped: never a FIFO, a device or a link out
        meta = json.loads(read_file(p / "zarr.json", p))
    except FileNotFoundError:
        raise StoreFormatError(f"{p}: not a zarr v3 store (no zarr.json)") from None
    except (OSError, ValueError) as e:
        raise StoreFormatError(f"{p}/zarr.json: unreadable ({e})") from None
    attrs = meta.get("attributes", {}) if isinstance(meta, dict) else {}
    out = parse_metadata(attrs, str(p))
    if require_complete and not out.complete:
        raise StoreIncompleteError(f"{p}: incomplete store (an interrupted build); re-run the same `clipvol brick` command to resume")
    return out
