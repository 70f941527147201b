"""The draw modes of the volume action, and the registry ``RenderParams.mode`` picks from.

A mode is what differs around the ray loop between, say, compositing and a projection
(:class:`~.base.DrawMode`): its parameters' checks, its shader variant, the target's clear value and
blending, the read-back, whether bricks may be culled, whether sort-last and the point splats draw
it. The draw paths, the action, sort-last, the splats, the viewer and the web page read these here.

=============  =================  ============================================================
``mode``       module             the pixel
=============  =================  ============================================================
``composite``  :mod:`.composite`  emission-absorption of the classified samples, front to back
``mip``        :mod:`.mip`        the largest texel along the ray, mapped on read-back
``minip``      :mod:`.minip`      the smallest texel along the ray
``average``    :mod:`.average`    the mean of the samples along the ray
``iso``        :mod:`.iso`        the first hit of ``iso_value``, lit on read-back
=============  =================  ============================================================

Adding a mode is one module with a :class:`~.base.DrawMode` subclass (its ``name`` is the value of
``RenderParams.mode`` that selects it; its ray code either a ``define`` tested in
``volume_common.glsl`` or GLSL of its own, :attr:`~.base.DrawMode.glsl`) and one :func:`register`
line below. Registering a mode also makes :class:`~clipvol.scene.params.RenderParams` accept its
name and run its checks: the scene stage holds the built-in names in ``clipvol.scene.params.MODES``
and the checks in ``clipvol.scene.params.MODE_CHECKS`` (it imports no render module), and
:func:`register` fills both.
"""

from __future__ import annotations

import re

import numpy as np

from ...errors import ParameterError
from ..glsl import register_source, unregister_source
from .average import Average
from .base import DrawMode
from .composite import Composite
from .iso import Iso, iso_texel
from .minip import MinIp
from .mip import Mip

__all__ = ["DRAW_MODES", "DrawMode", "register", "unregister", "mode_of", "modes_with", "mode_defines", "depth_range",
           "iso_texel", "BUILT_IN"]

#: registered draw modes (one instance each) by ``RenderParams.mode`` name
DRAW_MODES: dict[str, DrawMode] = {}
#: the modes whose names the scene stage knows without this package (``scene.params.MODES``)
BUILT_IN = ("composite", "mip", "minip", "average", "iso")


def _glsl_name(name: str) -> str:
    """The name under which a mode's own GLSL is registered (:func:`clipvol.render.glsl.register_source`)."""
    return "mode_" + re.sub(r"[^0-9A-Za-z_]", "_", name)


def register(cls: type[DrawMode]) -> type[DrawMode]:
    """Make ``cls`` the mode ``RenderParams.mode == cls.name`` selects (usable as a decorator)."""
    from ...scene import params

    if not cls.name or not isinstance(cls.name, str):
        raise ParameterError(f"draw mode {cls.__name__}: expected a name, got {cls.name!r}")
    if bool(cls.define) == bool(cls.glsl) and not cls.classifies:
        raise ParameterError(f"draw mode {cls.__name__}: expected its ray code as one of define (a variant of "
                             f"volume_common.glsl) or glsl (its own), got {'both' if cls.define else 'neither'}")
    mode = cls()
    DRAW_MODES[cls.name] = mode
    if cls.glsl:
        register_source(_glsl_name(cls.name), cls.glsl)
    if cls.name not in params.MODES:
        params.MODES = (*params.MODES, cls.name)
    params.MODE_CHECKS[cls.name] = mode.check
    return cls


def unregister(name: str) -> None:
    """Forget the mode ``name`` (a built-in one stays a valid ``RenderParams.mode`` name)."""
    from ...scene import params

    mode = DRAW_MODES.pop(name, None)
    if mode is not None and mode.glsl:
        unregister_source(_glsl_name(name))
    params.MODE_CHECKS.pop(name, None)
    if name not in BUILT_IN:
        params.MODES = tuple(m for m in params.MODES if m != name)


def mode_of(name: str) -> DrawMode:
    """The registered mode ``name`` (``RenderParams.mode``)."""
    try:
        return DRAW_MODES[name]
    except KeyError:
        raise ParameterError(f"mode: expected one of {', '.join(DRAW_MODES)}, got {name!r}") from None


def modes_with(flag: str) -> tuple[str, ...]:
    """The names of the registered modes whose attribute ``flag`` is true (``"splats"``: the point
    renderer draws them; ``"sort_last"``: sort-last rendering combines them)."""
    return tuple(name for name, m in DRAW_MODES.items() if getattr(m, flag))


def mode_defines(name: str) -> dict:
    """The shader ``#define``\\ s of mode ``name`` (:mod:`clipvol.render.glsl`): its own variant's
    define true and every other mode's false; ``MODE_GLSL`` naming its own GLSL where it has it."""
    mode = mode_of(name)
    defines: dict = {m.define: m is mode for m in DRAW_MODES.values() if m.define}
    if mode.glsl:
        defines["MODE_GLSL"] = _glsl_name(name)
    return defines


def depth_range(cam, lo, hi) -> tuple[float, float]:
    """``(near, far)`` of the ray parameter ``t`` over the box ``[lo, hi]``: distance from the eye
    (perspective; near at least 0) or signed distance from the plane through the camera centre
    (orthographic), as the shaders measure ``t``. ``iso_color="depth"`` spans its colours over it."""
    c = np.array(np.meshgrid(*zip(lo, hi), indexing="ij"), dtype=np.float64).reshape(3, -1).T  # 8 corners
    f = np.asarray(cam.forward, dtype=np.float64)
    if cam.orthographic:
        t = (c - np.asarray(cam.center, dtype=np.float64)) @ f
        return float(t.min()), float(t.max())
    rel = c - np.asarray(cam.eye, dtype=np.float64)
    return max(0.0, float((rel @ f).min())), float(np.linalg.norm(rel, axis=1).max())


register(Composite)
register(Mip)
register(MinIp)
register(Average)
register(Iso)
