"""One level everywhere (``level``), ancestors as fallback while it loads."""

from __future__ import annotations

import numpy as np

from .base import RefinePolicy

__all__ = ["FixedLevel"]


class FixedLevel(RefinePolicy):
    name = "fixed"

    def cut(self, t) -> None:
        super().cut(t)
        t.counts["level"] = self.params.level

    def refine(self, t, level, lo, hi):
        return np.full(len(lo), level > self.params.level)
