"""Image error metrics: CIELUV colour difference, RMSE and PSNR.

Why CIELUV: Wang, Garcia & Shen (2007) judge a multiresolution image against the
full-resolution one by the share of pixels whose colour difference ``Delta E`` in CIE L*u*v* is
at least 6 - roughly where people start to notice. Euclidean distance in L*u*v* approximates
perceived difference far better than RGB distance does, so the benchmarks report "% of pixels
with Delta E >= 6" beside the speed-up.

Conversion: sRGB (IEC 61966-2-1 transfer curve) -> linear RGB -> CIE XYZ (sRGB primaries, D65
white) -> CIE L*u*v* relative to the white of the same matrix (so sRGB white is exactly
``L* = 100, u* = v* = 0``).

RGBA inputs: a renderer's ``(h, w, 4)`` image is first **composited over a background**
(default black) in the stored (sRGB-encoded) values, as a viewer shows it: with
``premultiplied=True`` (the default; what ``(ONE, ONE_MINUS_SRC_ALPHA)`` blending leaves in a
framebuffer) ``rgb + bg * (1 - a)``, else ``rgb * a + bg * (1 - a)``. ``uint8`` images are scaled
by 1/255; float images are taken as values in ``[0, 1]``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError

__all__ = ["srgb_to_linear", "linear_to_xyz", "rgb_to_luv", "composite", "delta_e_luv", "percent_delta_e", "rmse", "psnr"]

_M = np.array(
    [
        [0.4124564, 0.3575761, 0.1804375],
        [0.2126729, 0.7151522, 0.0721750],
        [0.0193339, 0.1191920, 0.9503041],
    ]
)
_WHITE = _M.sum(axis=1)  # XYZ of sRGB (1, 1, 1): D65


def _as_float_rgb(img, background, premultiplied: bool, name: str) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim < 1 or a.shape[-1] not in (3, 4):
        raise ParameterError(f"{name}: expected an image of shape (..., 3) or (..., 4), got {a.shape}")
    return composite(a, background, premultiplied)


def composite(img, background=(0.0, 0.0, 0.0), premultiplied: bool = True) -> np.ndarray:
    """Float RGB in ``[0, 1]`` of ``img`` (``(..., 3)`` or ``(..., 4)``, uint8 or float) over ``background``.

    See the module docstring for the compositing rule.
    """
    a = np.asarray(img)
    if a.shape[-1] not in (3, 4):
        raise ParameterError(f"img: expected an image of shape (..., 3) or (..., 4), got {a.shape}")
    f = a.astype(np.float64) / 255.0 if a.dtype == np.uint8 else a.astype(np.float64)
    if f.shape[-1] == 3:
        return np.clip(f, 0.0, 1.0)
    bg = np.asarray(background, dtype=np.float64).reshape(-1)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ParameterError(f"background: expected an RGB triple in [0, 1], got {background!r}")
    rgb, alpha = f[..., :3], f[..., 3:4]
    out = rgb + bg * (1.0 - alpha) if premultiplied else rgb * alpha + bg * (1.0 - alpha)
    return np.clip(out, 0.0, 1.0)


def srgb_to_linear(c) -> np.ndarray:
    """Decode sRGB values in ``[0, 1]`` to linear light (IEC 61966-2-1)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_xyz(rgb) -> np.ndarray:
    """CIE XYZ (``Y`` of white = 1) of linear sRGB ``(..., 3)``."""
    return np.asarray(rgb, dtype=np.float64) @ _M.T


def _xyz_to_luv(xyz: np.ndarray) -> np.ndarray:
    X, Y, Z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    Xn, Yn, Zn = _WHITE
    yr = Y / Yn
    eps = (6.0 / 29.0) ** 3
    L = np.where(yr > eps, 116.0 * np.cbrt(yr) - 16.0, (29.0 / 3.0) ** 3 * yr)
    den = X + 15.0 * Y + 3.0 * Z
    dn = Xn + 15.0 * Yn + 3.0 * Zn
    safe = np.where(den > 0, den, 1.0)
    up = np.where(den > 0, 4.0 * X / safe, 0.0)
    vp = np.where(den > 0, 9.0 * Y / safe, 0.0)
    u = 13.0 * L * (up - 4.0 * Xn / dn)
    v = 13.0 * L * (vp - 9.0 * Yn / dn)
    return np.stack([L, u, v], axis=-1)


def rgb_to_luv(rgb) -> np.ndarray:
    """CIE L*u*v* ``(..., 3)`` of sRGB colours ``(..., 3)`` (float in ``[0, 1]`` or uint8)."""
    a = np.asarray(rgb)
    if a.shape[-1:] != (3,):
        raise ParameterError(f"rgb: expected shape (..., 3), got {a.shape}")
    f = a.astype(np.float64) / 255.0 if a.dtype == np.uint8 else np.clip(a.astype(np.float64), 0.0, 1.0)
    return _xyz_to_luv(linear_to_xyz(srgb_to_linear(f)))


def _pair(img_a, img_b, background, premultiplied) -> tuple[np.ndarray, np.ndarray]:
    a = _as_float_rgb(img_a, background, premultiplied, "img_a")
    b = _as_float_rgb(img_b, background, premultiplied, "img_b")
    if a.shape != b.shape:
        raise ParameterError(f"img_b: expected the shape of img_a {np.shape(img_a)}, got {np.shape(img_b)}")
    return a, b


def delta_e_luv(img_a, img_b, background=(0.0, 0.0, 0.0), premultiplied: bool = True) -> np.ndarray:
    """Per-pixel ``Delta E`` (Euclidean distance in CIE L*u*v*) between two images, shape ``(h, w)``."""
    a, b = _pair(img_a, img_b, background, premultiplied)
    la = _xyz_to_luv(linear_to_xyz(srgb_to_linear(a)))
    lb = _xyz_to_luv(linear_to_xyz(srgb_to_linear(b)))
    return np.sqrt(np.sum((la - lb) ** 2, axis=-1))


def percent_delta_e(img_a, img_b, threshold: float = 6.0, background=(0.0, 0.0, 0.0),
                    premultiplied: bool = True) -> float:
    """Percentage of pixels with ``Delta E >= threshold`` (the quality measure of Wang, Garcia & Shen 2007)."""
    d = delta_e_luv(img_a, img_b, background, premultiplied)
    return 100.0 * float(np.mean(d >= float(threshold))) if d.size else 0.0


def rmse(img_a, img_b, background=(0.0, 0.0, 0.0), premultiplied: bool = True) -> float:
    """Root-mean-square difference of the composited RGB in 8-bit units (0..255)."""
    a, b = _pair(img_a, img_b, background, premultiplied)
    return float(np.sqrt(np.mean((a * 255.0 - b * 255.0) ** 2))) if a.size else 0.0


def psnr(img_a, img_b, background=(0.0, 0.0, 0.0), premultiplied: bool = True) -> float:
    """Peak signal-to-noise ratio in dB of the composited 8-bit RGB; ``inf`` for identical images."""
    e = rmse(img_a, img_b, background, premultiplied)
    return float("inf") if e == 0 else float(20.0 * np.log10(255.0 / e))
