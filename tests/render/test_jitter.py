"""Per-pixel jitter of the sample lattice: the wood-grain rings of a constant-distance lattice on an
opaque surface go away, and the image is stable from frame to frame.

Ring energy (independent of the renderer): an eye looking straight at a flat opaque wall sees the
lattice's spherical shells cut the wall in circles around the image centre. Averaging the image
over rings of equal radius keeps that coherent pattern and averages per-pixel noise away, so the
fluctuation of the radial profile around its smooth trend measures the rings.
"""

from __future__ import annotations

import numpy as np
import pytest
from clipvol.loaders.numpy_array import NumpyLoader

from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

N = 48
#: opaque as soon as the value rises above 0; brightness = the value at the first sample behind the wall
WALL_TF = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.05, (0, 0, 0, 0)), (0.08, (0.08, 0.08, 0.08, 1.0)),
                                        (1.0, (1, 1, 1, 1))], value_range=(0.0, 1.0))


def wall_volume() -> np.ndarray:
    z = np.arange(N, dtype=np.float32)[:, None, None]
    return np.ascontiguousarray(np.broadcast_to(np.clip(z - 20.0, 0.0, 1.0), (N, N, N)), dtype=np.float32)


def radial_ring_energy(img: np.ndarray) -> float:
    """Variance of the image's radial profile (1-pixel rings around the centre) about its
    9-pixel moving average."""
    lum = img[..., :3].astype(np.float64).mean(axis=2)
    h, w = lum.shape
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(yy - (h - 1) / 2, xx - (w - 1) / 2).astype(np.int64)
    rmax = min(h, w) // 2
    prof = np.array([lum[r == k].mean() for k in range(rmax)])
    trend = np.convolve(np.pad(prof, 4, mode="edge"), np.ones(9) / 9, mode="valid")
    return float(np.var(prof[4:-4] - trend[4:-4]))


def render(ctx, jitter: bool, path: str = "single-pass", frames: int = 1):
    clip = ClipTexture(NumpyLoader(wall_volume(), brick=16), "64MB", threads=2)
    action = ClipRenderAction(ctx, clip, policy="fixed", level=0, step=1.0, jitter=jitter, path=path)
    cam = Camera.perspective(((N - 1) / 2, (N - 1) / 2, -30.0), ((N - 1) / 2, (N - 1) / 2, 20.0), up=(0, -1, 0),
                             fov_y=50, size=(128, 128))
    try:
        imgs = [action.render(cam, WALL_TF, wait=True, timeout=20) for _ in range(frames)]
        assert action.last_frame_stats.converged
        return imgs
    finally:
        action.close()
        clip.close()


def test_jitter_removes_lattice_rings_and_is_stable(ctx, draw_path):
    (plain,) = render(ctx, False, draw_path)
    a, b = render(ctx, True, draw_path, frames=2)
    assert (plain[..., 3] == 255).mean() > 0.9  # an opaque wall fills the view
    e_plain, e_jit = radial_ring_energy(plain), radial_ring_energy(a)
    assert e_plain > 500.0, f"the plain lattice must show rings here (energy {e_plain:.1f})"
    assert e_jit < 0.05 * e_plain, f"ring energy {e_jit:.2f} with jitter vs {e_plain:.2f} without"
    np.testing.assert_array_equal(a, b)  # a stable offset per pixel: no flicker
    # jitter moves samples within one step: the mean brightness stays (no bias)
    assert abs(a[..., :3].mean() - plain[..., :3].mean()) < 4.0
