"""What a draw mode is: the base class every mode of :mod:`clipvol.render.modes` subclasses.

A mode is everything around the ray loop that differs between, say, compositing and a maximum
intensity projection: its parameters' checks, its shader variant (a ``#define`` the volume shaders
test, or GLSL of its own), the target's clear value and blending between the per-brick path's boxes,
the read-back that turns the float target into the image, and what the frame may skip for it. Both
draw paths (:mod:`clipvol.render.paths`) read these from the mode instead of naming modes, which is
why a new mode is one module and one :func:`~clipvol.render.modes.register` line.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ...scene.params import check_mode_needs

__all__ = ["DrawMode", "EXTREME", "over_background"]

#: the target's value where no ray wrote in an extreme-value mode (MIP, minIP): beyond any texel
EXTREME = 3.0e38


def over_background(rgb: np.ndarray, a: np.ndarray, background) -> np.ndarray:
    """Premultiplied ``(h, w, 4)`` float64 RGBA: straight ``rgb`` of opacity ``a`` over the
    (straight) ``background`` colour."""
    prem = np.concatenate([rgb * a[..., None], a[..., None]], axis=-1)
    br, bg, bb, ba = background
    return prem + (1.0 - a[..., None]) * np.array([br * ba, bg * ba, bb * ba, ba])


class DrawMode:
    """One value of ``RenderParams.mode``: how a frame in that mode is set up, blended and read back.

    Subclasses set the class attributes and override the methods whose default does not fit. The
    defaults describe a *reduction*: each ray writes one or two values per pixel, the per-brick
    path's boxes combine with an associative blend, and the read-back maps the values through the
    transfer function on the CPU.

    Attributes
    ----------
    name : str
        The ``RenderParams.mode`` value that selects the mode.
    define : str
        The ``#define`` of the mode's shader variant (:mod:`clipvol.render.glsl`) whose code is in
        ``volume_common.glsl``; ``""`` for none (composite, or a mode with its own :attr:`glsl`).
    glsl : str
        GLSL of a mode whose ray code is not in ``volume_common.glsl``: it defines the ray state's
        macros ``STATE`` (as parameters), ``STATE_ARGS`` (as arguments), ``STATE_INIT`` (its
        declaration), ``STATE_OUT`` (the fragment written from it, or ``discard``) and
        ``MODE_TAKE(texel)`` (one sample's texel taken into the state; ``delta``, the step, is in
        scope). Such a mode is a reduction (no early ray termination). ``""``: none.
    classifies : bool
        The shader classifies each sample by the transfer function and composites the colours (the
        target is resolved on the GL); with it go lighting, the distribution's classification,
        overlays, progressive refinement and visibility culling. False: the target holds values.
    ordered : bool
        The per-brick path blends its boxes in visibility order ("under" front to back, "over"
        back to front); False: an associative blend (:meth:`set_blend`), any box order.
    culls : bool
        Bricks and cells wholly transparent under :meth:`occupancy_tf` may be skipped (culled, leapt
        over): no sample there changes the pixel.
    sort_last : bool
        Sort-last rendering (:mod:`clipvol.app.sortlast`) combines its groups' partial images
        (:meth:`sort_last_image`).
    splats : bool
        The point renderer (:mod:`clipvol.render.splat`) draws it.
    requires : tuple of str
        ``RenderParams`` fields the mode needs set (not None).
    clear : tuple of 4 floats
        The target's clear value (where no ray writes, the read-back finds "nothing hit").
    """

    name: ClassVar[str] = ""
    define: ClassVar[str] = ""
    glsl: ClassVar[str] = ""
    classifies: ClassVar[bool] = False
    ordered: ClassVar[bool] = False
    culls: ClassVar[bool] = False
    sort_last: ClassVar[bool] = False
    splats: ClassVar[bool] = False
    requires: ClassVar[tuple[str, ...]] = ()
    clear: ClassVar[tuple[float, float, float, float]] = (0.0, 0.0, 0.0, 0.0)

    @property
    def reduced(self) -> bool:
        """Does the target hold per-pixel values the CPU maps on read-back (:meth:`read_back`)?"""
        return not self.classifies

    def check(self, params) -> None:
        """Refuse ``params`` this mode cannot draw (:class:`~clipvol.errors.ParameterError` naming
        the field); called by :class:`~clipvol.scene.params.RenderParams` for its mode."""
        check_mode_needs(params, self.name, self.requires, self.classifies)

    def set_blend(self, ctx, mgl) -> bool:
        """Set the per-brick path's blending between boxes; False: the mode is :attr:`ordered` and
        the path sets "under" / "over" itself."""
        return False

    def occupancy_tf(self, params, tf, data_range):
        """The table under which a brick or cell whose values are all transparent can be skipped
        (used where :attr:`culls`): the frame's ``tf`` unless the mode says otherwise."""
        return tf

    def uniforms(self, prog, fmt, params) -> None:
        """Set the mode's own uniforms on ``prog`` (``fmt``: the textures' :class:`TextureFormat`)."""

    def read_back(self, raw: np.ndarray, params, tf, fmt, value_range, depth: tuple[float, float]) -> np.ndarray:
        """Premultiplied ``(h, w, 4)`` float64 RGBA over ``params.background`` from the float target
        ``raw`` (rows top first); ``depth``: the volume box's range of the ray parameter
        (:func:`~clipvol.render.modes.depth_range`). Only for :attr:`reduced` modes."""
        raise NotImplementedError(f"mode {self.name!r}: no read-back of a float target")

    def sort_last_image(self, raws: list, fmt, tf, value_range) -> np.ndarray:
        """Premultiplied ``(h, w, 4)`` RGBA (no background) of sort-last groups' float targets
        ``raws``, back to front. Only for :attr:`sort_last` modes."""
        raise NotImplementedError(f"mode {self.name!r}: no sort-last compositing")
