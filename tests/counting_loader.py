"""A loader wrapper that records every ``read_brick``: the tests' independent count of what was read
(the loaders' own byte counters are what some of those tests check)."""

from __future__ import annotations


class Counting:
    """Wraps a loader; ``reads`` lists ``(level, (bz, by, bx))`` of every ``read_brick`` call."""

    def __init__(self, inner):
        self.inner, self.pyramid, self.reads = inner, inner.pyramid, []

    def read_brick(self, level, index):
        self.reads.append((int(level), tuple(int(v) for v in index)))
        return self.inner.read_brick(level, index)
