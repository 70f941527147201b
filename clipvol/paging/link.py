"""How many requests a remote store needs in flight: the link's latency and bandwidth, measured.

Why: one request to object storage costs a round trip (tens of milliseconds) before its first byte,
then its bytes at the link's bandwidth. A reader that keeps ``n`` requests outstanding moves at most
``n * chunk / (latency + chunk / bandwidth)`` bytes a second, so to run at the speed of the link
it needs the **bandwidth-delay product** in flight - the bytes the link holds while a request
travels - in chunks, plus the one being received (Little's law: in flight = rate x time in the
system). Too few and the link idles between round trips; many more only queue at the server.

:class:`LinkEstimate` learns ``latency`` and ``bandwidth`` from the requests a byte source makes
(when each request was sent, when its last byte came, its bytes): a line through the answers'
times against their sizes separates the round trip from the cost per byte, and the throughput the
answers reached together bounds the link's bandwidth from below; a link whose answers' sizes do not
show in their times is not the limit, and only its latency counts (:meth:`LinkEstimate.estimate`). :func:`in_flight_for` turns the two into a
request count. Pure Python and numpy, no I/O: both are tested with synthetic timings alone.
"""

from __future__ import annotations

import math
import threading
from collections import deque

import numpy as np

from ..errors import ParameterError

__all__ = ["in_flight_for", "next_in_flight", "LinkEstimate"]


def in_flight_for(latency: float, bandwidth: float, chunk_bytes: float, *, rate: float | None = None,
                  lo: int = 2, hi: int = 256) -> int:
    """Requests to keep outstanding so that ``chunk_bytes`` answers arrive at the link's speed.

    Parameters
    ----------
    latency : float
        Seconds from a request to its first byte (the round trip plus the server's time).
    bandwidth : float
        Bytes a second one answer arrives at (``inf``: only the latency counts).
    chunk_bytes : float
        Bytes of one answer (a compressed chunk).
    rate : float, optional
        Answers a second the reader can use (its decode speed); the link is not asked for more.
        Default: what the bandwidth allows, ``bandwidth / chunk_bytes``.
    lo, hi : int
        Bounds of the result (a floor that keeps a fast link busy, a ceiling a server tolerates).

    Returns ``clip(ceil(rate * (latency + chunk / bandwidth)), lo, hi)``: the chunks in the
    bandwidth-delay product, plus the one being received.
    """
    for name, v in (("latency", latency), ("chunk_bytes", chunk_bytes)):
        if not (v >= 0 and math.isfinite(v)):
            raise ParameterError(f"{name}: expected a finite number >= 0, got {v!r}")
    if not bandwidth > 0:
        raise ParameterError(f"bandwidth: expected bytes a second > 0 (or inf), got {bandwidth!r}")
    if not 1 <= lo <= hi:
        raise ParameterError(f"lo, hi: expected 1 <= lo <= hi, got {lo}, {hi}")
    transfer = chunk_bytes / bandwidth
    per_second = bandwidth / max(chunk_bytes, 1.0) if rate is None else float(rate)
    if not per_second > 0:
        raise ParameterError(f"rate: expected answers a second > 0, got {rate!r}")
    if not math.isfinite(per_second):  # an infinite link and no reader limit: as many as allowed
        return hi
    n = math.ceil(per_second * (latency + transfer) - 1e-9)
    return int(min(max(n, lo), hi))


def next_in_flight(current: int, target: int) -> int:
    """The next size of the requests in flight on the way to ``target``: up at once (a link that
    can take more is used now), down by at most a quarter a step (one busy moment - a garbage
    collection, a burst of decoding - does not empty the pipe, and a size that swings between
    "latency-bound" and "queueing" settles between them)."""
    current, target = int(current), int(target)
    if target >= current:
        return target
    return max(target, current - max(1, current // 4))


def _union_length(lo: np.ndarray, hi: np.ndarray) -> float:
    """Total length of the union of the intervals ``[lo[i], hi[i]]``."""
    order = np.argsort(lo)
    lo, hi = lo[order], hi[order]
    reach = np.maximum.accumulate(hi)
    # an interval adds what it reaches beyond every earlier one, from where it starts
    prev = np.concatenate(([-np.inf], reach[:-1]))
    return float(np.sum(np.maximum(hi - np.maximum(lo, prev), 0.0) * (hi > prev)))


#: answers taking this many idle round trips are queueing (the link or the reader is the limit)
QUEUED = 2.0
#: the share of the answers' time spread their sizes must explain before a bandwidth is read from them
MIN_R2 = 0.25


class LinkEstimate:
    """Latency and bandwidth of a link learnt from its answers (thread-safe; module docstring).

    Parameters
    ----------
    window : int
        Answers remembered (the most recent ones).
    quantile : float
        Of the answers' times less their transfer, the quantile taken as the latency.
    """

    def __init__(self, window: int = 256, quantile: float = 0.1) -> None:
        if window < 2 or not 0 <= quantile <= 1:
            raise ParameterError(f"LinkEstimate: expected window >= 2 and quantile in [0, 1], got {window}, {quantile}")
        self._samples: deque[tuple[float, float, int]] = deque(maxlen=int(window))
        self._quantile = float(quantile)
        self._lock = threading.Lock()
        self._floor = math.inf  # the quickest answer ever: the round trip of the idle link

    def add(self, start: float, end: float, nbytes: int) -> None:
        """One answer: the request sent at ``start``, its last byte at ``end`` (seconds of one
        monotonic clock), ``nbytes`` received."""
        if math.isfinite(start) and math.isfinite(end) and end >= start:
            with self._lock:
                self._samples.append((float(start), float(end), int(nbytes)))
                self._floor = min(self._floor, float(end) - float(start))

    @property
    def count(self) -> int:
        with self._lock:
            return len(self._samples)

    def estimate(self) -> tuple[float, float] | None:
        """``(latency seconds, bandwidth bytes/s)``; ``None`` before two answers.

        Each answer's time is ``latency + bytes x k`` (``1 / k``: the bandwidth one answer got); the
        least-squares line through the answers' (bytes, time) gives both where the chunks differ in
        size, as compressed chunks do. Where the line explains less than :data:`MIN_R2` of the
        times' spread (a link so fast that the answers' sizes do not show in their times - or
        answers of one size), the bandwidth is ``inf``: the link is not what limits the reader, and
        the latency alone sizes the requests in flight. Otherwise the link's bandwidth is the
        larger of ``1 / k`` and the throughput the answers reached together (their bytes over the
        time at least one was outstanding): answers sharing the link in parallel each get a share.
        Answers whose median time exceeds :data:`QUEUED` times the quickest answer ever (the round
        trip of the idle link) are queueing - for the link, or for a reader that cannot take more -
        so their joint throughput is the rate there is and the idle round trip the latency.
        """
        with self._lock:
            if len(self._samples) < 2:
                return None
            s = np.array(self._samples, dtype=np.float64)
            floor = self._floor
        start, end, b = s[:, 0], s[:, 1], s[:, 2]
        dur = end - start
        k = 0.0
        if b.std() > 0.05 * max(b.mean(), 1.0) and dur.std() > 0:
            r = float(np.corrcoef(b, dur)[0, 1])
            if r > 0 and r * r >= MIN_R2:
                k = float(np.polyfit(b, dur, 1)[0])
        # the round trip: the low quantile of the times less their transfer (not the queueing of slow ones)
        lat = float(np.quantile(np.maximum(dur - k * b, 0.0), self._quantile))
        busy = _union_length(start, end)
        together = float(b.sum()) / busy if busy > 0 else math.inf
        if k > 0:
            return lat, max(1.0 / k, together)
        if float(np.median(dur)) > QUEUED * floor:
            # the answers take several round trips of an idle link: they queue behind each other (for
            # the link or for the reader), so what they reach together is the rate there is, and the
            # round trip the one an idle link showed
            return floor, together
        return lat, math.inf

    def in_flight(self, chunk_bytes: float | None = None, *, rate: float | None = None, lo: int = 2,
                  hi: int = 256, default: int = 16) -> int:
        """:func:`in_flight_for` of the estimate (``default`` before there is one); ``chunk_bytes``
        defaults to the mean answer remembered."""
        est = self.estimate()
        if est is None:
            return int(min(max(default, lo), hi))
        if chunk_bytes is None:
            with self._lock:
                chunk_bytes = float(np.mean([n for _, _, n in self._samples]))
        return in_flight_for(est[0], est[1], chunk_bytes, rate=rate, lo=lo, hi=hi)
