"""How many edges a view shows: the term that scales the visible-error estimate per view and level.

The image policy predicts the share of pixels a coarse level changes visibly (CIELUV Delta E >= 6
against the converged picture) from each brick's classification bias
(:func:`clipvol.scene.lod_error.classification_bias`), a per-brick statistic that knows nothing of
the view. Measured on the MNI ICBM152 T1 template (``tools/bench/bench_estimate.py``,
``docs/benchmarks.md``, "The visible-error estimate on smooth views"), a coarse level's
error concentrates on the pixels where the picture has an edge - where a ray crosses a sharp step
of the transfer function at a boundary seen side-on: a brain's folds in an overview put such an
edge on about 12 % of the pixels that show anything, a surface seen from near on 0.1 %. The same
level-1 bricks then differ on 2-4x fewer of their pixels per unit of bias in the close view than
in the overview, and the estimate ran 2.6-4.7x high there (0.58-1.17x on the overviews).

The visibility estimate the policy already draws (:class:`~clipvol.scene.visibility.OcclusionLayers`,
a 64² map of the total opacity along each ray) shows those edges at no extra cost: :func:`edge_share`
is the share of its non-empty pixels where the opacity steps by :data:`EDGE_JUMP` or more to a
neighbour. :func:`edge_weight` turns it into a factor on each coarse node's bias,
``clip((max(e, EDGE_MIN) / EDGE_REF) ** (EDGE_POWER / level), 0, EDGE_CAP)``: below the reference
share the bias counts less, and less so for coarser levels (level 2's blur of four voxels shows on
smooth surfaces too; level 1's of two shows mainly at edges); above it, as it is. The constants
are fitted on the template's iso, face and close views at 256² (image-policy cuts at block budgets
8-32 and error budgets 2-20 %) and checked at 512²; a model, not a bound.

The term applies to consistent coarse levels only (``classify="distribution"``, the default, which
it was fitted on). With the mean classified, a coarse level loses thin structures outright - on
smooth views too, where the error is then not at the edges: on the template's close view at 256²
the term took the mean mode's ``max_error`` cuts from 0.97-1.96x the measurement to 0.22-0.65x,
so there the bias counts as it is.

Pure numpy; no GL.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError

__all__ = ["edge_share", "edge_weight", "EDGE_JUMP", "EDGE_ALPHA", "EDGE_REF", "EDGE_MIN", "EDGE_POWER", "EDGE_CAP"]

#: a pixel of the opacity map counts as showing something above this total opacity (the policy's
#: ``NONEMPTY_ALPHA``)
EDGE_ALPHA = 0.02
#: a pixel is on an edge where the total opacity differs by at least this from a 4-neighbour
EDGE_JUMP = 0.1
#: the edge share at which a coarse node's bias counts as it is (fitted; see the module docstring)
EDGE_REF = 0.05
#: edge shares below this count as this (a view with no edge at all still shows a coarse level's blur)
EDGE_MIN = 0.005
#: exponent of the share's ratio to :data:`EDGE_REF` at level 1 (at level ``L``: ``EDGE_POWER / L``)
EDGE_POWER = 0.5
#: the factor's upper limit: an edge-rich view keeps the bias as it is. Above 1 (1.5 and 1.25
#: measured) the template's overviews came nearer (0.74-1.43 instead of 0.57-1.17), but the
#: procedural head of ``tests/render/test_error_budget.py`` (edge share 0.17, estimate already
#: 1.9-2.1x high at block budgets 16-32) went further off (2.1-2.4x): the edges explain why
#: smooth views differ less, not why one edge-rich data set differs more than another
EDGE_CAP = 1.0


def edge_share(alpha, nonempty: float = EDGE_ALPHA, jump: float = EDGE_JUMP) -> float:
    """Share of the pixels of ``alpha`` (a 2-D map of total opacity in ``[0, 1]``) above ``nonempty``
    whose opacity differs from one of their four neighbours by ``jump`` or more (0 for a map that
    shows nothing)."""
    a = np.asarray(alpha, dtype=np.float64)
    if a.ndim != 2:
        raise ParameterError(f"edge_share: expected a 2-D opacity map, got shape {a.shape}")
    shown = a > nonempty
    n = int(shown.sum())
    if n == 0:
        return 0.0
    edge = np.zeros(a.shape, dtype=bool)
    dx = np.abs(np.diff(a, axis=1)) >= jump
    dy = np.abs(np.diff(a, axis=0)) >= jump
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:] |= dy
    edge[:-1] |= dy
    return float((edge & shown).sum()) / n


def edge_weight(level, share: float) -> np.ndarray:
    """Factor on the classification bias of nodes of ``level`` (array-like; 0 at level 0) in a view
    whose opacity map has edge share ``share`` (:func:`edge_share`)."""
    lv = np.asarray(level, dtype=np.float64)
    ratio = max(float(share), EDGE_MIN) / EDGE_REF
    w = ratio ** (EDGE_POWER / np.maximum(lv, 1.0))
    return np.where(lv > 0, np.minimum(w, EDGE_CAP), 0.0)
