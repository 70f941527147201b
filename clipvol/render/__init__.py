"""Stage 4, render (GL): the offscreen context, the GPU brick cache, the frame loop, the render actions.

The frame loop (:mod:`.frame_loop`: select, plan uploads, wait) makes no GL call itself; the
actions draw what it settled on. Everything below this stage is pure numpy.

Importing this package imports moderngl lazily (only :func:`create_context` and the action need it).
"""

from __future__ import annotations

from .context import GLContextError, create_context

__all__ = ["create_context", "GLContextError", "ClipRenderAction", "FrameStats", "GpuBrickCache"]


def __getattr__(name: str):
    if name in ("ClipRenderAction", "FrameStats"):
        from . import action

        return getattr(action, name)
    if name == "GpuBrickCache":
        from .gpu_cache import GpuBrickCache

        return GpuBrickCache
    raise AttributeError(f"module 'clipvol.render' has no attribute {name!r}")
