"""The HUD shows a frame's failed bricks in red, with their causes (pixels read back from pillow)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from clipvol.render.failures import FailedBrick
from clipvol.viewer.hud import ALERT_RGBA, hud_lines, render_text


def _stats(failed):
    return SimpleNamespace(bricks_drawn={0: 3}, bytes_uploaded=0, texture_bytes=0, texture_budget=1, converged=False,
                           failed_bricks=tuple(failed))


def test_failed_bricks_are_listed_with_causes():
    failed = [FailedBrick(0, (1, 2, 3), "chunk file 0/c/1/2/3 is corrupt"), FailedBrick(0, (0, 0, 1), "gone", (1, (0, 0, 0))),
              FailedBrick(0, (0, 0, 2), "gone")]
    lines = hud_lines(frame_stats=_stats(failed))
    k = next(i for i, ln in enumerate(lines) if ln.startswith("FAILED"))
    assert lines[k] == "FAILED 3 brick(s): 2 missing from the image"
    assert "brick (level 0, 1, 2, 3): chunk file 0/c/1/2/3 is corrupt" in lines[k + 1]
    assert lines[k + 3].strip() == "and 1 more"
    assert not any(ln.startswith("FAILED") for ln in hud_lines(frame_stats=_stats([])))


def test_failed_lines_are_drawn_in_red_and_only_they():
    lines = ["drawn 3 bricks", *hud_lines(frame_stats=_stats([FailedBrick(0, (0, 0, 0), "bad")]))[-2:]]
    img = render_text(lines, padding=0)
    red = np.all(img[..., :3] == ALERT_RGBA[:3], axis=-1)
    white = np.all(img[..., :3] == 255, axis=-1)
    rows = img.shape[0] // len(lines)
    assert white[:rows].any() and not red[:rows].any()  # the plain line
    assert red[rows:].any() and not white[rows:].any()  # the two failure lines
