"""Watch or interrupt a local build after each brick it writes, through the real chunk write.

:func:`after_each_brick` wraps :func:`clipvol.bricking.pipeline.write_chunk` (the one call that
writes a brick's chunk file): the brick is written first, then ``fn(level, (k, y, x))`` runs, so a
test can crash the build, fill the disk, change the source or hold the build at a known brick.
``fn=None`` puts the real write back (the same command then resumes).
"""

from __future__ import annotations

from pathlib import Path

import clipvol.bricking.pipeline as pipeline

REAL_WRITE = pipeline.write_chunk


def brick_of(path) -> tuple[int, tuple[int, int, int]]:
    """``(level, (k, y, x))`` of a chunk file ``.../L/c/k/y/x``."""
    parts = Path(path).parts
    return int(parts[-5]), (int(parts[-3]), int(parts[-2]), int(parts[-1]))


def after_each_brick(monkeypatch, fn) -> None:
    """Call ``fn(level, index)`` after each brick a local build writes (None: no call)."""
    if fn is None:
        monkeypatch.setattr(pipeline, "write_chunk", REAL_WRITE)
        return

    def write(path, data):
        REAL_WRITE(path, data)
        fn(*brick_of(path))

    monkeypatch.setattr(pipeline, "write_chunk", write)
