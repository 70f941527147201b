"""The clip render action: select, upload, ray-cast bricks in visibility order (after ``vzClipRenderAction``).

Per frame (:meth:`ClipRenderAction.render`):

1. **Select** - :func:`clipvol.scene.selection.select` walks the octree from the coarsest level with a
   residency object that is the :class:`~clipvol.render.gpu_cache.GpuBrickCache`: a brick is
   drawable if it is on the GPU, or in the clip-texture's RAM and still inside this frame's
   ``texels_per_frame`` upload budget. Bricks the transfer function makes fully transparent are
   culled from the loader's per-brick value ranges (:class:`clipvol.paging.loader.HasBrickRanges`) without
   being read (composite mode only: in MIP a transparent value can still be the maximum).
2. **Upload** - :meth:`GpuBrickCache.commit`, the one place that writes textures: sub-loads of the
   newly selected bricks into their toroidal slots of the per-level 3D textures.
3. **Draw**, by one of two paths (``RenderParams.path``; the same image within 1 LSB; ``"auto"``, the
   default, takes the single pass for cuts of at least :data:`AUTO_SINGLE_PASS_BOXES` merged boxes):

   * ``"single-pass"`` (``shaders/raymarch.frag.glsl``) - the ray-guided path of
     BigVolumeViewer and the ray-guided renderers of the large-volume literature: the selection's
     cut, merged like the per-brick path's boxes (a complete sibling set is one node whose data is
     a block of finer bricks), becomes a per-level **page table** (:mod:`clipvol.scene.page_table`:
     per node EMPTY, REFINED or DRAWN-from-level-``Ld``, plus the faces filtering may cross),
     uploaded as one small integer texture. One proxy - the volume's box - is drawn; each pixel's
     ray walks the table from the coarsest level down at its current point, samples the node's box
     from the data level's toroidal texture on that level's lattice, skips EMPTY nodes in one step,
     switches level at node faces and stops when opaque. No framebuffer copies, no per-box set-up,
     no blending (one triangle under the scissor rectangle of the volume's box). The shader is
     compiled per range of data levels the table uses. A cut the table cannot express (more than
     16 levels) or rays of more than :data:`MAX_SINGLE_PASS_RAY_SAMPLES` samples (llvmpipe's loop
     cap) fall back to the bricks path.
   * ``"bricks"`` (on llvmpipe faster for a few large boxes, the single pass for many, see
     ``docs/benchmarks.md``) - one proxy box per :class:`~clipvol.scene.selection.DrawItem` into a
     float32 RGBA offscreen target (the method of Bhaniramka & Demange's OpenGL Volumizer, and the
     reference). Each box is drawn as one viewport-covering triangle restricted by the scissor
     test to the box's screen rectangle (``shaders/screen.vert.glsl``: no inner triangle edges for
     a software rasteriser to shade twice; the fragment finds its ray's interval in the box itself
     and returns where there is none), so the camera may sit inside a box. Between boxes composite
     mode uses the selection's exact visibility order in one of two equivalent ways (the operator
     is associative). Default (``early_termination=True``): *front to back* (the back-to-front list reversed) with the
     "under" operator ``(ONE_MINUS_DST_ALPHA, ONE)``; every ``len(items) / 32`` boxes the target
     is copied, and a box's fragment whose pixel is already opaque in the copy returns at once.
     ``early_termination=False``: *back to front* with ``(ONE, ONE_MINUS_SRC_ALPHA)`` over the
     background, exactly as ``vzClipRenderAction``. MIP uses the ``MAX`` blend equation.

   Both paths share ``shaders/volume_common.glsl``: the fragment shader rebuilds the pixel's ray
   from ``gl_FragCoord`` and the camera basis (per-frame uniforms, so bit-identical for every box
   and both paths), intersects it with the box (and the :class:`~clipvol.scene.geometry.Shape`'s
   box and planes) and samples the half-open interval ``[t_entry, t_exit)`` at
   ``t = off + k * delta``: spherical shells around the eye (perspective, after LaMar, Hamann & Joy) or planes
   parallel to the image through the camera centre (orthographic); ``off`` is 0, or with
   ``jitter=True`` a stable per-pixel hash times ``delta`` (rings on opaque surfaces become fine
   noise; the lattice stays constant-distance along the ray). Adjacent boxes share no sample and
   skip none. Each sample is trilinear in the level's texture (in the ``HAS_NAN`` variant over the
   finite neighbours only, weights renormalised) and looked up once in a **per-level corrected
   colour table**: row ``L`` holds the transfer function with its opacity corrected for level
   ``L``'s step relative to the level-0 voxel size, ``1 - exp(r * log1p(-a))``, computed on the
   CPU in float64 when the table or the step changes - no log/exp per sample. Compositing is
   front to back with premultiplied colour; MIP keeps the largest raw value and maps it through
   the transfer function on read-back. Per-frame constants (mode, NaN in the data) are compiled
   in as shader variants (:mod:`clipvol.render.glsl`), not branched on per sample.
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
  Large Data Sets", SGI, 2002 (the clip render action, back-to-front bricks, budgets).
* E. LaMar, B. Hamann and K. I. Joy, "Multiresolution Techniques for Interactive Texture-Based
  Volume Visualization", IEEE Visualization 1999 (spherical shells, opacity correction per level).
* M. Hadwiger, J. Beyer, W.-K. Jeong and H. Pfister, "Interactive Volume Exploration of Petascale
  Microscopy Data Streams Using a Visualization-Driven Virtual Memory Approach", IEEE TVCG 2012,
  and T. Fogal, A. Schiewe and J. Krüger, "An Analysis of Scalable GPU-Based Ray-Guided Volume
  Rendering", IEEE LDAV 2013 (ray-guided single-pass casting through a page table).
* T. Pietzsch, BigVolumeViewer (the Fiji / ImgLib2 GPU volume viewer, software, 2019 on):
  single-pass multiresolution casting through a cache of bricks addressed by a lookup texture.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..paging.loader import HasBrickRanges
from ..paging.properties import may_hold_nonfinite
from ..rows import unique_rows
from ..scene.page_table import block_cells, block_open_faces, build_page_table
from ..scene.params import MODES, RenderParams
from ..scene.transfer import corrected_tables, transparency_filter
from ..scene.visibility import box_depths, screen_rects
from ..scene.selection import merge_items
from ..scene.selection.policies import POLICIES
from .failures import failed_bricks
from .frame_loop import FrameLoop
from .glsl import ProgramCache
from .gpu_cache import GpuBrickCache, t_scale_offset, texel_to_raw
from .image_lod import ImageLod
from .overlay_binding import OverlayTextures, overlay_defines
from .resolve import Resolve

__all__ = ["ClipRenderAction", "FrameStats", "MODES", "SELECTIONS"]

#: selection policy names (clipvol.scene.selection.policies.POLICIES)
SELECTIONS = tuple(POLICIES)
#: most samples one ray takes inside one box (a smaller step is refused with ParameterError)
MAX_STEPS_PER_BOX = 1 << 16
_MIP_EMPTY = -3.0e38
#: accumulated opacity at which a ray stops early: 1 - 0.5 / 255. What the rest of the ray could
#: still add to a premultiplied channel is at most its transmittance, under half a step of the
#: 8-bit image, so the image the caller gets differs from the ray integrated to its end by at most
#: one level after rounding. (0.9995 before: 13 % of the samples of an opaque frame were spent
#: after 0.998, changing no 8-bit pixel by more than 1; tools/bench/bench_render.py measures both.)
OPAQUE = 1.0 - 0.5 / 255.0
#: composite: an occlusion pass after every len(items) / OCCLUSION_PASSES boxes (at least this many)
OCCLUSION_PASSES = 32
OCCLUSION_MIN_BATCH = 1
#: single-pass path: most pyramid levels (one texture unit each) and page-table entries
MAX_SINGLE_PASS_LEVELS = 16
#: single-pass path: most samples one ray may need (volume diagonal / finest step drawn). llvmpipe
#: caps the iterations of an outermost shader loop, nested loops included, at 65535 per SIMD group
#: (gallivm's loop limiter) and the group's iterations are the sum over nodes of its longest
#: segment, so a ray of more samples would be cut short there; such a frame is drawn per brick.
MAX_SINGLE_PASS_RAY_SAMPLES = 1 << 15
MAX_PAGE_TABLE_ENTRIES = 1 << 24
#: path="auto": the single pass draws cuts of at least this many (merged) boxes. Measured on Mesa
#: llvmpipe (docs/benchmarks.md, "Which path draws a frame"), the single pass over the per-brick
#: path, same cut: 1 box 1.04-1.06x, 2 boxes 1.04x, 4 boxes 0.94-0.97x, 8 boxes 0.90x, 10-18 boxes
#: (a loading frame whose cut cannot merge yet) 0.55-0.85x, 64 boxes 0.81x; below 32 boxes the
#: per-brick path takes an occlusion snapshot after every box, each a wait for both rasteriser threads.
AUTO_SINGLE_PASS_BOXES = 4
PAGE_TABLE_WIDTH = 1024

def scissor_boxes(cam, lo, hi) -> np.ndarray:
    """GL scissor boxes ``(n, 4)`` int ``x, y, w, h`` (origin bottom left) holding the screen
    rectangles of boxes ``lo``/``hi`` (world, ``(n, 3)``) with a pixel of margin; a box that reaches
    the eye plane gets the whole image, one off the image an empty box (``w`` or ``h`` 0)."""
    w, h = (int(v) for v in cam.size)
    lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
    hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
    r, _ = screen_rects(cam, lo, hi)
    x0 = np.clip(np.floor(r[:, 0]) - 1, 0, w)
    x1 = np.clip(np.ceil(r[:, 2]) + 1, 0, w)
    y0 = np.clip(h - np.ceil(r[:, 3]) - 1, 0, h)  # rows counted from the bottom
    y1 = np.clip(h - np.floor(r[:, 1]) + 1, 0, h)
    if not cam.orthographic:  # wholly behind the eye: no ray of the image meets it
        x1 = np.where(box_depths(cam, lo, hi)[1] <= 0.0, x0, x1)
    return np.stack([x0, y0, x1 - x0, y1 - y0], axis=1).astype(np.int64)


@dataclass(frozen=True, slots=True)
class FrameStats:
    """What one :meth:`ClipRenderAction.render` call did.

    Attributes
    ----------
    bricks_drawn : dict[int, int]
        Draw items per level (an ancestor drawn over several missing children counts once per child).
    bricks_distinct : int
        Distinct bricks drawn (each brick once, however many items sample it).
    texels_drawn : int
        Voxels of the bricks drawn (a sub-box drawn from an ancestor counts its whole brick once).
    bytes_uploaded, bricks_uploaded : int
        Texture sub-loads of this call (all passes).
    texture_bytes, texture_budget : int
        Bytes held by the brick textures (always <= the budget) and the budget.
    times : dict[str, float]
        Seconds spent in ``select``, ``upload``, ``wait``, ``draw``, ``readback`` and ``total``.
    converged : bool
        Every wanted brick was drawn at its own level.
    passes : int
        Select/upload passes made (more than one only with ``wait=True``).
    counts : dict
        The selection's counts (culled, refined, fallback).
    failed_bricks : tuple of FailedBrick
        Wanted bricks that failed to load, each with its cause and the ancestor drawn in its place
        (:mod:`clipvol.render.failures`); :attr:`unreplaced` are those drawn by nothing.
    """

    bricks_drawn: dict[int, int]
    bricks_distinct: int
    texels_drawn: int
    bytes_uploaded: int
    bricks_uploaded: int
    texture_bytes: int
    texture_budget: int
    times: dict[str, float]
    converged: bool
    passes: int = 1
    items_drawn: int = 0
    counts: dict = field(default_factory=dict)
    failed_bricks: tuple = ()

    @property
    def unreplaced(self) -> tuple:
        """The failed bricks no verified ancestor stands in for: regions missing from the image."""
        return tuple(f for f in self.failed_bricks if not f.replaced)


def _vec(v) -> tuple[float, float, float]:
    return tuple(float(x) for x in v)  # type: ignore[return-value]


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
        import moderngl

        self.ctx = ctx
        self.clip_texture = clip_texture
        self.pyramid = clip_texture.pyramid
        self.params = RenderParams.from_kwargs(params, **kwargs).check_for(self.pyramid)
        self.cache = GpuBrickCache(ctx, self.pyramid, self.params.texture_budget)
        self.frame_loop = FrameLoop(clip_texture, self.cache)
        self.programs = ProgramCache(ctx)
        self._vaos: dict = {}
        self.program = None  # the variant of the last frame
        self._vao = None
        self.nonfinite = may_hold_nonfinite(clip_texture.loader)
        self._tf_tex = None
        self._tf_key = None
        self._pt_tex = None
        self.path_drawn = None  # "single-pass" or "bricks": what drew the last frame
        self.page_table_nodes = 0  # single pass: drawn nodes of the last frame's table, after merge_items
        self._fbo = None
        self._fbo_size = None
        self._fbo_copy = None
        self._default_fbo = None
        self.last_frame_stats: FrameStats | None = None
        self.occlusion_passes = 0
        self.boxes_drawn = 0  # proxy boxes of the last frame, after merge_items
        self.last_selection = None
        self._last_raw: np.ndarray | None = None  # see last_raw
        self._resolve = None  # the GL pass to the 8-bit image (render/resolve.py), made on first use
        self.image_lod: ImageLod | None = None  # the image policy's tables and visibility, made on first use
        self._moderngl = moderngl
        self.overlays = OverlayTextures(ctx, clip_texture.loader)  # co-registered volumes (scene/overlay.py)
        try:
            self.overlays.sync(self.params.overlays)
        except BaseException:  # an overlay refused: give back what was made
            self.close()
            raise

    # -- shader variants ---------------------------------------------------------------------------
    def defines(self) -> dict:
        """The ``#define``\\ s of this frame's volume shader variant (see :mod:`clipvol.render.glsl`)."""
        mip = self.params.mode == "mip"
        return {"MODE_MIP": mip, "HAS_NAN": self.nonfinite, "SHADING": self.params.shading and not mip,
                **overlay_defines(self.params.overlays, self.params.blend)}

    def _brick_program(self):
        """The brick shader variant for the current parameters (compiled once per variant)."""
        prog = self.programs.get("screen.vert", "brick.frag", self.defines())
        if prog not in self._vaos:
            self._vaos[prog] = self.ctx.vertex_array(prog, [])
            _uset(prog, "u_volume", 0)
            _uset(prog, "u_tf", 1)
            _uset(prog, "u_acc", 2)
            _uset(prog, "u_max_steps", MAX_STEPS_PER_BOX)
            _uset(prog, "u_opaque", OPAQUE)
        self.program = prog
        self._vao = self._vaos[prog]
        return prog

    # -- helpers -----------------------------------------------------------------------------------
    def _check_samples(self, cam, items) -> None:
        """Refuse (ParameterError naming ``step``) a frame whose rays would need more than
        :data:`MAX_STEPS_PER_BOX` samples inside one box, instead of cutting them short."""
        worst = self._samples_per_box(cam, items)
        if worst > MAX_STEPS_PER_BOX:
            raise ParameterError(
                f"step: expected at most {MAX_STEPS_PER_BOX} samples per ray and brick, got about {worst:.3g} with "
                f"step {self.params.step} of the smallest voxel (spacing {self.pyramid.spacing}) for this view; use step >= "
                f"{self.params.step * worst / MAX_STEPS_PER_BOX:.3g}"
            )

    def _samples_per_box(self, cam, items) -> float:
        """Upper bound of the samples one ray takes inside one of ``items`` (10 % margin)."""
        if not items:
            return 0.0
        ext = np.array([np.subtract(it.hi, it.lo) for it in items], dtype=np.float64)  # (n, 3)
        levels = np.array([it.level for it in items])
        f, u, r = (np.asarray(v, dtype=np.float64) for v in (cam.forward, cam.up, cam.right))
        if cam.orthographic:
            dirs = f[None]
        else:
            w, h = cam.size
            ty = math.tan(math.radians(float(cam.fov_y)) / 2.0)
            g = np.linspace(-1.0, 1.0, 9)
            gx, gy = np.meshgrid(g * ty * w / h, g * ty)
            dirs = f + gx.reshape(-1, 1) * r + gy.reshape(-1, 1) * u
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        with np.errstate(divide="ignore"):
            path = np.min(ext[:, None, :] / np.abs(dirs[None, :, :]), axis=2).max(axis=1)  # (n,)
        sp_min = float(min(self.pyramid.spacing))
        delta = np.array([self.params.step * sp_min * 2.0**L for L in levels])
        return float(np.max(path / delta)) * 1.1

    def _transparent(self, tf):
        """``(level, idx) -> bool mask`` from the loader's brick ranges over each brick's sampling
        footprint (:func:`clipvol.scene.transfer.transparency_filter`), or None."""
        loader = self.clip_texture.loader
        if self.params.mode != "composite" or not isinstance(loader, HasBrickRanges):
            return None
        if self.params.overlays:  # a transparent brick still carries the rays through an overlay
            return self.overlays.cull_outside(transparency_filter(tf, loader), self.params.overlays)
        return transparency_filter(tf, loader)

    def _ensure_fbo(self, size: tuple[int, int]):
        if self._fbo_size != size:
            if self._fbo is not None:
                self._fbo.release()
                self._fbo_color.release()
            if self._fbo_copy is not None:
                self._fbo_copy.release()
            self._fbo_color = self.ctx.texture(size, 4, dtype="f4")
            self._fbo = self.ctx.framebuffer(color_attachments=[self._fbo_color])
            self._fbo_copy = self.ctx.texture(size, 4, dtype="f4")
            self._fbo_copy.filter = (self._moderngl.NEAREST, self._moderngl.NEAREST)
            self._fbo_size = size
        return self._fbo

    def _ensure_tf(self, tf):
        """The per-level corrected colour table (row ``L``: opacity corrected for level ``L``'s step),
        rebuilt only when the table or the step changes."""
        table = np.ascontiguousarray(np.asarray(tf.table, dtype=np.float32))
        key = (table.shape, table.tobytes(), self.params.step)
        if self._tf_key != key:
            if self._tf_tex is not None:
                self._tf_tex.release()
            rows = corrected_tables(table, self.level_ratios())
            tex = self.ctx.texture((rows.shape[1], len(rows)), 4, rows.astype(np.float32).tobytes(), dtype="f4")
            tex.filter = (self._moderngl.LINEAR, self._moderngl.LINEAR)
            tex.repeat_x = tex.repeat_y = False
            self._tf_tex, self._tf_key = tex, key
        return self._tf_tex

    def level_ratios(self) -> np.ndarray:
        """Per level, the sample spacing ``step * min(scale)`` over the level-0 voxel size (the
        transfer function's reference length)."""
        ref = float(min(self.pyramid.spacing))
        return np.array([self.params.step * float(min(lv.scale)) / ref for lv in self.pyramid.levels])

    def set_params(self, params: RenderParams) -> None:
        """Use ``params`` from the next frame on (the GPU cache is kept unless the texture budget
        changed; the clip-texture is never touched)."""
        if not isinstance(params, RenderParams):
            raise ParameterError(f"params: expected a RenderParams, got {type(params).__name__}")
        params.check_for(self.pyramid)
        self.overlays.sync(params.overlays)
        if params.texture_budget != self.params.texture_budget:
            self.cache.release()
            self.cache = GpuBrickCache(self.ctx, self.pyramid, params.texture_budget)
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
        self.cache = GpuBrickCache(self.ctx, pyr, self.params.texture_budget)
        self.frame_loop = FrameLoop(clip_texture, self.cache)

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
        cam = self._selection_camera(camera)
        if policy is None and self.params.policy == "image":  # image-based LOD: tables + visibility, kept per action
            if self.image_lod is None:
                self.image_lod = ImageLod(lambda p: type(self)(self.ctx, self.clip_texture, p), self.clip_texture)
            policy = self.image_lod.policy(cam, transfer_function, self.params)
        self.last_policy = policy
        plan = self.frame_loop.run(cam, self.params, transparent=self._transparent(transfer_function),
                                   policy=policy, wait=wait, timeout=timeout)
        sel, times = plan.selection, dict(plan.times)
        image, draw_t, read_t = self._draw(cam, transfer_function, sel)
        times["draw"], times["readback"] = draw_t, read_t
        times["total"] = time.perf_counter() - t_start
        keys = sel.item_keys()
        levels, per = np.unique(keys[:, 0], return_counts=True)
        per_level = dict(zip(levels.tolist(), per.tolist()))
        distinct = len(unique_rows(keys)) if len(keys) else 0
        self.last_selection = sel
        self.last_frame_stats = FrameStats(
            bricks_drawn=dict(sorted(per_level.items())), bricks_distinct=distinct,
            texels_drawn=distinct * self.cache.brick_texels, bytes_uploaded=plan.bytes_uploaded,
            bricks_uploaded=plan.bricks_uploaded, texture_bytes=self.cache.texture_bytes,
            texture_budget=self.params.texture_budget, times=times, converged=plan.converged, passes=plan.passes,
            items_drawn=len(sel.items), counts=dict(sel.counts), failed_bricks=failed_bricks(sel, self.clip_texture),
        )
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
        image, _, _ = self._draw(cam, transfer_function, SimpleNamespace(items=list(items)))
        return image

    def _selection_camera(self, camera):
        """The camera with near/far enclosing the volume, near tiny (the eye may be inside a huge volume)."""
        vlo, vhi = self.pyramid.volume_box()
        cam = camera.fit_depth(vlo, vhi)
        if not cam.orthographic:
            cam = cam.with_depth_range(min(cam.near, cam.far * 1e-7), cam.far)
        return cam

    def _frame_uniforms(self, cam, tf) -> np.ndarray:
        """Set per-frame uniforms; returns the origin ``O`` (float64) the box uniforms are relative to."""
        prog = self.program
        V = cam.view_matrix()
        R = V[:3, :3]
        origin = -R.T @ V[:3, 3]
        prog["u_right"].value = _vec(cam.right)
        prog["u_up"].value = _vec(cam.up)
        w, h = cam.size
        if cam.orthographic:
            prog["u_half"].value = (float(cam.width) / 2.0, float(cam.height) / 2.0)
        else:
            ty = math.tan(math.radians(float(cam.fov_y)) / 2.0)
            prog["u_half"].value = (ty * w / h, ty)
        w, h = cam.size
        prog["u_viewport"].value = (float(w), float(h))
        prog["u_ortho"].value = bool(cam.orthographic)
        prog["u_forward"].value = _vec(cam.forward)
        prog["u_center_rel"].value = _vec(np.asarray(cam.center, dtype=np.float64) - origin)
        # t = (raw - lo) / (hi - lo) with raw = a * texel + b, folded in float64
        scale, offset = t_scale_offset(self.cache.format, tf.window(self.pyramid.value_range))
        _uset(prog, "u_t_scale", float(np.clip(scale, -3e38, 3e38)))
        _uset(prog, "u_t_offset", float(np.clip(offset, -3e38, 3e38)))
        _uset(prog, "u_jitter", 1.0 if self.params.jitter else 0.0)
        p = self.params
        _uset(prog, "u_light", (p.ambient, p.diffuse, p.specular, p.shininess))  # SHADING variant only
        if self.params.shape is None:
            box = np.array([[-1e30] * 3, [1e30] * 3])
            planes = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (6, 1))
            n_planes, has_box = 0, False
        else:
            box, planes, n_planes = self.params.shape.box_and_planes_arrays()
            has_box = self.params.shape.box is not None
            box = np.asarray(box, dtype=np.float64)
            planes = np.array(planes, dtype=np.float64)
        finite = np.abs(box) < 1e29
        box = np.where(finite, box - origin, box)
        planes[:, 3] += planes[:, :3] @ origin  # n.(p' + O) + d = n.p' + (d + n.O)
        prog["u_shape_lo"].value = _vec(box[0])
        prog["u_shape_hi"].value = _vec(box[1])
        prog["u_planes"].write(planes.astype(np.float32).tobytes())
        prog["u_n_planes"].value = int(n_planes)
        prog["u_has_box"].value = bool(has_box)
        return origin

    def _draw(self, cam, tf, sel) -> tuple[np.ndarray, float, float]:
        mgl = self._moderngl
        ctx = self.ctx
        items = sel.items  # a full cut's DrawItems stay arrays: the merge reads those
        self.path_drawn = "bricks"
        self.page_table_nodes = 0
        if self.params.merge_boxes and len(items):  # once, for either path
            merged = merge_items(items, self.pyramid, self.cache.windows, self._may_cover(cam))
            if self._samples_per_box(cam, merged) <= MAX_STEPS_PER_BOX:  # else the rays would be cut
                items = merged
        items = list(items)
        if items and (self.params.path == "single-pass" or (self.params.path == "auto" and not self.params.overlays
                                                            and len(items) >= AUTO_SINGLE_PASS_BOXES)):
            out = self._draw_single_pass(cam, tf, items)
            if out is not None:
                self.path_drawn = "single-pass"
                return out
        self._check_samples(cam, items)
        self.boxes_drawn = len(items)
        t0 = time.perf_counter()
        w, h = cam.size
        fbo = self._ensure_fbo((int(w), int(h)))
        previous = ctx.fbo
        fbo.use()
        ctx.viewport = (0, 0, int(w), int(h))
        composite = self.params.mode != "mip"
        front_to_back = composite and self.params.early_termination
        if front_to_back:
            fbo.clear(0.0, 0.0, 0.0, 0.0)
        elif composite:
            r, g, b, a = self.params.background
            fbo.clear(r * a, g * a, b * a, a)
        else:
            fbo.clear(_MIP_EMPTY, 0.0, 0.0, 0.0)
        self._brick_program()
        origin = self._frame_uniforms(cam, tf)
        ctx.enable(mgl.BLEND)
        ctx.disable(mgl.DEPTH_TEST | mgl.CULL_FACE)
        _uset(self.program, "u_use_acc", False)  # no opacity snapshot until the first batch is drawn
        if self.params.mode == "mip":
            ctx.blend_equation = mgl.MAX
        else:
            ctx.blend_equation = mgl.FUNC_ADD
            if front_to_back:  # the "under" operator: dst += (1 - dst.a) * src
                ctx.blend_func = mgl.ONE_MINUS_DST_ALPHA, mgl.ONE
            else:  # "over": dst = src + (1 - src.a) * dst
                ctx.blend_func = mgl.ONE, mgl.ONE_MINUS_SRC_ALPHA
        if composite:
            self._ensure_tf(tf).use(location=1)
        if self.params.overlays:  # co-registered volumes sampled at each sample (render/overlay_binding.py)
            self.overlays.bind(self.program, self.params.overlays, origin, self.level_ratios())
        prog = self.program
        pyr = self.pyramid
        B = np.asarray(pyr.brick_shape, dtype=np.float64)
        clamps = self._block_clamps(items)
        rects = scissor_boxes(cam, [it.lo for it in items], [it.hi for it in items]) if items else None
        bound_level = None
        n_items = len(items)
        order = range(n_items - 1, -1, -1) if front_to_back else range(n_items)
        batch = max(OCCLUSION_MIN_BATCH, -(-n_items // OCCLUSION_PASSES))
        for count, i in enumerate(order):
            if front_to_back and count and count % batch == 0:
                self._occlusion_pass(fbo)
            it = items[i]
            L = it.level
            tex = self.cache.textures[L]
            if tex is None:
                continue
            lo = np.asarray(it.lo, dtype=np.float64)
            hi = np.asarray(it.hi, dtype=np.float64)
            if np.any(hi <= lo) or not (rects[i, 2] and rects[i, 3]):  # empty, or off the image
                continue
            if bound_level != L:
                tex.use(location=0)
                lv = pyr.levels[L]
                scale = np.asarray(lv.scale[::-1], dtype=np.float64)
                trans = np.asarray(lv.translation[::-1], dtype=np.float64)
                win = np.asarray(self.cache.windows[L], dtype=np.int64)
                delta = self.params.step * float(min(lv.scale))
                prog["u_delta"].value = delta
                _uset(prog, "u_tf_row", (L + 0.5) / pyr.num_levels)
                prog["u_inv_scale"].value = _vec(1.0 / scale)
                _uset(prog, "u_inv_tex_size", _vec(1.0 / (win[::-1] * B[::-1])))
                bound_level = L
            bidx = np.asarray(it.index, dtype=np.int64)
            first = trans + bidx[::-1] * B[::-1] * scale
            prog["u_box_lo"].value = _vec(lo - origin)
            prog["u_box_hi"].value = _vec(hi - origin)
            prog["u_o_minus_b"].value = _vec(origin - first)
            prog["u_slot_origin"].value = _vec(((bidx % win) * B)[::-1])
            clo, chi = clamps[i]
            prog["u_clamp_lo"].value = _vec(clo)
            prog["u_clamp_hi"].value = _vec(chi)
            ctx.scissor = tuple(rects[i])
            self._vao.render(mgl.TRIANGLES, vertices=3)
        ctx.scissor = None
        return self._read_back(fbo, previous, tf, front_to_back, t0)

    def _read_back(self, fbo, previous, tf, front_to_back: bool, t0: float) -> tuple[np.ndarray, float, float]:
        """Finish the frame, turn the target into the 8-bit image and give the previous framebuffer
        back. Composite: on the GL (:class:`~clipvol.render.resolve.Resolve`: the background under a
        front-to-back image, un-premultiplied, rounded), reading 4 bytes a pixel; MIP: the maximum
        read back and mapped through the transfer function here."""
        ctx, pyr = self.ctx, self.pyramid
        ctx.finish()
        t1 = time.perf_counter()
        self._last_raw = None
        image = None
        if self.params.mode != "mip":
            if self._resolve is None:
                self._resolve = Resolve(ctx)
            image = self._resolve(self._fbo_color, self.params.background if front_to_back else (0.0, 0.0, 0.0, 0.0))
        else:
            self._last_raw = self._read_raw(fbo)
        # give the binding back (a released framebuffer left bound breaks later framebuffers)
        if previous is None:
            if self._default_fbo is None:
                self._default_fbo = ctx.detect_framebuffer(0)
            previous = self._default_fbo
        previous.use()
        err = ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error after drawing the frame: expected GL_NO_ERROR, got {err}")
        if image is None:  # MIP
            m = self._last_raw[..., 0].astype(np.float64)
            hit = m > _MIP_EMPTY * 0.5
            fmt = self.cache.format
            rgba = tf.lookup(np.where(hit, texel_to_raw(fmt, m), fmt.b), pyr.value_range)
            a = np.where(hit, rgba[..., 3], 0.0)
            prem = np.concatenate([rgba[..., :3] * a[..., None], a[..., None]], axis=-1)
            r, g, b, ba = self.params.background
            bgp = np.array([r * ba, g * ba, b * ba, ba])
            prem = prem + (1.0 - a[..., None]) * bgp
            image = premultiplied_to_uint8(prem)
        return image, t1 - t0, time.perf_counter() - t1

    @staticmethod
    def _read_raw(fbo) -> np.ndarray:
        w, h = fbo.size
        return np.frombuffer(fbo.read(components=4, dtype="f4"), dtype=np.float32).reshape(int(h), int(w), 4)[::-1]

    @property
    def last_raw(self) -> np.ndarray | None:
        """``(h, w, 4)`` float32 target of the last frame before the background, rows top first
        (sort-last compositing reads it); read from the target when first asked, so valid until the
        next frame is drawn."""
        if self._last_raw is None and self._fbo is not None and self.last_frame_stats is not None:
            self._last_raw = self._read_raw(self._fbo)
        return self._last_raw

    def _ensure_page_table(self, entries: np.ndarray):
        """The page-table texture (R32UI, :data:`PAGE_TABLE_WIDTH` entries per row), rewritten per frame."""
        rows = max(1, -(-len(entries) // PAGE_TABLE_WIDTH))
        data = np.zeros(rows * PAGE_TABLE_WIDTH, dtype=np.uint32)
        data[:len(entries)] = entries
        if self._pt_tex is None or self._pt_tex.size[1] < rows:
            if self._pt_tex is not None:
                self._pt_tex.release()
            self._pt_tex = self.ctx.texture((PAGE_TABLE_WIDTH, rows), 1, dtype="u4")
            self._pt_tex.filter = (self._moderngl.NEAREST, self._moderngl.NEAREST)
        self._pt_tex.write(data.tobytes(), viewport=(0, 0, PAGE_TABLE_WIDTH, rows))
        return self._pt_tex

    def _draw_single_pass(self, cam, tf, items):
        """One pass over the volume box through the cut's page table (``shaders/raymarch.frag.glsl``);
        None when this cut or pyramid cannot be drawn that way (the per-brick path then draws it)."""
        pyr = self.pyramid
        nlev = pyr.num_levels
        if nlev > MAX_SINGLE_PASS_LEVELS:
            return None
        self._check_samples(cam, items)
        vlo, vhi = pyr.volume_box()
        finest = self.params.step * min(float(min(pyr.levels[it.level].scale)) for it in items)
        if float(np.linalg.norm(vhi - vlo)) / finest > MAX_SINGLE_PASS_RAY_SAMPLES:
            return None
        # items come merged (complete sibling sets are one node of the table, no face inside)
        table = build_page_table(items, pyr, self.cache.open_faces)
        if table is None or len(table.entries) > MAX_PAGE_TABLE_ENTRIES:
            return None
        self.page_table_nodes = len(items)
        self.boxes_drawn = 1
        mgl, ctx = self._moderngl, self.ctx
        t0 = time.perf_counter()
        w, h = cam.size
        fbo = self._ensure_fbo((int(w), int(h)))
        previous = ctx.fbo
        fbo.use()
        ctx.viewport = (0, 0, int(w), int(h))
        mip = self.params.mode == "mip"
        fbo.clear(_MIP_EMPTY if mip else 0.0, 0.0, 0.0, 0.0)
        data_levels = [it.level for it in items]  # only these get a march in the shader's level chain
        defines = dict(self.defines(), NUM_LEVELS=nlev, LEVEL_LO=min(data_levels), LEVEL_HI=max(data_levels))
        prog = self.programs.get("screen.vert", "raymarch.frag", defines)
        if prog not in self._vaos:
            self._vaos[prog] = ctx.vertex_array(prog, [])
        self.program, self._vao = prog, self._vaos[prog]
        origin = self._frame_uniforms(cam, tf)
        _uset(prog, "u_vol_lo", _vec(vlo - origin))
        _uset(prog, "u_vol_hi", _vec(vhi - origin))
        sp = np.array(pyr.spacing[::-1], dtype=np.float64)
        B = np.array(pyr.brick_shape[::-1], dtype=np.float64)
        c0 = table.c0[:, ::-1].astype(np.float64)  # (nlev, 3) x, y, z
        ext = np.array([B * 2.0**L * sp for L in range(nlev)])
        scale = np.array([lv.scale[::-1] for lv in pyr.levels], dtype=np.float64)
        trans = np.array([lv.translation[::-1] for lv in pyr.levels], dtype=np.float64)
        win = np.array([(wnd[::-1] if wnd is not None else (1, 1, 1)) for wnd in self.cache.windows], dtype=np.float64)
        f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32).tobytes()  # noqa: E731
        i32 = lambda a: np.ascontiguousarray(a, dtype=np.int32).tobytes()  # noqa: E731
        uniforms = {
            "u_pt_base": i32(table.base), "u_pt_size": i32(table.size[:, ::-1]), "u_pt_c0": i32(table.c0[:, ::-1]),
            "u_pt_origin": f32(vlo + c0 * ext - origin), "u_pt_ext": f32(ext),
            "u_lv_d0": i32(table.d0[:, ::-1]), "u_lv_grid": i32([pyr.grid(L)[::-1] for L in range(nlev)]),
            "u_lv_vox0": f32(trans + table.d0[:, ::-1] * B * scale - origin), "u_lv_inv_scale": f32(1.0 / scale),
            "u_lv_win": i32(win), "u_lv_inv_tex_size": f32(1.0 / (win * B)),
            "u_lv_delta": f32([self.params.step * float(min(lv.scale)) for lv in pyr.levels]),
        }
        for name, data in uniforms.items():
            u = prog.get(name, None)
            if u is not None:  # a variant may keep only an array's first elements (the levels it draws)
                u.write(data[:len(data) // nlev * max(1, u.array_length)])
        _uset(prog, "u_brick", _vec(B))
        _uset(prog, "u_top", nlev - 1)
        _uset(prog, "u_nudge", 1e-3 * float(sp.min()))
        # one DRAWN node whose box is the volume's (a merged resident cut): every ray is one region
        one = int(np.sum((table.entries & 3) == 2)) == 1 and len(items) == 1 and np.allclose(items[0].lo, vlo) \
            and np.allclose(items[0].hi, vhi)
        _uset(prog, "u_max_regions", 1 if one else int(16 + sum(sum(pyr.grid(L)) for L in range(nlev))))
        _uset(prog, "u_max_steps", MAX_STEPS_PER_BOX)
        _uset(prog, "u_opaque", OPAQUE)
        _uset(prog, "u_pt_width", PAGE_TABLE_WIDTH)
        _uset(prog, "u_page_table", 2)
        _uset(prog, "u_tf", 1)
        self._ensure_page_table(table.entries).use(location=2)
        if not mip:
            self._ensure_tf(tf).use(location=1)
        for L, tex in enumerate(self.cache.textures):
            if tex is not None:
                _uset(prog, f"u_level{L}", 3 + L)
                tex.use(location=3 + L)
        ctx.disable(mgl.DEPTH_TEST | mgl.BLEND | mgl.CULL_FACE)
        rect = scissor_boxes(cam, vlo, vhi)[0]
        if rect[2] and rect[3]:  # else the volume is off the image: nothing to draw
            ctx.scissor = tuple(rect)
            self._vao.render(mgl.TRIANGLES, vertices=3)
            ctx.scissor = None
        return self._read_back(fbo, previous, tf, not mip, t0)

    def _may_cover(self, cam):
        """``may_cover`` for :func:`merge_items`: may a merged box cover this culled node?

        Yes where the node's bricks of the drawn level are all in texture memory (the box then
        shows their real data: outside the view, or transparent). Yes also where they are not but
        the node, grown by one voxel of that level (trilinear filtering reads half a voxel beyond a
        sample), lies wholly beside the view (:meth:`Camera.boxes_beside_view`): no ray of the
        image samples there, so whatever the slots hold is never read. That lets a frame merge
        over bricks at the edge of the view that were never loaded - a warm 1024^3 frame with a
        few such bricks at its corners, a loading frame - instead of drawing the block in pieces.
        A culled node inside the view (transparent, shape-culled) must be in texture memory.
        """
        pyr = self.pyramid
        cache = self.cache

        def beside_view(level: int, node_level: int, node_index) -> bool:
            lo, hi = pyr.node_box(node_level, node_index)
            pad = float(max(pyr.levels[level].scale))
            return bool(cam.boxes_beside_view(np.asarray(lo) - pad, np.asarray(hi) + pad)[0])

        def may_cover(level: int, node_level: int, node_index) -> bool:
            if node_level == level:  # one brick (most calls: culled siblings of a full-resolution cut)
                resident = cache.on_gpu(level, node_index)
            else:
                f = 2 ** (node_level - level)
                first = np.asarray(node_index, dtype=np.int64) * f
                count = np.minimum(first + f, np.asarray(pyr.grid(level))) - first
                resident = bool(np.all(cache.on_gpu_mask(level, first + block_cells(count)[1])))
            return resident or beside_view(level, node_level, node_index)

        return may_cover

    def _block_clamps(self, items) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per item, the ``(lo, hi)`` clamp of its sampling in item-local voxels (``(x, y, z)``).

        An item covers ``span`` bricks per axis (clipped to the grid). A face of the item may be
        sampled across (half a voxel beyond its last texels, trilinear filtering reading the
        neighbour) only if that face is open for every brick on it (see
        :meth:`GpuBrickCache.open_faces`); otherwise sampling clamps to the item's own texels.
        """
        B = np.asarray(self.pyramid.brick_shape, dtype=np.int64)
        by_level: dict[int, list[int]] = {}
        for i, it in enumerate(items):
            by_level.setdefault(it.level, []).append(i)
        out: list = [None] * len(items)
        for L, rows in by_level.items():
            first = np.array([items[i].index for i in rows], dtype=np.int64)
            span = np.array([items[i].span for i in rows], dtype=np.int64)
            cnt = np.minimum(first + span[:, None], np.asarray(self.pyramid.grid(L), dtype=np.int64)) - first
            of = block_open_faces(self.cache.open_faces, L, first, cnt)  # (n, 3 zyx, 2 sides)
            ext = (cnt * B).astype(np.float64)
            lo = np.where(of[:, :, 0], -0.5, 0.0)
            hi = np.where(of[:, :, 1], ext - 0.5, ext - 1.0)
            for j, i in enumerate(rows):
                out[i] = (lo[j][::-1], hi[j][::-1])
        return out

    def _occlusion_pass(self, fbo) -> None:
        """Snapshot the target for the boxes' opacity test (early ray termination across boxes)."""
        self.ctx.scissor = None  # a blit obeys the scissor test: copy the whole target
        self.ctx.copy_framebuffer(self._fbo_copy, fbo)
        self._fbo_copy.use(location=2)
        _uset(self.program, "u_use_acc", True)
        self.occlusion_passes += 1

    def close(self) -> None:
        """Release every GL object of the action (the context stays)."""
        self.cache.release()
        if getattr(self, "overlays", None) is not None:
            self.overlays.release()
        if getattr(self, "image_lod", None) is not None:  # (close() may follow a failed __init__)
            self.image_lod.close()
            self.image_lod = None
        if getattr(self, "_resolve", None) is not None:
            self._resolve.release()
            self._resolve = None
        for obj in (*self._vaos.values(), self._tf_tex, self._pt_tex, self._fbo, getattr(self, "_fbo_color", None),
                    self._fbo_copy):
            if obj is not None:
                obj.release()
        self._vaos = {}
        self.programs.release()
        self._tf_tex = self._pt_tex = self._fbo = self._fbo_copy = self._fbo_color = self._default_fbo = None
        self._last_raw = None
        self._vao = self.program = None  # a second close() releases nothing twice

    def __enter__(self) -> "ClipRenderAction":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _uset(prog, name: str, value) -> None:
    """Set a uniform if this shader variant has it (a variant compiles unused ones away)."""
    u = prog.get(name, None)
    if u is not None:
        u.value = value


def premultiplied_to_uint8(prem: np.ndarray) -> np.ndarray:
    """``(h, w, 4)`` premultiplied float RGBA -> straight RGBA uint8 (colour 0 where the 8-bit alpha is 0,
    so a reader that ignores alpha sees black, not the transfer function's colour, where nothing is)."""
    a = np.clip(prem[..., 3], 0.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rgb = np.where(np.rint(a[..., None] * 255.0) > 0, prem[..., :3] / np.maximum(a[..., None], 1e-300), 0.0)
    out = np.concatenate([np.clip(rgb, 0.0, 1.0), a[..., None]], axis=-1)
    return np.rint(out * 255.0).astype(np.uint8)
