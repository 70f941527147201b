"""An independent numpy splatter: every point drawn as a Gaussian footprint, the reference the point
report's frames are tested against.

It shares nothing with ``clipvol.render`` but the camera's view and projection matrices and the
transfer function's table: its own projection to pixels, its own footprint (``sigma = h / 2``
pixels scaled by ``height / (2 tan(fov / 2)) / depth``, cut at 3 sigma, weight
``(2 / pi) exp(-r^2 / 2 sigma^2)`` renormalised for the cut), table lookup (``GL_LINEAR`` with texel
centres at ``(i + 0.5) / n``), opacity for a path of ``w h / unit`` and back-to-front premultiplied
"over" compositing - the splatting model of Meredith & Ma (2001) written out point by point.
"""

from __future__ import annotations

import numpy as np

__all__ = ["splat_every_point"]


def _lookup(table: np.ndarray, t: np.ndarray) -> np.ndarray:
    n = len(table)
    x = np.clip(t, 0.0, 1.0) * n - 0.5
    return np.stack([np.interp(x, np.arange(n), table[:, c]) for c in range(4)], axis=-1)


def splat_every_point(xyz, values, h, camera, table, window, unit: float, gradients=None, light=None) -> np.ndarray:
    """Straight RGBA uint8 ``(H, W, 4)`` (row 0 at top) of perspective ``camera`` drawing every point.

    With ``gradients`` (n, 3) and ``light`` (ambient, diffuse, specular, shininess), each point's
    colour is lit: ``min(rgb (ambient + diffuse d) + specular d^shininess, 1)``, ``d = |g . v| / |g|``
    with ``v`` the unit direction from the eye to the point (0 where ``g`` is 0).
    """
    xyz = np.asarray(xyz, np.float64)
    values = np.asarray(values, np.float64)
    h = np.broadcast_to(np.asarray(h, np.float64), values.shape)
    W, H = camera.size
    V = camera.view_matrix()
    P = camera.projection_matrix()
    hom = np.c_[xyz, np.ones(len(xyz))] @ (P @ V).T
    depth = hom[:, 3]
    px = (hom[:, 0] / depth + 1.0) / 2.0 * W
    py = (hom[:, 1] / depth + 1.0) / 2.0 * H
    k = H / (2.0 * np.tan(np.radians(camera.fov_y) / 2.0))
    sigma = np.maximum(0.5 * h * k / depth, 1e-3)
    lo, hi = window
    rgba = _lookup(np.asarray(table, np.float64), (values - lo) / (hi - lo))
    if gradients is not None:
        g = np.asarray(gradients, np.float64)
        v = xyz - np.asarray(camera.eye, np.float64)
        gn, vn = np.linalg.norm(g, axis=1), np.linalg.norm(v, axis=1)
        d = np.where((gn > 0) & (vn > 0), np.abs((g * v).sum(1)) / np.maximum(gn * vn, 1e-300), 0.0)
        amb, dif, spec, shin = light
        rgba[:, :3] = np.minimum(rgba[:, :3] * (amb + dif * d)[:, None] + (spec * d**shin)[:, None], 1.0)
    img = np.zeros((H, W, 4))  # premultiplied, y up (GL rows)
    for i in np.argsort(-depth, kind="stable"):  # back to front
        if depth[i] <= 0:
            continue
        s = sigma[i]
        x0, x1 = int(np.floor(px[i] - 3 * s)), int(np.ceil(px[i] + 3 * s))
        y0, y1 = int(np.floor(py[i] - 3 * s)), int(np.ceil(py[i] + 3 * s))
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W - 1), min(y1, H - 1)
        if x1 < x0 or y1 < y0:
            continue
        cy, cx = np.mgrid[y0:y1 + 1, x0:x1 + 1] + 0.5
        r2 = ((cx - px[i]) ** 2 + (cy - py[i]) ** 2) / (s * s)
        w = np.where(r2 <= 9.0, 0.63661977 * np.exp(-0.5 * r2) / 0.98889, 0.0)
        c = rgba[i]
        a = np.ones_like(w) if c[3] >= 1.0 else 1.0 - (1.0 - c[3]) ** (w * h[i] / unit)
        src = np.concatenate([c[:3] * a[..., None], a[..., None]], axis=-1)
        dst = img[y0:y1 + 1, x0:x1 + 1]
        img[y0:y1 + 1, x0:x1 + 1] = src + (1.0 - a[..., None]) * dst
    img = img[::-1]
    alpha = img[..., 3:4]
    rgb = np.where(alpha > 0, img[..., :3] / np.maximum(alpha, 1e-12), 0.0)
    return np.round(np.clip(np.concatenate([rgb, alpha], axis=-1), 0, 1) * 255.0).astype(np.uint8)
