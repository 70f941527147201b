"""The minimum-budget error says which brick size would fit the budget asked for."""

from __future__ import annotations

import math
import re

import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.paging.toroidal import allocate


def _minimum(n: int, b: int, itemsize: int) -> int:
    """Independent count: levels halve (ceil) until one brick holds the level; each needs min(grid, 2)^3 bricks."""
    total, size = 0, n
    while True:
        g = math.ceil(size / b)
        total += min(g, 2) ** 3 * b ** 3 * itemsize
        if g == 1:
            return total
        size = math.ceil(size / 2)


def test_min_budget_error_suggests_a_brick_that_fits():
    pyr = Pyramid.build((2**20,) * 3, (64, 64, 64), dtype="uint16")
    budget = 20 * 2**20
    with pytest.raises(ParameterError) as e:
        allocate(pyr, budget)
    msg = str(e.value)
    assert str(_minimum(2**20, 64, 2)) in msg
    b = int(re.search(r"bricked at (\d+)", msg).group(1))
    assert _minimum(2**20, b, 2) <= budget < _minimum(2**20, 2 * b, 2)  # the largest power of two that fits
    assert f"--brick {b}" in msg
    allocate(Pyramid.build((2**20,) * 3, (b, b, b), dtype="uint16"), budget)  # and it really fits
