"""The float offscreen target the volume, slice and splat actions draw into, and giving the binding back.

Each action keeps one RGBA float32 framebuffer that follows the requested image size (float, so
premultiplied colour is not quantised before read-back), and after drawing binds back whatever was
bound before - or the default framebuffer, found once: a framebuffer released while still bound
breaks every later one in the context.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FloatTarget"]


class FloatTarget:
    """An RGBA float32 framebuffer of the last size asked for, on ``ctx``."""

    def __init__(self, ctx, depth: bool = False) -> None:
        self.ctx = ctx
        self.depth = depth  # with a depth buffer (the volume frames' target: the mask of a refined frame)
        self._depth = None
        self.fbo = None
        self._color = None
        self._size = None
        self._default = None

    def ensure(self, size: tuple[int, int]):
        """The framebuffer, (re)allocated when ``size`` (width, height) changed."""
        size = (int(size[0]), int(size[1]))
        if self._size != size:
            self.release()
            self._color = self.ctx.texture(size, 4, dtype="f4")
            self._depth = self.ctx.depth_renderbuffer(size) if self.depth else None
            self.fbo = self.ctx.framebuffer(color_attachments=[self._color], depth_attachment=self._depth)
            self._size = size
        return self.fbo

    @property
    def color(self):
        """The colour texture of the framebuffer (a resolve pass samples it), or None before :meth:`ensure`."""
        return self._color

    def read(self) -> np.ndarray:
        """The target as ``(h, w, 4)`` float32, rows top first."""
        w, h = self.fbo.size
        return np.frombuffer(self.fbo.read(components=4, dtype="f4"), dtype=np.float32).reshape(int(h), int(w), 4)[::-1]

    def restore(self, previous) -> None:
        """Bind ``previous`` (``ctx.fbo`` before drawing), or the default framebuffer if it was None."""
        if previous is None:
            if self._default is None:
                self._default = self.ctx.detect_framebuffer(0)
            previous = self._default
        previous.use()

    def release(self) -> None:
        for obj in (self.fbo, self._color, self._depth):
            if obj is not None:
                obj.release()
        self.fbo = self._color = self._depth = self._size = None
