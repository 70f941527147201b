"""What every live view of a volume shares: the browser half, a frame made ready to show, the HUD, a probe.

Two front ends show a :class:`~clipvol.app.session.RenderSession`'s frames in a browser: the
notebook widget (:mod:`clipvol.app.notebook`, ``clipvol.show``) and the web server
(:mod:`clipvol.app.serve`, ``clipvol serve``). Both run the same JavaScript (``web/view.js``: the
image, drag to orbit, wheel to zoom, click to probe, the tf / mode menus, the HUD and error lines,
talking to a ``model``), finish a frame the same way (failed bricks with nothing standing in hatched
red and named, a mirrored store un-mirrored and lettered), write the same HUD (frame time, bricks per
level, resident memory, edge letters, the probe and the ruler) and probe a pixel the same way (the
un-flipped pixel of a mirrored store). Keeping these here is what makes a fix land in both.

No GL import: the functions take a session and what it drew.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["asset", "view_esm", "finish_frame", "hud_text", "probe_pixel"]

#: the folder of the browser files (package data)
WEB = Path(__file__).with_name("web")


@lru_cache(maxsize=None)
def asset(name: str) -> str:
    """The text of the browser file ``web/<name>`` (a fixed name of this package, never a request's path)."""
    return (WEB / name).read_text(encoding="utf-8")


def view_esm() -> str:
    """The live view's ES module (``render({model, el})``), shared by the widget and the server's page."""
    return asset("view.js")


def finish_frame(session, img: np.ndarray, cam, frame=None, *, labels: bool = True) -> tuple[np.ndarray, str]:
    """``(image, error line)``: a frame as shown, and the line naming bricks nothing stands in for.

    Regions drawn by nothing (failed bricks without a resident ancestor) are striped red, never
    blank; a mirrored store's image is flipped left-right and lettered (R/L, A/P, S/I) as
    ``clipvol render`` writes it (:func:`clipvol.app.annotate.present`).
    """
    from ..render.failures import describe_failed, hatch_failed
    from .annotate import present

    holes = tuple(getattr(session.frame_stats, "unreplaced", ()))
    if holes:
        img = hatch_failed(img, cam, session.pyramid, holes)
    img = present(img, cam, frame, labels=labels)
    error = (f"{len(holes)} brick(s) failed and nothing stands in for them (striped red): "
             f"{describe_failed(holes)}") if holes else ""
    return img, error


def hud_text(session, frame_s: float, cam=None, frame=None, *, probe=None, ruler=None, unit: str = "",
             extra: tuple[str, ...] = ()) -> str:
    """The HUD: frame time, bricks drawn per level, resident memory, edge letters, then ``extra``
    parts, and a line each for the last probe and the ruler."""
    fs = session.frame_stats
    ts = session.texture_stats
    parts = [f"{frame_s * 1e3:.0f} ms"]
    drawn = getattr(fs, "bricks_drawn", None) or {}
    items = drawn.items() if isinstance(drawn, dict) else enumerate(drawn)
    per = " ".join(f"L{k}:{int(v)}" for k, v in items if v)
    parts.append(f"bricks {per or '-'}")
    parts.append(f"resident {getattr(ts, 'resident_bytes', 0) / 1e6:.1f} MB")
    if not getattr(fs, "converged", True):
        parts.append("refining")
    if frame is not None and cam is not None:
        from ..scene.orientation import view_labels
        from ..scene.views import screen_axes

        lab = view_labels(frame.affine, *screen_axes(cam, frame), frame.frame)
        parts.append(f"left {lab['left']} right {lab['right']} top {lab['top']}")
    parts.extend(extra)
    lines = ["  ".join(parts)]
    if probe is not None:
        lines.append(probe.describe(unit))
    if ruler is not None and ruler.ends:
        lines.append(ruler.describe(unit))
    return "\n".join(lines)


def probe_pixel(session, prober, cam, frame, x: float, y: float, *, threshold: float | None = None, level: int = 0):
    """The first visible sample under pixel ``(x, y)`` of the image as shown (column, row from the
    top-left), or None: a mirrored store's shown image is flipped, so the ray is cast through the
    un-flipped pixel (:class:`clipvol.scene.probe.Prober`)."""
    from ..scene.probe import THRESHOLD
    from ..scene.views import mirrored

    w = cam.size[0]
    if mirrored(frame):  # the image shown is flipped left-right (clipvol.app.annotate.present)
        x = w - float(x)
    return prober.pick_pixel(cam, float(x), float(y), session.transfer_function, level=level,
                             threshold=THRESHOLD if threshold is None else threshold,
                             step=session.params.step, shape=session.params.shape)
