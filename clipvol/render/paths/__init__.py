"""The draw paths of the clip render action, and the registry ``RenderParams.path`` picks from.

A draw path turns the frame's cut into an image; every path draws into the one target, with the
one colour table and the one set-up of :mod:`.setup`, so the action
(:class:`~clipvol.render.action.ClipRenderAction`) only selects, uploads and hands the cut over. It
hands it over as a :class:`~.frame.FrameContext` (the cut, the camera, the transfer function, the
parameters, the pyramid, the GPU cache, ...) and gets a :class:`~.frame.DrawStats` back (the image
and what was drawn); a path never reads or writes the action.

=================  ===========================  ==================================================
``path``           module                       how
=================  ===========================  ==================================================
``"bricks"``       :mod:`.bricks`               one proxy box per draw item, blended in visibility
                                                order (the reference; draws what others cannot)
``"single-pass"``  :mod:`.single_pass`          one ray per pixel through a page table of the cut
``"auto"``         :func:`pick`                 the single pass for cuts of at least
                                                :data:`AUTO_SINGLE_PASS_BOXES` merged boxes and no
                                                overlays, the per-brick path otherwise
=================  ===========================  ==================================================

Adding a draw path is one module with a :class:`~.setup.DrawPath` subclass (its ``name`` is the
value of ``RenderParams.path`` that selects it; its ``draw(frame)`` returns the
:class:`~.frame.DrawStats` of :meth:`~.setup.DrawSetup.read_back`, or None to decline the cut) and
one :func:`register` line below. The tests that hold for every path are parametrised over
:data:`DRAW_PATHS` (``tests/render/conftest.py``), so a registered path is tested by them. Registering a
name also makes :class:`~clipvol.scene.params.RenderParams` accept it: the scene stage holds the
built-in names in ``clipvol.scene.params.PATHS`` (it imports no GL module) and :func:`register`
adds the others there.
"""

from __future__ import annotations

from ...errors import ParameterError
from .bricks import BricksPath
from .frame import DrawStats, FrameContext
from .setup import DrawPath, DrawSetup
from .single_pass import SinglePassPath

__all__ = ["DRAW_PATHS", "FALLBACK", "AUTO_SINGLE_PASS_BOXES", "register", "unregister", "pick", "DrawPath",
           "DrawSetup", "DrawStats", "FrameContext"]

#: registered draw paths by ``RenderParams.path`` name
DRAW_PATHS: dict[str, type[DrawPath]] = {}
#: the path that draws a cut another path declines (its ``draw`` returned None), and an empty cut
FALLBACK = "bricks"
#: path="auto": the single pass draws cuts of at least this many (merged) boxes. Measured on Mesa
#: llvmpipe (docs/benchmarks.md, "Which path draws a frame"), the single pass over the per-brick
#: path, same cut: 1 box 1.04-1.06x, 2 boxes 1.04x, 4 boxes 0.94-0.97x, 8 boxes 0.90x, 10-18 boxes
#: (a loading frame whose cut cannot merge yet) 0.55-0.85x, 64 boxes 0.81x; below 32 boxes the
#: per-brick path takes an occlusion snapshot after every box, each a wait for both rasteriser threads.
AUTO_SINGLE_PASS_BOXES = 4


def register(cls: type[DrawPath]) -> type[DrawPath]:
    """Make ``cls`` the draw path ``RenderParams.path == cls.name`` selects (usable as a decorator)."""
    from ...scene import params

    if not cls.name or cls.name == "auto":
        raise ParameterError(f"draw path {cls.__name__}: expected a name other than '' and 'auto', got {cls.name!r}")
    DRAW_PATHS[cls.name] = cls
    if cls.name not in params.PATHS:
        params.PATHS = (*params.PATHS, cls.name)
    return cls


def unregister(name: str) -> None:
    """Forget the draw path ``name`` (a built-in one stays a valid ``RenderParams.path``)."""
    from ...scene import params

    DRAW_PATHS.pop(name, None)
    if name not in (BricksPath.name, SinglePassPath.name, "auto"):
        params.PATHS = tuple(p for p in params.PATHS if p != name)


def pick(params, items) -> str:
    """The name of the path that draws this frame's (merged) cut ``items`` under ``params``."""
    if not items:
        return FALLBACK
    if params.path == "auto":
        return SinglePassPath.name if not params.overlays and len(items) >= AUTO_SINGLE_PASS_BOXES else FALLBACK
    return params.path


register(BricksPath)
register(SinglePassPath)
