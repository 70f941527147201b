"""Label volumes beside an image: a mode-filtered pyramid in the image store's OME-Zarr ``labels/``.

A segmentation (integer ids per voxel) is bricked like any volume, with two differences that
matter for correctness:

* its coarse levels use the ``mode`` filter (the most frequent id of each 2x2x2 block), so a
  coarse voxel always holds an id that occurs there - a mean of ids 3 and 5 would be id 4, a
  structure that is not in the data;
* it lives at ``<image>/labels/<name>``, with the OME-Zarr ``labels`` list on ``<image>/labels`` and
  ``image-label`` metadata on the label image, so OME-Zarr readers (napari, Neuroglancer) find it
  as the image's segmentation; it shares the image's shape, brick shape and spacing, so label brick
  ``(L, b)`` covers exactly image brick ``(L, b)``.

The OME-Zarr "labels" layout: https://ngff.openmicroscopy.org/0.5/#labels-md
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import InputFormatError, ParameterError
from .pipeline import brick_volume
from .sources import open_source
from .store import StoreMeta, parse_metadata

__all__ = ["brick_labels", "check_label_name", "label_names", "LABELS_GROUP"]

LABELS_GROUP = "labels"
#: one plain path component: starts with a letter, digit or '_' (so never '.', '..' or hidden)
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}$")


def check_label_name(name) -> str:
    """``name`` if it is one plain path component usable as ``labels/<name>``, else a
    :class:`~clipvol.errors.ParameterError`. The name becomes a folder inside the image store, and
    ``--overwrite`` removes that folder: ``..`` or ``a/b`` would point it at the image itself or
    outside the store."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise ParameterError(f"labels name: expected one plain folder name (letters, digits, '_', '.', '-', "
                             f"starting with a letter, digit or '_'), got {name!r}")
    return name


def _image_meta(image: Path) -> StoreMeta:
    import zarr

    try:
        attrs = dict(zarr.open_group(str(image), mode="r").attrs)
    except Exception as e:  # noqa: BLE001 - any failure to open is "not a store" for the user
        raise InputFormatError(f"{image}: expected a clipvol store to add labels to, got {type(e).__name__}: {e}") from e
    return parse_metadata(attrs, str(image))


def label_names(image) -> list[str]:
    """The label images listed in ``<image>/labels`` (empty if there are none)."""
    import zarr

    path = Path(image) / LABELS_GROUP
    if not (path / "zarr.json").is_file():
        return []
    ome = dict(zarr.open_group(str(path), mode="r").attrs).get("ome", {})
    return [str(n) for n in ome.get("labels", [])]


def brick_labels(image, labels, name: str = "labels", *, codec: str = "lz4", workers: int | None = None,
                 overwrite: bool = False, progress: bool = True) -> StoreMeta:
    """Brick the label volume ``labels`` into ``<image>/labels/<name>`` (mode filter).

    Parameters
    ----------
    image : str or Path
        A finished clipvol store; the labels take its brick shape, spacing and unit.
    labels : str, Path, numpy.ndarray or Source
        Integer label ids of the same shape as the image (any input ``clipvol brick`` reads).
    name : str
        The label image's name: one plain folder name (letters, digits, ``_.-``, not starting with ``.``).

    Returns
    -------
    StoreMeta
        The label pyramid's metadata.
    """
    import zarr

    image = Path(image)
    check_label_name(name)
    meta = _image_meta(image)
    pyr = meta.pyramid
    src = open_source(labels)
    try:
        desc = src.name
        if tuple(src.shape) != tuple(pyr.shape):
            raise InputFormatError(f"{desc}: expected a label volume of the image's shape {pyr.shape}, got {src.shape}")
        if np.dtype(src.dtype).kind not in "iub":
            raise InputFormatError(f"{desc}: expected integer label ids, got dtype {np.dtype(src.dtype)}")
    finally:
        src.close()
    out = image / LABELS_GROUP / name
    group = zarr.open_group(str(image / LABELS_GROUP), mode="a")
    result = brick_volume(labels, out, brick=pyr.brick_shape, filter="mode", codec=codec, spacing=pyr.spacing,
                          unit=meta.unit, workers=workers, overwrite=overwrite, progress=progress,
                          origin=tuple(meta.origin) if any(meta.origin) else None)  # the image's place in the world
    label_group = zarr.open_group(str(out), mode="r+")
    ome = dict(label_group.attrs.get("ome", {}))
    ome["image-label"] = {"version": ome.get("version", "0.5"), "source": {"image": "../../"}}
    label_group.attrs.update({"ome": ome})
    listed = dict(group.attrs).get("ome", {}).get("labels", [])
    if name not in listed:
        group.attrs.update({"ome": {"version": "0.5", "labels": [*listed, name]}})
    return result
