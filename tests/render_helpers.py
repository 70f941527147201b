"""Helpers shared by the GL test modules (imported like ``reference_raycast``)."""

from __future__ import annotations


def every_draw_path() -> list[str]:
    """The names of the registered draw paths (``clipvol.render.paths.DRAW_PATHS``), in the order
    they were registered. Read when the tests are collected (``conftest.pytest_generate_tests``
    runs every test taking ``draw_path`` once per name): a path registered by then is tested by
    every test that holds for all paths."""
    from clipvol.render.paths import DRAW_PATHS

    return list(DRAW_PATHS)


def render_converged(action, camera, tf, timeout: float = 60.0):
    """``action.render(wait=True)`` once, asserting the frame converged (no retries: a frame that
    returns unconverged before its timeout is a bug in the wait loop, and this makes it fail)."""
    img = action.render(camera, tf, wait=True, timeout=timeout)
    assert action.last_frame_stats.converged, action.last_frame_stats
    return img
