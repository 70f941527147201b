"""Where a view's edges are: the term that says on how many of a coarse node's pixels it differs.

The image policy predicts the share of pixels a coarse level changes visibly (CIELUV Delta E >= 6
against the converged picture). Measured on the MNI ICBM152 T1 template (``bone``, consistent coarse
levels, ``tools/bench/bench_estimate.py``; ``docs/benchmarks.md``, "The visible-error estimate: the
edges in front of each node"), a coarse level's error sits where the picture has edges - where
rays cross a sharp step of the transfer function at a boundary (a brain's folds, the outline):
per node of a cut, the share of its pixels that differ follows the share of its screen rectangle
on an edge (of the converged picture: correlation 0.8-0.99 over the 44-45 level-1 nodes of each
overview; of the opacity map below: 0.69-0.97), and not its classification bias
(:func:`clipvol.scene.lod_error.classification_bias`; correlation -0.1 to -0.4). The whole-view edge share of the term before (one factor per view and
level) could not tell the report's turntable views, whose edges crowd into some bricks, from the
benchmark's overviews: the estimate ran 0.45-0.73x the measurement there.

The visibility estimate the policy already draws (:class:`~clipvol.scene.visibility.OcclusionLayers`,
a 64² map of the total opacity along each ray) shows those edges at no extra cost: :func:`edge_map`
marks its non-empty pixels where the opacity steps by :data:`EDGE_JUMP` or more to a 4-neighbour;
:meth:`OcclusionLayers.footprint <clipvol.scene.visibility.OcclusionLayers.footprint>` gives
each node the share of its map rectangle's non-empty pixels on such an edge (two summed-area
tables; the policy weights each node by the shown share too: a node a mixed cut leaves coarse on
the outline shows something on a few % of its rectangle), and :func:`edge_difference` turns that
share ``e`` into the predicted fraction of the node's pixels that differ at level ``L``:

    ``q = 1 - exp(-EDGE_GAIN * EDGE_GROWTH**L * max(e * min(m / EDGE_MAP_VOXEL, EDGE_MAP_CAP), EDGE_FLOOR))``

- level 1 (a blur of two voxels) differs on about half as many pixels as lie on edges, level 2 on
  about 2.5 times as many (its blur also wipes out folds between the edges the map sees), level 3
  nearly everywhere: :data:`EDGE_GROWTH` 5 per level;
- a surface seen from near shows almost no edge in the map (share 0.001), yet a coarse level's blur
  differs there too (level 1 on 3 %, level 2 on 19 % of the pixels of the template's close view):
  :data:`EDGE_FLOOR`, the share below which a node counts as having that much.
- ``m`` is a level-0 voxel's size in map pixels at the node's nearest depth: one map pixel's edge
  stands for the edges of the voxels it covers, so from farther away (a voxel of 0.14 map pixels
  instead of the fitted views' 0.3) the map's edges are denser than the differing pixels in the
  image - there the estimate was 1.3-3.6x the measurement without the factor. It only lowers the
  share (:data:`EDGE_MAP_CAP` 1): raised for a larger voxel (the 96² views of the CT-like head of
  ``tests/render/test_error_budget.py``, 0.58 map pixels) the estimate there went from 1.9-2.2x to
  2.2-3.2x at block budgets 16-32.

The constants are fitted on the template's 256² views (the benchmark's iso, face and close
views and ``clipvol report``'s three turntable views; block-budget, error-budget and fixed-level
cuts) and checked at 512²: 92 of 94 cuts within 1.5x of the measurement (0.69-1.52; the term
before, one factor of the whole view's edge share on each node's bias: 51 of 94, 0.43-1.60), and
on two views from farther away 29 of 32 (0.64-1.90).
:func:`edge_share` (the view's share, which the benchmark prints) is the same map's mean. What it
does not model: level 0's own error (one ray per pixel at half a voxel's step), and a data set whose
coarse levels differ on fewer pixels per edge than the template's folds (a smooth CT-like head: the
estimate is 1.9-2.2x there at block budgets 16-32). Measured there (``bench_estimate.py --levels``,
``docs/benchmarks.md``, "The estimate on a smooth head"): drawn alone, the head's level 2 differs on
0.12-0.13 of its shown pixels and level 1 on 0.11-0.12 (the template's overviews: 0.26-0.33 and
0.05-0.09), while per node the edges predict the differing pixels there as on the template
(correlation 0.96-0.99 within a level; the template's 0.6-0.87). A level-2 voxel (4 level-0 voxels)
averages the head's skull, thicker than itself, and wipes out the template's folds, thinner than
itself; neither the 64² map nor the summary tables (the share of visible opacity a level's own
voxels lose: 0.032 against 0.045 at level 2; the classification bias; the share of fine voxels whose
colour the coarse value changes) separate the two, so the growth per level stays the template's.
A model, not a bound.

The term applies to consistent coarse levels only (``classify="distribution"``, the default, which
it was fitted on). With the mean classified, a coarse level loses thin structures outright, and the
classification bias predicts it (:mod:`clipvol.scene.selection.policies.image_based`).

Pure numpy; no GL.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError

__all__ = ["edge_map", "edge_share", "edge_difference", "EDGE_JUMP", "EDGE_ALPHA", "EDGE_GAIN", "EDGE_GROWTH",
           "EDGE_FLOOR", "EDGE_MAP_VOXEL", "EDGE_MAP_CAP"]

#: a pixel of the opacity map counts as showing something above this total opacity (the policy's
#: ``NONEMPTY_ALPHA``)
EDGE_ALPHA = 0.02
#: a pixel is on an edge where the total opacity differs by at least this from a 4-neighbour
EDGE_JUMP = 0.1
#: ``q`` at level 0 of the exponent per unit of edge share (fitted; see the module docstring)
EDGE_GAIN = 0.14
#: how much more of a node's pixels one level coarser differs on, per unit of edge share (fitted)
EDGE_GROWTH = 5.0
#: the edge share a node counts as having at least: a coarse level's blur on smooth surfaces (fitted)
EDGE_FLOOR = 0.04


def edge_map(alpha, nonempty: float = EDGE_ALPHA, jump: float = EDGE_JUMP) -> np.ndarray:
    """``(h, w)`` bool: the pixels of ``alpha`` (a 2-D map of total opacity in ``[0, 1]``) above
    ``nonempty`` whose opacity differs from one of their four neighbours by ``jump`` or more."""
    a = np.asarray(alpha, dtype=np.float64)
    if a.ndim != 2:
        raise ParameterError(f"edge_map: expected a 2-D opacity map, got shape {a.shape}")
    edge = np.zeros(a.shape, dtype=bool)
    dx = np.abs(np.diff(a, axis=1)) >= jump
    dy = np.abs(np.diff(a, axis=0)) >= jump
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:] |= dy
    edge[:-1] |= dy
    return edge & (a > nonempty)


def edge_share(alpha, nonempty: float = EDGE_ALPHA, jump: float = EDGE_JUMP) -> float:
    """Share of the pixels of ``alpha`` above ``nonempty`` on an edge (:func:`edge_map`; 0 for a
    map that shows nothing)."""
    a = np.asarray(alpha, dtype=np.float64)
    if a.ndim != 2:
        raise ParameterError(f"edge_share: expected a 2-D opacity map, got shape {a.shape}")
    n = int((a > nonempty).sum())
    return float(edge_map(a, nonempty, jump).sum()) / n if n else 0.0


#: map pixels one level-0 voxel covers where the constants were fitted (the template's views at 256²
#: and 512²: a level-0 voxel covers 1.2-1.4 pixels of a 256² image, about 0.3 pixels of the 64² map)
EDGE_MAP_VOXEL = 0.32
#: the largest factor the voxel's size in map pixels puts on the share: 1, it only lowers it (see the
#: module docstring; 2 measured: the template's views as well, the CT-like head's further off)
EDGE_MAP_CAP = 1.0


def edge_difference(level, share, map_voxel=None) -> np.ndarray:
    """``q``: the predicted fraction of the pixels of nodes of ``level`` (array-like; 0 at level 0)
    that differ visibly, from the share ``share`` (array-like) of their screen rectangles' non-empty
    pixels on an edge of the opacity map and ``map_voxel`` (array-like, optional), a level-0 voxel's
    size in map pixels at each node's nearest depth (see the module docstring)."""
    lv = np.asarray(level, dtype=np.float64)
    e = np.asarray(share, dtype=np.float64)
    if map_voxel is not None:
        e = e * np.minimum(np.asarray(map_voxel, dtype=np.float64) / EDGE_MAP_VOXEL, EDGE_MAP_CAP)
    e = np.maximum(e, EDGE_FLOOR)
    return np.where(lv > 0, -np.expm1(-EDGE_GAIN * EDGE_GROWTH ** lv * e), 0.0)
