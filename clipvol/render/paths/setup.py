"""What every draw path of the clip render action shares: one target, one colour table, one set-up.

A draw path (:mod:`clipvol.render.paths`) turns the frame's cut - a list of
:class:`~clipvol.scene.selection.DrawItem` - into an image. Whatever it does in between, every path
starts and ends the same way, and doing that in one place is what keeps the paths' images
bit-identical where they should be (the same ray, the same samples, the same rounding):

* **the target** - one RGBA float32 :class:`~clipvol.render.target.FloatTarget` the size of the
  image (premultiplied colour, not quantised before the end), cleared for the mode;
* **the per-frame uniforms** (:meth:`DrawSetup.frame_uniforms`) - the camera basis from which each
  fragment rebuilds its ray, the transfer function's window folded with the texel format, the
  :class:`~clipvol.scene.geometry.Shape`'s box and planes, all relative to the eye in float64;
* **the per-level corrected colour table** (:meth:`DrawSetup.tf_texture`) - row ``L`` holds the
  transfer function with its opacity corrected for level ``L``'s step, ``1 - exp(r * log1p(-a))``
  in float64 on the CPU, rebuilt only when the table or the step changes (LaMar, Hamann & Joy);
* **the empty-space cells** (:meth:`DrawSetup.bind_occupancy`) for ``EMPTY_SKIP`` variants;
* **the passes of a refined frame** (``FrameContext.refine_level``, :mod:`clipvol.render.refine`):
  a coarse pass draws into a target of its own with the image's rays through its pixels; every
  finer pass begins with the mask from the pass before (smooth pixels blended, their depth set)
  and draws under the depth test (:meth:`DrawSetup.depth_test`), so the rasteriser never shades
  the smooth pixels;
* **the read-back** (:meth:`DrawSetup.read_back`) - composite through the GL resolve pass
  (:class:`~clipvol.render.resolve.Resolve`), MIP by mapping the maximum through the transfer
  function here - and giving the previous framebuffer binding back.

:class:`DrawPath` is the base a path derives from: it holds this set-up, and each call of its
:meth:`~DrawPath.draw` is handed the frame's :class:`~clipvol.render.paths.frame.FrameContext`
(the cut, the parameters, the GPU cache, ...) and returns a
:class:`~clipvol.render.paths.frame.DrawStats`; the set-up's methods read the same context.

References
----------
* E. LaMar, B. Hamann and K. I. Joy, "Multiresolution Techniques for Interactive Texture-Based
  Volume Visualization", IEEE Visualization 1999 (spherical shells, opacity correction per level).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ...errors import ParameterError
from ...scene.selection.cut import DrawItems
from ...scene import consistent
from ...scene.consistent import SPREAD_MAX, distribution_tables
from ...scene.transfer import corrected_tables
from ...scene.visibility import box_depths, screen_rects
from ..glsl import ProgramCache
from ..gpu_cache import t_scale_offset
from ..modes import depth_range, mode_of
from ..refine import Refine, pass_origin
from ..resolve import Resolve
from ..target import FloatTarget
from ..uniforms import uset, vec3
from .frame import DrawStats, FrameContext

__all__ = ["DrawPath", "DrawSetup", "MAX_STEPS_PER_BOX", "samples_bound", "OPAQUE", "OCCUPANCY_UNIT", "MIP_EMPTY",
           "scissor_boxes", "samples_per_box", "max_step", "check_step", "check_samples", "premultiplied_to_uint8"]

#: most samples one ray takes inside one box (a smaller step is refused with ParameterError)
MAX_STEPS_PER_BOX = 1 << 16
#: distribution tables kept per draw set-up (:meth:`DrawSetup.dist_texture`)
DIST_TABLES_KEPT = 4
#: the cleared value of a MIP target: below every texel, so "nothing hit" is told apart on read-back
MIP_EMPTY = -3.0e38
#: accumulated opacity at which a ray stops early: 1 - 0.5 / 255. What the rest of the ray could
#: still add to a premultiplied channel is at most its transmittance, under half a step of the
#: 8-bit image, so the image the caller gets differs from the ray integrated to its end by at most
#: one level after rounding (tools/bench/bench_render.py measures the samples this saves).
OPAQUE = 1.0 - 0.5 / 255.0
#: texture unit of the empty-space cells (after the single pass's 3 + 16 level textures)
OCCUPANCY_UNIT = 20
#: texture unit of the distribution table (consistent coarse levels, DISTRIB variants)
DIST_UNIT = 21


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


def samples_per_box(cam, items, pyramid, step: float) -> float:
    """Upper bound of the samples one ray takes inside one of ``items`` (10 % margin)."""
    if not len(items):
        return 0.0
    arr = DrawItems.from_items(items)
    ext = arr.hi - arr.lo  # (n, 3)
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
    # each box's longest path over the sampled directions, once per distinct extent (a cut's boxes
    # share a handful of extents)
    shapes, inv = np.unique(ext, axis=0, return_inverse=True)
    with np.errstate(divide="ignore"):
        path = np.min(shapes[:, None, :] / np.abs(dirs[None, :, :]), axis=2).max(axis=1)[inv.reshape(-1)]  # (n,)
    return float(np.max(path / _sample_delta(arr, pyramid, step))) * 1.1


def samples_bound(items, pyramid, step: float) -> float:
    """:func:`samples_per_box`'s bound for every camera: no ray's path in a box is longer than its
    diagonal (10 % margin). Where it passes, a check made of it holds whatever the camera."""
    if not len(items):
        return 0.0
    arr = DrawItems.from_items(items)
    return float(np.max(np.linalg.norm(arr.hi - arr.lo, axis=1) / _sample_delta(arr, pyramid, step))) * 1.1


def _sample_delta(arr: DrawItems, pyramid, step: float) -> np.ndarray:
    """``(n,)`` the sample spacing in each item's level (``step`` voxels of it)."""
    return step * float(min(pyramid.spacing)) * 2.0 ** arr.rows[:, 0].astype(np.float64)


def max_step(pyramid) -> float:
    """The longest ``step`` (in units of the smallest voxel, as ``RenderParams.step``) a frame of
    ``pyramid`` may use: a brick's longest edge in world units. A longer step lets a ray cross a
    brick without one sample whatever its direction, so whole bricks vanish from the image
    (``--step 1e9`` drew a transparent frame). Why the longest edge in world units and not a count
    of voxels: the step is measured in the smallest voxel, and along the coarse axis of an
    anisotropic volume (spacing 1e3 beside 1e-3) a right step is 1e5 of those."""
    sp = np.asarray(pyramid.spacing, dtype=np.float64)
    return float(np.max(np.asarray(pyramid.brick_shape, dtype=np.float64) * sp) / np.min(sp))


def check_step(pyramid, step: float) -> None:
    """Refuse (ParameterError naming ``step`` and its range) a step longer than :func:`max_step`."""
    top = max_step(pyramid)
    if step > top:
        raise ParameterError(f"step: expected a number in (0, {top:g}] of the smallest voxel (at most a brick's "
                             f"longest edge: a longer step crosses bricks without a sample and leaves them out of the "
                             f"image), got {step:g}")


def check_samples(cam, items, pyramid, step: float) -> None:
    """Refuse (ParameterError naming ``step``) a frame whose rays would need more than
    :data:`MAX_STEPS_PER_BOX` samples inside one box, instead of cutting them short, or whose step
    is longer than a brick edge (:func:`max_step`), instead of skipping bricks."""
    check_step(pyramid, step)
    worst = samples_per_box(cam, items, pyramid, step)
    if worst > MAX_STEPS_PER_BOX:
        raise ParameterError(
            f"step: expected at most {MAX_STEPS_PER_BOX} samples per ray and brick, got about {worst:.3g} with "
            f"step {step} of the smallest voxel (spacing {pyramid.spacing}) for this view; use step >= "
            f"{step * worst / MAX_STEPS_PER_BOX:.3g}"
        )


def premultiplied_to_uint8(prem: np.ndarray) -> np.ndarray:
    """``(h, w, 4)`` premultiplied float RGBA -> straight RGBA uint8 (colour 0 where the 8-bit alpha is 0,
    so a reader that ignores alpha sees black, not the transfer function's colour, where nothing is)."""
    a = np.clip(prem[..., 3], 0.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rgb = np.where(np.rint(a[..., None] * 255.0) > 0, prem[..., :3] / np.maximum(a[..., None], 1e-300), 0.0)
    out = np.concatenate([np.clip(rgb, 0.0, 1.0), a[..., None]], axis=-1)
    return np.rint(out * 255.0).astype(np.uint8)


class DrawSetup:
    """The GL objects and the set-up every draw path of one action shares (see the module docstring).

    The set-up holds what lasts across frames - the target, the colour tables, the compiled
    programs with their (attribute-less) vertex arrays and the resolve pass - for the GL context
    ``ctx``; what a frame draws with (parameters, GPU cache, pyramid, the pass of a refined frame)
    is the :class:`~clipvol.render.paths.frame.FrameContext` each method is given.
    """

    def __init__(self, ctx) -> None:
        import moderngl

        self.mgl = moderngl
        self.ctx = ctx
        self.programs = ProgramCache(self.ctx)
        self.target = FloatTarget(self.ctx, depth=True)  # depth: the mask of a refined frame
        self._vaos: dict = {}
        self._tf_tex = None
        self._tf_key = None
        #: distribution tables by (table, step, model), the few most recent: a refined frame's passes and
        #: the report's paired frames alternate steps, and each table costs 0.1-0.25 s to build
        self._dist_texs: dict = {}
        self._resolve = None
        self.last_raw: np.ndarray | None = None  # MIP, minIP, average, iso: the target read back by the last frame
        self._depth_of: tuple | None = None  # (camera, box lo, box hi) of this frame: what depth reads
        self.refine: Refine | None = None  # the coarse targets and the mask pass, made by the first refined frame
        self.origin = (0, 0)  # where this pass's viewport starts in its target (refine.pass_origin)

    def program(self, vertex: str, fragment: str, defines: dict, first_use=None):
        """The variant ``(program, vertex array)`` (compiled once per variant); ``first_use(prog)``
        sets its constant uniforms when it is new."""
        prog = self.programs.get(vertex, fragment, defines)
        if prog not in self._vaos:
            self._vaos[prog] = self.ctx.vertex_array(prog, [])
            if first_use is not None:
                first_use(prog)
        return prog, self._vaos[prog]

    @staticmethod
    def loop_uniforms(prog) -> None:
        """The ray loop's limits: :data:`MAX_STEPS_PER_BOX` and the opacity :data:`OPAQUE` that ends a ray."""
        uset(prog, "u_max_steps", MAX_STEPS_PER_BOX)
        uset(prog, "u_opaque", OPAQUE)

    def begin(self, frame: FrameContext, clear: tuple[float, float, float, float]):
        """Bind the target at the size of ``frame``'s camera, cleared to ``clear``; returns
        ``(fbo, previous, t0)`` (``previous``: the binding :meth:`read_back` gives back; ``t0``:
        when drawing began). In a refined frame's coarse pass the target is the pass's own, and in
        its later passes the pixels the pass before left smooth are masked."""
        ctx = self.ctx
        t0 = time.perf_counter()
        w, h = (int(v) for v in frame.camera.size)
        k = frame.refine_level
        if k is not None and self.refine is None:
            self.refine = Refine(ctx)
        target = self.refine.target(k) if k else self.target
        self.origin = pass_origin((w, h)) if k else (0, 0)  # a coarse pass spread over the tiles
        ox, oy = self.origin
        fbo = target.ensure((ox + w, oy + h))
        previous = ctx.fbo
        fbo.use()
        ctx.viewport = (ox, oy, w, h)
        fbo.clear(*clear)  # (depth to 1: nothing masked)
        if frame.repeats_pass:  # a finer pass: the smooth pixels come from the coarser one (where the volume is)
            rect = self.scissor_rects(frame.camera, *frame.pyramid.volume_box())[0]
            self.refine.mask(fbo, frame.image_camera, k, frame.params.refine_tolerance, self.origin, rect)
        return fbo, previous, t0

    def scissor_rects(self, cam, lo, hi) -> np.ndarray:
        """:func:`scissor_boxes` of this pass, placed where its viewport starts in the target."""
        rects = scissor_boxes(cam, lo, hi)
        rects[:, :2] += np.asarray(self.origin, dtype=np.int64)
        return rects

    def depth_test(self, frame: FrameContext) -> None:
        """Set the depth test for a draw path's passes: off, except in a masked pass of a refined
        frame, where fragments (depth 0.5) pass only where the mask left the depth at 1."""
        if frame.repeats_pass:
            self.ctx.enable(self.mgl.DEPTH_TEST)
            self.ctx.depth_func = "<="
        else:
            self.ctx.disable(self.mgl.DEPTH_TEST)

    def frame_uniforms(self, prog, frame: FrameContext) -> np.ndarray:
        """Set per-frame uniforms; returns the origin ``O`` (float64) the box uniforms are relative to."""
        cam, tf, pyr, fmt = frame.camera, frame.tf, frame.pyramid, frame.cache.format
        V = cam.view_matrix()
        R = V[:3, :3]
        origin = -R.T @ V[:3, 3]
        prog["u_right"].value = vec3(cam.right)
        prog["u_up"].value = vec3(cam.up)
        w, h = cam.size
        if cam.orthographic:
            prog["u_half"].value = (float(cam.width) / 2.0, float(cam.height) / 2.0)
        else:
            ty = math.tan(math.radians(float(cam.fov_y)) / 2.0)
            prog["u_half"].value = (ty * w / h, ty)
        prog["u_viewport"].value = (float(w), float(h))
        uset(prog, "u_frag_origin", tuple(float(v) for v in self.origin))
        prog["u_ortho"].value = bool(cam.orthographic)
        prog["u_forward"].value = vec3(cam.forward)
        prog["u_center_rel"].value = vec3(np.asarray(cam.center, dtype=np.float64) - origin)
        # t = (raw - lo) / (hi - lo) with raw = a * texel + b, folded in float64
        scale, offset = t_scale_offset(fmt, tf.window(pyr.value_range))
        uset(prog, "u_t_scale", float(np.clip(scale, -3e38, 3e38)))
        uset(prog, "u_t_offset", float(np.clip(offset, -3e38, 3e38)))
        p = frame.params
        uset(prog, "u_jitter", 1.0 if p.jitter else 0.0)
        uset(prog, "u_light", (p.ambient, p.diffuse, p.specular, p.shininess))  # SHADING variant only
        mode_of(p.mode).uniforms(prog, fmt, p)  # iso: u_iso
        self._depth_of = (cam, *pyr.volume_box())  # iso_color="depth" (render/modes): see depth
        if p.shape is None:
            box = np.array([[-1e30] * 3, [1e30] * 3])
            planes = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (6, 1))
            n_planes, has_box = 0, False
        else:
            box, planes, n_planes = p.shape.box_and_planes_arrays()
            has_box = p.shape.box is not None
            box = np.asarray(box, dtype=np.float64)
            planes = np.array(planes, dtype=np.float64)
        finite = np.abs(box) < 1e29
        box = np.where(finite, box - origin, box)
        planes[:, 3] += planes[:, :3] @ origin  # n.(p' + O) + d = n.p' + (d + n.O)
        if frame.refine_level:  # a coarse pass: the image's rays through its pixels
            self.refine.coarse_uniforms(prog, frame.image_camera, frame.refine_level)
        prog["u_shape_lo"].value = vec3(box[0])
        prog["u_shape_hi"].value = vec3(box[1])
        prog["u_planes"].write(planes.astype(np.float32).tobytes())
        prog["u_n_planes"].value = int(n_planes)
        prog["u_has_box"].value = bool(has_box)
        return origin

    @property
    def depth(self) -> tuple[float, float]:
        """The volume box's range of ray parameters this frame (``iso_color="depth"`` spans its
        colours over it; ``(0, 1)`` before a frame): worked out when read, since only a mapped
        mode's read-back reads it and its numpy costs a still composite frame ~0.1-0.3 ms."""
        if self._depth_of is None:
            return (0.0, 1.0)
        return depth_range(*self._depth_of)

    def tf_texture(self, frame: FrameContext):
        """The per-level corrected colour table of ``frame``'s transfer function (row ``L``: opacity
        corrected for level ``L``'s step), rebuilt only when the table or the step changes."""
        table = np.ascontiguousarray(np.asarray(frame.tf.table, dtype=np.float32))
        key = (table.shape, table.tobytes(), frame.params.step)
        if self._tf_key != key:
            if self._tf_tex is not None:
                self._tf_tex.release()
            rows = corrected_tables(table, frame.level_ratios)
            tex = self.ctx.texture((rows.shape[1], len(rows)), 4, rows.astype(np.float32).tobytes(), dtype="f4")
            tex.filter = (self.mgl.LINEAR, self.mgl.LINEAR)
            tex.repeat_x = tex.repeat_y = False
            self._tf_tex, self._tf_key = tex, key
        return self._tf_tex

    def dist_texture(self, frame: FrameContext):
        """The per-level tables of ``frame``'s transfer function pre-integrated over each spread row
        (:func:`distribution_tables`), levels stacked along y, :data:`SPREAD_ROWS` rows each; rebuilt
        only when the table or the step changes."""
        table = np.ascontiguousarray(np.asarray(frame.tf.table, dtype=np.float32))
        key = (table.shape, table.tobytes(), frame.params.step, consistent.MODEL)
        tex = self._dist_texs.pop(key, None)
        if tex is None:
            rows = distribution_tables(table, frame.level_ratios)  # (levels, rows, n, 4)
            L, R, n, _ = rows.shape
            tex = self.ctx.texture((n, L * R), 4, rows.reshape(L * R, n, 4).astype(np.float32).tobytes(), dtype="f4")
            tex.filter = (self.mgl.LINEAR, self.mgl.LINEAR)
            tex.repeat_x = tex.repeat_y = False
            while len(self._dist_texs) >= DIST_TABLES_KEPT:
                self._dist_texs.pop(next(iter(self._dist_texs))).release()  # the least recently used
        self._dist_texs[key] = tex  # most recent last
        return tex

    def bind_distribution(self, prog, frame: FrameContext) -> None:
        """Bind the distribution table and its uniforms (DISTRIB variants only) to :data:`DIST_UNIT`."""
        if not frame.distribution:
            return
        tex = self.dist_texture(frame)
        tex.use(location=DIST_UNIT)
        uset(prog, "u_dist", DIST_UNIT)
        uset(prog, "u_dist_inv_h", 1.0 / tex.size[1])
        scale, _ = t_scale_offset(frame.cache.format, frame.tf.window(frame.pyramid.value_range))
        uset(prog, "u_sigma_scale", float(min(abs(scale) / SPREAD_MAX, 3e38)))

    def bind_occupancy(self, prog, frame: FrameContext) -> None:
        """Bind the cache's cell flags for the frame's transfer function
        (:meth:`GpuBrickCache.occupancy_texture`) to :data:`OCCUPANCY_UNIT` (EMPTY_SKIP variants
        only: when the frame leaps)."""
        if frame.skipped_empty:
            vr, cache = frame.pyramid.value_range, frame.cache
            tf = mode_of(frame.params.mode).occupancy_tf(frame.params, frame.tf, vr)  # iso: what lies below its value
            cache.occupancy_texture(tf, vr, frame.distribution).use(location=OCCUPANCY_UNIT)
            uset(prog, "u_occ", OCCUPANCY_UNIT)
            uset(prog, "u_occ_shift", vec3(0.5 / np.asarray(cache.cell_edges[::-1], dtype=np.float64)))

    @staticmethod
    def occupancy_uniforms(frame: FrameContext, level: int) -> tuple[tuple[float, float, float], float]:
        """Cells per axis ``(x, y, z)`` of ``level`` in the occupancy texture, and its first z there."""
        lv = frame.cache.occupancy_levels[level]
        if lv is None:
            return (1.0, 1.0, 1.0), 0.0
        return vec3(lv[0]), float(lv[1])

    def read_back(self, frame: FrameContext, previous, front_to_back: bool, t0: float, **drawn) -> DrawStats:
        """Finish the frame, turn the target into the 8-bit image and give the previous framebuffer
        back; returns the :class:`~clipvol.render.paths.frame.DrawStats` of the image, its draw and
        read-back seconds and ``drawn`` (the path's counts: ``boxes_drawn=``, ``program=``, ...).
        Composite: on the GL (:class:`~clipvol.render.resolve.Resolve`: the background under a
        front-to-back image, un-premultiplied, rounded), reading 4 bytes a pixel; MIP, minIP,
        average, iso: the float target read back and mapped here
        (:meth:`clipvol.render.modes.base.DrawMode.read_back`)."""
        ctx = self.ctx
        params, pyr, tf = frame.params, frame.pyramid, frame.tf
        if frame.refine_level:  # a coarse image stays on the GL for the next pass's mask
            self.target.restore(previous)
            return DrawStats(None, time.perf_counter() - t0, 0.0, **drawn)
        t_finish = time.perf_counter()
        ctx.finish()
        t1 = time.perf_counter()
        finish_s = t1 - t_finish  # the wait on the GL for the frame's draws (FrameStats' gpu time)
        self.last_raw = None
        image = None
        mode = mode_of(params.mode)
        if not mode.reduced:
            if self._resolve is None:
                self._resolve = Resolve(ctx)
            image = self._resolve(self.target.color, params.background if front_to_back else (0.0, 0.0, 0.0, 0.0))
        else:
            self.last_raw = self.target.read()
        # give the binding back (a released framebuffer left bound breaks later framebuffers)
        self.target.restore(previous)
        err = ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error after drawing the frame: expected GL_NO_ERROR, got {err}")
        if image is None:  # MIP, minIP, average, iso: the per-pixel values mapped here (render/modes)
            image = premultiplied_to_uint8(mode.read_back(self.last_raw, params, tf, frame.cache.format,
                                                          pyr.value_range, self.depth))
        return DrawStats(image, t1 - t0, time.perf_counter() - t1, finish_s=finish_s, **drawn)

    def raw(self) -> np.ndarray | None:
        """The float target of the last frame, rows top first (read now if the frame did not), or None."""
        if self.last_raw is None and self.target.fbo is not None:
            self.last_raw = self.target.read()
        return self.last_raw

    def release(self) -> None:
        """Release the programs, vertex arrays, target, colour table and resolve pass."""
        if self._resolve is not None:
            self._resolve.release()
            self._resolve = None
        if self.refine is not None:
            self.refine.release()
            self.refine = None
        for obj in (*self._vaos.values(), self._tf_tex, *self._dist_texs.values()):
            if obj is not None:
                obj.release()
        self._vaos = {}
        self.target.release()
        self.programs.release()
        self._tf_tex = self._tf_key = None
        self._dist_texs = {}
        self.last_raw = None


class DrawPath:
    """Base of a draw path: :meth:`draw` fills the shared target from a frame's cut.

    A path is made once per action with the action's :class:`DrawSetup` (the GL objects every
    path shares) and keeps GL objects of its own between frames, released in :meth:`release`. It
    never sees the action: a frame's whole input is the
    :class:`~clipvol.render.paths.frame.FrameContext` handed to :meth:`draw`, and what it drew
    (boxes, page-table nodes, occlusion passes, the program) is the
    :class:`~clipvol.render.paths.frame.DrawStats` it returns, which the action folds into the
    frame's statistics. Register a new one in :mod:`clipvol.render.paths`.
    """

    #: the name ``RenderParams.path`` gives it
    name: str = ""
    #: does the path draw ``frame.items`` in the order given (the selection's visibility order, which
    #: the action restores for a cut drawn again from another camera)? False: any order will do
    wants_order: bool = True

    def __init__(self, setup: DrawSetup) -> None:
        self.setup = setup
        self.ctx = setup.ctx
        self.mgl = setup.mgl

    def draw(self, frame: FrameContext) -> DrawStats | None:
        """Draw ``frame``'s cut into the shared target and read it back (:meth:`DrawSetup.read_back`);
        None when this path cannot draw this cut (the action then draws it with the per-brick path,
        the reference)."""
        raise NotImplementedError

    def release(self) -> None:
        """Release the path's own GL objects (the shared set-up is the action's)."""
