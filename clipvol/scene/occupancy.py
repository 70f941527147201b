"""Empty-space skipping below the brick: per-cell value ranges and the occupancy they give a transfer function.

Why cells: a brick is culled only when *all* of it is transparent (:func:`clipvol.scene.transfer.
transparency_filter`), but on a scan most of a ray's samples are air in front of the object or
tissue the transfer function hides, inside bricks that also hold something visible. Each brick is
cut into cells of ``CELL``\\ ³ voxels (fewer where the brick shape is not a multiple of it); each
cell's ``[min, max]`` is computed from the decoded brick in the clip-texture's loader threads
(:mod:`clipvol.paging.cells`), the GPU cache keeps them beside the brick's texels, in the same
toroidal layout as its level texture, and turns them into one flag per cell - *may be visible* - whenever the
transfer function changes or bricks arrive. The ray caster looks the flag up at a sample and leaps
over a cell that is empty in one step (``render/shaders/volume_common.glsl``).

Why it is exact: a sample at voxel coordinate ``x`` (voxel centres at integers) is trilinear in
voxels ``floor(x)`` and ``floor(x) + 1`` per axis. The caster assigns it to cell ``floor(x / e)``
(``e``: the cell edge), whose samples therefore read voxels ``e * i`` to ``e * (i + 1)`` - the
cell's own and the first layer of the next cell on each axis. :func:`widen` joins each cell's range
with those of the 7 cells ahead of it (``+x``, ``+y``, ``+z`` and their diagonals), across brick
faces through the toroidal window of the level: a neighbour slot that holds another brick, or
nothing yet, only widens the range (a sample is clamped to its own brick at a face whose neighbour
is not on the GPU, so it then reads the cell's own voxels). The flag is 0 only where
:meth:`TransferFunction.transparent_mask` - every table entry any value of the widened range
reaches through ``GL_LINEAR`` interpolation has alpha 0 - says so; an interpolated value lies
between its voxels' values, and opacity correction maps alpha 0 to 0, so a leapt sample would
have added exactly nothing. The caster leaps only over samples at least 1/1000 of a cell inside
it, far beyond float32 rounding of sample positions.

The same argument at brick granularity is :func:`clipvol.scene.transfer.footprint_ranges`; cells
are the idea of the min-max octrees and empty-space leaping of the GPU ray-casting literature
(J. Krüger and R. Westermann, "Acceleration Techniques for GPU-based Volume Rendering", IEEE
Visualization 2003; M. Hadwiger et al., "Real-Time Volume Graphics", A K Peters 2006, ch. 8).
"""

from __future__ import annotations

import numpy as np

from ..paging.cells import CELL, cell_edges, cell_ranges

__all__ = ["CELL", "cell_edges", "cell_ranges", "widen", "occupancy"]

def widen(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's range joined with the 7 cells ahead of it (``+1`` on any subset of the axes:
    the voxels a trilinear sample assigned to the cell can reach), the grid wrapping round on every
    axis (the toroidal window of a level)."""
    lo = np.asarray(lo)
    hi = np.asarray(hi)
    for axis in range(3):  # separable: the next cell along each axis in turn spans the 2x2x2 block
        lo = np.minimum(lo, np.roll(lo, -1, axis))
        hi = np.maximum(hi, np.roll(hi, -1, axis))
    return lo, hi


def occupancy(lo: np.ndarray, hi: np.ndarray, tf, data_range, a: float = 1.0, b: float = 0.0) -> np.ndarray:
    """``uint8`` flags, ``lo``'s shape: 1 where a value in ``[a * lo + b, a * hi + b]`` may be
    visible under ``tf`` (over ``data_range``, see :meth:`TransferFunction.transparent_mask`), 0
    where every such value is transparent or the range is empty (``lo > hi``: no finite value).

    ``a``, ``b``: from the stored representation to the data's values (``raw = a * stored + b``).
    The range is widened by a millionth of the window on both sides, so float32 rounding on the
    GPU of the value's table coordinate can never reach an entry the test did not look at.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    empty = ~(lo <= hi)
    with np.errstate(invalid="ignore", over="ignore"):
        r0 = np.where(empty, 0.0, a * lo + b)
        r1 = np.where(empty, 0.0, a * hi + b)
    w_lo, w_hi = tf.window(data_range)
    eps = 1e-6 * max(abs(float(w_hi) - float(w_lo)), 1e-30)
    r = np.stack([np.minimum(r0, r1) - eps, np.maximum(r0, r1) + eps], axis=-1).reshape(-1, 2)
    transparent = tf.transparent_mask(r, data_range).reshape(lo.shape)
    return (~(transparent | empty)).astype(np.uint8)
