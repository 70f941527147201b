"""``--allow-partial``: what the frame commands (render, slice, view --offscreen, report) do when
some bricks of the view failed to load, or the frame is not complete at the level asked.

A failed brick that nothing stands in for leaves a hole that would look like empty space: the
command then writes nothing and exits with status 3 naming the bricks and their causes
(:class:`clipvol.errors.FrameIncompleteError`), or with ``--allow-partial`` writes the image with
those regions hatched in red and says so on stderr.

A failed brick drawn from a verified ancestor (coarser, but data that passed the same checks) is
noted on stderr by the commands that show a sequence (``view --offscreen``, ``report``). The
one-shot commands (``render``, ``slice``: ``strict``) promise an output that is what was asked:
there the stand-in is a refusal too (exit 3), and ``--allow-partial`` writes today's picture, the
ancestor in the failed brick's place, with a note on stderr. The interactive viewer keeps its
fallback and says so on its HUD.

The same promise covers a frame the budgets could not complete (:func:`settle_unconverged`): a
one-shot frame that waited and still draws some wanted bricks from coarser levels is refused
(exit 3) naming what was short - the memory budget (the clip-texture's windows cannot hold the
wanted bricks), the texture budget (the GPU cache cannot), or the time (``--timeout``) - and
by how much, unless ``--allow-partial``.
"""

from __future__ import annotations

import math
import sys

from ..errors import FrameIncompleteError

__all__ = ["settle_failed", "settle_unconverged"]


def settle_failed(command: str, out, failed, image, hatch, allow: bool, stopped: str = "nothing written",
                  note: bool = True, strict: bool = False):
    """``image`` when no failed brick is left unreplaced; else raise, or with ``allow`` return
    ``hatch(image)`` after a warning. ``failed``: :class:`~clipvol.render.failures.FailedBrick` s;
    ``stopped`` says what the refusal leaves behind; ``note=False`` leaves out the note about
    replaced bricks (a path's frames note a set of them once). ``strict`` (a one-shot output):
    a failed brick a coarser ancestor stands in for is refused too, unless ``allow``."""
    from ..render.failures import describe_failed

    failed = list(failed)
    replaced = [f for f in failed if f.replaced]
    missing = [f for f in failed if not f.replaced]
    if replaced and strict and not allow:
        raise FrameIncompleteError(
            f"{out}: {len(failed)} brick(s) of the view failed ({len(replaced)} drawn from a coarser verified "
            f"ancestor, not at the level asked): {describe_failed(failed)}; {stopped} (--allow-partial writes it with "
            "the coarser ancestors in their place" + (" and the rest hatched)" if missing else ")"))
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


def settle_unconverged(command: str, out, *, converged: bool, waited: bool, selection, clip, brick_gpu_bytes: int,
                       texture_budget: int, timeout, allow: bool, stopped: str = "nothing written",
                       unblended=()) -> None:
    """Refuse (:class:`FrameIncompleteError`, exit 3) a one-shot frame that ``waited`` and is still
    not complete at the level asked, naming the budget that was short; with ``allow`` say so on
    stderr and return.

    Not complete: not ``converged`` (wanted bricks drawn from coarser levels, or a slice's blend
    parents - ``unblended``, ``(level, index)`` - not drawn), or bricks the selection would have
    refined into lying outside the clip-texture's windows (its ``outside_window`` count: drawn
    from their parent instead, so not even wanted). ``selection``: the frame's selection;
    ``clip``: the clip-texture (memory budget, windows, brick size); ``brick_gpu_bytes``: one
    brick's bytes in the GPU cache. Which budget: bricks outside the windows mean the memory
    budget cannot hold the view at the level asked; more bricks than the texture budget holds, or
    parents the GPU cache could not take, the texture budget; else the loads did not end within
    ``timeout``.
    """
    import numpy as np

    from ..units import format_bytes

    if not waited:
        return
    missing = selection.missing_wanted()
    unblended = [(int(L), tuple(int(i) for i in idx)) for L, idx in unblended]
    beyond = int(selection.counts.get("outside_window", 0))
    if converged and not beyond and not missing and not unblended:
        return
    wanted = {(int(r[0]), (int(r[1]), int(r[2]), int(r[3]))) for r in selection.wanted_keys().tolist()}
    needed = len(wanted | set(unblended)) + beyond
    host = needed * clip.pyramid.brick_nbytes
    gpu = needed * int(brick_gpu_bytes)
    outside = beyond + sum(1 for L, idx in missing + unblended
                           if not bool(np.asarray(clip.in_window_mask(L, np.array([idx])))[0]))
    parts = []
    if beyond:
        parts.append(f"{beyond} bricks it would refine into lie outside the clip-texture's windows and are drawn "
                     "from their coarser parents")
    if missing:
        parts.append(f"{len(missing)} of the {len(wanted)} bricks it wants are drawn from coarser levels")
    if unblended:
        parts.append(f"{len(unblended)} parent bricks that blend its level transitions are not drawn")
    if outside:
        suggest = 1 << max(20, int(math.ceil(math.log2(max(2 * clip.memory_budget, 4 * host)))))
        short = (f"the memory budget {format_bytes(clip.memory_budget)} cannot hold the view at that level: raise "
                 f"--memory-budget (the view needs about {needed} bricks, {format_bytes(host)}, plus the windows "
                 f"around them; try {format_bytes(suggest)})")
    elif gpu > texture_budget or unblended:
        short = (f"the texture budget {format_bytes(texture_budget)} cannot hold them on the GPU: raise "
                 f"--texture-budget (about {needed} bricks, {format_bytes(gpu)}; try "
                 f"{format_bytes(1 << int(math.ceil(math.log2(max(2 * texture_budget, 2 * gpu)))))})")
    else:
        short = (f"their loads did not end within --timeout {timeout:g} s: raise --timeout" if timeout is not None
                 else "their loads did not end")
    what = f"{out}: not complete at the level asked: {'; '.join(parts) or 'the frame did not converge'}; {short}"
    if not allow:
        raise FrameIncompleteError(f"{what}; {stopped} (--allow-partial writes it with the coarser bricks)")
    print(f"clipvol {command}: warning: {what}; written with the coarser bricks (--allow-partial)", file=sys.stderr)
