"""unique_rows against numpy's own np.unique(axis=0)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.rows import unique_rows


@pytest.mark.parametrize("shape, lo, hi", [((500, 3), 0, 6), ((300, 4), -3, 9), ((50, 1), 0, 1000),
                                           ((40, 3), -(1 << 40), 1 << 40)])  # the last: too wide, np.unique
def test_same_as_numpy(rng, shape, lo, hi):
    a = rng.integers(lo, hi, size=shape, dtype=np.int64)
    u, inv, cnt = unique_rows(a, return_inverse=True, return_counts=True)
    ru, rinv, rcnt = np.unique(a, axis=0, return_inverse=True, return_counts=True)
    np.testing.assert_array_equal(u, ru)
    np.testing.assert_array_equal(inv, rinv.reshape(-1))
    np.testing.assert_array_equal(cnt, rcnt)
    np.testing.assert_array_equal(u[inv], a)
    np.testing.assert_array_equal(unique_rows(a), ru)


def test_empty_and_bad_input():
    assert unique_rows(np.zeros((0, 3), np.int64)).shape == (0, 3)
    with pytest.raises(ValueError, match="2-D integer"):
        unique_rows(np.zeros((4, 3)))


@pytest.mark.parametrize("lo, hi", [(0, 5), (-4, 4), (-(1 << 40), 1 << 40)])  # the last: too wide, a set
def test_rows_in_is_set_membership(rng, lo, hi):
    from clipvol.rows import rows_in

    a = rng.integers(lo, hi, size=(400, 4), dtype=np.int64)
    b = np.concatenate([a[rng.random(len(a)) < 0.4], rng.integers(lo, hi, size=(50, 4), dtype=np.int64)])
    want = np.array([tuple(r) in set(map(tuple, b.tolist())) for r in a.tolist()])
    got = rows_in(a, b)
    np.testing.assert_array_equal(got, want)
    assert want.any() and (~want).any()
    assert rows_in(a, b[:0]).shape == (400,) and not rows_in(a, b[:0]).any()
    assert rows_in(a[:0], b).shape == (0,)
    with pytest.raises(ValueError, match="2-D integer"):
        rows_in(a, b[:, :3])
