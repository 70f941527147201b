"""The viewer's ``I`` key steps through the render modes its renderer draws."""

from __future__ import annotations

import pytest

from clipvol.errors import ParameterError
from clipvol.viewer.controls import ViewState


def test_i_cycles_through_the_widened_modes_and_wraps():
    s = ViewState(num_levels=3, render_modes=("composite", "mip", "minip", "average", "iso"))
    seen = []
    for _ in range(5):
        assert s.handle_key("I")
        seen.append(s.render_mode)
    assert seen == ["mip", "minip", "average", "iso", "composite"]


def test_i_from_a_mode_outside_the_cycle_goes_to_its_first():
    s = ViewState(num_levels=3, render_mode="iso")  # started with --mode iso, the default cycle
    assert s.handle_key("I") and s.render_mode == "composite"


def test_an_unknown_render_mode_is_refused():
    with pytest.raises(ParameterError, match="render_mode"):
        ViewState(num_levels=3, render_mode="xray")
