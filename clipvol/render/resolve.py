"""The last pass of a volume frame, on the GL: the premultiplied float target to the 8-bit image.

Why a pass of its own
---------------------
Every composite frame ends the same way: put the background under the premultiplied colour,
un-premultiply, clamp and round to 8 bits (:func:`clipvol.render.paths.setup.premultiplied_to_uint8`
is that arithmetic in numpy). Done in numpy on the read-back float32 target it cost 13-16 ms of a
512² frame on the development machine (float64 temporaries over a million values), and the
read-back itself moves 16 bytes a pixel. A full-screen pass into an ``RGBA8UI`` target does the
same per pixel on the GL (well under a millisecond on a GPU, ~1-2 ms on Mesa llvmpipe at 512²) and
reads back 4 bytes a pixel. The target is an *integer* one so that the rounding is the shader's
own ``roundEven`` (numpy's ``rint``), not the driver's float-to-normalised conversion.

The float target is left as drawn: a caller that needs it (sort-last compositing reads the
unrounded premultiplied colour) reads it from there.
"""

from __future__ import annotations

import numpy as np

from .glsl import shader_source

__all__ = ["Resolve"]


class Resolve:
    """Turns an RGBA float32 colour texture into straight RGBA uint8 on ``ctx``
    (:meth:`__call__`); holds its program and an integer target of the last size asked for."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx
        self.prog = ctx.program(vertex_shader=shader_source("screen.vert"),
                                fragment_shader=shader_source("resolve.frag"))
        self.vao = ctx.vertex_array(self.prog, [])
        self._fbo = None
        self._tex = None
        self._size = None

    def __call__(self, src, background=(0.0, 0.0, 0.0, 0.0)) -> np.ndarray:
        """``(h, w, 4)`` straight RGBA uint8 of the float colour texture ``src``, row 0 at the top;
        ``background`` (straight RGBA) goes under it (alpha 0: nothing goes under). Leaves its own
        target bound: the caller binds back what it had bound (the render action does)."""
        import moderngl

        ctx = self.ctx
        size = tuple(int(v) for v in src.size)
        if self._size != size:
            self._release_target()
            self._tex = ctx.texture(size, 4, dtype="u1")  # GL_RGBA8UI: the shader's integers, as written
            self._fbo = ctx.framebuffer(color_attachments=[self._tex])
            self._size = size
        r, g, b, a = (float(v) for v in background)
        self.prog["u_bg"].value = (r * a, g * a, b * a, a)
        self.prog["u_src"].value = 0
        src.use(location=0)
        self._fbo.use()
        ctx.viewport = (0, 0, size[0], size[1])
        ctx.scissor = None
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)  # no blending into integers
        self.vao.render(moderngl.TRIANGLES, vertices=3)
        data = self._fbo.read(components=4, dtype="u1")
        return np.frombuffer(data, dtype=np.uint8).reshape(size[1], size[0], 4)[::-1].copy()

    def _release_target(self) -> None:
        for obj in (self._fbo, self._tex):
            if obj is not None:
                obj.release()
        self._fbo = self._tex = self._size = None

    def release(self) -> None:
        self._release_target()
        for obj in (self.vao, self.prog):
            if obj is not None:
                obj.release()
        self.vao = self.prog = None
