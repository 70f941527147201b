"""napari reader plug-in: a clipvol store opens in napari as a lazy multiscale image, with no copy.

napari (Sofroniew et al., *napari: a multi-dimensional image viewer for Python*, 2024) slices
multiscale images in 2D by asking, per screen, for the level whose voxels match the screen's
pixels; it reads them through any array with numpy slicing. This reader hands it one
``dask.array.from_zarr`` array per level of the store (chunks = bricks, nothing read until napari
asks), with the OME scale and translation of each level, the store's value range as contrast
limits and, for stores built from NIfTI or DICOM, the rotation of the patient frame as the layer's
``affine`` — napari then draws in world (RAS) millimetres.

The manifest is ``clipvol/napari.yaml`` (npe2), found through the ``napari.manifest`` entry point;
napari itself is an optional extra (``pip install 'clipvol[napari]'``) and is not imported here,
so the reader's contract (:func:`read_store`) is usable and testable without it.

What napari can and cannot show of a store larger than memory is in ``docs/coming-from.md``
(measured in ``docs/benchmarks.md``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

__all__ = ["napari_get_reader", "read_store"]

LayerData = tuple[Any, dict[str, Any], str]


def _is_clipvol_store(path: Path) -> bool:
    import json

    try:
        attrs = json.loads((path / "zarr.json").read_text()).get("attributes", {})
    except (OSError, ValueError, AttributeError):
        return False
    if not isinstance(attrs, dict):
        return False
    from .bricking.channels import set_attrs

    try:
        found = set_attrs(attrs, str(path))
    except Exception:  # malformed set attributes: not ours to open (read_store would say why)
        return False
    return "clipvol" in attrs or (found is not None and found[2] >= 2)


def napari_get_reader(path) -> Callable[[Any], list[LayerData]] | None:
    """napari's hook: :func:`read_store` if ``path`` is a clipvol store directory, else None."""
    if isinstance(path, (list, tuple)):
        if len(path) != 1:
            return None
        path = path[0]
    p = Path(str(path))
    return read_store if p.is_dir() and _is_clipvol_store(p) else None


def read_store(path) -> list[LayerData]:
    """One image layer: ``(levels, kwargs, "image")`` with ``levels`` lazy dask arrays, finest first.

    Raises the store's own errors (:class:`~clipvol.errors.StoreFormatError`, ...) for a bad or
    incomplete store, naming it.
    """
    import dask.array as da
    import zarr

    from .bricking.store import open_store_meta

    if isinstance(path, (list, tuple)):
        path = path[0]
    p = Path(str(path))
    from .bricking.channels import image_set, member_path, series_window

    found = image_set(p)  # the root of a 4-D clipvol brick: one 4-D image, a c or t axis in front
    metas = [open_store_meta(member_path(p, found[0], k) if found else p, require_complete=True)
             for k in range(found[1] if found else 1)]
    meta = metas[0]
    group = zarr.open_group(str(p), mode="r")
    pyr = meta.pyramid
    levels = [da.from_zarr(group[str(L)]) for L in range(pyr.num_levels)]
    lv0 = pyr.levels[0]
    kwargs: dict[str, Any] = {
        "name": p.stem,
        "multiscale": True,
        "scale": tuple(lv0.scale),
        # napari places voxel 0 of every level by its own scale factor; level 0 carries the origin
        "translate": tuple(t + o for t, o in zip(lv0.translation, meta.origin)),
        "contrast_limits": tuple(float(v) for v in pyr.value_range) if pyr.value_range[1] > pyr.value_range[0] else None,
        "metadata": {"clipvol_store": str(p), "unit": meta.unit, "level_scales": [list(lv.scale) for lv in pyr.levels],
                     "level_translations": [[t + o for t, o in zip(lv.translation, meta.origin)] for lv in pyr.levels]},
        "axis_labels": ("z", "y", "x"),
        "units": (meta.unit,) * 3,
    }
    if found and found[0] == "c":  # napari splits the channel axis into one layer per channel
        ranges = [tuple(float(v) for v in m.pyramid.value_range) for m in metas]
        kwargs.update(channel_axis=0, name=[f"{p.stem} c{k}" for k in range(found[1])],
                      contrast_limits=[r if r[1] > r[0] else (r[0], r[0] + 1.0) for r in ranges],
                      colormap=["green", "magenta", "cyan", "yellow", "red", "blue"][: found[1]] if found[1] <= 6 else None,
                      blending="additive")
        if kwargs["colormap"] is None:
            del kwargs["colormap"]
    elif found:  # a time series: a 4-D image, one contrast window over every step (comparable across t)
        lo, hi = series_window([m.pyramid.value_range for m in metas])
        kwargs.update(scale=(1.0,) + kwargs["scale"], translate=(0.0,) + kwargs["translate"],
                      contrast_limits=(lo, hi) if hi > lo else None, axis_labels=("t", "z", "y", "x"))
        del kwargs["units"]  # the input records no time unit
    if kwargs["contrast_limits"] is None:
        del kwargs["contrast_limits"]
    if meta.frame is not None:
        rot = meta.frame.directions[::-1, ::-1]  # (x, y, z) -> napari's (z, y, x) order
        aff = np.eye(4)
        aff[:3, :3] = rot
        if found and found[0] == "t":  # napari's affine covers every axis of the layer: t untouched
            aff = np.eye(5)
            aff[1:4, 1:4] = rot
        kwargs["affine"] = aff
        kwargs["metadata"]["world_frame"] = meta.frame.frame or "world"
        kwargs["metadata"]["affine_xyz"] = [list(r) for r in meta.frame.affine]
    return [(levels, kwargs, "image")]
