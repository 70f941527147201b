"""Run a call that might hang (a FIFO read, a stalled server) in a thread with a time limit, so that a
hang fails the test instead of blocking the run."""

from __future__ import annotations

import threading


def bounded(fn, seconds: float = 60.0, what: str = "the call did not give up"):
    """``(exception or None, return value or None)`` of ``fn()``; fails with ``what`` when it is
    still running after ``seconds``."""
    out: dict = {}

    def target():
        try:
            out["value"] = fn()
        except BaseException as e:  # noqa: BLE001 - handed to the test
            out["e"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), what
    return out.get("e"), out.get("value")
