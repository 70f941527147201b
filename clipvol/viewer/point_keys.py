"""The point viewer's keys, free of any window: the tolerance ladder, MIP, colour maps, HUD.

``clipvol view POINTS.zarr`` (:mod:`clipvol.viewer.point_window`) maps its keys here so they can
be tested without a window. The **tolerance** is Meredith & Ma's (2001) screen-space error bound:
the largest splat any node may draw, a fraction of the window's linear size; a finer tolerance
draws deeper nodes (more, smaller splats, slower), a coarser one fewer. ``[`` and ``]`` step it
along :data:`TOLERANCE_LADDER` (about x2 a step; from a value off the ladder, to the next rung).
Mouse and WASD/QE motion are the volume viewer's (:class:`clipvol.viewer.controls.OrbitControls`).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import ParameterError
from ..scene.splat_select import tolerance_pixels
from .controls import KeyState, apply_common_key

__all__ = ["PointViewState", "POINT_KEY_HELP", "TOLERANCE_LADDER"]

#: tolerances ``[`` / ``]`` step through (fractions of the window's larger side)
TOLERANCE_LADDER = (0.0025, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.4)

#: the point viewer's keys, shown in the guide
POINT_KEY_HELP = (
    ("left drag / right drag / wheel", "orbit / pan / zoom, as the volume viewer"),
    ("W A S D / Q E", "fly: move camera and centre of interest"),
    ("[ ]", "tolerance finer (more, smaller splats) / coarser (fewer, faster)"),
    ("I", "MIP / composite"),
    ("N", "lighting on / off (composite; gradients by weighted least squares over each node's points)"),
    ("T", "next colour map"),
    ("P", "screenshot (PNG) into --screenshot-dir"),
    ("H", "HUD on / off (points and nodes drawn, tolerance, fps)"),
    ("R", "reset the view"),
    ("Esc", "quit"),
)


@dataclass
class PointViewState(KeyState):
    """Settings the point viewer's keys change.

    Parameters
    ----------
    tolerance : float
        The starting tolerance, a fraction of the window's linear size in ``(0, 1)``.
    tf_presets : tuple of str
        Colour maps ``T`` cycles through.
    """

    tolerance: float = 0.05
    tf_presets: tuple[str, ...] = ("viridis", "magma", "inferno", "grey")

    def __post_init__(self) -> None:
        t = float(self.tolerance)
        if not 0.0 < t < 1.0:
            raise ParameterError(f"tolerance: expected a fraction of the screen in (0, 1), got {self.tolerance!r}")
        self.tolerance = t
        from ..render.modes import modes_with

        if self.render_mode not in modes_with("splats"):
            raise ParameterError(f"render_mode: expected one of {', '.join(modes_with('splats'))}, "
                                 f"got {self.render_mode!r}")
        if not self.tf_presets:
            raise ParameterError("tf_presets: expected at least one preset name")

    @classmethod
    def starting_at(cls, tolerance, size, **kwargs) -> "PointViewState":
        """A state whose tolerance is ``tolerance`` (``0.05``, ``"5%"``, ``"12px"``) for a window of ``size``."""
        frac = tolerance_pixels(tolerance, size) / max(size)
        return cls(tolerance=min(max(frac, 1e-6), 0.999), **kwargs)

    def tolerance_px(self, size) -> float:
        """The tolerance in pixels of a window of ``size``."""
        return self.tolerance * max(size)

    def _step(self, finer: bool) -> None:
        t = self.tolerance
        if finer:
            below = [v for v in TOLERANCE_LADDER if v < t * (1 - 1e-9)]
            self.tolerance = below[-1] if below else TOLERANCE_LADDER[0]
        else:
            above = [v for v in TOLERANCE_LADDER if v > t * (1 + 1e-9)]
            self.tolerance = above[0] if above else TOLERANCE_LADDER[-1]

    def handle_key(self, key: str) -> bool:
        """Apply one key (``'['``, ``']'``, ``'I'``, ...; letters in either case). Returns whether it was used.

        ``P`` sets :attr:`screenshot`, ``Esc`` (``'ESCAPE'``) :attr:`quit` and ``R`` :attr:`reset`;
        the window acts on those flags and clears them.
        """
        k = key.upper() if len(key) == 1 else key
        if k in ("[", "]"):
            self._step(finer=k == "[")
            self.message = f"tolerance {100 * self.tolerance:.3g} % of the screen"
            return True
        return apply_common_key(self, k)
