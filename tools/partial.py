"""``--allow-partial``, the flag of the frame commands (render, slice, view --offscreen, report).

What a frame with failed bricks or one the budgets could not complete does with and without it is
the application's (:mod:`clipvol.app.partial`); this module declares the flag only.
"""

from __future__ import annotations

__all__ = ["add_partial_argument"]


def add_partial_argument(p) -> None:
    p.add_argument("--allow-partial", action="store_true",
                   help="write the image even when bricks of the view failed and no ancestor stands in for "
                        "them, their regions hatched in red (without it: nothing written, exit status 3)")
