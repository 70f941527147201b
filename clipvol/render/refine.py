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
   image changes. The image's pass ends as any frame (resolve, read-back, ``last_raw``).

Edges, silhouettes and fine texture keep their full-resolution rays. What is lost is what no coarse
ray sees: a feature thinner than the coarse rays' spacing (four pixels at the coarsest) lying
between four rays that agree. That error is
measured (``clipvol report``, ``tools/bench/bench_mission.py``: % of pixels with CIELUV ΔE >= 6
against the converged picture), not bounded. MIP, minIP, average and iso frames draw every
pixel (their targets hold values mapped after the pass, not colours a blend can stand for).

What it saves on a CPU rasteriser is less than the rays it leaves out. Mesa llvmpipe shades 4 x 4
pixels as SIMD lanes that run until the block's longest ray ends. The coarse passes' neighbouring
rays are far apart and the masked passes' rays lie along edges, so their blocks diverge: on an idle
2-core machine a 1/4-pass ray of a 256² frame costs 1.7-1.8 us against 0.5-0.6 us in a dense frame
at the same step, and the three passes of a refined 256² frame with no ray refined are already
only 3.7-6.4x faster than the full-resolution frame (``tools/bench/bench_refine_breakdown.py``;
``docs/benchmarks.md``, "The deciding figures on an idle machine"). At 512² the gain is larger.

References
----------
* M. Levoy, "Volume rendering by adaptive refinement", The Visual Computer 6(1), 1990.
"""

from __future__ import annotations

import math
from dataclasses import replace

from .glsl import shader_source
from .modes import mode_of
from .target import FloatTarget
from .uniforms import uset

__all__ = ["Refine", "MIN_REFINE_EDGE", "MAX_REFINE_LEVELS", "TILE", "pass_origin", "refine_levels", "refines"]

#: the coarsest pass of a refined frame has at least this many pixels each way
MIN_REFINE_EDGE = 8
#: coarse passes at most (1 / 2 and 1 / 4 of the image's resolution)
MAX_REFINE_LEVELS = 2
#: Mesa llvmpipe bins a frame into tiles of this many pixels a side and shades each tile on one
#: thread: a coarse pass that fits one tile is drawn across four (:func:`pass_origin`)
TILE = 64


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


def refines(params, camera) -> bool:
    """Does a frame with ``params`` seen by ``camera`` draw refined (composite, a tolerance above 0,
    an image large enough for a coarse pass, :func:`refine_levels`)?"""
    return params.refine_tolerance > 0.0 and mode_of(params.mode).classifies and refine_levels(camera) > 0


class Refine:
    """The coarse targets and the mask pass of refined frames on one context (made on first use)."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx
        self._targets: dict[int, FloatTarget] = {}
        self.prog = ctx.program(vertex_shader=shader_source("screen.vert"),
                                fragment_shader=shader_source("refine_mask.frag"))
        self.vao = ctx.vertex_array(self.prog, [])

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
        for t in self._targets.values():
            t.release()
        self._targets = {}
        for obj in (self.vao, self.prog):
            if obj is not None:
                obj.release()
        self.vao = self.prog = None
