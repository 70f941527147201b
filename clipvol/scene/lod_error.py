"""Multiresolution error of every brick under a transfer function, from the summary tables only.

After Wang, Garcia & Shen (2007), section IV-C/D. No voxel is read: a transfer-function change
re-evaluates the per-brick histograms and parent-child correspondence tables written by
:mod:`clipvol.bricking.summary` (256 quantised levels), which takes well under a second for 10^4
bricks.

Per quantised level ``k`` the *function table* ``F[k]`` is the CIE L*u*v* colour of the
transfer function's premultiplied colour ``c(x_k) * alpha(x_k)`` (what the frame shows over black),
and the *distance table* ``D[k, l] = |F[k] - F[l]|`` (Delta E). For a brick ``b`` with histogram
``H_b`` (``N_b`` voxels) and mean value ``mu_b`` (from its histogram):

* ``mu~_b`` = L* of the colour of ``mu_b``; ``sigma~_b^2 = sum_k H_b[k] |F[k] - Luv(mu_b)|^2 / (N_b - 1)``
  (the paper's Eqn. 8 with Eqn. 9's colour differences);
* for a child ``j`` of parent ``i``, the distortion term ``sigma~_ij`` is the root-mean-square Delta E of
  the corresponding voxel pairs, ``sqrt(sum_(k,l) C_j[k, l] D[k, l]^2 / (N_j - 1))`` - looked up from
  ``C`` and ``D`` as the paper's lookup relation says (``sigma~_ij <- C, D``). We do not use the
  literal covariance of Eqn. 7: it vanishes whenever the parent is uniform, which is exactly when a
  coarse brick has averaged a thin feature away;
* ``eps_ij = sigma~_ij * (mu~_i^2 + mu~_j^2 + C1) / (2 mu~_i mu~_j + C1) * (sigma~_i^2 + sigma~_j^2 + C2) /
  (2 sigma~_i sigma~_j + C2)`` (Eqn. 6: distortion times luminance and contrast distortion), with
  ``C1 = C2 = 100`` (10 % of the L* range, squared);
* ``eps_b = sum_j eps_bj + max_j eps_j`` over the children (Eqn. 1; 0 for level-0 bricks),
  normalised by the largest value of the pyramid to ``[0, 1]``.

The *emission* of a brick is the mean over its histogram of ``|Luv(c(x) alpha(x))|``. The paper
uses the colour of the mean value, ``|c(mu)| alpha(mu)``, which is zero for a coarse brick whose
mean falls in a transparent range although it holds bone; the histogram mean keeps such bricks
visible to the priority queue. A coarse level's own voxels are means too: under a sharp transfer
function a thin shell or vessel averaged with air can leave every voxel of a level-3 brick
transparent although level 0 beneath it shows bone. So a brick's emission (and its mean opacity)
is the larger of its own histogram's and the voxel-weighted mean of its children's, bottom-up
(:func:`_beneath`): what drawing the brick instead of its descendants would lose. It is positive
exactly where the brick or a descendant at any level shows something.

References
----------
C. Wang, A. Garcia, H.-W. Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality
Metric for Large Volume Visualization", IEEE TVCG 13(1), 2007.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..bricking.summary import SUMMARY_BINS, SummaryTables
from ..errors import ParameterError
from .metrics import rgb_to_luv

__all__ = ["LodErrors", "lod_errors", "colour_table", "classification_bias", "distribution_residual", "CLASSIFY_MODES",
           "DISTRIBUTION_FLOOR", "C1", "C2"]

C1 = 100.0
C2 = 100.0
#: how a coarse voxel is classified: the transfer function of the mean of the fine voxels beneath
#: it ("mean"), or the expected colour of their distribution ("distribution": consistent levels)
CLASSIFY_MODES = ("mean", "distribution")
#: with ``classify="distribution"`` a brick's bias is at least this share of its mean-mode bias: the
#: distribution's residual (:func:`distribution_residual`, what a normal model classifies wrong) does
#: not see the blur a coarse level keeps under any classification. Measured on the MNI ICBM152 T1
#: template (``docs/benchmarks.md``, "The visible-error estimate with consistent levels"): 0 lets
#: ``--max-error 5%`` choose level 3 on overviews (31 % of pixels against an estimate of 4 %); 0.5,
#: 0.7 and 0.85 measure 5.5-8.3 % on the 256² overviews; 1 (the mean mode's bias, an upper bound of
#: the residual) 3.5 / 5.8 %, and runs high on the close view (4x) as the mean mode does. At 1 or
#: more the residual is not computed: on the template it exceeded the mean mode's bias on 1 brick of
#: 393 by 0.03 Delta E (``bone``; none under ``viridis``), and it would triple the time a transfer
#: function change costs (19 s against 6 s for a 37 449-brick pyramid on the loaded 2-core machine)
DISTRIBUTION_FLOOR = 1.0


@dataclass
class LodErrors:
    """Per level (over the brick grid): normalised error ``eps`` in ``[0, 1]``, ``emission`` (mean
    ``|Luv|`` of the premultiplied colour over the histogram, at least the voxel-weighted mean of the
    children's), ``raw_eps`` (before normalising), ``seconds`` taken, ``opacity`` (mean alpha over
    the histogram, at least the children's mean, likewise) and ``bias`` (:func:`classification_bias`: the
    Delta E that survives the ray's integration, which the visible-error estimate uses; 0 at level 0)."""

    eps: list[np.ndarray]
    raw_eps: list[np.ndarray]
    emission: list[np.ndarray]
    seconds: float
    opacity: list[np.ndarray] | None = None
    bias: list[np.ndarray] | None = None
    #: how the coarse voxels these errors describe are classified (:data:`CLASSIFY_MODES`)
    classify: str = "mean"

    def lookup(self, level: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(eps, emission, opacity)`` of bricks ``idx`` ``(n, 3)`` of ``level``."""
        i = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
        k = (i[:, 0], i[:, 1], i[:, 2])
        return self.eps[level][k], self.emission[level][k], self.opacity[level][k]


def colour_table(tf, values: np.ndarray, data_range) -> np.ndarray:
    """``(..., 3)`` CIE L*u*v* of the premultiplied transfer-function colour of ``values``."""
    rgba = tf.lookup(values, data_range)
    return rgb_to_luv(rgba[..., :3] * rgba[..., 3:4])


def _contrast(a2: np.ndarray, b2: np.ndarray, c: float) -> np.ndarray:
    return (a2 + b2 + c) / (2.0 * np.sqrt(a2 * b2) + c)


def classification_bias(tables: SummaryTables, F: np.ndarray, classify: str = "mean", tf=None) -> list[np.ndarray]:
    """Per level (flat over the brick grid): the Delta E between a brick and level 0 that a ray's
    integration does not average away, from the correspondence tables only.

    A coarse voxel stands for the fine voxels beneath it. Where they differ from it by zero-mean
    noise (a scan's grain), a ray through many voxels averages the difference out: the pair error
    ``sigma~_ij`` (:func:`lod_errors`) counts it, the image does not show it. What the image keeps
    is the *bias*: the colour of a coarse value against the mean colour of the fine values it
    stands for - ``F(mean)`` against ``mean(F)``, large exactly where a sharp transfer function
    meets an edge or a thin structure (bone beside air: the mean is a value neither has). Per child
    brick ``j`` with correspondence table ``C_j[k, l]`` (parent code ``k``, child code ``l``):
    ``b_ij = sqrt(sum_k n_k |F[k] - Fbar_k|^2 / N_j)`` with ``n_k = sum_l C_j[k, l]`` and
    ``Fbar_k = sum_l C_j[k, l] F[l] / n_k``. A node's bias sums down the pyramid like ``eps``:
    ``b_i = mean_j b_ij + max_j b_j`` (0 at level 0).

    With ``classify="distribution"`` (consistent coarse levels, :mod:`clipvol.scene.consistent`: the
    transfer function applied to a normal distribution of each coarse voxel's mean and spread) the
    coarse colour is that expectation, and what survives is the gap between the model and the fine
    values: per (child brick, parent code ``k``) group, ``Luv(E[a c] over N(x_k, s))`` against
    ``Luv`` of the mean premultiplied colour of the fine values, ``s^2`` the group's pooled
    variance of fine values plus the mean spread^2 beneath them (0 at level 0; for level 2 and up,
    each child brick's mean spread^2, carried up the levels with the tables). The fine side at
    level 1 is the level-0 colour itself; above, the child level's own consistent colour at its
    brick's mean spread. Large where the fine values are far from normal (two values in equal
    parts: bone beside air) and small where the transfer function is smooth over their spread.
    That residual is :func:`distribution_residual`; this mode returns the larger of it and
    :data:`DISTRIBUTION_FLOOR` times the mean mode's bias (at a floor of 1, the default, the mean
    mode's bias itself), because the residual does not see the
    blur a coarse level keeps under any classification (measured: alone it lets the image policy
    choose level 3 for a 5 % budget where the picture differs on 31 % of pixels). ``tf`` is needed
    for this mode (its pre-integrated table, :func:`~clipvol.scene.consistent.expected_premultiplied`);
    ``F`` alone serves the mean mode.
    """
    if classify not in CLASSIFY_MODES:
        raise ParameterError(f"classify: expected one of {', '.join(CLASSIFY_MODES)}, got {classify!r}")
    if classify == "distribution":
        if tf is None:
            raise ParameterError("classification_bias: classify='distribution' needs the transfer function tf")
        mean = classification_bias(tables, F, "mean") if DISTRIBUTION_FLOOR > 0 else None
        if DISTRIBUTION_FLOOR >= 1:  # the mean mode's bias bounds the residual (see DISTRIBUTION_FLOOR)
            return mean
        residual = distribution_residual(tables, tf)
        if mean is None:
            return residual
        return [np.maximum(d, DISTRIBUTION_FLOOR * m) for d, m in zip(residual, mean)]
    pyr = tables.pyramid
    nb = SUMMARY_BINS
    out = [np.zeros(pyr.num_bricks(L)) for L in range(pyr.num_levels)]
    for L in range(1, pyr.num_levels):
        cl = L - 1
        n_child, owner, k, l, w = _pairs(tables, cl)
        grp = owner * nb + k  # (child brick, parent code)
        ug, inv = np.unique(grp, return_inverse=True)
        n = np.bincount(inv, weights=w, minlength=len(ug))
        fbar = np.stack([np.bincount(inv, weights=w * F[l, c], minlength=len(ug)) for c in range(3)], axis=1)
        fbar /= np.maximum(n, 1e-300)[:, None]
        d2 = np.sum((F[ug % nb] - fbar) ** 2, axis=1) * n
        per_child = np.bincount(ug // nb, weights=d2, minlength=n_child)
        out[L], _ = _parent_bias(pyr, cl, owner, w, per_child, out[cl])
    return out


def _pairs(tables: SummaryTables, cl: int):
    """The summary tables' (child voxel code, parent voxel code) pairs of level ``cl`` and the next:
    ``(children, owner, parent code, child code, count)``, ``owner`` the child brick of each pair."""
    off = tables.pairs_offsets[cl]
    n_child = len(off) - 1
    owner = np.repeat(np.arange(n_child, dtype=np.int64), np.diff(off))
    code = tables.pairs_code[cl].astype(np.int64)
    return n_child, owner, code // SUMMARY_BINS, code % SUMMARY_BINS, tables.pairs_count[cl].astype(np.float64)


def _parent_bias(pyr, cl: int, owner, w, per_child, child_bias):
    """Each brick of level ``cl + 1``'s bias: the RMS Delta E of its children's pairs (``per_child``,
    the sum of squares per child brick over ``w``-weighted pairs), averaged over the children that
    hold any, plus the worst child's own bias (errors of levels add up); and the children's parents."""
    n_child = len(per_child)
    N = np.bincount(owner, weights=w, minlength=n_child)
    b_ij = np.sqrt(per_child / np.maximum(N, 1.0))
    pflat = _child_parent(pyr, cl)
    nb = pyr.num_bricks(cl + 1)
    kids = np.bincount(pflat, weights=(N > 0).astype(np.float64), minlength=nb)
    total = np.bincount(pflat, weights=np.where(N > 0, b_ij, 0.0), minlength=nb)
    worst = np.zeros(nb)
    np.maximum.at(worst, pflat, child_bias)
    return total / np.maximum(kids, 1.0) + worst, pflat


def _child_parent(pyr, cl: int) -> np.ndarray:
    """Flat index in level ``cl + 1`` of each (flat) brick of level ``cl``'s parent."""
    n_child = pyr.num_bricks(cl)
    cidx = np.stack(np.unravel_index(np.arange(n_child), pyr.grid(cl)), axis=1)
    return np.ravel_multi_index(tuple((cidx // 2).T), pyr.grid(cl + 1))


def distribution_residual(tables: SummaryTables, tf) -> list[np.ndarray]:
    """Per level (flat over the brick grid): the Delta E of consistent levels' coarse colours against
    the fine values they stand for that a ray's integration keeps (the residual of the normal model;
    :func:`classification_bias` with ``classify="distribution"`` takes the larger of it and
    :data:`DISTRIBUTION_FLOOR` times the mean mode's bias)."""
    from .consistent import expected_premultiplied

    pyr = tables.pyramid
    nb = SUMMARY_BINS
    rng = pyr.value_range
    centres = tables.quantiser.centres()
    rgba = tf.lookup(centres, rng)
    P = rgba[:, :3] * rgba[:, 3:4]  # premultiplied colour of each code (level 0: no spread)
    out = [np.zeros(pyr.num_bricks(L)) for L in range(pyr.num_levels)]
    s2_lv = np.zeros(pyr.num_bricks(0))  # per brick of the child level: mean spread^2 of its voxels
    for L in range(1, pyr.num_levels):
        cl = L - 1
        n_child, owner, k, l, w = _pairs(tables, cl)
        # the fine side: level 0's colour, or the child level's consistent colour at its brick's spread
        fine = P[l] if cl == 0 else expected_premultiplied(tf, centres[l], np.sqrt(s2_lv[owner]), rng)
        grp = owner * nb + k  # (child brick, parent code)
        ug, inv = np.unique(grp, return_inverse=True)
        inv = inv.reshape(-1)
        n = np.bincount(inv, weights=w, minlength=len(ug))
        safe = np.maximum(n, 1e-300)
        m1 = np.bincount(inv, weights=w * centres[l], minlength=len(ug)) / safe
        m2 = np.bincount(inv, weights=w * centres[l] ** 2, minlength=len(ug)) / safe
        g_owner = ug // nb
        s2 = np.maximum(m2 - m1 * m1, 0.0) + s2_lv[g_owner]  # the level-0 variance beneath the parent code
        pbar = np.stack([np.bincount(inv, weights=w * fine[:, c], minlength=len(ug)) for c in range(3)], axis=1) / safe[:, None]
        coarse = expected_premultiplied(tf, centres[ug % nb], np.sqrt(s2), rng)
        d2 = np.sum((rgb_to_luv(coarse) - rgb_to_luv(pbar)) ** 2, axis=1) * n
        per_child = np.bincount(g_owner, weights=d2, minlength=n_child)
        out[L], pflat = _parent_bias(pyr, cl, owner, w, per_child, out[cl])
        # each parent brick's mean spread^2 over its voxels (the child voxels it pairs, weighted)
        num = np.bincount(pflat[g_owner], weights=n * s2, minlength=pyr.num_bricks(L))
        den = np.bincount(pflat, weights=np.bincount(owner, weights=w, minlength=n_child), minlength=pyr.num_bricks(L))
        s2_lv = num / np.maximum(den, 1.0)
    return out


def lod_errors(tables: SummaryTables, tf, classify: str = "mean") -> LodErrors:
    """Evaluate ``eps``, ``emission`` and ``bias`` of every brick of ``tables``' pyramid under ``tf``
    (``classify``: how coarse voxels are classified, :func:`classification_bias`)."""
    t0 = time.perf_counter()
    pyr = tables.pyramid
    data_range = pyr.value_range
    centres = tables.quantiser.centres()
    F = colour_table(tf, centres, data_range)  # (256, 3)
    D2 = np.sum((F[:, None, :] - F[None, :, :]) ** 2, axis=-1).reshape(-1)  # squared Delta E, by code
    absF = np.linalg.norm(F, axis=1)
    alpha = tf.lookup(centres, data_range)[:, 3]
    nlev = pyr.num_levels
    mean_l, var, emission, count, opacity = [], [], [], [], []
    for L in range(nlev):
        H = tables.histogram[L].reshape(-1, SUMMARY_BINS).astype(np.float64)
        N = H.sum(axis=1)
        safe = np.maximum(N, 1.0)
        mu = (H @ centres) / safe
        Fmu = colour_table(tf, mu, data_range)  # (n, 3)
        # |F[k] - Fmu|^2 = |F[k]|^2 - 2 F[k].Fmu + |Fmu|^2, summed with the histogram's weights
        s2 = H @ (absF**2) - 2.0 * np.sum((H @ F) * Fmu, axis=1) + N * np.sum(Fmu**2, axis=1)
        var.append(np.maximum(s2, 0.0) / np.maximum(N - 1.0, 1.0))
        mean_l.append(Fmu[:, 0])
        emission.append((H @ absF) / safe)
        opacity.append((H @ alpha) / safe)
        count.append(N)
    raw = [np.zeros(pyr.num_bricks(L)) for L in range(nlev)]
    for L in range(1, nlev):
        cl = L - 1  # the children's level: their tables pair them with level L
        gc = np.array(pyr.grid(cl))
        off = tables.pairs_offsets[cl]
        n_child = len(off) - 1
        owner = np.repeat(np.arange(n_child), np.diff(off))
        w = tables.pairs_count[cl].astype(np.float64)
        s = np.bincount(owner, weights=w * D2[tables.pairs_code[cl].astype(np.int64)], minlength=n_child)
        sig_ij = np.sqrt(s / np.maximum(count[cl] - 1.0, 1.0))
        cidx = np.stack(np.unravel_index(np.arange(n_child), tuple(gc)), axis=1)
        pflat = np.ravel_multi_index(tuple((cidx // 2).T), pyr.grid(L))
        mi, mj = mean_l[L][pflat], mean_l[cl]
        lum = (mi**2 + mj**2 + C1) / (2.0 * mi * mj + C1)
        con = _contrast(var[L][pflat], var[cl], C2)
        eps_ij = np.where(count[cl] > 0, sig_ij * lum * con, 0.0)
        total = np.bincount(pflat, weights=eps_ij, minlength=pyr.num_bricks(L))
        worst = np.zeros(pyr.num_bricks(L))
        np.maximum.at(worst, pflat, raw[cl])
        raw[L] = total + worst
    top = max((float(r.max()) for r in raw if r.size), default=0.0)
    scale = 1.0 / top if top > 0 else 0.0
    grids = [pyr.grid(L) for L in range(nlev)]
    raw_g = [r.reshape(g) for r, g in zip(raw, grids)]
    eps = [r * scale for r in raw_g]
    emission, opacity = _beneath(pyr, count, emission), _beneath(pyr, count, opacity)
    em = [e.reshape(g) for e, g in zip(emission, grids)]
    op = [o.reshape(g) for o, g in zip(opacity, grids)]
    bias = [b.reshape(g) for b, g in zip(classification_bias(tables, F, classify, tf), grids)]
    return LodErrors(eps, raw_g, em, time.perf_counter() - t0, op, bias, classify)


def _beneath(pyr, count: list[np.ndarray], own: list[np.ndarray]) -> list[np.ndarray]:
    """Per level (flat): the larger of each brick's ``own`` value (emission or opacity of its
    histogram) and the voxel-weighted mean of its children's, bottom-up from level 1.

    A coarse voxel is the mean of the fine voxels beneath it; under a sharp transfer function that
    mean can lie where the function shows nothing although the fine voxels show bone (a thin shell
    or vessel averaged with air). The brick's own histogram then says "nothing here", the image
    policy gives it no importance and never refines it. What drawing a coarse brick instead of its
    descendants loses is what they show, so a brick carries at least the mean of its children's
    values (each already carrying its own descendants'). It is positive exactly when the brick or
    some descendant at any level shows something, which keeps the policy's cull conservative.
    """
    out = [np.asarray(own[0], dtype=np.float64)]
    for L in range(1, pyr.num_levels):
        pflat = _child_parent(pyr, L - 1)
        n = pyr.num_bricks(L)
        w = count[L - 1]
        mean = np.bincount(pflat, weights=w * out[L - 1], minlength=n) / np.maximum(np.bincount(pflat, weights=w, minlength=n), 1.0)
        out.append(np.maximum(own[L], mean))
    return out
