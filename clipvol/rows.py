"""Distinct rows of small integer arrays (brick indices, ``(level, z, y, x)`` keys), fast.

Why not ``np.unique(a, axis=0)``: it views each row as one opaque record and sorts those, which is
one to two orders of magnitude slower than sorting plain int64 - 45 ms of a 2 203-brick frame in
one place, ~25 ms of a 4 096-brick one in another. Brick indices are small non-negative integers,
so each row maps to one int64 in mixed radix (column ``j`` scaled by the spans of the columns after
it, offset by its minimum): distinct rows are distinct keys, and the keys sort in the same
lexicographic order as the rows, so the result is exactly ``np.unique(axis=0)``'s.
"""

from __future__ import annotations

import numpy as np

__all__ = ["unique_rows", "rows_in"]

_MAX_KEY = 1 << 62  # keys stay exact in int64 below this; wider spans fall back to np.unique(axis=0)


def unique_rows(a, return_inverse: bool = False, return_counts: bool = False):
    """``np.unique(a, axis=0, ...)`` for a 2-D integer array: the distinct rows in lexicographic
    order, and optionally the inverse (``(n,)``, row ``i`` of ``a`` is ``uniq[inv[i]]``) and counts."""
    a = np.asarray(a)
    if a.ndim != 2 or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"unique_rows: expected a 2-D integer array, got shape {a.shape} of {a.dtype}")
    if len(a) == 0 or a.shape[1] == 0:
        return np.unique(a, axis=0, return_inverse=return_inverse, return_counts=return_counts)
    a64 = a.astype(np.int64, copy=False)
    lo = a64.min(axis=0)
    span = a64.max(axis=0) - lo + 1
    if float(np.prod(span.astype(np.float64))) >= _MAX_KEY:
        return np.unique(a, axis=0, return_inverse=return_inverse, return_counts=return_counts)
    key = a64[:, 0] - lo[0]
    for j in range(1, a.shape[1]):
        key = key * span[j] + (a64[:, j] - lo[j])
    _, first, *rest = np.unique(key, return_index=True, return_inverse=return_inverse, return_counts=return_counts)
    out = [a[first]]
    if return_inverse:
        out.append(rest.pop(0).reshape(-1))
    if return_counts:
        out.append(rest.pop(0))
    return out[0] if len(out) == 1 else tuple(out)


def rows_in(a, b) -> np.ndarray:
    """``(len(a),)`` bool: row ``i`` of ``a`` occurs among the rows of ``b`` (2-D integer arrays
    of the same width) - a set test of brick keys without a Python tuple per row."""
    a = np.asarray(a)
    b = np.asarray(b)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or not (
            np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype, np.integer)):
        raise ValueError(f"rows_in: expected 2-D integer arrays of one width, got {a.shape} {a.dtype} and "
                         f"{b.shape} {b.dtype}")
    if len(a) == 0 or len(b) == 0:
        return np.zeros(len(a), dtype=bool)
    both = np.concatenate([a, b]).astype(np.int64, copy=False)
    lo = both.min(axis=0)
    span = both.max(axis=0) - lo + 1
    if float(np.prod(span.astype(np.float64))) >= _MAX_KEY:
        seen = set(map(tuple, b.tolist()))
        return np.fromiter((tuple(r) in seen for r in a.tolist()), dtype=bool, count=len(a))
    key = both[:, 0] - lo[0]
    for j in range(1, both.shape[1]):
        key = key * span[j] + (both[:, j] - lo[j])
    return np.isin(key[:len(a)], key[len(a):])
