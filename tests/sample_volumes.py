"""Small volumes distributed like real ones (CT with air, fluorescence with a dark background,
a signed map with NaN outside), with masks of their structure and background known by construction.

Each maker takes a numpy Generator and returns ``(volume, foreground_mask, background_mask)``.
"""

from __future__ import annotations

import numpy as np

N = 48


def _radius(n=N):
    c = (np.arange(n) + 0.5) / n * 2 - 1
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    return np.sqrt(x * x + y * y + z * z), (z, y, x)


def ct_like(rng):
    """int16 HU: air (-1000 +- 15) around a head of soft tissue (40), a skull shell (1200) and a
    few voxels of dense bone (3000)."""
    r, _ = _radius()
    v = np.full(r.shape, -1000.0)
    v[r < 0.55] = 40.0
    v[(r > 0.45) & (r < 0.55)] = 1200.0
    v[N // 2, N // 2, N // 2 - 2 : N // 2 + 2] = 3000.0
    v += rng.normal(0, 15, v.shape)
    fg = r < 0.55
    return v.astype(np.int16), fg, ~fg


def fluorescence(rng):
    """uint16: a dark background (100 +- 4) with a few bright Gaussian cells."""
    r, (z, y, x) = _radius()
    v = 100.0 + rng.normal(0, 4, r.shape)
    cells = np.zeros(r.shape)
    for c in ((0.2, 0.1, -0.2), (-0.25, 0.0, 0.2), (0.0, -0.25, 0.05)):
        d2 = (z - c[0]) ** 2 + (y - c[1]) ** 2 + (x - c[2]) ** 2
        cells += 3000.0 * np.exp(-d2 / 0.012)
    v += cells
    return np.clip(v, 0, 65535).astype(np.uint16), cells > 300, cells < 1


def signed_map(rng):
    """float32: 0 +- 0.05 around a positive (+6) and a negative (-5) blob, NaN outside a sphere."""
    r, (z, y, x) = _radius()
    v = 6.0 * np.exp(-((x - 0.3) ** 2 + y * y + z * z) / 0.02) - 5.0 * np.exp(-((x + 0.3) ** 2 + y * y + z * z) / 0.02)
    v = v + rng.normal(0, 0.05, r.shape)
    v[r > 0.9] = np.nan
    fg = np.abs(np.nan_to_num(v)) > 1.5
    return v.astype(np.float32), fg, ~fg


VOLUMES = {"ct": ct_like, "fluorescence": fluorescence, "signed": signed_map}
