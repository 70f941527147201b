"""Bricking a 4-D input: one clipvol store per channel or per time step under one root group.

A microscope's 4-D stack (a ``.npy`` of shape ``(c, z, y, x)`` or ``(t, z, y, x)``, or an OME-TIFF
whose axes hold a ``C``) becomes an **image set**: ``OUTPUT/c/0``, ``OUTPUT/c/1``, ... (channels)
or ``OUTPUT/t/0``, ``OUTPUT/t/1``, ... (time steps) are complete clipvol stores (pyramid,
statistics, checksums, summary tables: everything a single volume gets, each with its own value
range). A 4-D array does not say which its first axis is; ``axis`` does (default ``"c"``).

The root group says what it holds twice, once for clipvol and once for any OME-Zarr reader:

* ``attributes["clipvol_channels"] = {"version": 1, "channels": C}`` or
  ``attributes["clipvol_timeseries"] = {"version": 1, "steps": T}`` (what :func:`image_set` reads);
* ``attributes["ome"] = {"version": "0.5", "bioformats2raw.layout": 3}`` and a group ``OUTPUT/OME``
  whose ``attributes["ome"]["series"]`` lists the image paths (``["c/0", "c/1", ...]``): the
  collection layout of OME-Zarr 0.5 (Moore et al., *OME-Zarr: a cloud-optimized bioimaging file
  format with international community support*, 2023), which lets a reader find each image
  without knowing clipvol. OME-Zarr 0.5 offers no single multiscale image made of 3-D arrays with
  a fourth axis, so the set is a collection of images, not one 4-D image.

Both are written last (the set is recognised only once every member is complete; an interrupted
build resumes member by member). ``open_store(OUTPUT, c=k)`` / ``open_store(OUTPUT, t=k)``
(:mod:`clipvol.paging.open`) opens member ``k`` with ``axes == ("c",)`` or ``("t",)``, so
``clipvol render OUTPUT --channels 0:green,1:magenta`` works as on an OME-Zarr image with a ``c``
axis and ``clipvol view OUTPUT --play`` plays a time series.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputFormatError, ParameterError

__all__ = ["CHANNELS_ATTR", "TIMESERIES_ATTR", "SET_AXES", "channel_count", "read_channels", "brick_channels",
           "brick_set", "image_set"]

#: the group attribute that marks a channel set
CHANNELS_ATTR = "clipvol_channels"
#: the group attribute that marks a time series
TIMESERIES_ATTR = "clipvol_timeseries"
#: the leading axis a set may have, and its attribute and count key
SET_AXES = {"c": (CHANNELS_ATTR, "channels"), "t": (TIMESERIES_ATTR, "steps")}


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
    """Brick each ``axis`` entry of a 4-D input into ``output/AXIS/K`` (see the module docstring);
    ``kwargs`` as :func:`clipvol.bricking.pipeline.brick_volume`. Returns each member's metadata."""
    import zarr

    from .pipeline import brick_volume

    if axis not in SET_AXES:
        raise ParameterError(f"axes: expected the first axis of a 4-D input to be one of {sorted(SET_AXES)}, got {axis!r}")
    if axis == "t" and not isinstance(source, np.ndarray) and not str(source).lower().endswith(".npy"):
        raise ParameterError(f"--axes: tzyx is read from a 4-D .npy (or an array), got {source}")
    arr = read_channels(source)
    output = Path(output)
    from .output_guard import check_not_input, check_overwrite, remove_output

    inputs = [source] if isinstance(source, (str, Path)) else []
    check_not_input(output, inputs)
    if kwargs.get("overwrite") and (output.exists() or output.is_symlink()):
        check_overwrite(output, inputs)
        remove_output(output)
        kwargs = {**kwargs, "overwrite": False}
    n = int(arr.shape[0])
    metas = [brick_volume(np.asarray(arr[k]), output / axis / str(k), **kwargs) for k in range(n)]
    paths = [f"{axis}/{k}" for k in range(n)]
    ome_group = zarr.open_group(str(output / "OME"), mode="a", zarr_format=3)
    ome_group.attrs.update({"ome": {"version": "0.5", "series": paths}})
    attr, key = SET_AXES[axis]
    group = zarr.open_group(str(output), mode="a", zarr_format=3)
    group.attrs.update({"ome": {"version": "0.5", "bioformats2raw.layout": 3},
                        attr: {"version": 1, key: n}})  # the last write: the set exists from here on
    return metas


def brick_channels(source, output, **kwargs) -> list:
    """Brick each channel of a ``(c, z, y, x)`` input into ``output/c/K``: :func:`brick_set` with ``axis="c"``."""
    return brick_set(source, output, axis="c", **kwargs)


def image_set(path) -> tuple[str, int] | None:
    """``(axis, count)`` of the image set rooted at ``path`` (``("c", 3)``), or None for any other
    directory or group. Malformed set attributes are an :class:`InputFormatError` naming the key."""
    from .store_files import read_file

    try:  # never a FIFO or a device, never a file outside the store (store_files refuses those)
        attrs = json.loads(read_file(Path(path) / "zarr.json", path)).get("attributes", {})
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(attrs, dict):
        return None
    for axis, (attr, key) in SET_AXES.items():
        cs = attrs.get(attr)
        if cs is None:
            continue
        try:
            n = int(cs[key])
        except (KeyError, TypeError, ValueError):
            raise InputFormatError(f"{path}: attributes[{attr!r}] is malformed: {cs!r}") from None
        if n < 1:
            raise InputFormatError(f"{path}: attributes[{attr!r}][{key!r}]: expected >= 1, got {n}")
        return axis, n
    return None
