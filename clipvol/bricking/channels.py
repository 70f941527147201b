"""Bricking a multi-channel (c, z, y, x) input: one clipvol store per channel under one group.

A microscope's 4-D stack (a ``.npy`` of shape ``(c, z, y, x)``, or an OME-TIFF whose axes hold a
``C``) becomes a **channel set**: ``OUTPUT/c/0``, ``OUTPUT/c/1``, ... are complete clipvol stores
(pyramid, statistics, checksums, summary tables: everything a single volume gets, each channel
with its own value range), and ``OUTPUT/zarr.json`` carries ``attributes["clipvol_channels"] =
{"version": 1, "channels": C}``, written last (the set is recognised only once every channel is
complete; an interrupted build resumes channel by channel). ``open_store(OUTPUT, c=k)``
(:mod:`clipvol.paging.open`) opens channel ``k`` with ``axes == ("c",)``, so ``clipvol render OUTPUT
--channels 0:green,1:magenta`` works as on an OME-Zarr image with a ``c`` axis.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputFormatError

__all__ = ["CHANNELS_ATTR", "channel_count", "read_channels", "brick_channels"]

#: the group attribute that marks a channel set
CHANNELS_ATTR = "clipvol_channels"


def _ome_tiff_axes(path: Path):
    import tifffile

    with tifffile.TiffFile(path) as tf:
        s = tf.series[0]
        return s.axes, s.shape


def channel_count(source) -> int | None:
    """Channels of a 4-D ``(c, z, y, x)`` input (a numpy array, a ``.npy`` or an OME-TIFF with a C
    axis), or None for anything else (3-D inputs and formats without channels)."""
    if isinstance(source, np.ndarray):
        return int(source.shape[0]) if source.ndim == 4 else None
    p = Path(str(source))
    name = p.name.lower()
    if name.endswith(".npy") and p.is_file():
        arr = np.load(p, mmap_mode="r")
        return int(arr.shape[0]) if arr.ndim == 4 else None
    if name.endswith((".ome.tif", ".ome.tiff")) and p.is_file():
        axes, shape = _ome_tiff_axes(p)
        if "C" in axes and len(shape) == 4 and set(axes) == set("CZYX"):
            return int(shape[axes.index("C")])
    return None


def read_channels(source) -> np.ndarray:
    """The ``(c, z, y, x)`` array of a 4-D input (a memory map for ``.npy``)."""
    if isinstance(source, np.ndarray):
        arr = source
    else:
        p = Path(str(source))
        if p.name.lower().endswith(".npy"):
            arr = np.load(p, mmap_mode="r")
        else:
            import tifffile

            axes, _ = _ome_tiff_axes(p)
            arr = np.moveaxis(tifffile.imread(p), [axes.index(a) for a in "CZYX"], [0, 1, 2, 3])
    if arr.ndim != 4:
        raise InputFormatError(f"{source if not isinstance(source, np.ndarray) else 'array'}: expected a 4-D "
                               f"(c, z, y, x) input, got shape {arr.shape}")
    return arr


def brick_channels(source, output, **kwargs) -> list:
    """Brick each channel of a 4-D input into ``output/c/K`` (see the module docstring); ``kwargs``
    as :func:`clipvol.bricking.pipeline.brick_volume`. Returns each channel's metadata."""
    import zarr

    from .pipeline import brick_volume

    arr = read_channels(source)
    output = Path(output)
    if kwargs.get("overwrite") and output.exists():
        import shutil

        from .pipeline import check_overwrite_spares

        check_overwrite_spares(output, [source] if isinstance(source, (str, Path)) else [])
        shutil.rmtree(output)
        kwargs = {**kwargs, "overwrite": False}
    metas = [brick_volume(np.asarray(arr[c]), output / "c" / str(c), **kwargs) for c in range(arr.shape[0])]
    group = zarr.open_group(str(output), mode="a", zarr_format=3)
    group.attrs.update({CHANNELS_ATTR: {"version": 1, "channels": int(arr.shape[0])}})  # the last write
    return metas
