"""``--timeout`` of a one-shot command (``render``, ``slice``): one deadline for the whole command.

Why one deadline and not a wait per stage: the frame's wait, each remote request and the loader
threads' shutdown each had a time limit of their own, so a server that trickles a chunk a byte a
second held a command for the sum of them (a ``--timeout 20`` render ended after 29 s with a raw
``RuntimeWarning`` about threads left in reads, and without it after 97 s). The deadline is taken
when the command starts; a remote store's byte source refuses to wait, start or go on with a
request past it (:class:`clipvol.paging.bytesource.FsspecByteSource`, ``deadline``), the frame
waits for what is left of it, and the clip-texture's loader threads are waited for at most the
rest (a thread still inside a read is a daemon and is left behind, with one line on stderr
instead of a warning). The frame that did not complete in time is then refused naming
``--timeout`` (:func:`clipvol.app.partial.settle_unconverged`, exit 3).
"""

from __future__ import annotations

import contextlib
import sys
import time
import warnings

__all__ = ["CommandDeadline"]

#: the most seconds spent waiting for loader threads once the frame is settled
CLOSE_WAIT_S = 1.0


class CommandDeadline:
    """The instant a command started plus its ``--timeout`` seconds (``None``: no limit)."""

    def __init__(self, seconds: float | None) -> None:
        self.seconds = seconds
        self.at = None if seconds is None else time.monotonic() + float(seconds)

    def left(self) -> float | None:
        """Seconds left (0 when past it), or None without a limit."""
        return None if self.at is None else max(0.0, self.at - time.monotonic())

    def remote_kwargs(self, source: str, kwargs: dict) -> dict:
        """``kwargs`` of the loader of ``source`` with the deadline added when it is a remote store."""
        from ..paging.bytesource import is_remote_url

        if self.at is None or not is_remote_url(str(source)):
            return kwargs
        return {**kwargs, "deadline": self.at}

    @contextlib.contextmanager
    def closing(self, command: str):
        """Around a clip-texture's ``with`` block: yields ``register(clip)``, after which leaving that
        block waits for its loader threads at most :data:`CLOSE_WAIT_S`; threads still inside a
        read are then reported in one line, not as a ``RuntimeWarning``."""
        clips = []

        def register(clip):
            clip.close_timeout = CLOSE_WAIT_S
            clips.append(clip)
            return clip

        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="ClipTexture.close", category=RuntimeWarning)
            yield register
        stuck = sum(1 for c in clips for t in getattr(c, "_threads", ()) if t.is_alive())
        if stuck:
            print(f"clipvol {command}: note: {stuck} loader thread(s) still waiting on reads were left behind "
                  "at the end of the command", file=sys.stderr)
