"""The per-brick draw path (``RenderParams.path="bricks"``): one proxy box per draw item.

One proxy box per :class:`~clipvol.scene.selection.DrawItem` into the float32 RGBA target (the
method of Bhaniramka & Demange's OpenGL Volumizer, and the reference the other paths fall back
to). Each box is drawn as one viewport-covering triangle restricted by the scissor test to the
box's screen rectangle (``shaders/screen.vert.glsl``: no inner triangle edges for a software
rasteriser to shade twice; the fragment, ``shaders/brick.frag.glsl``, finds its ray's interval in
the box itself and returns where there is none), so the camera may sit inside a box.

Between boxes composite mode uses the selection's exact visibility order in one of two equivalent
ways (the operator is associative). Default (``early_termination=True``): *front to back* (the
back-to-front list reversed) with the "under" operator ``(ONE_MINUS_DST_ALPHA, ONE)``; every
``len(items) / 32`` boxes the target is copied, and a box's fragment whose pixel is already opaque
in the copy returns at once. ``early_termination=False``: *back to front* with
``(ONE, ONE_MINUS_SRC_ALPHA)`` over the background, exactly as ``vzClipRenderAction``. MIP uses the
``MAX`` blend equation. On Mesa llvmpipe this path is faster than the single pass for a few large
boxes (``RenderParams.path="auto"`` picks it below ``AUTO_SINGLE_PASS_BOXES`` boxes).

References
----------
* P. Bhaniramka and Y. Demange, "OpenGL Volumizer: A Toolkit for High Quality Volume Rendering of
  Large Data Sets", SGI, 2002 (the clip render action, back-to-front bricks, budgets).
"""

from __future__ import annotations

import numpy as np

from ...scene.page_table import block_open_faces
from ..uniforms import uset, vec3
from ..modes import mode_of
from ..refine import MAX_REFINE_LEVELS
from .frame import DrawStats, FrameContext
from .setup import DrawPath, DrawSetup

__all__ = ["BricksPath", "OCCLUSION_PASSES", "OCCLUSION_MIN_BATCH"]

#: composite: an occlusion pass after every len(items) / OCCLUSION_PASSES boxes (at least this many)
OCCLUSION_PASSES = 32
OCCLUSION_MIN_BATCH = 1


class BricksPath(DrawPath):
    """Draw the cut box by box, in visibility order, blending into the shared target."""

    name = "bricks"

    def __init__(self, setup: DrawSetup) -> None:
        super().__init__(setup)
        self._copies: dict = {}  # the opacity snapshot for early termination across boxes, per image size
        self._clamps = (None, None)  # (items, their block_clamps) of the pass before, in a refined frame

    def _program(self, frame: FrameContext):
        """The brick shader variant of ``frame`` (compiled once per variant)."""

        def first_use(prog) -> None:
            uset(prog, "u_volume", 0)
            uset(prog, "u_tf", 1)
            uset(prog, "u_acc", 2)
            self.setup.loop_uniforms(prog)

        return self.setup.program("screen.vert", "brick.frag", frame.defines, first_use)

    def _ensure_copy(self, size: tuple[int, int]):
        """The snapshot texture of ``size`` (kept per size: a refined frame draws three sizes)."""
        copy = self._copies.get(size)
        if copy is None:
            if len(self._copies) > MAX_REFINE_LEVELS:  # a new image size: the old ones go
                self._release_copies()
            copy = self._copies[size] = self.ctx.texture(size, 4, dtype="f4")
            copy.filter = (self.mgl.NEAREST, self.mgl.NEAREST)
        return copy

    def _release_copies(self) -> None:
        for copy in self._copies.values():
            copy.release()
        self._copies = {}

    def draw(self, frame: FrameContext) -> DrawStats:
        mgl, ctx = self.mgl, self.ctx
        cam, items, params, pyr, cache = frame.camera, frame.items, frame.params, frame.pyramid, frame.cache
        mode = mode_of(params.mode)
        front_to_back = mode.ordered and params.early_termination  # under / over (iso: opaque hits)
        if front_to_back or mode.reduced:  # (render/modes)
            clear = mode.clear
        else:
            r, g, b, al = params.background
            clear = (r * al, g * al, b * al, al)
        fbo, previous, t0 = self.setup.begin(frame, clear)
        copy = self._ensure_copy(tuple(int(v) for v in fbo.size)) if front_to_back else None
        prog, vao = self._program(frame)
        origin = self.setup.frame_uniforms(prog, frame)
        ctx.enable(mgl.BLEND)
        ctx.disable(mgl.CULL_FACE)
        self.setup.depth_test(frame)  # on only in the fine pass of a refined frame
        uset(prog, "u_use_acc", False)  # no opacity snapshot until the first batch is drawn
        if not mode.set_blend(ctx, mgl):  # MIP MAX, minIP MIN, average ONE + ONE
            ctx.blend_equation = mgl.FUNC_ADD
            if front_to_back:  # the "under" operator: dst += (1 - dst.a) * src
                ctx.blend_func = mgl.ONE_MINUS_DST_ALPHA, mgl.ONE
            else:  # "over": dst = src + (1 - src.a) * dst
                ctx.blend_func = mgl.ONE, mgl.ONE_MINUS_SRC_ALPHA
        if mode.classifies:
            self.setup.tf_texture(frame).use(location=1)
        self.setup.bind_distribution(prog, frame)
        self.setup.bind_occupancy(prog, frame)
        if params.overlays:  # co-registered volumes sampled at each sample (render/overlay_binding.py)
            frame.overlays.bind(prog, params.overlays, origin, frame.level_ratios)
        B = np.asarray(pyr.brick_shape, dtype=np.float64)
        clamps = self._frame_clamps(frame)
        rects = self.setup.scissor_rects(cam, [it.lo for it in items], [it.hi for it in items]) if items else None
        bound_level = None
        n_items = len(items)
        order = range(n_items - 1, -1, -1) if front_to_back else range(n_items)
        batch = max(OCCLUSION_MIN_BATCH, -(-n_items // OCCLUSION_PASSES))
        occlusion_passes = 0
        for count, i in enumerate(order):
            if front_to_back and count and count % batch == 0:
                self._occlusion_pass(prog, fbo, copy)
                occlusion_passes += 1
            it = items[i]
            L = it.level
            tex = cache.textures[L]
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
                win = np.asarray(cache.windows[L], dtype=np.int64)
                prog["u_delta"].value = params.step * float(min(lv.scale))
                uset(prog, "u_tf_row", (L + 0.5) / pyr.num_levels)
                prog["u_inv_scale"].value = vec3(1.0 / scale)
                uset(prog, "u_inv_tex_size", vec3(1.0 / (win[::-1] * B[::-1])))
                if frame.skipped_empty:
                    occ_size, occ_z0 = self.setup.occupancy_uniforms(frame, L)
                    uset(prog, "u_occ_size", occ_size)
                    uset(prog, "u_occ_z0", occ_z0)
                bound_level = L
            bidx = np.asarray(it.index, dtype=np.int64)
            first = trans + bidx[::-1] * B[::-1] * scale
            prog["u_box_lo"].value = vec3(lo - origin)
            prog["u_box_hi"].value = vec3(hi - origin)
            prog["u_o_minus_b"].value = vec3(origin - first)
            prog["u_slot_origin"].value = vec3(((bidx % win) * B)[::-1])
            clo, chi = clamps[i]
            prog["u_clamp_lo"].value = vec3(clo)
            prog["u_clamp_hi"].value = vec3(chi)
            ctx.scissor = tuple(rects[i])
            vao.render(mgl.TRIANGLES, vertices=3)
        ctx.scissor = None
        return self.setup.read_back(frame, previous, front_to_back, t0, boxes_drawn=n_items, program=prog,
                                    occlusion_passes=occlusion_passes)

    def _frame_clamps(self, frame: FrameContext) -> list:
        """:meth:`block_clamps` of the frame's items, computed once per frame: the passes of a
        refined frame draw the same list with the same residency, so the passes after its first
        reuse them."""
        items = frame.items
        if not (frame.repeats_pass and self._clamps[0] is items):
            self._clamps = (items, self.block_clamps(items, frame.pyramid, frame.cache))
        return self._clamps[1]

    @staticmethod
    def block_clamps(items, pyr, cache) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per item, the ``(lo, hi)`` clamp of its sampling in item-local voxels (``(x, y, z)``).

        An item covers ``span`` bricks per axis (clipped to the grid). A face of the item may be
        sampled across (half a voxel beyond its last texels, trilinear filtering reading the
        neighbour) only if that face is open for every brick on it (see
        :meth:`GpuBrickCache.open_faces`); otherwise sampling clamps to the item's own texels.
        ``pyr``: the pyramid, ``cache``: the GPU brick cache the items are resident in.
        """
        B = np.asarray(pyr.brick_shape, dtype=np.int64)
        by_level: dict[int, list[int]] = {}
        for i, it in enumerate(items):
            by_level.setdefault(it.level, []).append(i)
        out: list = [None] * len(items)
        for L, rows in by_level.items():
            first = np.array([items[i].index for i in rows], dtype=np.int64)
            span = np.array([items[i].span for i in rows], dtype=np.int64)
            cnt = np.minimum(first + span[:, None], np.asarray(pyr.grid(L), dtype=np.int64)) - first
            of = block_open_faces(cache.open_faces, L, first, cnt)  # (n, 3 zyx, 2 sides)
            ext = (cnt * B).astype(np.float64)
            lo = np.where(of[:, :, 0], -0.5, 0.0)
            hi = np.where(of[:, :, 1], ext - 0.5, ext - 1.0)
            for j, i in enumerate(rows):
                out[i] = (lo[j][::-1], hi[j][::-1])
        return out

    def _occlusion_pass(self, prog, fbo, copy) -> None:
        """Snapshot the target for the boxes' opacity test (early ray termination across boxes)."""
        self.ctx.scissor = None  # a blit obeys the scissor test: copy the whole target
        self.ctx.copy_framebuffer(copy, fbo)
        copy.use(location=2)
        uset(prog, "u_use_acc", True)

    def release(self) -> None:
        self._release_copies()
        self._clamps = (None, None)
