"""``--allow-partial``: what the frame commands (render, slice, view --offscreen, report) do when
some bricks of the view failed to load.

A failed brick drawn from a verified ancestor (coarser, but data that passed the same checks) is
noted on stderr. A failed brick that nothing stands in for leaves a hole that would look like
empty space: the command then writes nothing and exits with status 3 naming the bricks and their
causes (:class:`clipvol.errors.FrameIncompleteError`), or with ``--allow-partial`` writes the
image with those regions hatched in red and says so on stderr.
"""

from __future__ import annotations

import sys

from clipvol.errors import FrameIncompleteError

__all__ = ["add_partial_argument", "settle_failed"]


def add_partial_argument(p) -> None:
    p.add_argument("--allow-partial", action="store_true",
                   help="write the image even when bricks of the view failed and no ancestor stands in for "
                        "them, their regions hatched in red (without it: nothing written, exit status 3)")


def settle_failed(command: str, out, failed, image, hatch, allow: bool, stopped: str = "nothing written",
                  note: bool = True):
    """``image`` when no failed brick is left unreplaced; else raise, or with ``allow`` return
    ``hatch(image)`` after a warning. ``failed``: :class:`~clipvol.render.failures.FailedBrick` s;
    ``stopped`` says what the refusal leaves behind; ``note=False`` leaves out the note about
    replaced bricks (a path's frames note a set of them once)."""
    from clipvol.render.failures import describe_failed

    failed = list(failed)
    replaced = [f for f in failed if f.replaced]
    missing = [f for f in failed if not f.replaced]
    if replaced and note:
        print(f"clipvol {command}: note: {len(replaced)} failed brick(s) drawn from a coarser verified ancestor: "
              f"{describe_failed(replaced, 2)}", file=sys.stderr)
    if not missing:
        return image
    if not allow:
        raise FrameIncompleteError(
            f"{out}: {len(missing)} brick(s) of the view failed and no verified ancestor stands in for them: "
            f"{describe_failed(missing)}; {stopped} (--allow-partial writes it with these regions hatched)")
    print(f"clipvol {command}: warning: {out}: {len(missing)} brick(s) of the view failed and are hatched in red "
          f"(no data drawn there): {describe_failed(missing)}", file=sys.stderr)
    return hatch(image)
