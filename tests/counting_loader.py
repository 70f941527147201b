"""Loader wrappers for tests: one that records every ``read_brick`` (the tests' independent count of
what was read; the loaders' own byte counters are what some of those tests check), and a base for
wrappers that must see every read."""

from __future__ import annotations


class Counting:
    """Wraps a loader; ``reads`` lists ``(level, (bz, by, bx))`` of every ``read_brick`` call."""

    def __init__(self, inner):
        self.inner, self.pyramid, self.reads = inner, inner.pyramid, []

    def read_brick(self, level, index):
        self.reads.append((int(level), tuple(int(v) for v in index)))
        return self.inner.read_brick(level, index)


class ReadThrough:
    """Wraps a loader so that every read goes through ``read_brick`` (its ``read_brick_into`` is
    hidden: the clip-texture then calls ``read_brick``), and everything else is the inner loader's.
    Subclasses override ``read_brick`` to gate, order or count reads."""

    def __init__(self, inner) -> None:
        self._inner = inner

    def __getattr__(self, name):
        if name == "read_brick_into":
            raise AttributeError(name)
        return getattr(self._inner, name)

    @property
    def pyramid(self):
        return self._inner.pyramid
