"""Shared fixtures (kept small: most test modules build their own data)."""

from __future__ import annotations

import numpy as np
import pytest
from render_helpers import every_draw_path


def pytest_generate_tests(metafunc):
    """A test taking a ``draw_path`` argument runs once per registered draw path: what holds for
    every path is written once and covers a path the moment it is registered."""
    if "draw_path" in metafunc.fixturenames:
        # ``@pytest.mark.slow_paths("bricks")``: a heavy test runs those paths in the slow run only
        slow = metafunc.definition.get_closest_marker("slow_paths")
        slow = set(slow.args) if slow else set()
        metafunc.parametrize("draw_path", [pytest.param(p, marks=pytest.mark.slow) if p in slow else p
                                           for p in every_draw_path()])


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator, so every failure reproduces."""
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def ctx():
    """One standalone EGL context for the whole test session (Mesa llvmpipe is enough).

    Skips GL tests, saying why, on a machine with no EGL / GL 3.3.
    """
    from clipvol.render import GLContextError, create_context

    try:
        c = create_context()
    except GLContextError as e:  # pragma: no cover - machines without EGL
        pytest.skip(f"no offscreen GL context: {e}")
    yield c
    c.release()


@pytest.fixture(autouse=True)
def _current_gl_context(request):
    """Make the session's context current before every test that uses it.

    A window test (GLFW) or a test that creates and releases its own context leaves another
    context - or none - current on this thread; moderngl calls GL on whatever is current, so
    without this a later test's first texture would fail to be created (``glGenTextures`` gives 0).
    """
    if "ctx" in request.fixturenames or "gl" in request.fixturenames:
        c = request.getfixturevalue("ctx")
        c.mglo.__enter__()
    yield


@pytest.fixture
def gl(ctx):
    """``ctx``, checked to hold no GL error before and after the test."""
    assert ctx.error == "GL_NO_ERROR"
    yield ctx
    assert ctx.error == "GL_NO_ERROR"

