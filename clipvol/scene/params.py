"""One frozen set of render parameters, validated once.

Every part that renders (the render actions, the session, the CLI, the viewer, the report) takes a
:class:`RenderParams` and changes it with :func:`dataclasses.replace`, which validates the new value
in ``__post_init__``. No other module re-checks or re-clamps these values; the one check that needs
the data (a fixed level must exist in the pyramid) is :meth:`RenderParams.check_for`.

Why one object: a parameter validated in three places drifts in three ways (the clamp of one
module, the error text of another), and a viewer that patches attributes of a live render action
bypasses all of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

from ..choices import BLENDS, CLASSIFY, ISO_COLORS, MODES, PARAM_FIELDS, PATHS
from ..errors import ParameterError
from ..units import parse_bytes
from .geometry import Shape
from .policy_registry import POLICIES, policy_names

__all__ = ["RenderParams", "MODES", "MODE_CHECKS", "ISO_COLORS", "PATHS", "CLASSIFY", "DEFAULT_BLOCK_BUDGET"]

#: mode -> its checks of the parameters (``check(params)``, raising ParameterError).
#: clipvol.render.modes.register puts each registered mode's own check here (and a new mode's name
#: in MODES); the scene stage imports no render module, so the built-in modes' needs are also
#: stated here, for parameters made before the renderer is imported: which fields a mode needs,
#: and whether it classifies (composites) - overlays are composited, so only such a mode takes them.
#: ``tests/render/test_mode_registry.py`` checks these against the registered modes.
BUILT_IN_MODE_NEEDS: dict[str, tuple[tuple[str, ...], bool]] = {
    "composite": ((), True), "mip": ((), False), "minip": ((), False), "average": ((), False),
    "iso": (("iso_value",), False),
}


def check_mode_needs(params, mode: str, requires: tuple[str, ...], classifies: bool) -> None:
    """Refuse ``params`` that ``mode`` cannot draw: a field it ``requires`` left None, or overlays
    with a mode that does not composite (:class:`~clipvol.errors.ParameterError` naming the field)."""
    for field in requires:
        if getattr(params, field) is None:
            raise ParameterError(f"{field}: expected a value for mode {mode!r}, got None")
    if params.overlays and not classifies:
        raise ParameterError(f"overlays: expected mode 'composite' (an overlay is composited over the primary), "
                             f"got mode {params.mode!r} with overlay {params.overlays[0].name}")


MODE_CHECKS: dict = {name: (lambda p, n=name, need=need: check_mode_needs(p, n, *need))
                     for name, need in BUILT_IN_MODE_NEEDS.items()}
#: bricks the "image" policy may draw when no block_budget is given
DEFAULT_BLOCK_BUDGET = 128


def _positive(value: Any, name: str, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name}: expected a finite number > 0 ({unit}), got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f"{name}: expected a finite number > 0 ({unit}), got {value!r}")
    return v


def _count_or_none(value: Any, name: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise ParameterError(f"{name}: expected None or an integer >= 1, got {value!r}")
    return int(value)


def _field(name: str):
    """The field ``name`` with its default and one-line help from :data:`clipvol.choices.PARAM_FIELDS`,
    which the command-line flag of the field shows (:mod:`clipvol.tools.render_args`): written once,
    in a module a parser reads without importing numpy."""
    default, help = PARAM_FIELDS[name]
    return field(default=default, metadata={"help": help})


def _fraction_or_none(value: Any, name: str) -> float | None:
    """``None``, or a fraction in ``(0, 1]`` given as a number or a percentage string (``"5%"``)."""
    if value is None:
        return None
    text = value.strip() if isinstance(value, str) else None
    try:
        if isinstance(value, bool):
            raise ValueError
        v = float(text[:-1]) / 100.0 if text is not None and text.endswith("%") else float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (math.isfinite(v) and 0.0 < v <= 1.0):
        raise ParameterError(f"{name}: expected a fraction in (0, 1] or a percentage like '5%', got {value!r}")
    return v


@dataclass(frozen=True, slots=True)
class RenderParams:
    """What a render action is asked to do, apart from the camera and the transfer function.

    Parameters
    ----------
    mode : {"composite", "mip", "minip", "average", "iso"}
        Front-to-back emission-absorption compositing; maximum (``"mip"``) or minimum
        (``"minip"``) intensity projection; ``"average"``, the mean of the samples inside the
        volume along the ray, each weighted by its step (a radiograph-like projection; equal to
        the plain sample mean on one level); ``"iso"``, the first point along the ray where the
        data reaches ``iso_value`` (the first sample ``>= iso_value``, placed between it and the
        sample before by linear interpolation), lit with the gradient lighting below and opaque.
        The projections and the iso-surface map their per-pixel value through the transfer
        function on read-back (:mod:`clipvol.render.modes`). The projections neither cull
        transparent bricks nor leap over empty cells; ``"iso"`` culls and leaps over what lies
        wholly below ``iso_value``. Each mode is a module of :mod:`clipvol.render.modes`; a mode
        registered there is accepted here too (and its own checks run).
    iso_value : float, optional
        ``mode="iso"``: the data value of the surface (raw units of the data; required there).
    iso_color : {"tf", "depth"}
        ``mode="iso"``: colour the surface by the transfer function at ``iso_value`` (``"tf"``,
        default) or by its distance along the ray across the volume box's depth range, through
        the transfer function's colours (``"depth"``: near is the table's bottom); lit either way.
    policy : str
        The selection policy (:mod:`clipvol.scene.selection.policies`): ``"projected-size"``
        (refine while a voxel projects to more than ``lod_threshold`` pixels; the default),
        ``"fixed"`` (``level`` everywhere), ``"roaming"`` (one level for the frame),
        ``"texel-budget"`` (largest projected voxels first until ``max_texels_drawn``),
        ``"distance"`` and ``"field-of-view"`` (the filters of LaMar, Hamann & Joy), ``"image"``
        (image-based importance of Wang, Garcia & Shen under ``block_budget``; needs the store's
        summary tables). The names are those of :mod:`clipvol.scene.policy_registry`.
    lod_threshold : float
        Pixels a voxel of a drawn level may project to before the brick is refined (> 0).
    level : int, optional
        The level drawn by the ``"fixed"`` policy (default 0 for it).
    distance_factor : float
        ``"distance"`` policy: a node is refined while its centre is closer to the focus than this
        many times its diagonal. A slice with a point of interest draws each brick whose box comes
        closer to it than this many times its parent's diagonal, the same reach per brick
        (:mod:`clipvol.scene.slice_cover`).
    fov_fraction : float
        ``"field-of-view"`` policy: a node is refined while it subtends more than this fraction of
        the vertical field of view (0.5 is the paper's "half the field-of-view angle").
    focus : 3 floats, optional
        World ``(x, y, z)`` point of interest of the distance policy (default: the eye).
    max_texels_drawn : int, optional
        Upper bound on the voxels of the drawn bricks; any policy then refines greedily, largest
        projected voxel first, until the next refinement would exceed it.
    texels_per_frame : int, optional
        Most texels uploaded to the GPU per frame (at least one brick per frame is always allowed).
    texture_budget : int or str
        Bytes of texture memory for bricks (``"256MB"``).
    step : float
        Sample spacing along a ray, in units of the drawn level's smallest voxel size.
    early_termination : bool
        Composite: draw front to back and stop rays that are opaque (same image, faster).
    merge_boxes : bool
        Draw complete sibling sets of one level as one box over their parent (same image).
    path : {"auto", "bricks", "single-pass"}
        ``"bricks"``: one proxy box per draw item composited in visibility order (the method of
        LaMar, Hamann & Joy and of OpenGL Volumizer; merged boxes); ``"single-pass"``: one
        ray-guided pass over the volume box through a per-level page table of the cut (merged
        sibling sets are one node; rays stop early per pixel, no framebuffer copies). Same image
        within 1 LSB. ``"auto"`` (default): per frame, the single pass for a cut of at least
        ``AUTO_SINGLE_PASS_BOXES`` (4) merged boxes and no overlays, the per-brick path otherwise -
        on Mesa llvmpipe the per-brick path is faster for one or two large boxes (a resident volume
        merges to one), the single pass from four (its per-pixel early termination needs no
        occlusion snapshots, which idle the rasteriser's threads); docs/benchmarks.md.
    skip_empty : bool
        Composite without overlays: leap over cells of 8³ voxels that the transfer function makes
        transparent inside drawn bricks (:mod:`clipvol.scene.occupancy`; the same image). On by
        default; off draws every sample (a reference, and for timing what skipping saves).
    refine_tolerance : float
        Composite: adaptive image sampling (:mod:`clipvol.render.refine`, after Levoy's adaptive
        refinement, 1990). 0 (default): one ray per pixel. Above 0: the frame is drawn first at
        1/4 and 1/2 of the image's resolution, and each finer pass casts a pixel's ray only where
        the four coarser rays around it differ by more than this in a premultiplied RGBA channel
        (in ``[0, 1]``); elsewhere the pixel is their bilinear blend. Smooth images cost a fraction
        of the rays; a feature thinner than the coarse spacing between coarse rays that agree is
        lost (measure the error with ``clipvol report``). Other modes ignore it.
    jitter : bool
        Start each pixel's sample lattice at a stable per-pixel hashed offset (a fraction of the
        step), which turns the wood-grain rings of a constant-distance lattice on opaque surfaces
        into fine noise; the lattice stays constant-distance along each ray. Off by default (and for
        reference comparisons); the viewer and the flythrough turn it on.
    background : 4 floats
        Straight RGBA in ``[0, 1]`` behind the volume.
    block_budget : int, optional
        ``"image"`` policy: most bricks in the cut (>= 1; default
        :data:`DEFAULT_BLOCK_BUDGET`); the highest-importance brick is refined first.
    visibility : bool
        ``"image"`` policy: estimate each brick's visibility from a low-resolution front-to-back
        pass and weight its importance by it (False: every brick counts as fully visible).
    max_error : float, optional
        ``"image"`` policy: the visible-error budget, a fraction in ``(0, 1]`` of the image's pixels
        predicted to differ visibly (CIELUV Delta E >= 6) from the full-resolution frame; ``"5%"``
        and ``0.05`` are the same. The policy refines the most important brick first until its
        estimate (:attr:`ImageBased.estimated_error`,
        :func:`clipvol.scene.selection.policies.image_based.predicted_visible_error`) falls to
        this, ``block_budget`` bricks (no limit when unset) or the texel budget, whichever comes
        first. None (default): the block budget alone decides.
    visibility_threshold : float
        ``"image"`` policy with ``visibility``: bricks less visible than this (in ``[0, 1)``) are
        neither loaded nor drawn, like empty space.
    shape : Shape, optional
        Region of interest and clip planes.
    shading : bool
        Composite only: Blinn-Phong gradient lighting with the light fixed to the camera (the
        ``SHADING`` shader variant, :mod:`clipvol.render.glsl`); ignored for MIP. A sample's
        colour becomes ``min(rgb * (ambient + diffuse * d) + specular * d ** shininess, 1)`` with
        ``d = |g . v| / |g|``, ``g`` the central-difference gradient in world units, ``v`` the view
        direction (0 where ``g`` is 0); its opacity is unchanged (Blinn, *Models of light
        reflection for computer synthesized pictures*, 1977; Levoy, *Display of surfaces from volume
        data*, 1988).
    ambient, diffuse, specular : float
        Lighting weights (>= 0).
    shininess : float
        Specular exponent (> 0).
    classify : {"distribution", "mean"}
        How a sample of a coarse level (>= 1) meets the transfer function. ``"distribution"``
        (default): where the store holds each coarse voxel's spread (the standard deviation of the
        level-0 voxels beneath it, written by ``clipvol brick``), the transfer function is applied to
        that distribution, so the sample's opacity and premultiplied colour are the expected ones
        of the fine voxels it stands for (Younesy, Möller & Carr 2006; Sicat, Krüger, Möller &
        Hadwiger 2014; docs/rendering-math.md). ``"mean"``: the mean is classified, as a store
        without the spread always is (the same image as before).
    overlays : tuple of Overlay
        Co-registered volumes composited over the primary at each of its samples, in one ray cast
        (:mod:`clipvol.scene.overlay`; at most :data:`~clipvol.scene.overlay.MAX_OVERLAYS`, the first
        on top). Composite mode and the ``"bricks"`` path only.
    blend : {"over", "additive"}
        How overlays combine with the primary at each sample: ``"over"`` (their premultiplied
        colours over the primary's, the first on top) or ``"additive"`` (channels of one image:
        the colours add up, ``sum(a_k * rgb_k)``, opacity ``1 - prod(1 - a_k)``; not with shading).
    """

    mode: str = _field("mode")
    iso_value: float | None = _field("iso_value")
    iso_color: str = "tf"
    policy: str = _field("policy")
    lod_threshold: float = _field("lod_threshold")
    level: int | None = _field("level")
    distance_factor: float = _field("distance_factor")
    fov_fraction: float = _field("fov_fraction")
    focus: tuple[float, float, float] | None = None
    max_texels_drawn: int | None = _field("max_texels_drawn")
    texels_per_frame: int | None = _field("texels_per_frame")
    texture_budget: int = _field("texture_budget")
    step: float = _field("step")
    early_termination: bool = True
    merge_boxes: bool = True
    refine_tolerance: float = _field("refine_tolerance")
    jitter: bool = _field("jitter")
    skip_empty: bool = _field("skip_empty")
    path: str = _field("path")
    background: tuple[float, float, float, float] = _field("background")
    shape: Shape | None = None
    block_budget: int | None = _field("block_budget")
    max_error: float | None = _field("max_error")
    visibility: bool = _field("visibility")
    visibility_threshold: float = 0.01
    shading: bool = _field("shading")
    ambient: float = _field("ambient")
    diffuse: float = _field("diffuse")
    specular: float = _field("specular")
    shininess: float = _field("shininess")
    classify: str = _field("classify")
    overlays: tuple = ()
    blend: str = "over"

    def __post_init__(self) -> None:
        s = object.__setattr__
        if self.path not in PATHS:
            raise ParameterError(f"path: expected one of {', '.join(PATHS)}, got {self.path!r}")
        if self.classify not in CLASSIFY:
            raise ParameterError(f"classify: expected one of {', '.join(CLASSIFY)}, got {self.classify!r}")
        if self.mode not in MODES:
            raise ParameterError(f"mode: expected one of {', '.join(MODES)}, got {self.mode!r}")
        if self.iso_value is not None:
            try:
                iso = float(self.iso_value)
            except (TypeError, ValueError):
                iso = float("nan")
            if not math.isfinite(iso):
                raise ParameterError(f"iso_value: expected a finite data value, got {self.iso_value!r}")
            s(self, "iso_value", iso)
        if self.iso_color not in ISO_COLORS:
            raise ParameterError(f"iso_color: expected one of {', '.join(ISO_COLORS)}, got {self.iso_color!r}")
        policy = self.policy
        if policy not in POLICIES:
            raise ParameterError(f"policy: expected one of {', '.join(policy_names())}, got {policy!r}")
        s(self, "lod_threshold", _positive(self.lod_threshold, "lod_threshold", "pixels"))
        s(self, "distance_factor", _positive(self.distance_factor, "distance_factor", "node diagonals"))
        s(self, "fov_fraction", _positive(self.fov_fraction, "fov_fraction", "of the field of view"))
        s(self, "step", _positive(self.step, "step", "voxels"))
        if policy == "fixed" and self.level is None:
            s(self, "level", 0)
        if self.level is not None:
            if isinstance(self.level, bool) or int(self.level) != self.level or self.level < 0:
                raise ParameterError(f"level: expected an integer >= 0, got {self.level!r}")
            s(self, "level", int(self.level))
        s(self, "max_texels_drawn", _count_or_none(self.max_texels_drawn, "max_texels_drawn"))
        s(self, "texels_per_frame", _count_or_none(self.texels_per_frame, "texels_per_frame"))
        if policy == "texel-budget" and self.max_texels_drawn is None:
            raise ParameterError("max_texels_drawn: expected a texel count for policy 'texel-budget', got None")
        s(self, "texture_budget", parse_bytes(self.texture_budget, "texture_budget"))
        if self.focus is not None:
            f = tuple(float(v) for v in self.focus)
            if len(f) != 3 or not all(math.isfinite(v) for v in f):
                raise ParameterError(f"focus: expected three finite world coordinates (x, y, z), got {self.focus!r}")
            s(self, "focus", f)
        try:
            bg = tuple(float(v) for v in self.background)
        except (TypeError, ValueError):
            bg = ()
        if len(bg) != 4 or not all(0.0 <= v <= 1.0 for v in bg):
            raise ParameterError(f"background: expected four values in [0, 1] (r, g, b, a), got {self.background!r}")
        s(self, "background", bg)
        if self.shape is not None and not isinstance(self.shape, Shape):
            raise ParameterError(f"shape: expected a clipvol Shape or None, got {type(self.shape).__name__}")
        s(self, "early_termination", bool(self.early_termination))
        s(self, "block_budget", _count_or_none(self.block_budget, "block_budget"))
        s(self, "max_error", _fraction_or_none(self.max_error, "max_error"))
        if self.max_error is not None and policy != "image":
            raise ParameterError(f"max_error: expected policy 'image' (the policy that estimates the visible error), "
                                 f"got policy {policy!r}")
        if policy == "image" and self.block_budget is None and self.max_error is None:
            s(self, "block_budget", DEFAULT_BLOCK_BUDGET)
        s(self, "visibility", bool(self.visibility))
        try:
            vt = float(self.visibility_threshold)
        except (TypeError, ValueError):
            vt = float("nan")
        if not (0.0 <= vt < 1.0):
            raise ParameterError(f"visibility_threshold: expected a number in [0, 1), got {self.visibility_threshold!r}")
        s(self, "visibility_threshold", vt)
        s(self, "merge_boxes", bool(self.merge_boxes))
        s(self, "jitter", bool(self.jitter))
        try:
            tol = float(self.refine_tolerance)
        except (TypeError, ValueError):
            tol = float("nan")
        if not (0.0 <= tol <= 1.0):
            raise ParameterError(f"refine_tolerance: expected a spread of premultiplied colour in [0, 1] (0: a ray "
                                 f"per pixel), got {self.refine_tolerance!r}")
        s(self, "refine_tolerance", tol)
        s(self, "skip_empty", bool(self.skip_empty))
        s(self, "shading", bool(self.shading))
        for name in ("ambient", "diffuse", "specular"):
            v = getattr(self, name)
            try:
                f = float(v)
            except (TypeError, ValueError):
                f = -1.0
            if not (math.isfinite(f) and f >= 0):
                raise ParameterError(f"{name}: expected a finite lighting weight >= 0, got {v!r}")
            s(self, name, f)
        s(self, "shininess", _positive(self.shininess, "shininess", "specular exponent"))
        self._check_overlays()
        check = MODE_CHECKS.get(self.mode)
        if check is not None:  # the mode's own (clipvol.render.modes): iso needs iso_value, overlays composite
            check(self)

    def _check_overlays(self) -> None:
        from .overlay import MAX_OVERLAYS, Overlay

        ovs = self.overlays
        if isinstance(ovs, Overlay):
            ovs = (ovs,)
        ovs = tuple(ovs or ())
        for ov in ovs:
            if not isinstance(ov, Overlay):
                raise ParameterError(f"overlays: expected clipvol.scene.overlay.Overlay objects, got {type(ov).__name__}")
        if len(ovs) > MAX_OVERLAYS:
            raise ParameterError(f"overlays: expected at most {MAX_OVERLAYS}, got {len(ovs)}")
        if ovs and self.path == "single-pass":
            raise ParameterError(f"overlays: expected path 'bricks' (the single-pass path draws no overlay), "
                                 f"got path {self.path!r} with overlay {ovs[0].name}")
        object.__setattr__(self, "overlays", ovs)
        if self.blend not in BLENDS:
            raise ParameterError(f"blend: expected one of {', '.join(BLENDS)}, got {self.blend!r}")
        if self.blend == "additive" and self.shading and ovs:
            raise ParameterError("blend: expected 'over' with shading (additive channels are not lit), got 'additive'")

    # -- helpers ---------------------------------------------------------------------------------
    @classmethod
    def help(cls, name: str) -> str:
        """The one-line help of field ``name`` (its ``metadata["help"]``; the command-line flags of
        :mod:`clipvol.tools.render_args` show it), or "" when it has none."""
        for f in fields(cls):
            if f.name == name:
                return f.metadata.get("help", "")
        raise ParameterError(f"unknown render parameter {name!r}; expected one of {', '.join(cls.names())}")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The field names (for ``update(**changes)`` checks and CLI mapping)."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_kwargs(cls, params: "RenderParams | None" = None, **kwargs) -> "RenderParams":
        """``params`` (or the defaults) with keyword overrides. Unknown names are a
        :class:`ParameterError` naming them."""
        bad = sorted(set(kwargs) - set(cls.names()))
        if bad:
            raise ParameterError(f"unknown render parameter(s) {', '.join(bad)}; expected {', '.join(cls.names())}")
        base = params if params is not None else cls()
        if not kwargs:
            return base
        from dataclasses import replace

        return replace(base, **kwargs)

    def check_for(self, pyramid) -> "RenderParams":
        """Raise :class:`ParameterError` if the parameters do not fit ``pyramid`` (a fixed level
        past its top, an iso-value outside the data's range); returns ``self``.

        An iso-value at or below the data's minimum is reached by every ray's first sample (an
        opaque box), one above its maximum by none (an empty image): both are refused, naming the
        range, rather than drawn as if they showed a surface."""
        if self.level is not None and self.level >= pyramid.num_levels:
            raise ParameterError(f"level: expected 0..{pyramid.num_levels - 1} for this store, got {self.level}")
        rng = getattr(pyramid, "value_range", None)
        if self.iso_value is not None and rng is not None:
            lo, hi = (float(v) for v in rng)
            if not (lo < self.iso_value <= hi or lo == hi == self.iso_value):
                side = "at or below the minimum: every ray hits at once, an opaque box" if self.iso_value <= lo \
                    else "above the maximum: no surface, an empty image"
                raise ParameterError(f"iso_value: expected a value above the data's minimum {lo:g} and at most its "
                                     f"maximum {hi:g}, got {self.iso_value:g} ({side})")
        return self
