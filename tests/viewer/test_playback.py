"""Time-series playback in the viewer, without a window: the keys, the clock (never skipping a step
that is not drawn yet), the measured rate and the HUD line."""

from __future__ import annotations

import pytest

from clipvol.errors import ParameterError
from clipvol.viewer.playback import Playback


def test_keys_play_pause_step_and_rate():
    p = Playback(5)
    assert not p.playing and p.step == 0
    assert p.handle_key("SPACE") and p.playing
    assert p.handle_key("K") and not p.playing and p.step == 1  # stepping pauses
    assert p.handle_key("j") and p.step == 0
    assert p.handle_key("J") and p.step == 4  # wraps
    rate = p.rate
    assert p.handle_key("}") and p.rate == 2 * rate
    assert p.handle_key("{") and p.handle_key("{") and p.rate == rate / 2
    assert not p.handle_key("M")  # not a playback key: the view state's


def test_clock_waits_for_the_rate_and_for_the_drawn_step():
    p = Playback(3, rate=2.0)
    assert not p.due(0.0)  # paused
    p.handle_key("SPACE")
    assert not p.due(10.0)  # the clock starts at the first tick after play
    assert not p.due(10.4)  # 1 / rate = 0.5 s not yet over
    assert not p.due(10.6, ready=False)  # the current step is still loading: wait, do not skip it
    assert p.due(10.6, ready=True)
    assert p.advance(10.6) == 1
    assert not p.due(10.9)
    assert p.due(11.1) and p.advance(11.1) == 2
    assert p.due(11.7) and p.advance(11.7) == 0  # wraps round
    assert p.steps_per_second == pytest.approx(3 / (0.6 + 0.5 + 0.6))
    line = p.hud_line("ready")
    assert line.startswith("t 0/2 playing") and "steps/s" in line and "next step ready" in line
    p.handle_key(" ")
    assert "paused" in p.hud_line("loading") and not p.due(99.0)


def test_one_step_never_advances_and_bad_values_are_refused():
    p = Playback(1)
    p.handle_key("SPACE")
    p.due(0.0)
    assert not p.due(100.0)
    with pytest.raises(ParameterError, match="n_steps"):
        Playback(0)
    with pytest.raises(ParameterError, match="rate"):
        Playback(3, rate=0)
