"""Procedural volumes as a loader: synthetic data of any size (2**20 voxels per axis and more).

Every brick of every level is evaluated directly by :mod:`clipvol.bricking.generators` (the generators
are exact with respect to the ``mean`` filter, so coarse levels equal what ``clipvol brick``
would compute from level 0), without ever touching level 0. That makes these loaders the test
bed for huge virtual volumes and for paging without any I/O. ``sparse`` volumes also know value
bounds per brick analytically (:class:`~clipvol.paging.loader.HasBrickRanges`), so the renderer can skip
empty bricks without evaluating them.
"""

from __future__ import annotations

import numpy as np

from clipvol.bricking.generators import Generator, Sparse, parse_procedural
from clipvol.bricking.pyramid import Int3, Pyramid, pad_to_brick
from clipvol.errors import ParameterError

__all__ = ["ProceduralLoader"]


class ProceduralLoader:
    """Loader over a procedural generator.

    Parameters
    ----------
    url_or_generator : str or Generator
        ``procedural:fractal?size=256&seed=1``, ``procedural:sparse?size=1048576&count=50``, or a
        :class:`clipvol.bricking.generators.Generator`.
    brick : int or (int, int, int)
        Brick shape.
    spacing : (float, float, float)
        Level-0 voxel size ``(z, y, x)``.
    """

    def __init__(self, url_or_generator: str | Generator, brick=64, spacing=(1.0, 1.0, 1.0)) -> None:
        gen = parse_procedural(url_or_generator) if isinstance(url_or_generator, str) else url_or_generator
        if not isinstance(gen, Generator):
            raise ParameterError(f"url_or_generator: expected a 'procedural:...' URL or a Generator, got {type(url_or_generator).__name__}")
        self.generator = gen
        brick = (int(brick),) * 3 if np.isscalar(brick) else tuple(int(b) for b in brick)
        spacing = (float(spacing),) * 3 if np.isscalar(spacing) else tuple(float(s) for s in spacing)
        self._pyramid = Pyramid.build(gen.shape, brick, spacing, "mean", gen.dtype, gen.value_range)

    @property
    def pyramid(self) -> Pyramid:
        return self._pyramid

    def read_brick(self, level: int, index: Int3) -> np.ndarray:
        """Evaluate brick ``index`` of ``level`` (edge bricks edge-replicated)."""
        index = self._pyramid.check_key(level, index)
        start, stop = self._pyramid.brick_voxel_box(level, index)
        return pad_to_brick(self.generator.region(level, start, stop), self._pyramid.brick_shape)

    def brick_ranges(self, level: int, indices: np.ndarray) -> np.ndarray | None:
        """Per-brick ``[min, max]`` bounds for ``sparse`` volumes (``[0, 0]`` for empty bricks);
        ``None`` for ``fractal`` (every brick spans most of the range)."""
        if not isinstance(self.generator, Sparse):
            return None
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        out = np.empty((len(idx), 2), dtype=np.float64)
        for i, b in enumerate(idx):
            start, stop = self._pyramid.brick_voxel_box(level, tuple(int(v) for v in b))
            out[i] = self.generator.region_bounds(level, start, stop)
        return out

    def __repr__(self) -> str:
        return f"ProceduralLoader({self.generator.url()!r}, brick {self._pyramid.brick_shape})"
