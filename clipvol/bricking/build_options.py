"""How a store is built, as one frozen value that the local and the Dask build both take.

:func:`clipvol.bricking.pipeline.brick_volume` (local threads) and
:func:`clipvol.bricking.dask_build.brick_volume_dask` (a Dask cluster) write byte-identical stores
from the same options. Declaring the options once, validated once in ``__post_init__``, keeps the
two builds from drifting (a new option, a changed default or error text in one of them only);
both still accept the options as keywords (``brick_volume(vol, out, brick=32)``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from ..errors import ParameterError
from .pyramid import FILTERS

__all__ = ["BuildOptions", "CODECS", "BRICK_RANGE", "brick_shape"]

CODECS = ("lz4", "zstd", "none")
BRICK_RANGE = (8, 256)


def brick_shape(brick) -> tuple[int, int, int]:
    """``brick`` (one edge or three, z, y, x) as three even edges in :data:`BRICK_RANGE`."""
    if isinstance(brick, (int, np.integer)) and not isinstance(brick, bool):
        b = (int(brick),) * 3
    else:
        try:
            b = tuple(int(v) for v in brick)
        except (TypeError, ValueError):
            raise ParameterError(f"brick: expected an even integer in {BRICK_RANGE[0]}..{BRICK_RANGE[1]}, got {brick!r}") from None
        if len(b) != 3:
            raise ParameterError(f"brick: expected one integer or three (z, y, x), got {brick!r}")
    lo, hi = BRICK_RANGE
    if any(v < lo or v > hi or v % 2 for v in b):
        raise ParameterError(f"brick: expected an even integer in {lo}..{hi}, got {brick!r}")
    return b  # type: ignore[return-value]


def _spacing(spacing) -> tuple[float, float, float] | None:
    if spacing is None:
        return None
    try:
        sp = tuple(float(v) for v in spacing)
    except (TypeError, ValueError):
        raise ParameterError(f"spacing: expected three numbers z,y,x, got {spacing!r}") from None
    if len(sp) != 3 or not all(np.isfinite(sp)) or any(v <= 0 for v in sp):
        raise ParameterError(f"spacing: expected three finite numbers > 0 (z, y, x), got {spacing!r}")
    return sp  # type: ignore[return-value]


def _workers(workers) -> int:
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or not (1 <= workers <= 1024):
        raise ParameterError(f"workers: expected an integer in 1..1024, got {workers!r}")
    return int(workers)


@dataclass(frozen=True, slots=True)
class BuildOptions:
    """The options of one build of a store (the same for the local and the Dask build).

    Parameters
    ----------
    brick : int or (int, int, int)
        Brick edge in voxels, even, 8..256 (stored as three edges, z, y, x).
    filter : {'mean', 'subsample', 'max', 'mode'}
        The 2x2x2 down-sampling filter.
    codec : {'lz4', 'zstd', 'none'}
        Blosc lz4 (clevel 5) or zstd (clevel 1) with byte shuffle (bit shuffle for 8-bit data).
    spacing : (z, y, x) or None
        Level-0 voxel size; None takes the input's own, else 1.
    unit : str or None
        Unit of ``spacing`` in the OME metadata; None takes the input's own (``millimeter`` for
        NIfTI and DICOM, ``angstrom`` for MRC), else ``micrometer``.
    workers : int or None
        Threads for compression and filtering, or Dask workers (default: number of cores).
    overwrite : bool
        Remove an existing output first. Without it an existing output is an error, except an
        interrupted build of the same job, which is resumed.
    progress : bool
        Show a progress bar on stderr.
    raw_shape, raw_dtype, byte_order
        Layout of a raw binary input.
    summary : bool
        Also build the summary tables of image-based level of detail
        (:func:`clipvol.bricking.summary.build_summary`) once the pyramid is complete.
    origin : (z, y, x) or None
        World position of voxel 0 (OME ``translation``); None takes the input's own (NIfTI, DICOM,
        MRC), else 0. Co-registered volumes (overlays, :mod:`clipvol.scene.overlay`) are placed by it.
    """

    brick: Any = 64
    filter: str = "mean"
    codec: str = "lz4"
    spacing: tuple[float, float, float] | None = None
    unit: str | None = None
    workers: int | None = None
    overwrite: bool = False
    progress: bool = True
    raw_shape: tuple[int, ...] | None = None
    raw_dtype: Any = None
    byte_order: str = "little"
    summary: bool = True
    origin: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        s = object.__setattr__
        s(self, "brick", brick_shape(self.brick))
        if self.filter not in FILTERS:
            raise ParameterError(f"filter: expected one of {', '.join(FILTERS)}, got {self.filter!r}")
        if self.codec not in CODECS:
            raise ParameterError(f"codec: expected one of {', '.join(CODECS)}, got {self.codec!r}")
        s(self, "spacing", _spacing(self.spacing))
        unit = self.unit or "micrometer"  # None (or empty): the input's own unit, decided by the build
        if not isinstance(unit, str) or not unit.strip():
            raise ParameterError(f"unit: expected a unit name such as 'micrometer', got {self.unit!r}")
        s(self, "workers", _workers(self.workers))
        if self.raw_shape is not None:
            s(self, "raw_shape", tuple(self.raw_shape))
        for name in ("overwrite", "progress", "summary"):
            s(self, name, bool(getattr(self, name)))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_kwargs(cls, options: "BuildOptions | None" = None, **kwargs) -> "BuildOptions":
        """``options`` (or the defaults) with keyword overrides; an unknown name is a
        :class:`ParameterError` naming it."""
        bad = sorted(set(kwargs) - set(cls.names()))
        if bad:
            raise ParameterError(f"unknown build option(s) {', '.join(bad)}; expected {', '.join(cls.names())}")
        if options is None:
            return cls(**kwargs)
        if not isinstance(options, BuildOptions):
            raise ParameterError(f"options: expected a clipvol BuildOptions, got {type(options).__name__}")
        return replace(options, **kwargs) if kwargs else options
