"""Bricking a 4-D input: one OME-Zarr 0.5 image with a channel or time axis.

A microscope's 4-D stack (a ``.npy`` of shape ``(c, z, y, x)`` or ``(t, z, y, x)``, or an OME-TIFF
whose axes hold a ``C``) becomes one multiscale image whose arrays are 4-D: ``OUTPUT/0``,
``OUTPUT/1``, ... have shape ``(n, Z_L, Y_L, X_L)``, chunks ``(1, bz, by, bx)`` and
``dimension_names`` ``["c", "z", "y", "x"]`` (or ``"t"``), and the root's ``attrs["ome"]`` names the
axis (type ``channel`` or ``time``, scale 1 and translation 0 along it) with an ``omero`` block
(each channel's window; for a time series one window over every step). This is the layout of
OME-Zarr 0.5 (Moore et al., *OME-Zarr: a cloud-optimized bioimaging file format with international
community support*, 2023), so napari, ome-zarr-py, ome-zarr-models, tensorstore and zarr-python
open the root as one 4-D image. A 4-D array does not say which its first axis is; ``axis`` does
(default ``"c"``).

What clipvol keeps per brick stays per ``(c)`` or ``(t)``: ``OUTPUT/clipvol_members/c/K`` is a group
holding member ``K``'s ``attrs["clipvol"]`` (its levels, value range and manifest digest), its
statistics, manifest and summary tables, exactly as a single store holds them, without the level
arrays (its bricks are the root's chunks ``L/c/K/bz/by/bx``). Each member is built as a complete
store first, then *adopted*: its chunk files are moved into the root's arrays unchanged (a chunk of
shape ``(1, bz, by, bx)`` has the bytes of the ``(bz, by, bx)`` one), so the manifest's sizes and
crc32c still pin every chunk. The loader sees a 3-D pyramid per member, a view of the 4-D arrays
(:class:`clipvol.loaders.zarr_store.ZarrLoader` with ``c=`` / ``t=``).

The root's attributes are written last (the set is recognised only once every member is adopted;
an interrupted build resumes member by member):

* ``attributes["clipvol_channels"] = {"version": 2, "channels": C, "members": "clipvol_members/c"}``
  or ``attributes["clipvol_timeseries"] = {"version": 2, "steps": T, "members": "clipvol_members/t"}``
  (what :func:`image_set` reads);
* ``attributes["ome"]``: the multiscale image above.

Sets written before this layout (``version`` 1: one complete store per member at ``OUTPUT/c/K``
with an OME-Zarr collection, ``bioformats2raw.layout``) keep opening as before
(:func:`set_version` tells them apart; :func:`clipvol.paging.open.open_store` opens their members).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputFormatError, ParameterError

__all__ = ["CHANNELS_ATTR", "TIMESERIES_ATTR", "SET_AXES", "MEMBERS_GROUP", "MEMBER_ATTR", "SET_VERSION",
           "channel_count", "read_channels", "brick_channels", "brick_set", "image_set", "set_version",
           "member_path", "series_window"]

#: the group attribute that marks a channel set
CHANNELS_ATTR = "clipvol_channels"
#: the group attribute that marks a time series
TIMESERIES_ATTR = "clipvol_timeseries"
#: the leading axis a set may have, and its attribute and count key
SET_AXES = {"c": (CHANNELS_ATTR, "channels"), "t": (TIMESERIES_ATTR, "steps")}
#: the group under the root holding each member's clipvol metadata, statistics and manifest
MEMBERS_GROUP = "clipvol_members"
#: the attribute that marks a member group (``{"axis": "c", "index": K}``): not a store by itself
MEMBER_ATTR = "clipvol_member"
#: the layout :func:`brick_set` writes (1: one store per member under an OME-Zarr collection)
SET_VERSION = 2


def _ome_tiff_axes(path: Path):
    import tifffile

    with tifffile.TiffFile(path) as tf:
        s = tf.series[0]
        return s.axes, s.shape


def channel_count(source) -> int | None:
    """Length of the first axis of a 4-D input (a numpy array, a ``.npy``, or an OME-TIFF with a C
    axis), or None for anything else (3-D inputs and formats without a fourth axis)."""
    if isinstance(source, np.ndarray):
        return int(source.shape[0]) if source.ndim == 4 else None
    p = Path(str(source))
    name = p.name.lower()
    if name.endswith(".npy") and p.is_file():
        from .npy import npy_header

        shape = npy_header(p)[0]  # a .npy that cannot be read is refused here, naming the file
        return int(shape[0]) if len(shape) == 4 else None
        return int(arr.shape[0]) if arr.ndim == 4 else None
    if name.endswith((".ome.tif", ".ome.tiff")) and p.is_file():
        axes, shape = _ome_tiff_axes(p)
        if "C" in axes and len(shape) == 4 and set(axes) == set("CZYX"):
            return int(shape[axes.index("C")])
    return None


def read_channels(source) -> np.ndarray:
    """The 4-D ``(c or t, z, y, x)`` array of a 4-D input (a memory map for ``.npy``)."""
    if isinstance(source, np.ndarray):
        arr = source
    else:
        p = Path(str(source))
        if p.name.lower().endswith(".npy"):
            from .npy import open_npy

            arr = open_npy(p)
        else:
            import tifffile

            axes, _ = _ome_tiff_axes(p)
            arr = np.moveaxis(tifffile.imread(p), [axes.index(a) for a in "CZYX"], [0, 1, 2, 3])
    if arr.ndim != 4:
        raise InputFormatError(f"{source if not isinstance(source, np.ndarray) else 'array'}: expected a 4-D "
                               f"(c, z, y, x) or (t, z, y, x) input, got shape {arr.shape}")
    return arr


def brick_set(source, output, *, axis: str = "c", **kwargs) -> list:
    """Brick each ``axis`` entry of a 4-D input into one OME-Zarr 0.5 image with a ``c`` or ``t``
    axis at ``output`` (see the module docstring); ``kwargs`` as
    :func:`clipvol.bricking.pipeline.brick_volume`. Returns each member's metadata."""
    from .pipeline import brick_volume, output_lock, write_errors
    from .store import parse_metadata

    if axis not in SET_AXES:
        raise ParameterError(f"axes: expected the first axis of a 4-D input to be one of {sorted(SET_AXES)}, got {axis!r}")
    if axis == "t" and not isinstance(source, np.ndarray) and not str(source).lower().endswith(".npy"):
        raise ParameterError(f"--axes: tzyx is read from a 4-D .npy (or an array), got {source}")
    arr = read_channels(source)
    output = Path(output)
    from .output_guard import check_not_input, check_overwrite, exists_error, remove_output

    inputs = [source] if isinstance(source, (str, Path)) else []
    check_not_input(output, inputs)
    if kwargs.get("overwrite") and (output.exists() or output.is_symlink()):
        check_overwrite(output, inputs)
        remove_output(output)
    kwargs = {**kwargs, "overwrite": False}
    if image_set(output) is not None:
        raise exists_error(output, what="exists (a complete image set)", name="output")
    if output.exists() and (not output.is_dir() or not (output / "zarr.json").exists() and any(output.iterdir())):
        raise exists_error(output, name="output")
    n = int(arr.shape[0])
    metas = []
    if (output / "zarr.json").exists() and _member_attrs(output):
        from ..errors import OutputExistsError

        raise OutputExistsError(f"{output}: output exists and is not an interrupted image set; pass --overwrite to "
                                "replace it")
    output.mkdir(parents=True, exist_ok=True)
    with write_errors(output), output_lock(output):
        _write_json(output / "zarr.json", {"zarr_format": 3, "node_type": "group", "attributes": {}})
        members = output / MEMBERS_GROUP
        _write_json(members / "zarr.json", {"zarr_format": 3, "node_type": "group", "attributes": {}})
        _write_json(members / axis / "zarr.json", {"zarr_format": 3, "node_type": "group", "attributes": {}})
        for k in range(n):
            member = members / axis / str(k)
            attrs = _member_attrs(member)
            if MEMBER_ATTR not in attrs:  # not yet adopted: build it (or finish an interrupted build), then adopt it
                if not (attrs.get("clipvol") or {}).get("complete"):
                    brick_volume(np.asarray(arr[k]), member, **kwargs)
                elif kwargs.get("summary", True):
                    from .summary import build_summary  # an interrupted summary: resumed, else a no-op

                    build_summary(member, workers=kwargs.get("workers"), progress=False)
                _adopt(output, member, axis, k, n)
                attrs = _member_attrs(member)
            metas.append(parse_metadata(attrs, str(member)))
        _check_members(metas, output, axis)
        root_attrs = {"ome": _root_ome(output, metas, axis, n),
                      SET_AXES[axis][0]: {"version": SET_VERSION, SET_AXES[axis][1]: n, "members": f"{MEMBERS_GROUP}/{axis}"}}
        _write_json(output / "zarr.json", {"zarr_format": 3, "node_type": "group", "attributes": root_attrs})
    return metas  # the root's attributes were the last write: the set exists from here on


def _write_json(path: Path, doc: dict) -> None:
    """Write ``doc`` to ``path`` atomically (a reader sees the old file or the new one, never half)."""
    import os

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(doc, indent=2))
    os.replace(tmp, path)


def _member_attrs(member: Path) -> dict:
    try:
        return json.loads((member / "zarr.json").read_text()).get("attributes") or {}
    except (OSError, ValueError):
        return {}


def _adopt(root: Path, member: Path, axis: str, k: int, n: int) -> None:
    """Move member ``k``'s chunk files into the root's 4-D level arrays (``L/c/K/bz/by/bx``).

    A chunk of shape ``(1, bz, by, bx)`` is the same C-order bytes as the member's ``(bz, by, bx)``
    one, through the same codecs (blosc's ``typesize`` is the dtype's), so the encoded file, its
    crc32c and its size - what the member's manifest records - are unchanged by the move. Each
    level's root array is created from member 0's array metadata with the leading axis added.
    Idempotent: an interrupted adoption is finished by running it again (moved files are gone
    from the member, the level folders are removed last)."""
    import os
    import shutil

    attrs = _member_attrs(member)
    levels = len(attrs["clipvol"]["levels"])
    for L in range(levels):
        src = member / str(L)
        dst = root / str(L)
        if not (dst / "zarr.json").exists():
            meta = json.loads((src / "zarr.json").read_text())
            meta["shape"] = [n] + list(meta["shape"])
            cfg = meta["chunk_grid"]["configuration"]
            cfg["chunk_shape"] = [1] + list(cfg["chunk_shape"])
            meta["dimension_names"] = [axis] + list(meta.get("dimension_names") or ["z", "y", "x"])
            meta["attributes"] = {}
            _write_json(dst / "zarr.json", meta)
        chunks = src / "c"
        if chunks.is_dir():
            for d, _, files in os.walk(chunks):
                rel = Path(d).relative_to(chunks)
                for f in files:
                    target = dst / "c" / str(k) / rel / f
                    target.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(Path(d) / f, target)
    attrs = {key: v for key, v in attrs.items() if key != "ome"}  # the root's OME block describes the image
    attrs[MEMBER_ATTR] = {"axis": axis, "index": k}
    doc = json.loads((member / "zarr.json").read_text())
    doc["attributes"] = attrs
    _write_json(member / "zarr.json", doc)
    for L in range(levels):
        shutil.rmtree(member / str(L), ignore_errors=True)


def _check_members(metas: list, output: Path, axis: str) -> None:
    first = metas[0].pyramid
    for k, m in enumerate(metas[1:], start=1):
        p = m.pyramid
        if [lv.shape for lv in p.levels] != [lv.shape for lv in first.levels] or p.brick_shape != first.brick_shape \
                or p.dtype != first.dtype:
            raise InputFormatError(f"{output}/{MEMBERS_GROUP}/{axis}/{k}: expected the levels, brick and dtype of "
                                   f"{axis} = 0, got {[lv.shape for lv in p.levels]} {p.brick_shape} {p.dtype}")


#: default colours of a channel set's OME ``omero`` block (as ``--channels`` draws them)
_OMERO_COLORS = ("00FF00", "FF00FF", "00FFFF", "FFFF00", "FF0000", "0000FF")


def _root_ome(output: Path, metas: list, axis: str, n: int) -> dict:
    """The root's ``attrs["ome"]``: member 0's multiscales with the ``c`` / ``t`` axis in front
    (scale 1, translation 0 along it) and an ``omero`` block: one channel per member of a channel
    set (its own window), one channel of a time series (the window over every step)."""
    from .store import ome_metadata

    m0 = metas[0]
    ome = ome_metadata(m0.pyramid, name=output.stem or "image", unit=m0.unit, origin=m0.origin)
    ms = ome["multiscales"][0]
    ms["axes"].insert(0, {"name": "c", "type": "channel"} if axis == "c" else {"name": "t", "type": "time"})
    for ds in ms["datasets"]:
        for tr in ds["coordinateTransformations"]:
            tr[tr["type"]] = [1.0 if tr["type"] == "scale" else 0.0] + list(tr[tr["type"]])
    ranges = [tuple(float(v) for v in m.pyramid.value_range) for m in metas]
    if axis == "t":
        ranges = [series_window(ranges)]

    def channel(k, lo, hi):
        return {"label": f"{axis}{k}" if axis == "c" else "t", "color": _OMERO_COLORS[k % len(_OMERO_COLORS)],
                "window": {"min": lo, "max": hi, "start": lo, "end": hi}, "active": True,
                "coefficient": 1.0, "family": "linear", "inverted": False}

    ome["omero"] = {"channels": [channel(k, lo, hi) for k, (lo, hi) in enumerate(ranges)],
                    "rdefs": {"defaultT": 0, "defaultZ": m0.pyramid.shape[0] // 2, "model": "color"}}
    return ome


def series_window(ranges) -> tuple[float, float]:
    """One value window for every step of a time series: the union of the steps' ranges, so a
    value has the same brightness at every ``t``."""
    return min(float(lo) for lo, _ in ranges), max(float(hi) for _, hi in ranges)


def brick_channels(source, output, **kwargs) -> list:
    """Brick each channel of a ``(c, z, y, x)`` input into ``output/c/K``: :func:`brick_set` with ``axis="c"``."""
    return brick_set(source, output, axis="c", **kwargs)


def image_set(path) -> tuple[str, int] | None:
    """``(axis, count)`` of the image set rooted at ``path`` (``("c", 3)``), or None for any other
    directory or group. Malformed set attributes are an :class:`InputFormatError` naming the key."""
    found = set_attrs(_root_attrs(path), str(path))
    return None if found is None else found[:2]


def set_attrs(attrs: dict, where: str) -> tuple[str, int, int] | None:
    """``(axis, count, version)`` from a root group's attributes, or None when they mark no set."""
    if not isinstance(attrs, dict):
        return None
    for axis, (attr, key) in SET_AXES.items():
        cs = attrs.get(attr)
        if cs is None:
            continue
        try:
            n = int(cs[key])
            v = int(cs.get("version", 1))
        except (KeyError, TypeError, ValueError, AttributeError):
            raise InputFormatError(f"{where}: attributes[{attr!r}] is malformed: {cs!r}") from None
        if n < 1:
            raise InputFormatError(f"{where}: attributes[{attr!r}][{key!r}]: expected >= 1, got {n}")
        if v not in (1, SET_VERSION):
            raise InputFormatError(f"{where}: attributes[{attr!r}]['version']: expected 1 or {SET_VERSION}, got {v}")
        return axis, n, v
    return None


def _root_attrs(path) -> dict:
    from .store_files import read_file

    try:
        attrs = json.loads(read_file(Path(path) / "zarr.json", path)).get("attributes", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return attrs if isinstance(attrs, dict) else {}


def set_version(path) -> int | None:
    """The layout of the image set rooted at ``path``: 2 (one 4-D image, members' metadata under
    ``clipvol_members``), 1 (one store per member, written before), or None (no set)."""
    found = set_attrs(_root_attrs(path), str(path))
    return None if found is None else found[2]


def member_path(root, axis: str, k: int) -> Path:
    """The group of member ``k`` (its clipvol metadata, statistics, manifest, summary tables) of the
    version-2 set rooted at ``root``."""
    return Path(root) / MEMBERS_GROUP / axis / str(int(k))
