"""Gradients on unstructured points: weighted least squares over a node's own points (pure numpy).

Meredith & Ma (2001, section 3.2) light their splats with a gradient estimated at every point from
one-sided differences to its neighbours, weighted towards the nearer and larger ones. Without a
mesh, the neighbours here are the other points of the same octree node: a leaf's input points, or
an inner node's representatives (a coarser sampling of its subtree, so a coarse node's gradient is
the coarse field's). The one-sided differences are combined by weighted least squares: for point
``i``, ``g`` minimises ``sum_k w_ik (v_k - v_i - g . (p_k - p_i))^2`` with ``w_ik = 1 / |p_k - p_i|^2``
(the nearer neighbours count more), which is exact for a linear field whatever the neighbours'
layout, unlike a plain average of the differences. Points with fewer than three usable neighbours,
or neighbours in a plane, get the minimum-norm answer of a slightly regularised system
(``1e-9`` of the matrix's trace), which is 0 along the missing directions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["wls_gradients"]


def wls_gradients(xyz: np.ndarray, values: np.ndarray, counts: np.ndarray, pairs_per_batch: int = 1 << 22) -> np.ndarray:
    """``(m, n, 3)`` gradients of ``values`` at the points of ``m`` nodes.

    Parameters
    ----------
    xyz : (m, n, 3) array
        Positions; node ``j`` uses its first ``counts[j]`` rows (the rest is padding).
    values : (m, n) array
        The scalar; non-finite values take no part (and get a zero gradient).
    counts : (m,) array
        Points per node.
    """
    xyz = np.asarray(xyz, np.float64)
    values = np.asarray(values, np.float64)
    counts = np.asarray(counts, np.int64)
    m, n = values.shape
    out = np.zeros((m, n, 3))
    if m == 0 or n == 0:
        return out
    valid = (np.arange(n)[None, :] < counts[:, None]) & np.isfinite(values)
    step = max(1, int(pairs_per_batch) // max(n * n, 1))
    for a in range(0, m, step):
        p = xyz[a:a + step]
        v = np.where(valid[a:a + step], values[a:a + step], 0.0)
        ok = valid[a:a + step]
        d = p[:, None, :, :] - p[:, :, None, :]          # (b, i, k, 3): p_k - p_i
        dv = v[:, None, :] - v[:, :, None]                # (b, i, k)
        r2 = np.einsum("bikc,bikc->bik", d, d)
        use = ok[:, None, :] & ok[:, :, None] & (r2 > 0)
        w = np.where(use, 1.0 / np.where(use, r2, 1.0), 0.0)
        A = np.einsum("bik,bikc,bike->bice", w, d, d)    # (b, i, 3, 3)
        rhs = np.einsum("bik,bikc,bik->bic", w, d, dv)
        tr = np.trace(A, axis1=-2, axis2=-1)
        A = A + (1e-9 * tr + 1e-300)[..., None, None] * np.eye(3)
        g = np.linalg.solve(A, rhs[..., None])[..., 0]
        out[a:a + step] = np.where(ok[..., None], g, 0.0)
    return out
