"""Adaptive image sampling: rays at 1/4 and 1/2 resolution where the image is smooth, one per pixel elsewhere.

Why
---
A ray caster's frame costs one ray per pixel, and on a scan most pixels lie where the image
changes slowly: air around the head, the smooth shading of skin or bone. Levoy cast rays sparsely
and refined only where neighbouring colours differ ("Volume rendering by adaptive refinement", The
Visual Computer 6(1), 1990). With ``RenderParams.refine_tolerance`` above 0 the render action
draws a composite frame in passes of rising resolution, all through the same draw path and the
same selection:

1. **coarse** - the cut drawn at 1/4 of the image's resolution (``ceil(w / 4) x ceil(h / 4)``
   rays; :data:`MAX_REFINE_LEVELS`, fewer for small images, :func:`refine_levels`) into a float
   target of its own (a pass within one rasteriser tile drawn across four, :func:`pass_origin`).
   Pass ``k``'s ray ``(i, j)`` is the image's ray through the point
   ``((i + 1/2) 2**k, (j + 1/2) 2**k)``, halfway between pixels ``2i`` and ``2i + 1`` of pass
   ``k - 1``, so the four rays of pass ``k`` around any pixel of pass ``k - 1`` are the corners of
   a cell it lies in;
2. **mask** - each finer pass (1/2, then the image) begins with one full-screen pass
   (``shaders/refine_mask.frag.glsl``): where the four coarser rays around a pixel agree to within
   the tolerance in every premultiplied RGBA channel, the pixel becomes their bilinear blend and
   its depth 0;
3. **rays** - then the cut is drawn at that resolution under the depth test: the rasteriser
   rejects the masked pixels before their fragments are shaded (a fragment that returns at once
   still costs Mesa llvmpipe about a third of a ray), so rays are cast only where the coarser
   image changes. The image's pass ends as any frame (resolve, read-back, ``last_raw``);
4. **compaction** - a masked pass's rays are few and scattered along the edges, and a SIMD
   rasteriser shades fragments in blocks (Mesa llvmpipe: 8 lanes of a 4 x 4 block, every lane
   running until the block's longest ray ends), so a block with one live pixel costs as much as
   a block of eight: measured on the MNI template at 256², the masked passes cost 10-17 µs per
   ray cast against 5 µs in a full-resolution frame. :class:`Compaction` reads the mask's depth
   back, lists the live pixels block by block (:func:`compact_order`), packs them densely into
   a compact target (:func:`compact_texels`) whose fragment ``(i, j)`` casts the ray of the
   pixel the list holds there (the ``COMPACT`` shader variant reads it from a texture instead
   of ``gl_FragCoord``: the same ray, bit for bit), and scatters the colours back as points.
   Used where :data:`COMPACT` is on (off by default: measured, it lowers the rays' GL time but
   not the frame's), the draw path draws at most :data:`COMPACT_MAX_BOXES` boxes (each box of a
   compacted pass runs over every live pixel: a scissor rectangle has no meaning there) and the
   image has at most :data:`COMPACT_MAX_PIXELS` pixels (:func:`compacts`); the images are those
   of the masked passes drawn in place.

Edges, silhouettes and fine texture keep their full-resolution rays. What is lost is what no coarse
ray sees: a feature thinner than the coarse rays' spacing (four pixels at the coarsest) lying
between four rays that agree. That error is
measured (``clipvol report``, ``tools/bench/bench_mission.py``: % of pixels with CIELUV ΔE >= 6
against the full-resolution frame), not bounded. MIP, minIP, average and iso frames draw every
pixel (their targets hold values mapped after the pass, not colours a blend can stand for).

References
----------
* M. Levoy, "Volume rendering by adaptive refinement", The Visual Computer 6(1), 1990.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .glsl import shader_source
from .modes import mode_of
from .target import FloatTarget
from .uniforms import uset

__all__ = ["Refine", "Compaction", "MIN_REFINE_EDGE", "MAX_REFINE_LEVELS", "TILE", "COMPACT", "COMPACT_WIDTH",
           "COMPACT_MAX_BOXES", "COMPACT_MAX_PIXELS", "COMPACT_UNIT", "compact_order", "compact_texels", "compacts",
           "pass_origin", "refine_levels", "refines"]

#: the coarsest pass of a refined frame has at least this many pixels each way
MIN_REFINE_EDGE = 8
#: coarse passes at most (1 / 2 and 1 / 4 of the image's resolution)
MAX_REFINE_LEVELS = 2
#: Mesa llvmpipe bins a frame into tiles of this many pixels a side and shades each tile on one
#: thread: a coarse pass that fits one tile is drawn across four (:func:`pass_origin`)
TILE = 64
#: draw the masked passes of a refined frame compacted (:class:`Compaction`; False, the default: in
#: place). Off because it did not make frames faster: on Mesa llvmpipe at 256² it cuts the GL time
#: of the masked passes' rays 1.2-2.9×, but the depth read-back that lists the pixels stops the
#: pipeline twice a frame, and the frame times compacted and in place were within the pairing
#: noise (docs/benchmarks.md, "The 256² overviews: where a refined frame's time goes"); on a GPU
#: the read-back costs more. A list built on the GL (a prefix sum) would remove the read-back.
COMPACT = False
#: the compact target's width: four rasteriser tiles, so that a pass of a few thousand rays is
#: shaded by several threads
COMPACT_WIDTH = 4 * TILE
#: a pass is compacted only when its draw path draws at most this many boxes
COMPACT_MAX_BOXES = 4
#: ... and its image has at most this many pixels: on the MNI template at 512² the compacted passes
#: were slower than in place on the close view (the list built on the host from the read-back mask
#: grows with the image, and the rays along its edges already fill the rasteriser's blocks), at
#: 256² faster on the overviews (docs/benchmarks.md, "The benchmark that decides")
COMPACT_MAX_PIXELS = 256 * 256
#: the texture unit of the compact list's pixel coordinates (after the single pass's 3 + 16 level
#: textures, the empty-space cells' 20 and the distribution table's 21)
COMPACT_UNIT = 22
#: the side of the blocks the live pixels are listed and packed by
COMPACT_BLOCK = 4


def refine_levels(camera) -> int:
    """The coarse passes of a refined frame for ``camera``: up to :data:`MAX_REFINE_LEVELS`, the
    coarsest at least :data:`MIN_REFINE_EDGE` pixels each way (0: the image is too small)."""
    edge = min(int(v) for v in camera.size)
    k = 0
    while k < MAX_REFINE_LEVELS and -(-edge // 2 ** (k + 1)) >= MIN_REFINE_EDGE:
        k += 1
    return k


def pass_origin(size) -> tuple[int, int]:
    """Where in its target a coarse pass of ``size`` (w, h) pixels is drawn: about the corner shared
    by four :data:`TILE` tiles when it fits in one (so that four of the rasteriser's threads share
    it: at the origin a 64 x 64 pass takes one thread 9-11 ms, as long as the 128 x 128 pass above it),
    else at the origin."""
    w, h = (int(v) for v in size)
    if w > TILE or h > TILE:
        return 0, 0
    return TILE - w // 2, TILE - h // 2


def compact_order(live: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``(x, y)`` indices of the true pixels of ``live`` (``(h, w)`` bool, row ``y``), listed block
    by block (blocks of :data:`COMPACT_BLOCK` pixels a side, row by row; inside a block row by row),
    so that neighbouring entries are neighbouring pixels, whose rays are alike in length and read
    the same texels."""
    B = COMPACT_BLOCK
    h, w = live.shape
    H, W = -(-h // B) * B, -(-w // B) * B
    pad = np.zeros((H, W), dtype=bool)
    pad[:h, :w] = live
    by, bx, iy, ix = np.nonzero(pad.reshape(H // B, B, W // B, B).transpose(0, 2, 1, 3))
    return (bx * B + ix).astype(np.int64), (by * B + iy).astype(np.int64)


def compact_texels(n: int, width: int = COMPACT_WIDTH) -> tuple[np.ndarray, np.ndarray]:
    """The ``(x, y)`` texels of the compact target that entries ``0 .. n-1`` of the list take: blocks of
    16 entries as 4 x 4 texels, ``width / 4`` blocks a row (``shaders/compact_scatter.vert.glsl``
    computes the same from the entry's index)."""
    i = np.arange(int(n), dtype=np.int64)
    b, j = np.divmod(i, COMPACT_BLOCK * COMPACT_BLOCK)
    per_row = int(width) // COMPACT_BLOCK
    return (b % per_row) * COMPACT_BLOCK + j % COMPACT_BLOCK, (b // per_row) * COMPACT_BLOCK + j // COMPACT_BLOCK


def compacts(camera, boxes: int, single_pass: bool) -> bool:
    """Are the masked passes of a refined frame seen by ``camera`` drawn compacted, their draw path
    drawing ``boxes`` boxes (the single pass: one triangle, whatever its page table)?"""
    w, h = (int(v) for v in camera.size)
    return COMPACT and w * h <= COMPACT_MAX_PIXELS and (single_pass or boxes <= COMPACT_MAX_BOXES)


def refines(params, camera) -> bool:
    """Does a frame with ``params`` seen by ``camera`` draw refined (composite, a tolerance above 0,
    an image large enough for a coarse pass, :func:`refine_levels`)?"""
    return params.refine_tolerance > 0.0 and mode_of(params.mode).classifies and refine_levels(camera) > 0


class Compaction:
    """A masked pass drawn compacted: its live pixels listed and packed into a compact target, their
    rays cast there (the ``COMPACT`` shader variant), the colours scattered back (module docstring)."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx
        self.target = FloatTarget(ctx)
        self._pixels = None  # RG32F: per compact texel, its pixel's centre in the pass's target
        self.prog = ctx.program(vertex_shader=shader_source("compact_scatter.vert"),
                                fragment_shader=shader_source("compact_scatter.frag"))
        self.vao = ctx.vertex_array(self.prog, [])
        self.count = 0  # live pixels of the pass being drawn
        self.rows = 0  # the compact target's rows they take

    def begin(self, fbo, region, pixels: int, clear):
        """List the live pixels of ``fbo`` (the masked pass's target: depth not 0 inside ``region``
        ``(x, y, w, h)``, the volume's rectangle), pack them, bind the compact target (room for the
        pass's ``pixels``) cleared to ``clear`` with its viewport over the rows they take; returns
        the compact framebuffer."""
        import moderngl

        x0, y0, w, h = (int(v) for v in region)
        if w > 0 and h > 0:
            depth = np.frombuffer(fbo.read(viewport=(x0, y0, w, h), components=1, attachment=-1, dtype="f4"),
                                  dtype=np.float32).reshape(h, w)
            xs, ys = compact_order(depth != 0.0)
        else:  # the volume is off the image: nothing to cast
            xs = ys = np.zeros(0, dtype=np.int64)
        n = self.count = len(xs)
        W = COMPACT_WIDTH
        cap = max(COMPACT_BLOCK, -(-int(pixels) // (W * COMPACT_BLOCK)) * COMPACT_BLOCK)  # rows for every pixel
        cfbo = self.target.ensure((W, cap))
        if self._pixels is None or self._pixels.size != (W, cap):
            if self._pixels is not None:
                self._pixels.release()
            self._pixels = self.ctx.texture((W, cap), 2, dtype="f4")
            self._pixels.filter = (moderngl.NEAREST, moderngl.NEAREST)
        blocks = -(-n // (COMPACT_BLOCK * COMPACT_BLOCK))
        self.rows = rows = max(1, -(-blocks // (W // COMPACT_BLOCK))) * COMPACT_BLOCK
        grid = np.full((rows, W, 2), -1.0, dtype=np.float32)  # -1: no pixel (the shader discards)
        cx, cy = compact_texels(n, W)
        grid[cy, cx, 0] = xs + (x0 + 0.5)
        grid[cy, cx, 1] = ys + (y0 + 0.5)
        self._pixels.write(grid.tobytes(), viewport=(0, 0, W, rows))
        cfbo.use()
        self.ctx.viewport = (0, 0, W, rows)
        self.ctx.scissor = None
        cfbo.clear(*clear)
        return cfbo

    @property
    def rect(self) -> tuple[int, int, int, int]:
        """The scissor rectangle of the compacted pass: the rows its list takes."""
        return 0, 0, COMPACT_WIDTH, self.rows

    def bind(self, prog) -> None:
        """Bind the list's pixel coordinates for a ``COMPACT`` volume shader ``prog``."""
        self._pixels.use(location=COMPACT_UNIT)
        uset(prog, "u_pixels", COMPACT_UNIT)

    def scatter(self, fbo) -> None:
        """Write each live pixel's colour from the compact target into ``fbo`` (the pass's target,
        bound here), unblended; the caller's state (blending, depth test, scissor) is set here."""
        import moderngl

        ctx = self.ctx
        fbo.use()
        w, h = fbo.size
        ctx.viewport = (0, 0, w, h)
        ctx.scissor = None
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        if self.count:
            self._pixels.use(location=0)
            self.target.color.use(location=1)
            uset(self.prog, "u_pixels", 0)
            uset(self.prog, "u_compact", 1)
            uset(self.prog, "u_width", COMPACT_WIDTH)
            uset(self.prog, "u_target", (float(w), float(h)))
            self.vao.render(moderngl.POINTS, vertices=self.count)

    def release(self) -> None:
        self.target.release()
        for obj in (self._pixels, self.vao, self.prog):
            if obj is not None:
                obj.release()
        self._pixels = self.vao = self.prog = None


class Refine:
    """The coarse targets, the mask pass and the compaction of refined frames on one context (made
    on first use)."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx
        self._targets: dict[int, FloatTarget] = {}
        self.prog = ctx.program(vertex_shader=shader_source("screen.vert"),
                                fragment_shader=shader_source("refine_mask.frag"))
        self.vao = ctx.vertex_array(self.prog, [])
        self.compaction = Compaction(ctx)

    def target(self, k: int) -> FloatTarget:
        """The float target of coarse pass ``k`` (1 / 2**k of the image), with a depth buffer (a
        coarse pass is masked by the one below it)."""
        if k not in self._targets:
            self._targets[k] = FloatTarget(self.ctx, depth=True)
        return self._targets[k]

    @staticmethod
    def coarse_size(camera, k: int) -> tuple[int, int]:
        """``(ceil(w / 2**k), ceil(h / 2**k))``: the size of pass ``k`` of an image seen by ``camera``."""
        w, h = (int(v) for v in camera.size)
        return -(-w // 2**k), -(-h // 2**k)

    @staticmethod
    def coarse_camera(camera, k: int):
        """``camera`` with :meth:`coarse_size` pixels: the size of pass ``k``'s target (its rays come
        from the image's camera, :meth:`coarse_uniforms`)."""
        if k == 0:
            return camera
        return replace(camera, size=Refine.coarse_size(camera, k))

    @staticmethod
    def coarse_uniforms(prog, camera, k: int) -> None:
        """Make pass ``k``'s fragment ``(i, j)`` cast the image's ray through the image point
        ``((i + 1/2) * 2**k, (j + 1/2) * 2**k)`` (pixel-corner units): the image camera's half
        extents over its viewport divided by ``2**k`` (exact for odd sizes too, where the coarse
        target has a column or row beyond the image). Pass ``k``'s ray ``i`` then lies halfway
        between pass ``k - 1``'s pixels ``2i`` and ``2i + 1``."""
        w, h = (int(v) for v in camera.size)
        f = float(2**k)
        prog["u_viewport"].value = (w / f, h / f)
        if not camera.orthographic:
            ty = math.tan(math.radians(float(camera.fov_y)) / 2.0)
            prog["u_half"].value = (ty * w / h, ty)

    def mask(self, fbo, camera, k: int, tolerance: float, origin, rect=None) -> None:
        """Blend pass ``k + 1``'s image into the smooth pixels of pass ``k``'s ``fbo`` (bound, depth
        cleared to 1, its viewport set at ``origin``) and set their depth to 0, so that the pass's
        fragments (depth test ``<=``, at 0.5) leave them alone; the caller's draw path then sets its
        own blending and depth test. ``camera``: the image's. ``rect``: the scissor box ``(x, y, w,
        h)`` of the volume in the target, or None (the whole target): outside it the pass draws
        nothing and every coarser pass drew nothing, so the cleared pixel is what a blend of the
        coarse pass's cleared pixels would give, and the mask is not drawn there."""
        import moderngl

        ctx = self.ctx
        self.target(k + 1).color.use(location=0)
        coarse = self.coarse_size(camera, k + 1)
        lo = pass_origin(coarse)
        uset(self.prog, "u_coarse", 0)
        uset(self.prog, "u_refine_tol", float(tolerance))
        uset(self.prog, "u_origin", tuple(float(v) for v in origin))
        uset(self.prog, "u_coarse_lo", lo)
        uset(self.prog, "u_coarse_hi", (lo[0] + int(coarse[0]) - 1, lo[1] + int(coarse[1]) - 1))
        ctx.scissor = None if rect is None else tuple(int(v) for v in rect)
        ctx.disable(moderngl.BLEND)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "1"  # always: the depth test must be on for the depth to be written
        self.vao.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        self.compaction.release()
        for t in self._targets.values():
            t.release()
        self._targets = {}
        for obj in (self.vao, self.prog):
            if obj is not None:
                obj.release()
        self.vao = self.prog = None
