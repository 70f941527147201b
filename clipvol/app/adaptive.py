"""Adaptive quality while the camera moves, full quality when it stops (progressive refinement).

Why: on a machine without a GPU (Mesa llvmpipe) a full 960x640 ray-cast frame takes a few hundred
milliseconds, so dragging the view at full quality crawls at 2-3 frames per second and the user
loses the sense of what they are turning. Ray-casting cost is nearly proportional to the number of
rays times the samples per ray, so while the camera moves we render a smaller image (scaled up on
screen) with a longer sample step, and choose both to hold a target frame time; once the camera
has been still for a moment one full-quality frame is drawn (and refined as bricks arrive).

The controller is pure (no GL, no clock of its own: callers pass ``now`` and the measured frame
time), so it can be tested on a synthetic slow path and used by the window and the benchmarks
alike.

**The control law.** The quality is one number, the *cost* ``c`` in ``(0, 1]``: the fraction of a
full frame's rays x samples. After an interactive frame that took ``t`` seconds at cost ``c``,
the next cost is ``c * (h T / t) ** gain`` (``h``: a headroom, 0.75), clipped to ``[min_cost, 1]`` - a damped multiplicative
step towards the target ``T`` that needs no model of the fixed per-frame overhead (if the overhead
alone exceeds ``T``, the cost settles at ``min_cost``). A full-quality frame seeds the estimate the
same way. The cost maps to an image scale ``s`` and a step factor ``f`` (``c = s**2 / f``): the
step grows first as ``c ** (-1/3)`` up to ``max_step_factor``, held to a few rungs
(:data:`STEP_RUNGS`), and the scale takes the rest, down to ``min_scale``.

**One whole level while moving.** An interactive frame draws one whole level of the pyramid (the
``"fixed"`` policy): the coarsest level whose voxel covers at most ``preview_lod`` times the user's
level-of-detail threshold in pixels of the small image, at the volume's nearest point
(:func:`preview_level`, :func:`frame_params`). Why: on llvmpipe a drag frame's time is not only
rays x samples. A projected-size cut changes with every camera, so each frame walks the octree,
merges the cut and builds a page table again (tens of milliseconds of host time on two busy
cores); a whole level is a camera-free cut, which the frame loop draws again from frame to frame
while it holds (:mod:`clipvol.render.frame_loop`, "Coherence"), and its bricks merge into few large
regions for the rays to cross. Measured on the viewer's stores (``tools/bench/bench_interactive.py``,
docs/benchmarks.md), with the preview's error against the converged frame (% pixels Delta E >= 6)
beside the frame rate. A full-quality frame always uses the user's policy, level and threshold,
so still images are unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ParameterError

__all__ = ["Quality", "AdaptiveQuality", "FULL", "DRAG_FRAME_S", "preview_level", "frame_params"]

#: the frame time a drag holds by default: 15 frames a second
DRAG_FRAME_S = 1.0 / 15.0
#: the step factors an interactive frame uses (with ``max_step_factor``): see ``quality_for``
STEP_RUNGS = (1.0, 1.5, 2.0, 3.0)


@dataclass(frozen=True, slots=True)
class Quality:
    """How to render one frame: the image ``scale`` (fraction of each side), ``step_factor``
    (the sample spacing times this) and ``lod_factor`` (an interactive frame draws the whole level
    whose voxel covers this many times the level-of-detail threshold: :func:`frame_params`);
    ``full`` marks a full-quality frame."""

    scale: float
    step_factor: float
    full: bool
    lod_factor: float = 1.0

    @property
    def cost(self) -> float:
        """Rays x samples relative to a full-quality frame."""
        return self.scale * self.scale / self.step_factor

    def size(self, full_size) -> tuple[int, int]:
        """The image size in pixels at this scale (at least 1x1)."""
        w, h = full_size
        if self.full:
            return int(w), int(h)
        return max(1, int(round(w * self.scale))), max(1, int(round(h * self.scale)))


FULL = Quality(1.0, 1.0, True)


class AdaptiveQuality:
    """Chooses each frame's :class:`Quality` to hold ``target_s`` while the view moves.

    Parameters
    ----------
    target_s : float
        Frame time to hold while the camera moves (seconds, > 0; default :data:`DRAG_FRAME_S`, 15 fps).
    settle_s : float
        How long the camera must be still before the full-quality frame is drawn.
    min_scale : float
        Smallest image scale (fraction of each side).
    max_step_factor : float
        Largest sample-step multiplier.
    gain : float
        Damping of the control step, in ``(0, 1]`` (1: jump to the estimate at once).
    headroom : float
        The controller aims at ``headroom * target_s`` so that frame-to-frame noise (other
        processes, brick uploads) keeps frames under the target rather than around it.
    preview_lod : float
        Interactive frames draw the whole level whose voxel covers at most this many times the
        level-of-detail threshold in pixels (>= 1; see :func:`frame_params`).
    step_rungs : tuple of float or None
        The step factors interactive frames use (:meth:`quality_for`); None: any, following the
        cost (the controller before 2026-11-29).

    Use: ``q = aq.next(moving, now)``; when ``q`` is not None render at ``q`` and call
    ``aq.done(q, frame_seconds)``. ``next`` returns None when nothing needs drawing for
    quality's sake (the full frame is already there).
    """

    def __init__(self, target_s: float = DRAG_FRAME_S, *, settle_s: float = 0.2, min_scale: float = 0.2,
                 max_step_factor: float = 3.0, gain: float = 0.7, headroom: float = 0.75,
                 preview_lod: float = 2.0, step_rungs: tuple | None = STEP_RUNGS) -> None:
        for name, v, lo in (("target_s", target_s, 0.0), ("settle_s", settle_s, -1e-300),
                            ("min_scale", min_scale, 0.0), ("max_step_factor", max_step_factor, 1.0 - 1e-12)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > lo):
                raise ParameterError(f"{name}: expected a finite number > {max(lo, 0):g}, got {v!r}")
        if not (0.0 < min_scale <= 1.0):
            raise ParameterError(f"min_scale: expected a fraction in (0, 1], got {min_scale!r}")
        if not (0.0 < gain <= 1.0):
            raise ParameterError(f"gain: expected a number in (0, 1], got {gain!r}")
        if not (0.0 < headroom <= 1.0):
            raise ParameterError(f"headroom: expected a number in (0, 1], got {headroom!r}")
        if not (isinstance(preview_lod, (int, float)) and math.isfinite(preview_lod) and preview_lod >= 1.0):
            raise ParameterError(f"preview_lod: expected a finite number >= 1, got {preview_lod!r}")
        self.preview_lod = float(preview_lod)
        self.headroom = float(headroom)
        self.target_s = float(target_s)
        self.settle_s = float(settle_s)
        self.min_scale = float(min_scale)
        self.max_step_factor = float(max_step_factor)
        self.gain = float(gain)
        self.min_cost = self.min_scale ** 2 / self.max_step_factor
        self._rungs = None if step_rungs is None else \
            sorted({float(r) for r in step_rungs if 1.0 <= r <= self.max_step_factor} | {1.0, self.max_step_factor})
        self.cost = 1.0
        self._last_motion = -math.inf
        self._full_drawn = False
        self.last_quality: Quality | None = None

    # -- the mapping ----------------------------------------------------------------------------
    def quality_for(self, cost: float) -> Quality:
        """The interactive :class:`Quality` of a cost (step first, then scale).

        The step factor is one of :data:`STEP_RUNGS` (and ``max_step_factor``), the largest not
        above ``c ** (-1/3)``; the scale makes up the cost. Why rungs: what a frame derives from its
        step - the opacity-corrected and pre-integrated transfer-function tables (a few hundred
        milliseconds for the distribution tables on a busy CPU), the parameters a kept cut is
        replayed under - is rebuilt whenever the step changes; a step that followed the cost
        continuously changed nearly every frame of a drag."""
        c = min(max(float(cost), self.min_cost), 1.0)
        f = min(max(c ** (-1.0 / 3.0), 1.0), self.max_step_factor)
        if self._rungs is not None:
            f = max(r for r in self._rungs if r <= f * (1.0 + 1e-9))
        s = min(max(math.sqrt(c * f), self.min_scale), 1.0)
        return Quality(s, f, False, self.preview_lod)

    # -- per frame ------------------------------------------------------------------------------
    @property
    def state(self) -> str:
        """``interactive`` (moving), ``refining`` (still, full frame not drawn yet) or ``refined``."""
        if self._full_drawn:
            return "refined"
        if self.last_quality is not None and not self.last_quality.full:
            return "interactive"
        return "refining"

    def next(self, moving: bool, now: float) -> Quality | None:
        """The quality of the next frame, or None when the full-quality frame is already drawn
        and the camera is still."""
        if moving:
            self._last_motion = float(now)
            self._full_drawn = False
        if float(now) - self._last_motion < self.settle_s:
            return self.quality_for(self.cost)
        if self._full_drawn:
            return None
        return FULL

    def done(self, q: Quality, frame_s: float) -> None:
        """Record that a frame at ``q`` took ``frame_s`` seconds."""
        t = float(frame_s)
        self.last_quality = q
        if q.full:
            self._full_drawn = True
        if not (t > 0 and math.isfinite(t)):
            return
        c = q.cost * (self.headroom * self.target_s / t) ** self.gain
        if q.full:  # a full frame seeds the estimate or lowers it, never raises what motion measured
            c = min(c, self.cost)
        self.cost = min(max(c, self.min_cost), 1.0)

    def invalidate(self) -> None:
        """Something other than the camera changed (transfer function, mode): draw the full frame again."""
        self._full_drawn = False


def preview_level(pyramid, camera, lod_threshold: float) -> int:
    """The coarsest level of ``pyramid`` whose voxel (its largest edge) covers at most ``lod_threshold``
    pixels of ``camera``'s image at the volume's nearest point (0 when even level 0's covers more):
    the finest level a projected-size cut at that threshold would draw anywhere in view."""
    lo, hi = pyramid.volume_box()
    best = 0
    for L in range(pyramid.num_levels):
        if float(camera.projected_size(lo, hi, max(pyramid.levels[L].scale))[0]) <= lod_threshold:
            best = L
    return best


def frame_params(q: Quality, pyramid, camera, *, step: float, lod_threshold: float, policy: str,
                 level: int | None, max_step: float | None = None, previous: int | None = None) -> dict:
    """The :class:`~clipvol.scene.params.RenderParams` fields of a frame at ``q`` for a user whose
    own are ``step``, ``lod_threshold``, ``policy`` and ``level``.

    A full frame gets the user's fields unchanged. An interactive frame gets the step times
    ``q.step_factor`` (at most ``max_step``, never below the user's) and one whole level, the
    ``"fixed"`` policy at :func:`preview_level` for ``q.lod_factor`` times the threshold (never
    finer than the user's own fixed level): a camera-free cut the frame loop replays while the
    view turns (module docstring). ``previous``, the level of the interactive frame before, is
    kept while it is that level or one coarser: a level that changes ends the replay (and uploads
    the new level's bricks), and the image's size changes a little every frame while the
    controller settles.
    """
    if q.full:
        return dict(step=step, lod_threshold=lod_threshold, policy=policy, level=level)
    s = step * q.step_factor
    if max_step is not None:
        s = min(s, max_step)
    L = preview_level(pyramid, camera, lod_threshold * q.lod_factor)
    if previous is not None and L <= int(previous) <= L + 1:
        L = int(previous)
    if policy == "fixed" and level is not None:
        L = max(L, int(level))
    return dict(step=max(step, s), lod_threshold=lod_threshold, policy="fixed", level=L)
