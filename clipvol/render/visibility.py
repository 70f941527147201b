"""The GL half of the visibility estimate: a low-resolution front-to-back pass, read back once.

After Wang, Garcia & Shen (2007, section IV-E). The paper draws the coarsest level as view-aligned
slices front to back and snapshots the accumulated opacity whenever a brick's nearest vertex is
passed. We get the same *occlusion layers* from the clip render action itself: the coarse level
(the finest one with at most :data:`MAX_VISIBILITY_BRICKS` bricks and
:data:`MAX_VISIBILITY_TEXELS` voxels, which the clip-texture holds whole) is ray-cast into a small image (``size`` pixels on the long side) ``layers - 1`` times, each
time with one extra clip plane at depth ``d_k`` along the view axis that keeps only what lies in
front of it; the alpha of each image is the opacity accumulated in front of ``d_k``. The images are
read back once per estimate and reduced per brick on the CPU with a summed-area table
(:class:`clipvol.scene.visibility.OcclusionLayers`). An estimate is reused while the view turns less
than a few degrees (:meth:`OcclusionLayers.reusable`).

:class:`CpuVisibilityEstimator` (what :class:`~clipvol.render.image_lod.ImageLod` uses by default)
gets the same layers without GL: it reads the same coarse level once and ray-casts it on the CPU
(:func:`clipvol.scene.visibility.march_occlusion`), one pass for any number of layers. Measured on
the benchmark head (``docs/benchmarks.md``): 32 layers in a few tens of milliseconds where the GL
estimate takes about 40 ms for 8 layers and 300 ms for 32, and the finer layers let the image
policy drop 10-20 % more bricks that lie behind the skin.

References
----------
C. Wang, A. Garcia, H.-W. Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality
Metric for Large Volume Visualization", IEEE TVCG 13(1), 2007.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..scene.geometry import Shape
from ..scene.params import RenderParams
from ..scene.visibility import OcclusionLayers, box_depths, march_occlusion

__all__ = ["VisibilityEstimator", "CpuVisibilityEstimator", "coarse_level", "MAX_VISIBILITY_BRICKS",
           "MAX_VISIBILITY_TEXELS"]

#: the estimate draws the finest level with at most this many bricks and texels (a 128^3 volume)
MAX_VISIBILITY_BRICKS = 64
MAX_VISIBILITY_TEXELS = 1 << 21


def coarse_level(pyr) -> int:
    """The finest level with at most :data:`MAX_VISIBILITY_BRICKS` bricks and :data:`MAX_VISIBILITY_TEXELS`
    voxels (else the top level)."""
    texels = int(np.prod(pyr.brick_shape))
    return min(L for L in range(pyr.num_levels)
               if (pyr.num_bricks(L) <= MAX_VISIBILITY_BRICKS and pyr.num_bricks(L) * texels <= MAX_VISIBILITY_TEXELS)
               or L == pyr.num_levels - 1)


class VisibilityEstimator:
    """Occlusion layers of ``clip_texture``'s coarse level for a camera and transfer function.

    Parameters
    ----------
    make_action : callable
        ``make_action(params) -> ClipRenderAction`` over the same clip-texture: the renderer of the
        coarse pass (handed in by the action that owns the estimate, so this module does not
        import the action module that uses it).
    clip_texture : ClipTexture
    size : int
        Pixels of the estimate's image on its long side.
    layers : int
        Depth layers (the first is the empty layer at depth 0).
    level : int, optional
        The level drawn (default: the finest with at most :data:`MAX_VISIBILITY_BRICKS` bricks).
    """

    def __init__(self, make_action, clip_texture, *, size: int = 64, layers: int = 8, level: int | None = None) -> None:
        pyr = clip_texture.pyramid
        if level is None:
            level = coarse_level(pyr)
        self.level, self.size, self.layers = int(level), int(size), max(2, int(layers))
        budget = max(8 << 20, 2 * pyr.num_bricks(self.level) * int(np.prod(pyr.brick_shape)) * 4)
        self.base = RenderParams(policy="fixed", level=self.level, step=1.0, texture_budget=budget)
        self.pyramid = pyr
        self.action = make_action(self.base)
        self.renders = 0

    def _small(self, camera):
        w, h = camera.size
        k = self.size / max(w, h)
        return replace(camera, size=(max(1, round(w * k)), max(1, round(h * k))))

    def estimate(self, camera, tf, shape: Shape | None = None, key=None) -> OcclusionLayers:
        """Render the layers for ``camera`` and ``tf`` (and the user's ``shape``); ``key`` is stored
        for :meth:`OcclusionLayers.reusable`."""
        small = self._small(camera)
        vlo, vhi = self.pyramid.volume_box()
        near, far = box_depths(camera, vlo[None], vhi[None])
        d0, d1 = max(float(near[0]), 0.0), max(float(far[0]), 0.0)
        depths = [0.0] + [d0 + (d1 - d0) * k / self.layers for k in range(1, self.layers)]
        w, h = small.size
        alpha = np.zeros((self.layers, h, w))
        f = np.asarray(camera.forward, dtype=np.float64)
        user_planes = tuple(shape.planes) if shape is not None else ()
        box = shape.box if shape is not None else None
        for k in range(1, self.layers):
            if depths[k] <= 0:
                continue
            plane = tuple((-f).tolist()) + (float(depths[k] + f @ np.asarray(camera.eye, dtype=np.float64)),)
            planes = (user_planes + (plane,))[-6:]
            self.action.set_params(replace(self.base, shape=Shape(box=box, planes=planes)))
            img = self.action.render(small, tf, wait=True)
            alpha[k] = img[..., 3] / 255.0
            self.renders += 1
        return OcclusionLayers(camera, np.array(depths), alpha, key=key)

    def close(self) -> None:
        self.action.close()


class CpuVisibilityEstimator:
    """The occlusion layers of :class:`VisibilityEstimator`, ray-cast on the CPU in one pass.

    Parameters
    ----------
    loader : Loader
        Read once for the coarse level's bricks (kept: at most :data:`MAX_VISIBILITY_TEXELS` voxels).
    size : int
        Pixels of the estimate's image on its long side.
    layers : int
        Depth layers (the first is the empty layer at depth 0).
    level : int, optional
        The level cast (default: :func:`coarse_level`).
    step : float
        Sample spacing in voxels of that level.
    """

    def __init__(self, loader, *, size: int = 64, layers: int = 32, level: int | None = None, step: float = 1.0) -> None:
        pyr = loader.pyramid
        self.pyramid, self.loader = pyr, loader
        self.level = coarse_level(pyr) if level is None else int(level)
        self.size, self.layers, self.step = int(size), max(2, int(layers)), float(step)
        self.renders = 0
        self.failed: list = []  # ((level, brick), error) of coarse bricks the loader could not read
        self._volume = None

    def volume(self) -> np.ndarray:
        """The coarse level's voxels ``(z, y, x)``, read brick by brick on first use. A brick the
        loader fails to read is NaN, which the estimate treats as empty (nothing hidden behind it:
        the cautious answer); :attr:`failed` lists such bricks."""
        if self._volume is None:
            pyr, L = self.pyramid, self.level
            shape = pyr.levels[L].shape
            B = pyr.brick_shape
            vol = np.empty(shape, dtype=np.float32)
            for b in np.ndindex(*pyr.grid(L)):
                sl = tuple(slice(i * n, min((i + 1) * n, s)) for i, n, s in zip(b, B, shape))
                try:
                    data = np.asarray(self.loader.read_brick(L, b))
                except Exception as e:  # noqa: BLE001 - a loader may raise anything; the frame goes on
                    self.failed.append(((L, b), f"{type(e).__name__}: {e}"))
                    vol[sl] = np.nan
                    continue
                vol[sl] = data[tuple(slice(0, x.stop - x.start) for x in sl)]
            self._volume = vol
        return self._volume

    def estimate(self, camera, tf, shape: Shape | None = None, key=None) -> OcclusionLayers:
        """The layers for ``camera`` and ``tf`` (and the user's ``shape``); ``key`` is stored for
        :meth:`OcclusionLayers.reusable`."""
        w, h = camera.size
        k = self.size / max(w, h)
        small = replace(camera, size=(max(1, round(w * k)), max(1, round(h * k))))
        vlo, vhi = self.pyramid.volume_box()
        near, far = box_depths(camera, vlo[None], vhi[None])
        if camera.orthographic:  # signed depths: the first (empty) layer at the volume's near face
            d0, d1 = float(near[0]), float(far[0])
            first = d0
        else:
            d0, d1 = max(float(near[0]), 0.0), max(float(far[0]), 0.0)
            first = 0.0
        depths = np.array([first] + [d0 + (d1 - d0) * j / self.layers for j in range(1, self.layers)])
        lv = self.pyramid.levels[self.level]
        vr = self.pyramid.value_range
        # the transfer function's opacity tabulated 16x finer than its own table, read by nearest entry
        n = 16 * len(tf.table)
        lo_v, hi_v = float(vr[0]), float(vr[1])
        a_tab = tf.lookup(np.linspace(lo_v, hi_v, n + 1), vr)[:, 3].astype(np.float32)
        k = n / (hi_v - lo_v) if hi_v > lo_v else 0.0

        def alpha_of(v):  # NaN (unread or undefined data): empty, so that it hides nothing
            a = a_tab[np.clip(np.rint((np.nan_to_num(v, nan=lo_v) - lo_v) * k), 0, n).astype(np.int64)]
            return np.where(np.isnan(v), np.float32(0.0), a)

        alpha = march_occlusion(self.volume(), lv.scale, lv.translation, small, alpha_of, depths,
                                float(min(self.pyramid.spacing)), self.step, shape)
        self.renders += 1
        return OcclusionLayers(camera, depths, alpha, key=key)

    def close(self) -> None:
        self._volume = None
