"""A Ctrl-C that C code swallowed, kept so that the next step of a long loop stops.

Python runs a SIGINT handler between bytecodes, and the ``KeyboardInterrupt`` it raises can land
inside a C function that calls back into Python and then clears whatever error it met (numpy's
structured compare, an attribute lookup that treats any error as "absent"). The loop that was
meant to stop then runs to its end: a 2,000-frame flythrough interrupted at frame 3 wrote all
2,000 frames. The command line's handler records every interrupt here as well as raising it;
the loops that run long (a frame, a wait for bricks) call :func:`check` at each step, so a
swallowed Ctrl-C stops them at the next one.

Only the main thread raises: a worker thread that checks goes on, and its owner stops it.
A library user who never installs the handler is never stopped by this module.
"""

from __future__ import annotations

import threading

__all__ = ["note", "pending", "clear", "check"]

_pending = threading.Event()


def note() -> None:
    """Record an interrupt (the command line's SIGINT handler calls this before raising)."""
    _pending.set()


def pending() -> bool:
    """Whether an interrupt was recorded since the last :func:`clear`."""
    return _pending.is_set()


def clear() -> None:
    """Forget a recorded interrupt (a command starting, or one ending, in the same process)."""
    _pending.clear()


def check() -> None:
    """Raise ``KeyboardInterrupt`` in the main thread when an interrupt was recorded and not acted on."""
    if _pending.is_set() and threading.current_thread() is threading.main_thread():
        raise KeyboardInterrupt
