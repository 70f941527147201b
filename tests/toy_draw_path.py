"""A toy draw path for the registry tests, and a pytest plugin that registers it.

:class:`ReversedCutPath` draws the cut through the single pass's code, handed the cut's items in
reverse order: the single pass walks a page table built from the items, which no order changes,
so its images must be the single pass's bit for bit - while it is a path of its own name, made and
registered outside the package. ``pytest -p toy_draw_path`` (with ``tests`` on ``PYTHONPATH``)
registers it before the tests are collected, so every test taking ``draw_path``
(``conftest.pytest_generate_tests``) runs with it too (``tests/render/test_draw_paths.py``).
"""

from __future__ import annotations

import dataclasses

from clipvol.render.paths import register
from clipvol.render.paths.single_pass import SinglePassPath


class ReversedCutPath(SinglePassPath):
    """The single pass, handed the frame's items in reverse order."""

    name = "test-reversed-cut"

    def draw(self, frame):
        return super().draw(dataclasses.replace(frame, items=frame.items[::-1]))


def pytest_configure(config) -> None:
    """As a plugin: register the toy path before collection."""
    register(ReversedCutPath)
