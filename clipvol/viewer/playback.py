"""Play, pause and step a time series in the viewer: the keys and the clock, free of any window.

The window owns a :class:`~clipvol.app.timeseries.SeriesSession` (a render session over one
:class:`~clipvol.app.timeseries.TimeSeriesPlayer`: the current step drawn, the next prefetched
under the same budget) and a :class:`Playback`. Each loop iteration asks :meth:`Playback.due`
whether the next step is due (the playing rate, ``rate`` steps per second, is a ceiling: a step
is shown at least one frame, and while the current step is still loading the clock waits, so
playback never skips a step); keys change the state (:meth:`Playback.handle_key`):

* ``SPACE`` play / pause;
* ``J`` / ``K`` one step back / forward (pauses);
* ``{`` / ``}`` half / double the playing rate.

The HUD line (:meth:`Playback.hud_line`) shows the step ``t``, the state, the measured steps per
second and the prefetch state of the next step (``ready``, ``loading``, ``off``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import ParameterError

__all__ = ["Playback", "PLAYBACK_KEY_HELP"]

#: the playback keys, for --help-keys and the guide (shown only for a time series)
PLAYBACK_KEY_HELP = (
    ("Space", "time series: play / pause"),
    ("J / K", "time series: one step back / forward (pauses)"),
    ("{ / }", "time series: half / double the playing rate"),
)


@dataclass
class Playback:
    """Time-series playback state.

    Parameters
    ----------
    n_steps : int
        Time steps of the series (>= 1).
    rate : float
        Steps per second while playing (a ceiling; > 0).
    step : int
        The step shown first.
    """

    n_steps: int
    rate: float = 4.0
    step: int = 0
    playing: bool = False
    message: str = ""
    _last: float | None = field(default=None, repr=False)
    _intervals: list = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if int(self.n_steps) < 1:
            raise ParameterError(f"n_steps: expected a time series of >= 1 steps, got {self.n_steps!r}")
        if not float(self.rate) > 0:
            raise ParameterError(f"rate: expected steps per second > 0, got {self.rate!r}")
        self.n_steps, self.rate = int(self.n_steps), float(self.rate)
        self.step = int(self.step) % self.n_steps

    def handle_key(self, key: str) -> bool:
        """Apply one key (``'SPACE'``, ``'J'``, ``'K'``, ``'{'``, ``'}'``); returns whether it was a playback key."""
        k = key.upper() if len(key) == 1 else key
        if k in ("SPACE", " "):
            self.playing = not self.playing
            self._last = None
            self.message = "playing" if self.playing else f"paused at t {self.step}"
        elif k in ("J", "K"):
            self.playing = False
            self.step = (self.step + (1 if k == "K" else -1)) % self.n_steps
            self.message = f"t {self.step}"
        elif k in ("{", "}"):
            self.rate = min(max(self.rate * (2.0 if k == "}" else 0.5), 0.125), 120.0)
            self.message = f"playing rate {self.rate:g} steps/s"
        else:
            return False
        return True

    def due(self, now: float, ready: bool = True) -> bool:
        """While playing: whether to advance now (``1 / rate`` since the last step, and the current
        step ``ready``: drawn converged). Advancing is :meth:`advance`'s job."""
        if not self.playing or self.n_steps < 2:
            return False
        if self._last is None:
            self._last = now
            return False
        return ready and now - self._last >= 1.0 / self.rate

    def advance(self, now: float) -> int:
        """Go to the next step (wrapping) at time ``now``; returns it."""
        if self._last is not None:
            self._intervals = (self._intervals + [now - self._last])[-8:]
        self._last = now
        self.step = (self.step + 1) % self.n_steps
        return self.step

    @property
    def steps_per_second(self) -> float:
        """Measured playing rate over the last steps (0 before two steps)."""
        if not self._intervals:
            return 0.0
        return len(self._intervals) / max(sum(self._intervals), 1e-9)

    def hud_line(self, prefetch: str) -> str:
        """``t 3/20 playing 3.9 steps/s, next step ready``."""
        state = "playing" if self.playing else "paused"
        return (f"t {self.step}/{self.n_steps - 1} {state} {self.steps_per_second:.1f} steps/s "
                f"(max {self.rate:g}), next step {prefetch}")
