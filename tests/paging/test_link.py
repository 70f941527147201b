"""Requests in flight from the bandwidth-delay product, and the link's latency and bandwidth learnt
from synthetic answer timings (no clock: every time is made up here)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.paging.link import LinkEstimate, in_flight_for, next_in_flight


def test_in_flight_is_the_bandwidth_delay_product_in_chunks_plus_one():
    # 50 ms, 100 MB/s, 1 MB chunks: 5 MB in the pipe = 5 chunks, plus the one arriving (10 ms)
    assert in_flight_for(0.05, 100e6, 1e6) == 6
    assert in_flight_for(0.02, 100e6, 1e6) == 3
    assert in_flight_for(0.0, 100e6, 1e6, lo=1) == 1  # no latency: one at a time keeps the link busy
    # a reader that decodes 200 chunks/s at 50 ms latency on an unlimited link: 200 x 0.05 = 10
    assert in_flight_for(0.05, math.inf, 1e6, rate=200) == 10
    assert in_flight_for(0.05, math.inf, 1e6) == 256  # unlimited link and reader: the ceiling
    assert in_flight_for(2.0, 1e9, 1e3, hi=64) == 64 and in_flight_for(0.0, 1e3, 1e3) == 2


def test_little_law_against_a_simulated_pipe():
    # an independent check: n requests, each `lat` then `chunk/bw` on a link shared in order
    def throughput(n, lat, bw, chunk, total=400):
        free, done, t_send = 0.0, [], [0.0] * n
        for i in range(total):
            start = t_send[i % n]
            arrive = max(start + lat, free)  # first byte after the latency, once the link is free
            free = arrive + chunk / bw
            done.append(free)
            t_send[i % n] = free  # the slot sends its next request when this answer is in
        return total * chunk / done[-1]

    for lat, bw, chunk in [(0.02, 50e6, 0.7e6), (0.05, 100e6, 1e6), (0.05, 20e6, 0.3e6)]:
        n = in_flight_for(lat, bw, chunk, lo=1)
        assert throughput(n, lat, bw, chunk) >= 0.9 * bw  # enough to fill the link
        assert throughput(max(n - 2, 1), lat, bw, chunk) < 0.95 * bw  # fewer leave it idle


def test_bad_arguments_name_the_parameter():
    for kw, name in [(dict(latency=-1, bandwidth=1, chunk_bytes=1), "latency"),
                     (dict(latency=0, bandwidth=0, chunk_bytes=1), "bandwidth"),
                     (dict(latency=0, bandwidth=1, chunk_bytes=math.nan), "chunk_bytes"),
                     (dict(latency=0, bandwidth=1, chunk_bytes=1, rate=0), "rate")]:
        with pytest.raises(ParameterError, match=name):
            in_flight_for(**kw)


def _pipe(n, lat, bw, chunk, total, jitter=0.0, seed=0):
    """Synthetic answers of n requests in flight over a link of bandwidth bw, chunks of 0.5 to 1.5
    times ``chunk`` bytes (compressed chunks differ): (start, end, bytes)."""
    rng = np.random.default_rng(seed)
    free, out, t_send = 0.0, [], [0.0] * n
    for i in range(total):
        start = t_send[i % n]
        size = chunk * (0.5 + rng.random())
        arrive = max(start + lat * (1 + jitter * rng.random()), free)
        free = arrive + size / bw
        out.append((start, free, size))
        t_send[i % n] = free
    return out


@pytest.mark.parametrize("n", [1, 3, 16])
def test_estimate_recovers_latency_and_bandwidth(n):
    # 50 ms, 40 MB/s, 0.5 MB chunks: 5 requests fill the link; 16 saturate it and queue
    est = LinkEstimate()
    assert est.estimate() is None and est.in_flight(default=16) == 16
    for s in _pipe(n, 0.05, 40e6, 0.5e6, 300, jitter=0.2):
        est.add(*s)
    lat, bw = est.estimate()
    need = in_flight_for(0.05, 40e6, 0.5e6)
    if n < need:  # the link idles between answers: the round trip and the cost per byte show
        assert 0.045 <= lat <= 0.07 and bw == pytest.approx(40e6, rel=0.1)
        assert need <= est.in_flight() <= need + 2
    else:  # saturated: the answers queue (their sizes no longer explain their times); the throughput
        # they reach together is the link's, the idle round trip the first answer's
        assert bw == pytest.approx(40e6, rel=0.1) and 0.05 <= lat <= 0.08
        assert est.in_flight() >= need


def test_a_link_whose_sizes_do_not_show_is_not_the_limit():
    est = LinkEstimate()
    rng = np.random.default_rng(1)
    for i in range(50):  # 20-30 ms whatever the size: latency and jitter only
        est.add(float(i), float(i) + 0.02 + 0.01 * rng.random(), int(rng.integers(50_000, 150_000)))
    lat, bw = est.estimate()
    assert 0.02 <= lat <= 0.025 and math.isinf(bw)
    assert est.in_flight(hi=64) == 64  # only the latency counts: as many as allowed


def test_next_in_flight_rises_at_once_and_falls_by_a_quarter_a_step():
    assert next_in_flight(16, 64) == 64 and next_in_flight(16, 16) == 16
    steps = [64]
    while steps[-1] > 16:
        steps.append(next_in_flight(steps[-1], 16))
    assert steps == [64, 48, 36, 27, 21, 16]
    assert next_in_flight(3, 1) == 2 and next_in_flight(2, 1) == 1
