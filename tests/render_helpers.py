"""Helpers shared by the GL test modules (imported like ``reference_raycast``)."""

from __future__ import annotations


def render_converged(action, camera, tf, timeout: float = 60.0):
    """``action.render(wait=True)`` once, asserting the frame converged (no retries: a frame that
    returns unconverged before its timeout is a bug in the wait loop, and this makes it fail)."""
    img = action.render(camera, tf, wait=True, timeout=timeout)
    assert action.last_frame_stats.converged, action.last_frame_stats
    return img
