"""Creating the OpenGL context that the render action draws into.

clipvol renders offscreen by default: a standalone EGL context needs no window system and runs on
Mesa's llvmpipe on a machine without a GPU, so the same code path serves tests, benchmarks and the
``clipvol render`` command. The renderer needs GL 3.3 core (3D float textures, float render targets
with blending, ``MAX`` blend equation); anything less is refused here with a message that says what
was tried, instead of failing later inside a shader compile.
"""

from __future__ import annotations

from ..errors import ClipvolError

__all__ = ["create_context", "GLContextError", "REQUIRED_GL"]

#: minimum GL version (major * 100 + minor * 10) the shaders are written for
REQUIRED_GL = 330


class GLContextError(ClipvolError, RuntimeError):
    """No usable OpenGL context could be created (names the backend tried and why)."""


def create_context(standalone: bool = True, backend: str | None = "egl"):
    """Return a ``moderngl.Context`` of at least GL 3.3 core.

    Parameters
    ----------
    standalone : bool
        ``True`` (default) for an offscreen context; ``False`` to attach to the current one
        (a window created by GLFW, say).
    backend : str or None
        ``"egl"`` (default, headless) or ``None`` for moderngl's platform default.

    Raises
    ------
    GLContextError
        When moderngl is missing, the context cannot be created, or its version is below 3.3.
    """
    try:
        import moderngl
    except ImportError as e:  # pragma: no cover - moderngl is a dependency
        raise GLContextError(f"expected the moderngl package to be installed, got ImportError: {e}") from e
    kwargs = {"standalone": standalone, "require": REQUIRED_GL}
    if backend is not None and standalone:
        kwargs["backend"] = backend
    what = f"moderngl.create_context(standalone={standalone}, backend={backend!r}, require={REQUIRED_GL})"
    try:
        ctx = moderngl.create_context(**kwargs)
    except Exception as e:
        raise GLContextError(
            f"expected an OpenGL >= 3.3 core context, but {what} failed: {e}. "
            "Offscreen rendering needs EGL (libEGL, e.g. Mesa's llvmpipe: apt install libegl1 libgl1-mesa-dri)"
        ) from e
    if ctx.version_code < REQUIRED_GL:
        version = ctx.info.get("GL_VERSION", ctx.version_code)
        ctx.release()
        raise GLContextError(f"expected OpenGL >= 3.3 from {what}, got {version}")
    return ctx
