"""The clip render action: select, upload, ray-cast bricks in visibility order (after ``vzClipRenderAction``).

Per frame (:meth:`ClipRenderAction.render`):

1. **Select** - :func:`clipvol.scene.selection.select` walks the octree from the coarsest level with a
   residency object that is the :class:`~clipvol.render.gpu_cache.GpuBrickCache`: a brick is
   drawable if it is on the GPU, or in the clip-texture's RAM and still inside this frame's
   ``texels_per_frame`` upload budget. Bricks the transfer function makes fully transparent are
   culled from the loader's per-brick value ranges (:class:`clipvol.paging.loader.HasBrickRanges`) without
   being read (composite mode; an iso-surface culls the bricks wholly below its value; in MIP/minIP a
   transparent value can still be the extreme, and the average counts every sample).
2. **Upload** - :meth:`GpuBrickCache.commit`, the one place that writes textures: sub-loads of the
   newly selected bricks into their toroidal slots of the per-level 3D textures.
3. **Draw** - the cut, merged once for every path (:func:`clipvol.scene.selection.merge_items`: a
   complete sibling set drawn from one level is one box), goes to the draw path
   ``RenderParams.path`` names (:mod:`clipvol.render.paths`; ``"auto"``, the default, takes the
   single pass for cuts of at least ``AUTO_SINGLE_PASS_BOXES`` merged boxes). The action hands a
   path the frame as one :class:`~clipvol.render.paths.frame.FrameContext` (the cut, the camera,
   the parameters, the GPU cache, ...) and folds the :class:`~clipvol.render.paths.frame.DrawStats`
   it returns (boxes, page-table nodes, occlusion passes) into :class:`FrameStats`; a path never
   touches the action. A path that cannot draw a cut hands it to the per-brick path, the reference:

   * ``"single-pass"`` (:mod:`clipvol.render.paths.single_pass`) - one ray per pixel walks a
     per-level page table of the cut (ray-guided casting);
   * ``"bricks"`` (:mod:`clipvol.render.paths.bricks`) - one proxy box per draw item, blended in
     the selection's visibility order (OpenGL Volumizer's method).

   Both paths leap over empty space below the brick (``EMPTY_SKIP``, composite without overlays,
   :mod:`clipvol.scene.occupancy`) when this action decides the frame gains from it
   (:data:`MIN_EMPTY_FRACTION`): each brick's cells of 8³ voxels carry their value range
   (computed by the clip-texture's loader threads), the GPU cache turns them into one flag per cell
   for the transfer function, and the march jumps over cells whose every sample is transparent.

   Both paths share one target, one per-level colour table and one set-up
   (:mod:`clipvol.render.paths.setup`) and ``shaders/volume_common.glsl``: the fragment shader
   rebuilds the pixel's ray from ``gl_FragCoord`` and the camera basis (per-frame uniforms, so
   bit-identical for every box and both paths), intersects it with the box (and the
   :class:`~clipvol.scene.geometry.Shape`'s box and planes) and samples the half-open interval
   ``[t_entry, t_exit)`` at ``t = off + k * delta``: spherical shells around the eye (perspective,
   after LaMar, Hamann & Joy) or planes parallel to the image through the camera centre
   (orthographic); ``off`` is 0, or with ``jitter=True`` a stable per-pixel hash times ``delta``
   (rings on opaque surfaces become fine noise; the lattice stays constant-distance along the
   ray). Adjacent boxes share no sample and skip none. Each sample is trilinear in the level's
   texture (in the ``HAS_NAN`` variant over the finite neighbours only, weights renormalised) and
   looked up once in a **per-level corrected colour table** (opacity corrected for the level's
   step relative to the level-0 voxel size, computed on the CPU in float64 - no log/exp per
   sample). Compositing is front to back with premultiplied colour; MIP keeps the largest raw
   value and maps it through the transfer function on read-back. Per-frame constants (mode, NaN in
   the data) are compiled in as shader variants (:mod:`clipvol.render.glsl`), not branched on per
   sample.
4. **Read back** - ``(h, w, 4)`` uint8 straight RGBA, composited over ``background``, row 0 at top.

Precision: box corners and the brick origin are made relative to the eye in float64 and only then
rounded to float32, and samples are addressed in brick-local voxel coordinates, so a volume of
``2**20`` voxels per axis renders as precisely as a small one near the eye.

``wait=True`` repeats select -> ``clip_texture.wait_for`` (the wanted bricks) -> upload, without
drawing, until the selection is converged (everything wanted is drawn at its own level), nothing
more can arrive, or ``timeout`` passes; each pass honours ``texels_per_frame``.

References
----------
* P. Bhaniramka and Y. Demange, "OpenGL Volumizer: A Toolkit for High Quality Volume Rendering of
  Large Data Sets", SGI, 2002 (the clip render action, budgets).
* E. LaMar, B. Hamann and K. I. Joy, "Multiresolution Techniques for Interactive Texture-Based
  Volume Visualization", IEEE Visualization 1999 (spherical shells, opacity correction per level).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..errors import ParameterError
from ..paging.loader import HasBrickRanges
from ..paging.properties import may_hold_nonfinite
from ..paging.readcount import bytes_read_of, split_reads
from ..scene.consistent import SPREAD_ROWS, DistributionRanges
from ..scene.page_table import block_cells
from ..scene.params import MODES, RenderParams
from ..scene.selection import DrawItems, Selection, merge_items
from ..scene.selection.coherence import node_order
from ..scene.selection.merge import KeptMerge
from ..scene.selection.policies import POLICIES
from ..scene.transfer import transparency_filter
from .frame_loop import FrameLoop
from .frame_stats import FrameStats, frame_stats
from .gpu_cache import GpuBrickCache
from .image_lod import ImageLod
from .modes import mode_defines, mode_of
from .overlay_binding import OverlayTextures, overlay_defines
from .refine import Refine, refine_levels, refines
from .paths import DRAW_PATHS, FALLBACK, DrawStats, FrameContext, pick
from .paths.frame import level_ratios
from .paths.setup import MAX_STEPS_PER_BOX, DrawSetup, check_samples, check_step, samples_bound, samples_per_box

__all__ = ["ClipRenderAction", "FrameStats", "MODES", "SELECTIONS", "MIN_EMPTY_FRACTION"]

#: selection policy names (clipvol.scene.selection.policies.POLICIES)
SELECTIONS = tuple(POLICIES)
#: a frame leaps over empty cells only when at least this fraction of the cells holding data is
#: empty under the transfer function: with none empty, the cell lookups (one per 8 samples) cost
#: 5-12 % of a frame on llvmpipe (the CT-like head under a table visible everywhere, 128³-256³)
MIN_EMPTY_FRACTION = 0.1


class ClipRenderAction:
    """Render a :class:`~clipvol.paging.cliptexture.ClipTexture` with a moderngl context.

    Parameters
    ----------
    ctx : moderngl.Context
        From :func:`clipvol.render.create_context` (or a window's context).
    clip_texture : ClipTexture
        Source of bricks (its ``loader`` and ``pyramid`` are used).
    params : RenderParams, optional
        Mode, selection policy and its parameters, step, budgets, shape, background
        (:class:`clipvol.scene.params.RenderParams`); change them later with :meth:`set_params`.
    **kwargs
        Any :class:`~clipvol.scene.params.RenderParams` field as a keyword, applied over ``params``
        (``texture_budget="512MB", lod_threshold=2``).
    """

    def __init__(self, ctx, clip_texture, params: RenderParams | None = None, **kwargs) -> None:
        self.ctx = ctx
        self.clip_texture = clip_texture
        self.pyramid = clip_texture.pyramid
        self.params = RenderParams.from_kwargs(params, **kwargs).check_for(self.pyramid)
        self.cache = self._new_cache(clip_texture, self.params.texture_budget)
        self.frame_loop = FrameLoop(clip_texture, self.cache)
        self.setup = DrawSetup(ctx)  # the target, colour table and programs every draw path shares
        self._paths: dict = {}  # draw paths by name, made on first use (clipvol.render.paths)
        self.program = None  # the variant of the last frame
        self.nonfinite = may_hold_nonfinite(clip_texture.loader)
        self.path_drawn = None  # the registered name of the path that drew the last frame
        self.skipped_empty = False  # the last frame leapt over empty cells (EMPTY_SKIP, see _skips)
        self.page_table_nodes = 0  # single pass: drawn nodes of the last frame's table, after merge_items
        self.last_frame_stats: FrameStats | None = None
        self._transparent_kept = None  # (key, callback) of _transparent for the last transfer function
        self.occlusion_passes = 0  # bricks path: opacity snapshots taken, all frames
        self.boxes_drawn = 0  # proxy boxes of the last frame, after merge_items
        self.last_selection = None
        self._merged_kept = None  # (selection, GPU cache generation, merged items, asked): see _merged
        self._kept_merge = KeptMerge(self.pyramid)  # a kept cut's merge, by cells (see _merged)
        self._extents_kept = None  # (merged items, their distinct extents): see _extents
        self._camera_kept = None  # (the caller's camera, the selection camera made of it): see _selection_camera
        self._answered = None  # the selection camera whose answers held the kept merge last: see _merged
        self._samples_kept = None  # (selection camera or None for any, merged items, step, bound): see _samples
        self._replayed = False  # the frame loop drew the last cut again (its order is the old camera's)
        self.image_lod: ImageLod | None = None  # the image policy's tables and visibility, made on first use
        self.overlays = OverlayTextures(ctx, clip_texture.loader)  # co-registered volumes (scene/overlay.py)
        try:
            self.overlays.sync(self.params.overlays)
        except BaseException:  # an overlay refused: give back what was made
            self.close()
            raise

    def _new_cache(self, clip_texture, budget: int) -> GpuBrickCache:
        """The GPU brick cache of ``clip_texture``'s pyramid (two channels where its levels carry a spread)."""
        return GpuBrickCache(self.ctx, clip_texture.pyramid, budget,
                             spread_levels=getattr(clip_texture, "spread_levels", ()))

    @property
    def distribution(self) -> bool:
        """Are coarse samples classified by their distribution this frame (``classify="distribution"``,
        a store with the spread, composite, finite data; :mod:`clipvol.scene.consistent`)? MIP, minIP,
        the average and the iso-surface take the mean: the average of a distribution is its mean, and
        the extreme or the surface of a distribution is no single voxel's value to classify."""
        p = self.params
        return (p.classify == "distribution" and bool(self.cache.spread_levels) and mode_of(p.mode).classifies
                and not self.nonfinite)

    # -- shader variants ---------------------------------------------------------------------------
    def defines(self) -> dict:
        """The ``#define``\\ s of this frame's volume shader variant (see :mod:`clipvol.render.glsl`)."""
        mode = self.params.mode
        return {**mode_defines(mode), "HAS_NAN": self.nonfinite,
                "DISTRIB": SPREAD_ROWS if self.distribution else False,
                "SHADING": self.params.shading and mode_of(mode).classifies,
                "EMPTY_SKIP": self.skipped_empty, **overlay_defines(self.params.overlays, self.params.blend)}

    # -- helpers -----------------------------------------------------------------------------------
    def _transparent(self, tf):
        """``(level, idx) -> bool mask`` from the loader's brick ranges over each brick's sampling
        footprint (:func:`clipvol.scene.transfer.transparency_filter`), or None: composite under
        ``tf``, iso under :meth:`~clipvol.render.modes.base.DrawMode.occupancy_tf` (wholly below the value)."""
        loader = self.clip_texture.loader
        mode = mode_of(self.params.mode)
        tf = mode.occupancy_tf(self.params, tf, self.pyramid.value_range)  # iso: values below the surface's
        if not mode.culls or not isinstance(loader, HasBrickRanges):
            return None
        # kept while the table, its window and the overlays stay (the filter answers whole levels once)
        key = (loader, np.asarray(tf.table).tobytes(), tf.window(self.pyramid.value_range), self.params.overlays,
               self.distribution)
        if self._transparent_kept is not None and self._transparent_kept[0] == key:
            return self._transparent_kept[1]
        if self.distribution:  # a coarse brick's spread reaches values its means do not (scene/consistent.py)
            lo, hi = tf.window(self.pyramid.value_range)
            loader = DistributionRanges(loader, hi - lo, self.cache.spread_levels)
        if self.params.overlays:  # a transparent brick still carries the rays through an overlay
            fn = self.overlays.cull_outside(transparency_filter(tf, loader), self.params.overlays)
        else:
            fn = transparency_filter(tf, loader)
        self._transparent_kept = (key, fn)
        return fn

    def _skips(self, tf) -> bool:
        """Does this frame leap over empty cells? Composite or iso without overlays (an overlay is
        sampled wherever the primary is; in MIP/minIP a transparent value can still be the extreme,
        in the average every sample counts; iso's "empty" is below its value: its mode's ``occupancy_tf``), with
        ``skip_empty``, cells for this brick shape, a window of non-zero width (a zero-width window
        is a step whose float32 table coordinate the cells' test cannot bound), and at least
        :data:`MIN_EMPTY_FRACTION` of the cells holding data empty under ``tf`` (the lookups cost
        samples where there is little to leap). Derives the cells' flags for ``tf``."""
        p = self.params
        mode = mode_of(p.mode)
        tf = mode.occupancy_tf(p, tf, self.pyramid.value_range)  # iso: values below the surface's are "empty"
        if not p.skip_empty or not mode.culls or p.overlays or self.cache.cell_edges is None:
            return False
        lo, hi = tf.window(self.pyramid.value_range)
        if not hi > lo:
            return False
        self.cache.occupancy_texture(tf, self.pyramid.value_range, self.distribution)
        return self.cache.empty_fraction() >= MIN_EMPTY_FRACTION

    def level_ratios(self) -> np.ndarray:
        """Per level, the sample spacing ``step * min(scale)`` over the level-0 voxel size (the
        transfer function's reference length; :func:`clipvol.render.paths.frame.level_ratios`)."""
        return level_ratios(self.pyramid, self.params.step)

    def set_params(self, params: RenderParams) -> None:
        """Use ``params`` from the next frame on (the GPU cache is kept unless the texture budget
        changed; the clip-texture is never touched)."""
        if not isinstance(params, RenderParams):
            raise ParameterError(f"params: expected a RenderParams, got {type(params).__name__}")
        params.check_for(self.pyramid)
        self.overlays.sync(params.overlays)
        if params.texture_budget != self.params.texture_budget:
            self.cache.release()
            self.cache = self._new_cache(self.clip_texture, params.texture_budget)
            self.frame_loop = FrameLoop(self.clip_texture, self.cache)
        self.params = params

    def use_clip_texture(self, clip_texture) -> None:
        """Draw from another clip-texture of the same brick geometry from the next frame on (the
        next time step of a series): the GPU cache is emptied, the program and targets are kept."""
        pyr = clip_texture.pyramid
        if pyr.brick_shape != self.pyramid.brick_shape or [lv.shape for lv in pyr.levels] != \
                [lv.shape for lv in self.pyramid.levels] or pyr.dtype != self.pyramid.dtype:
            raise ParameterError("clip_texture: expected the same levels, brick shape and dtype as the current one, "
                                 f"got levels {[lv.shape for lv in pyr.levels]} brick {pyr.brick_shape} {pyr.dtype}")
        self.cache.release()
        self.clip_texture, self.pyramid = clip_texture, pyr
        self.cache = self._new_cache(clip_texture, self.params.texture_budget)
        self.frame_loop = FrameLoop(clip_texture, self.cache)
        self._camera_kept = None  # (another pyramid: another volume box to fit)

    # -- the frame ---------------------------------------------------------------------------------
    def render(self, camera, transfer_function, wait: bool = False, timeout: float | None = None,
               policy=None) -> np.ndarray:
        """Render one frame; returns ``(h, w, 4)`` uint8 straight RGBA, row 0 at the top.

        Parameters
        ----------
        camera : Camera
        transfer_function : TransferFunction
        wait : bool
            Wait for the wanted bricks (loads and uploads) until the selection converges.
        timeout : float, optional
            Seconds to wait at most with ``wait=True`` (None: until nothing more can arrive).
        policy : object, optional
            A selection policy instance to use instead of the one ``params.policy`` names.
        """
        t_start = time.perf_counter()
        read0 = bytes_read_of(self.clip_texture.loader)
        self.clip_texture.set_region(None)  # a volume view pages cube windows around the centre
        cam = self._selection_camera(camera)
        if policy is None and self.params.policy == "image":  # image-based LOD: tables + visibility, kept per action
            if self.image_lod is None:
                self.image_lod = ImageLod(lambda p: type(self)(self.ctx, self.clip_texture, p), self.clip_texture)
            policy = self.image_lod.policy(cam, transfer_function, self.params)
        self.last_policy = policy
        plan = self.frame_loop.run(cam, self.params, transparent=self._transparent(transfer_function),
                                   policy=policy, wait=wait, timeout=timeout, ordered=False)
        sel, times = plan.selection, dict(plan.times)
        self._replayed = plan.replayed or not sel.ordered  # items not in this camera's order: _draw orders them
        drawn = self._draw(cam, transfer_function, sel)
        image, read_t = drawn.image, drawn.readback_s
        times["draw"], times["readback"] = drawn.draw_s, read_t
        times["total"] = time.perf_counter() - t_start
        # the host's share: all but the waits on the loader and on the GL (finish and read-back)
        times["gpu"] = drawn.finish_s + read_t
        times["host"] = max(0.0, times["total"] - times["wait"] - times["gpu"])
        bytes_read = None if read0 is None else bytes_read_of(self.clip_texture.loader) - read0
        reads = self.clip_texture.take_reads()
        last, before = self.last_frame_stats, self.last_selection
        if (plan.replayed or plan.updated) and last is not None and before is not None \
                and getattr(before, "items", None) is sel.items:
            # the same cut (drawn again, or a kept cut updated with the same leaves: the same items
            # object): what the statistics count of its items is the last frame's, not counted again
            # over the whole cut (a bincount and a pass per brick: ~0.2 ms a frame of the 512^3
            # head's 15 774 bricks, where the frame's other work is flat in the cut)
            frame_read, other_read = split_reads(reads, np.concatenate([sel.item_keys(), sel.wanted_keys()])) \
                if reads else ((None, None) if reads is None else (0, 0))
            self.last_frame_stats = dataclasses.replace(
                last, times=times, bytes_uploaded=0, bricks_uploaded=0, passes=1, converged=True,
                bytes_read=bytes_read, frame_bytes_read=frame_read, prefetch_bytes_read=other_read,
                replayed=plan.replayed, updated=plan.updated,
                counts=sel.counts.copy(), **self._drawn_fields(drawn))  # (a kept cut's: this camera's)
        else:
            self.last_frame_stats = dataclasses.replace(
                frame_stats(sel, plan, times, self.cache, self.params.texture_budget, self.clip_texture,
                            bytes_read=bytes_read, reads=reads), **self._drawn_fields(drawn))
        self.last_selection = sel
        return image

    def render_items(self, camera, transfer_function, items) -> np.ndarray:
        """Draw the given :class:`~clipvol.scene.selection.DrawItem` list in the given order (no selection).

        Every item's brick must be resident in the clip-texture; missing ones are uploaded now
        regardless of ``texels_per_frame``. For tests (draw order) and benchmarks (one fixed cut).
        """
        from types import SimpleNamespace

        cam = self._selection_camera(camera)
        cache = self.cache.begin_frame(self.clip_texture, None)
        for it in items:
            if not cache.resident_mask(it.level, np.array([it.index]))[0]:
                raise ParameterError(f"items: expected resident bricks, got brick (level {it.level}, {tuple(it.index)}) "
                                     "that is neither on the GPU nor in the clip-texture (or shares a slot)")
        cache.reserve_neighbours(items)  # so that filtering across faces is seamless
        cache.commit()
        return self._draw(cam, transfer_function, SimpleNamespace(items=list(items))).image

    def _selection_camera(self, camera):
        """The camera with near/far enclosing the volume, near tiny (the eye may be inside a huge volume).

        A camera equal to the last one (a still view: the same position, aim, lens and image)
        gives the same object back, so that what a frame made of it - the kept cut's tests, the
        merge's questions to it, its frustum planes - is known to hold by identity, and a frame
        that changes nothing costs a redraw."""
        kept = self._camera_kept
        if kept is not None and (kept[0] is camera or kept[0] == camera):
            return kept[1]
        cam = self._fit_camera(camera)
        self._camera_kept = (camera, cam)
        return cam

    def _fit_camera(self, camera):
        vlo, vhi = self.pyramid.volume_box()
        cam = camera.fit_depth(vlo, vhi)
        if not cam.orthographic:
            cam = cam.with_depth_range(min(cam.near, cam.far * 1e-7), cam.far)
        return cam

    def _draw(self, cam, tf, sel) -> DrawStats:
        """Merge the cut once, check once that no ray needs more samples in a box than the loop
        takes (:func:`check_samples`; every pass and path of the frame casts the image camera's
        rays through these boxes), decide whether the frame leaps over empty cells, and hand the
        cut to the draw path ``params.path`` picks (:func:`clipvol.render.paths.pick`), or to the
        fallback path where that one declines it, as a :class:`FrameContext`; fold the
        :class:`DrawStats` it returns into the action's counters."""
        check_step(self.pyramid, self.params.step)  # bricks are never stepped over, whatever the cut
        items = sel.items  # a full cut's DrawItems stay arrays: the merge reads those
        replayed = self._replayed and isinstance(sel, Selection)
        self._replayed = False
        checked = False
        if self.params.merge_boxes and len(items):  # once, for either path
            merged = self._merged(cam, sel)
            if self._samples(cam, merged) <= MAX_STEPS_PER_BOX:
                items, checked = merged, True  # (else the rays would be cut)
        if not checked:
            check_samples(cam, items, self.pyramid, self.params.step)
        if not checked and not isinstance(items, list):  # (the kept merged DrawItems stay themselves: the
            items = list(items)  # single pass keys on them and reads their arrays, making no DrawItem objects)
        self.skipped_empty = self._skips(tf)
        name = pick(self.params, items)

        def ordered(items):  # a cut drawn again is in the order of the camera that made it
            return [items[i] for i in node_order(items, self.pyramid, cam)] if replayed else items

        if self._path(name).wants_order:  # (the single pass walks a page table: it needs no order)
            items = ordered(items)
        frame = self._frame_context(cam, tf, items)
        out = self._draw_refined(name, frame) if refines(self.params, cam) else self._path(name).draw(frame)
        if out is None:  # the path cannot draw this cut: the reference path does
            name = FALLBACK
            out = self._path(name).draw(dataclasses.replace(frame, items=ordered(items)))
        self.path_drawn = name
        self.boxes_drawn, self.page_table_nodes = out.boxes_drawn, out.page_table_nodes
        self.occlusion_passes += out.occlusion_passes
        self.program = out.program
        return out

    def _frame_context(self, cam, tf, items) -> FrameContext:
        """What a draw path reads of this frame (:class:`~clipvol.render.paths.frame.FrameContext`)."""
        return FrameContext(camera=cam, tf=tf, items=items, params=self.params, pyramid=self.pyramid,
                            cache=self.cache, residency_version=self.clip_texture.residency_version,
                            overlays=self.overlays, defines=self.defines(), skipped_empty=self.skipped_empty,
                            distribution=self.distribution)

    def _drawn_fields(self, drawn: DrawStats) -> dict:
        """The :class:`FrameStats` fields of what the draw path drew."""
        return dict(path=self.path_drawn, boxes_drawn=drawn.boxes_drawn, page_table_nodes=drawn.page_table_nodes,
                    occlusion_passes=drawn.occlusion_passes)

    def _merged(self, cam, sel) -> DrawItems:
        """:func:`merge_items` of ``sel``'s items, kept while ``sel``'s items are drawn again (the
        frame loop's replay, or a kept cut whose leaves did not change, hands back the same object),
        the GPU cache's slots are unchanged and the camera answers what the merge asked of it again
        (a culled sibling not in texture memory is covered only while it lies beside the view: those
        boxes are asked again, one vectorised call, and the merge is the same while every answer is).

        A kept cut updated for the camera (``sel.ordered`` False: depth-first, whole nodes) is
        merged by :class:`~clipvol.scene.selection.merge.KeptMerge` while the slots are the same:
        only the cells whose leaves changed, or whose culled nodes ``may_cover`` answers otherwise
        for this camera, are merged again."""
        kept = self._merged_kept
        same_gpu = kept is not None and kept[1] == self.cache.generation
        if isinstance(sel, Selection) and not sel.ordered:  # a kept cut, updated: merged by cells
            km, may_cover = self._kept_merge, self._may_cover(cam)
            if not (same_gpu and kept[3] is None):
                km.reset()  # (other slots: the kept cells' answers may differ)
            elif kept[0].items is sel.items and (self._answered is cam or km.answers_hold(may_cover)):
                self._answered = cam  # (the same camera answers the same: not asked again)
                return kept[2]
            merged = km.merge(sel.items, self.cache.windows, may_cover)
            self._merged_kept = (sel, self.cache.generation, merged, None)  # (None: the questions are km's)
            self._answered = cam
            return merged
        self._answered = None
        if same_gpu and kept[3] is not None and kept[0].items is getattr(sel, "items", sel) and all(
                np.array_equal(np.asarray(cam.boxes_beside_view(lo, hi), dtype=bool), ans) for lo, hi, ans in kept[3]):
            return kept[2]
        asked: list = []
        self._kept_merge.reset()
        merged = merge_items(sel.items, self.pyramid, self.cache.windows, self._may_cover(cam, asked))
        self._merged_kept = (sel, self.cache.generation, merged, asked) if isinstance(sel, Selection) else None
        return merged

    def _samples(self, cam, merged) -> float:
        """An upper bound of the samples one ray of ``cam`` takes in one of ``merged``'s boxes, to
        compare with :data:`MAX_STEPS_PER_BOX`: the boxes' longest diagonal over the step where
        that is below it (no ray's path in a box is longer; the same for every camera, kept with
        the merged items and the step), else :func:`samples_per_box` over the camera's rays (kept
        while the camera, the merged items and the step are the same objects)."""
        kept, step = self._samples_kept, self.params.step
        if kept is not None and kept[1] is merged and kept[2] == step and (kept[0] is None or kept[0] is cam):
            return kept[3]
        rep = self._extents(merged)
        n = samples_bound(rep, self.pyramid, step)
        if n <= MAX_STEPS_PER_BOX:
            self._samples_kept = (None, merged, step, n)  # (None: any camera)
            return n
        n = samples_per_box(cam, rep, self.pyramid, step)
        self._samples_kept = (cam, merged, step, n)
        return n

    def _extents(self, merged: list) -> DrawItems:
        """One box per distinct (level, extent) of ``merged``: all :func:`samples_per_box` reads of
        them, kept with the kept merged list (a cut of hundreds of boxes has a handful)."""
        kept = self._extents_kept
        if kept is not None and kept[0] is merged:
            return kept[1]
        arr = DrawItems.from_items(merged)
        both = np.ascontiguousarray(np.concatenate([arr.rows[:, :1].astype(np.float64), arr.hi - arr.lo], axis=1))
        # distinct rows by their bytes (``np.unique(axis=0)`` cost ~1.5 ms over a 700-box merge; any
        # order does: samples_per_box takes the largest over them)
        rows = np.unique(both.view(np.dtype((np.void, both.itemsize * 4)))).view(np.float64).reshape(-1, 4)
        keys = np.concatenate([rows[:, :1].astype(np.int64), np.zeros((len(rows), 3), dtype=np.int64)], axis=1)
        rep = DrawItems(keys, np.zeros((len(rows), 3)), rows[:, 1:])
        self._extents_kept = (merged, rep)
        return rep

    def _draw_refined(self, name: str, frame: FrameContext) -> DrawStats | None:
        """Draw ``frame`` with path ``name`` as a refined frame (:mod:`clipvol.render.refine`): its
        passes from the coarsest to the image, each finer one masked by the one before; None where
        the path declines the cut (the fallback path then draws every pixel). The statistics are
        the image pass's, with the draw seconds and occlusion passes of all passes."""
        path, cam = self._path(name), frame.camera
        drawn, occlusion = 0.0, 0
        for k in range(refine_levels(cam), -1, -1):  # coarsest first; 0: the image
            out = path.draw(frame.for_pass(k, Refine.coarse_camera(cam, k)))
            if out is None:
                return None
            drawn += out.draw_s
            occlusion += out.occlusion_passes
        return dataclasses.replace(out, draw_s=drawn, occlusion_passes=occlusion)

    def _path(self, name: str):
        """The draw path registered as ``name``, made for this action on first use."""
        path = self._paths.get(name)
        if path is None:
            if name not in DRAW_PATHS:
                raise ParameterError(f"path: expected one of {', '.join(DRAW_PATHS)} (clipvol.render.paths), "
                                     f"got {name!r}")
            path = self._paths[name] = DRAW_PATHS[name](self.setup)
        return path

    @property
    def last_raw(self) -> np.ndarray | None:
        """``(h, w, 4)`` float32 target of the last frame before the background, rows top first
        (sort-last compositing reads it); read from the target when first asked, so valid until the
        next frame is drawn."""
        if self.last_frame_stats is None:
            return self.setup.last_raw
        return self.setup.raw()

    def _may_cover(self, cam, asked: list | None = None):
        """``may_cover`` for :func:`merge_items`: may a merged box cover these culled nodes
        (``(m, 3)`` of one node level, answered in one go: a full-resolution cut asks thousands)?

        Yes where the node's bricks of the drawn level are all in texture memory (the box then
        shows their real data: outside the view, or transparent). Yes also where they are not but
        the node, grown by one voxel of that level (trilinear filtering reads half a voxel beyond a
        sample), lies wholly beside the view (:meth:`Camera.boxes_beside_view`): no ray of the
        image samples there, so whatever the slots hold is never read. That lets a frame merge
        over bricks at the edge of the view that were never loaded - a warm 1024^3 frame with a
        few such bricks at its corners, a loading frame - instead of drawing the block in pieces.
        A culled node inside the view (transparent, shape-culled) must be in texture memory.

        The two answers are also attributes of the function, ``may_cover.resident`` (the same for
        every camera while the slots are the same) and ``may_cover.beside``: a
        :class:`~clipvol.scene.selection.merge.KeptMerge` asks only the camera's again. So are the
        parts of ``beside``, ``may_cover.boxes`` (the padded node boxes, the same for every camera)
        and ``may_cover.beside_boxes`` (the camera's test of boxes): the kept merge makes the boxes
        of its questions once and asks each frame's camera about all of them in one call.
        """
        pyr = self.pyramid
        cache = self.cache

        def resident(level: int, node_level: int, nodes) -> np.ndarray:
            nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
            if node_level == level:  # one brick each (most calls: culled siblings of a full-resolution cut)
                return cache.on_gpu_mask(level, nodes)
            f = 2 ** (node_level - level)  # a block of bricks each: all of them on the GPU
            first = nodes * f
            count = np.minimum(first + f, np.asarray(pyr.grid(level))) - first
            block, local = block_cells(count)
            gone = ~cache.on_gpu_mask(level, first[block] + local)
            return np.bincount(block[gone], minlength=len(nodes)) == 0

        def boxes(level: int, node_level: int, nodes) -> tuple[np.ndarray, np.ndarray]:
            lo, hi = pyr.node_box(node_level, np.asarray(nodes, dtype=np.int64).reshape(-1, 3))
            pad = float(max(pyr.levels[level].scale))  # grown by one voxel of the level
            return lo - pad, hi + pad

        def beside(level: int, node_level: int, nodes) -> np.ndarray:
            lo, hi = boxes(level, node_level, nodes)
            out = np.asarray(cam.boxes_beside_view(lo, hi), dtype=bool)
            if asked is not None:  # the answer depends on the camera: kept to be asked again
                asked.append((lo, hi, out))
            return out

        def may_cover(level: int, node_level: int, nodes) -> np.ndarray:
            nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
            out = resident(level, node_level, nodes)
            if not out.all():  # the others: beside the view
                out[~out] = beside(level, node_level, nodes[~out])
            return out

        may_cover.resident, may_cover.beside = resident, beside
        may_cover.boxes, may_cover.beside_boxes = boxes, cam.boxes_beside_view  # (the camera-free boxes)

        return may_cover

    def close(self) -> None:
        """Release every GL object of the action (the context stays)."""
        self.cache.release()
        if getattr(self, "overlays", None) is not None:
            self.overlays.release()
        if getattr(self, "image_lod", None) is not None:  # (close() may follow a failed __init__)
            self.image_lod.close()
            self.image_lod = None
        for path in getattr(self, "_paths", {}).values():
            path.release()
        self._paths = {}
        if getattr(self, "setup", None) is not None:
            self.setup.release()
        self.program = None

    def __enter__(self) -> "ClipRenderAction":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
