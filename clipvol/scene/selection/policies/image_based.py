"""Image-based level of detail: refine the brick that matters most to the image, under a block budget.

After Wang, Garcia & Shen (2007, sections IV-B and IV-F). Each node of the brick octree gets an
importance

    ``I = E * eps * t * a * v``

with ``E`` the brick's emission (mean ``|L*u*v*|`` of its premultiplied transfer-function colour over
its histogram, at least the voxel-weighted mean of its children's: a coarse brick whose own mean
voxels are transparent under a sharp transfer function still counts the bone its descendants show,
:mod:`clipvol.scene.lod_error`), ``eps`` its multiresolution error in ``[0, 1]`` (:mod:`clipvol.scene.lod_error`,
from the summary tables only), ``t`` its mean thickness along the view direction (volume over
projected area), ``a`` its projected area in pixels and ``v`` its estimated visibility
(:class:`~clipvol.scene.visibility.OcclusionLayers`; 1 without an estimate).

Two changes to the paper's formula, both measured on the benchmark head (``docs/benchmarks.md``):
``E * t`` becomes the emission of a slab of the brick's mean opacity and thickness ``t``
(``E / alpha * (1 - (1 - alpha)**t)``: the paper's linear term while thin, saturating once opaque -
else a brick of opaque bone outranks everything by its thickness alone), and the product is
weighted by ``p**6`` (:data:`VOXEL_WEIGHT`), ``p`` the pixels one of the brick's voxels covers
(as the projected-size policy measures it): without it a brick whose voxels are already below a
pixel keeps being refined while a neighbour still shows four-pixel voxels - on the benchmark head
the paper's formula needs about 1.3x (face view) and 2.7x (side view) the bricks for 5 % of
pixels with Delta E >= 6. With the visibility estimate's depth layers, an exponent of 6 needs
about 0.85x (face) and 0.96x (side) the bricks of 3 (weights 2 to 20 measured: 2 needs
more, 6 to 20 about the same). A priority queue refines the most important nodes until the cut
holds ``block_budget`` nodes (or the texel budget's worth of bricks), in batches while much of
the budget is left (:meth:`ImageBased._greedy`); the cut stays a valid octree cut, so
back-to-front order and ancestor fallback work as for every policy. A cut can be replayed for the
next frames (``reuse``) while the view turns less than a few degrees and nothing the frustum culled
comes into view (:meth:`covers`; nodes that show nothing at any level, :meth:`subtree_empty`, do
not count).

Silhouette bricks: where the skin meets the air, a coarse level's blurred edge lands about a
pixel away from level 0's, a ring of pixels with Delta E >= 6 along the whole outline. The terms
above do not see it: a brick on the outline is mostly air, so its mean emission and opacity, and
the pair error of its mostly-air voxels, are diluted, while the ring it causes is as long as the
outline it holds. On the benchmark head the leaves on the outline held 6x (face view) to 10x (side
view) more wrong pixels per unit of importance than the others, and the ring (about 1 % of the
image) did not shrink at any budget up to the 5 % point. So a node whose screen rectangle holds a
silhouette pixel of the visibility estimate (:meth:`OcclusionLayers.silhouette`: the total
opacity crosses 0.5 between neighbouring pixels of the coarse pass) has its importance times
``1 + SILHOUETTE_WEIGHT`` (10; 3 and 30 measured). Without a visibility estimate there is no boost.

Two culls come with the policy (its ``keep``): a brick whose visibility is below
``visibility_threshold`` is neither loaded nor drawn (occluded space is left out like empty
space), and so is a brick with neither emission nor error (it and all its descendants are
transparent).

The estimate and the error budget: :attr:`ImageBased.estimated_error` is the predicted fraction
of the image's pixels with CIELUV Delta E >= 6 against the **converged picture** (level 0 at a
quarter-voxel step, supersampled: :mod:`clipvol.app.converged`; :func:`predicted_visible_error`).
Each node of the cut covers ``w = a * v`` of the image (its projected area times its visibility);
a node drawn at level 0 differs nowhere, a coarser one on a fraction ``q = 1 - exp(-b / S0)`` of
its pixels, where ``b`` is its classification bias (:func:`clipvol.scene.lod_error.classification_bias`:
per child brick, the root-mean-square Delta E between the colour of each coarse value and the mean
colour of the fine values it stands for, summed down the pyramid) and ``S0`` (:data:`BIAS_SCALE`,
10) the one constant, fitted on the procedural CT head (12-bit 256³ at 32³ bricks, ``bone``,
iso, face and close views at 256², image-policy block budgets 8-96). The fraction is
``sum(w q) / sum(w)`` over the cut times the share of the image the visibility estimate finds
non-empty (total opacity > 0.02; 1 without an estimate).

Why the bias and not the pair error: the pair error (the RMS Delta E of every fine voxel against its
coarse one, :data:`ERROR_SCALE` 80 with it, the estimate before) also counts zero-mean differences
- a scan's grain, which the coarse level averages away - that a ray through many voxels averages
away in the image too; the bias is what survives the ray's integration, and it is largest exactly
where a sharp transfer function meets an edge or a thin structure (the mean of bone and air is a
value neither has). Against the converged picture, on the head it was fitted on, the bias model is
within 1.5x of the measurement on 13 of 15 cuts measuring 0.5-20 % (the pair error at 80: 7 of
15; at its best constant, 60, 12). It is a model, not a measurement, and two things it does not
see were measured (``docs/benchmarks.md``, "The benchmark that decides"): on the MNI ICBM152 T1
template it runs 2-3x low on overviews (brain folds under ``bone``: thin structures whose
differences are edges in the image, many per brick), and on close views of smooth surfaces it
runs high (a 32³ brick of skin seen from near differs voxel by voxel, not pixel by pixel). Neither
the full-resolution frame's own error (0-0.9 % of pixels there) nor the non-empty share (within
0.01 of the converged picture's) nor the image size (256² and 512² measure the same) explains the
gap. It guides the cut; it is not a bound.

The view's edges (:mod:`clipvol.scene.visible_edges`): with a visibility estimate and consistent
coarse levels (errors of ``classify="distribution"``), a coarse node's ``q`` is not its bias's but
:func:`~clipvol.scene.visible_edges.edge_difference` of its level and of the share of its screen
rectangle that the estimate's opacity map shows on an edge (:meth:`OcclusionLayers.footprint`),
0 where the bias is 0 (a node that classifies exactly as the fine data beneath it). Measured on the
MNI ICBM152 T1 template, per node of a cut the differing pixels follow the edges in front of the node
(many in a brain's folds, few on a surface seen from near) and not the bias; with the edges of the
whole view as one factor on the bias (the term before) the estimate was 0.43-0.86x the measurement
on ``clipvol report``'s turntable views and 0.54-1.60x on the benchmark's views; per node, 0.77-1.22x
and 0.69-1.52x (92 of 94 cuts within 1.5x; ``docs/benchmarks.md``, "The visible-error estimate: the
edges in front of each node"). Each node's weight ``w`` is then its area times visibility times the
share of its map rectangle that shows something (:meth:`OcclusionLayers.footprint`).

Consistent coarse levels (``RenderParams.classify = "distribution"``) change a coarse level's error:
the image policy asks for the errors of the frame's classify mode
(:meth:`clipvol.render.image_lod.ImageLod.errors_for`, :func:`~clipvol.scene.lod_error.lod_errors`'s
``classify``). The bias of that mode is the larger of the normal model's residual
(:func:`~clipvol.scene.lod_error.distribution_residual`: the renderer's pre-integrated colour of each
coarse code against the mean colour of the fine values beneath it) and
:data:`~clipvol.scene.lod_error.DISTRIBUTION_FLOOR` times the mean mode's bias (at 1, the default, the
mean mode's bias itself, as measured best): the residual is
3-6x below the mean's on the MNI template, but it does not see the blur a coarse level keeps, and
alone it let a 5 % budget choose level 3 on overviews (31 % of pixels measured against an estimate of
4 %; smaller floors measured in docs/benchmarks.md).

With ``max_error`` (RenderParams; ``--max-error 5%``) the greedy refinement stops as soon as the
estimate is at most that fraction - the error budget chooses the cut's size, not a brick count.
The cut is then evened out where that is cheap: while it mixes levels, its coarsest nodes are
refined, one level at a time, as long as the cut grows to at most :data:`EVEN_OUT_GROWTH` (2)
times the size the budget chose (and within the block budget). A finer node only lowers the error
(the estimate is taken over the evened cut), and a cut of fewer levels merges into fewer boxes
(:func:`~clipvol.scene.selection.merge_items`): the renderer's rays restart at every box or
page-table node they cross, which on a CPU rasteriser costs more than the samples the coarser
bricks save. On the 12-bit CT-like head at 5 % the budget's cut of 28 level-1 and 4 level-2
bricks draws in 8 boxes at 0.9-1.0x the full-resolution frame's speed, 4.4 % of pixels; evened
out to 48 level-1 bricks, 1.1-1.5x at 3.8 % (``tools/bench/bench_mission.py``, 256² and 512²).

References
----------
C. Wang, A. Garcia, H.-W. Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality
Metric for Large Volume Visualization", IEEE TVCG 13(1), 2007.
"""

from __future__ import annotations

import heapq

import numpy as np

from ....errors import ParameterError
from ...visibility import box_depths, screen_rects
from ...visible_edges import edge_difference

__all__ = ["ImageBased", "VOXEL_WEIGHT", "SILHOUETTE_WEIGHT", "ERROR_SCALE", "BIAS_SCALE", "NONEMPTY_ALPHA",
           "predicted_visible_error"]

#: exponent of the projected voxel size (pixels per voxel) in the importance (see the module docstring)
VOXEL_WEIGHT = 6.0
#: a node whose screen rectangle holds part of the silhouette (in the visibility estimate's total
#: opacity) has its importance times ``1 + SILHOUETTE_WEIGHT`` (see the module docstring)
SILHOUETTE_WEIGHT = 10.0
#: Delta E (RMS per voxel, summed down the pyramid) at which a coarse node is predicted to differ
#: visibly on ``1 - 1/e`` of its pixels (fitted; see the module docstring)
ERROR_SCALE = 80.0
#: Delta E of classification bias (:func:`clipvol.scene.lod_error.classification_bias`) at which a
#: coarse node is predicted to differ visibly on ``1 - 1/e`` of its pixels (fitted on the procedural
#: CT head against the converged picture; see the module docstring)
BIAS_SCALE = 10.0
#: total opacity of the visibility estimate above which a pixel counts as showing something
NONEMPTY_ALPHA = 0.02
#: once ``max_error`` is met, the coarsest nodes of a cut that mixes levels are refined, level by
#: level, while the cut grows to at most this many times its size (see the module docstring)
EVEN_OUT_GROWTH = 2.0
_EMPTY3 = np.zeros((0, 3))


def visible_difference(rms_delta_e, scale: float | None = None) -> np.ndarray:
    """``q``: the predicted fraction of a coarse node's pixels with Delta E >= 6, from its RMS pair
    Delta E (``scale`` :data:`ERROR_SCALE`) or its classification bias (``scale`` :data:`BIAS_SCALE`)."""
    return -np.expm1(-np.asarray(rms_delta_e, dtype=np.float64) / (ERROR_SCALE if scale is None else scale))


def predicted_visible_error(weight, differ, nonempty: float = 1.0) -> float:
    """Predicted fraction of pixels with Delta E >= 6: ``nonempty * sum(weight * differ) / sum(weight)``
    (``weight``: each cut node's projected area times visibility; ``differ``: its :func:`visible_difference`,
    0 at level 0; ``nonempty``: the share of the image that shows something)."""
    w = np.asarray(weight, dtype=np.float64)
    tot = float(w.sum())
    if tot <= 0:
        return 0.0
    return max(0.0, float(nonempty) * float((w * np.asarray(differ, dtype=np.float64)).sum()) / tot)


class _FrozenView:
    """What the importance needs of a camera, computed once (a Camera recomputes its basis per access)."""

    def __init__(self, cam) -> None:
        self.eye = np.asarray(cam.eye, dtype=np.float64)
        self.forward = np.asarray(cam.forward, dtype=np.float64)
        self.size, self.near, self.orthographic = cam.size, cam.near, cam.orthographic
        self._vp = cam.view_projection()

    def view_projection(self) -> np.ndarray:
        return self._vp


class ImageBased:
    """The ``"image"`` policy.

    Parameters
    ----------
    params : RenderParams
        ``block_budget``, ``max_texels_drawn``, ``visibility``, ``visibility_threshold``.
    errors : LodErrors, optional
        Per-brick ``eps`` and emission under the current transfer function
        (:func:`clipvol.scene.lod_error.lod_errors`); required to cut.
    visibility : OcclusionLayers, optional
        The current visibility estimate (ignored when ``params.visibility`` is False).
    reuse : tuple, optional
        A previous policy's :attr:`recorded` cut to replay instead of running the greedy queue
        (:class:`~clipvol.render.image_lod.ImageLod` passes it while the view turns less than a few
        degrees and nothing else changed); :attr:`reused` says whether it was.
    """

    name = "image"

    def __init__(self, params, errors=None, visibility=None, reuse=None) -> None:
        self.params = params
        self.reuse = reuse
        self.reused = False
        self.recorded = None
        self._culled = (_EMPTY3, _EMPTY3)  # boxes the frustum culled while the recorded cut was made
        self.errors = errors
        self.visibility = visibility if params.visibility else None
        self.node_data: dict = {}
        self.estimated_error = float("nan")
        self._importance: dict = {}
        self._mass: dict = {}  # (level, brick) -> (w, w * q) of the error estimate
        self._cam = None
        self._last = None

    # -- per-node terms ------------------------------------------------------------------------
    @staticmethod
    def _indices(t, level: int, lo: np.ndarray) -> np.ndarray:
        """Brick indices ``(n, 3)`` ``(z, y, x)`` of nodes of ``level`` from their boxes' low corners."""
        tree = t.tree
        ext = tree.brick * 2.0**level * tree.sp
        return np.rint((lo + 0.5 * tree.sp) / ext).astype(np.int64)[:, ::-1]

    def _vis(self, t, lo, hi) -> np.ndarray:
        if self.visibility is None:
            return np.ones(len(lo))
        return self.visibility.visibility(lo, hi, self._camera(t))

    def _camera(self, t):
        """The traversal's camera with its basis and matrices computed once per frame."""
        if self._cam is None or self._cam[0] is not t.camera:
            self._cam = (t.camera, _FrozenView(t.camera))
        return self._cam[1]

    def importance(self, t, level: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """``(n,)`` ``I = E * eps * t * a * v * p**6`` of nodes of ``level`` (virtual levels: inf)."""
        last = self._last
        if last is not None and last[0] == level and last[1] is lo:
            return last[2]  # the greedy traversal asks refine() and priority() for the same nodes
        imp = self._importance_of(t, level, lo, hi)
        self._last = (level, lo, imp)
        return imp

    def _importance_of(self, t, level, lo, hi):
        if level > t.tree.top:
            return np.full(len(lo), np.inf)
        idx = self._indices(t, level, lo)
        eps, em, op = self.errors.lookup(level, idx)
        cam = self._camera(t)
        rect, behind = screen_rects(cam, lo, hi)
        area = (rect[:, 2] - rect[:, 0]) * (rect[:, 3] - rect[:, 1])
        thick = self._thickness(t, lo, hi)
        # emission of a slab of the brick's mean opacity and this thickness: E * t while thin (the
        # paper's linear term), saturating at the colour's magnitude once opaque
        with np.errstate(divide="ignore", invalid="ignore"):
            slab = np.where(op > 0, em / op * -np.expm1(thick * np.log1p(-np.minimum(op, 1.0 - 1e-12))), em * thick)
        pv = t.projected_voxel(level, lo, hi)
        imp = slab * eps * area * self._vis(t, lo, hi) * pv ** VOXEL_WEIGHT
        if self.visibility is not None and SILHOUETTE_WEIGHT:
            imp = imp * np.where(self.visibility.silhouette(lo, hi, cam) > 0, 1.0 + SILHOUETTE_WEIGHT, 1.0)
        near, _ = box_depths(cam, lo, hi)
        imp = np.where(behind | (near <= 0), np.inf, imp)  # a node around the eye: refine first
        w = area * self._vis(t, lo, hi)
        if self._edge_model():  # the pixels a node shows, and the edges in front of them
            shown, edges = self.visibility.footprint(lo, hi, cam)
            w = w * shown
            # a level-0 voxel's size in map pixels: how many voxels' edges one map pixel stands for
            mv = pv * (t.tree.voxel(0) / t.tree.voxel(level)) * self.visibility.alpha.shape[-1] / cam.size[0]
            q = np.where(self.errors.bias[level][tuple(idx.T)] > 0, edge_difference(level, edges, mv), 0.0)
        else:
            q = np.zeros(len(lo)) if level == 0 else visible_difference(*self._visible_delta_e(t, level, idx))
        for b, v, wi, qi in zip(map(tuple, idx.tolist()), imp.tolist(), w.tolist(), q.tolist()):
            self._importance[(level, b)] = v
            self._mass[(level, b)] = (wi, wi * qi)
        return imp

    def _edge_model(self) -> bool:
        """Whether ``q`` comes from the edges in front of each node
        (:func:`~clipvol.scene.visible_edges.edge_difference`, weighted by the share of its rectangle
        that shows something): with a visibility estimate and consistent coarse levels; else from the
        classification bias (:func:`visible_difference` of :meth:`_visible_delta_e`)."""
        return (self.visibility is not None and getattr(self.errors, "bias", None) is not None
                and getattr(self.errors, "classify", "mean") == "distribution")

    def _visible_delta_e(self, t, level: int, idx: np.ndarray) -> tuple[np.ndarray, float]:
        """``(Delta E, scale)`` of nodes ``idx`` of ``level`` for :func:`visible_difference`: the
        classification bias (:func:`clipvol.scene.lod_error.classification_bias`) and
        :data:`BIAS_SCALE` where the errors carry it, else (errors made without it) the pair error
        per child and :data:`ERROR_SCALE`."""
        bias = getattr(self.errors, "bias", None)
        if bias is not None:
            return bias[level][tuple(idx.T)], BIAS_SCALE
        raw = self.errors.raw_eps[level][tuple(idx.T)]
        return raw / np.maximum(t.tree.n_children(level, idx), 1), ERROR_SCALE

    # -- the policy protocol --------------------------------------------------------------------
    def priority(self, t, level, lo, hi):
        return self.importance(t, level, lo, hi)

    def refine(self, t, level, lo, hi):
        return self.importance(t, level, lo, hi) > 0

    def _thickness(self, t, lo, hi) -> np.ndarray:
        """Mean thickness along the view (volume over projected area) in level-0 voxels."""
        ext = hi - lo
        d = np.abs(np.asarray(self._camera(t).forward, dtype=np.float64))
        proj = d[0] * ext[:, 1] * ext[:, 2] + d[1] * ext[:, 0] * ext[:, 2] + d[2] * ext[:, 0] * ext[:, 1]
        return np.prod(ext, axis=1) / np.maximum(proj, 1e-300) / float(min(t.tree.sp))

    def keep(self, t, level, lo, hi):
        if level > t.tree.top or self.errors is None:
            return np.ones(len(lo), dtype=bool)
        idx = self._indices(t, level, lo)
        eps, em, _ = self.errors.lookup(level, idx)
        keep = (em > 0) | (eps > 0)
        if self.visibility is not None and self.params.visibility_threshold > 0:
            keep &= self._vis(t, lo, hi) >= self.params.visibility_threshold
        return keep

    def subtree_empty(self, t, level, lo, hi) -> np.ndarray:
        """``(n,)`` True where a node and all its descendants show nothing under the transfer
        function (no emission, no error against any finer level): the traversal leaves such nodes
        out of the boxes a replayed cut must keep out of view (:meth:`covers`)."""
        if self.errors is None:
            return np.zeros(len(lo), dtype=bool)
        eps, em, _ = self.errors.lookup(level, self._indices(t, level, lo))
        return (em <= 0) & (eps <= 0)

    def budget_blocks(self, texels_per_brick: int) -> int:
        """The cut's size limit in bricks: ``block_budget``, and the texel budget's worth of bricks."""
        p = self.params
        n = p.block_budget if p.block_budget is not None else 1 << 62
        if p.max_texels_drawn is not None:
            n = min(n, max(1, p.max_texels_drawn // texels_per_brick))
        return int(n)

    def _greedy(self, t, budget: int) -> None:
        """The greedy refinement of :meth:`Traversal.greedy` with ``cost = number of nodes``, in batches.

        While ``r >= 16`` nodes of budget remain, the ``r // 8`` most important refinable nodes are
        refined together - one vectorised expand, cull and importance evaluation per level instead
        of one per node (a refinement replaces one node by at most eight, so the batch cannot
        overrun the budget). Children are ranked against the queue from the next batch on; with
        importance falling steeply with level (``p**6``) they seldom outrank the nodes refined
        beside their parent. The last few nodes of budget are spent one at a time, exactly as the
        traversal's own greedy does (a refinement that does not fit ends it). With ``max_error`` the
        running estimate (:func:`predicted_visible_error` over the nodes so far) ends it as soon as
        it is within the budget, and a batch is at most a quarter of the cut times the share by which
        the estimate still exceeds the budget, so batches shrink near it instead of overshooting.
        """
        nodes: set = set()
        heap: list = []
        counter = 0
        sums = [0.0, 0.0]  # sum(w), sum(w * q) over ``nodes``: the running error estimate
        max_error = self.params.max_error
        nonempty = self._nonempty()

        def add(key, sign):
            w, wq = self._mass.get(key, (0.0, 0.0))
            sums[0] += sign * w
            sums[1] += sign * wq

        def done() -> bool:
            return max_error is not None and nonempty * sums[1] <= max_error * max(sums[0], 0.0)

        def drop(key):
            nodes.discard(key)
            add(key, -1.0)

        def push(lv, rows, lo, hi):
            nonlocal counter
            if not len(rows):
                return
            ref = t._refine(lv, lo, hi)
            pr = np.asarray(self.priority(t, lv, lo, hi), dtype=np.float64)
            for r, s, f in zip(rows.tolist(), pr.tolist(), ref.tolist()):
                key = (lv, tuple(r))
                nodes.add(key)
                add(key, 1.0)
                if f:
                    heapq.heappush(heap, (-min(s, 1e300), counter, key))
                    counter += 1

        from_parent = 0  # records of children outside the window, drawn from their parent

        def refine_nodes(lv, rows):
            """Replace nodes ``rows`` of level ``lv`` (already dropped) by their culled children."""
            nonlocal from_parent
            rec0 = len(t.rec)
            c = t.expand(lv, np.array(rows, dtype=np.int64))
            from_parent += sum(len(r[1]) for r in t.rec[rec0:])
            c, clo, chi = t.cull(lv - 1, c) if len(c) else (c, _EMPTY3, _EMPTY3)
            push(lv - 1, c, clo, chi)

        level, idx, lo, hi = t.root_level()
        push(level, idx, lo, hi)
        while heap:
            room = budget - len(nodes) - from_parent
            if room < 16 or done():
                break
            n = room // 8
            if max_error is not None:  # batches shrink as the estimate nears the budget (no overshoot)
                est = nonempty * sums[1] / max(sums[0], 1e-300)
                n = max(1, min(n, int(len(nodes) * (1.0 - max_error / max(est, 1e-300)) / 4)))
            batch = [heapq.heappop(heap)[2] for _ in range(min(len(heap), n))]
            by_level: dict = {}
            for key in batch:
                by_level.setdefault(key[0], []).append(key[1])
                drop(key)
            t.counts["refined"] += len(batch)
            for lv in sorted(by_level, reverse=True):
                refine_nodes(lv, by_level[lv])
        while heap and not done():  # the tail, one node at a time
            _, _, key = heap[0]
            lv, b = key
            got = t.refine_one(lv, b, lambda n_c, n_out: len(nodes) - 1 + n_c + from_parent + n_out <= budget)
            if got is None:
                break
            heapq.heappop(heap)
            c, clo, chi, n_out = got
            from_parent += n_out
            drop(key)
            push(lv - 1, c, clo, chi)
        if max_error is not None:  # the error budget is met: even the cut out where that is cheap
            limit = min(budget, int(EVEN_OUT_GROWTH * len(nodes)))
            while True:
                levels = sorted({key[0] for key in nodes if key[0] <= t.tree.top})
                if len(levels) < 2:
                    break
                top = [key for key in nodes if key[0] == levels[-1]]
                idx = np.array([key[1] for key in top], dtype=np.int64)
                kids = int(t.tree.n_children(levels[-1], idx).sum())
                if len(nodes) - len(top) + kids + from_parent > limit:
                    break
                for key in top:
                    drop(key)
                refine_nodes(levels[-1], idx)
        t.leaves_of(nodes)
        self.estimated_error = predicted_visible_error([sums[0]], [sums[1] / sums[0] if sums[0] > 0 else 0.0], nonempty)

    def _nonempty(self) -> float:
        """The share of the image the visibility estimate finds showing something (1 without one)."""
        if self.visibility is None:
            return 1.0
        return float(np.mean(np.asarray(self.visibility.alpha[-1]) > NONEMPTY_ALPHA))

    def node_estimates(self) -> dict:
        """``{(level, index): (w, q)}`` over the last cut's nodes: each node's weight in
        :attr:`estimated_error` (projected area times visibility, times the share of its rectangle
        that shows something with the edge term) and its predicted fraction of differing pixels ``q``
        (0 at level 0) - what ``tools/bench/bench_estimate.py --nodes`` holds against the measured
        fraction per node. A replayed cut (:attr:`reused`) computed no weights: its nodes read ``(0, 0)``."""
        out = {}
        for k in self.node_data:
            w, wq = self._mass.get(k, (0.0, 0.0))
            out[k] = (w, wq / w if w > 0 else 0.0)
        return out

    def covers(self, camera) -> bool:
        """Whether the recorded cut still holds every node ``camera`` sees: none of the boxes the
        frustum culled while the cut was made enters ``camera``'s frustum (else a replay would leave
        a hole at the image's edge, drawn as if empty)."""
        if self.recorded is None:
            return False
        lo, hi = self._culled
        return not (len(lo) and camera.boxes_in_frustum(lo, hi).any())

    def cut(self, t) -> None:
        if self.errors is None:
            raise ParameterError("policy 'image': expected the store's multiresolution errors (summary tables); render "
                                 "through ClipRenderAction on a clipvol store, or pass ImageBased(params, errors=...); "
                                 "build the tables with `clipvol summarize STORE`")
        if self.reuse is not None:  # the previous frame's cut, for a view that turned less than a few degrees
            rec, counts, self.node_data, self.estimated_error = self.reuse
            t.rec.extend(rec)
            t.counts.update(counts)
            self.reused = True
            return
        self._importance, self._mass, self._last = {}, {}, None
        t.frustum_culled = []
        self._greedy(t, self.budget_blocks(t.tree.texels))
        culled = t.frustum_culled
        t.frustum_culled = None
        self._culled = ((np.concatenate([c[0] for c in culled]), np.concatenate([c[1] for c in culled]))
                        if culled else (_EMPTY3, _EMPTY3))
        leaves = [(lv, tuple(int(v) for v in b)) for lv, idx, rl, _ in t.rec if lv == rl for b in idx]
        self.node_data = {k: self._importance.get(k, 0.0) for k in leaves}
        self.recorded = (list(t.rec), dict(t.counts), self.node_data, self.estimated_error)
        self.reuse = self.recorded  # a second selection in the same frame (upload planning) gets the same cut
