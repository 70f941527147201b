"""The viewer's cut, probe and ruler: keys and cursor in, a :class:`~clipvol.scene.geometry.Shape`
and HUD lines out, free of any window (tested without one).

* **Cut** (:class:`clipvol.scene.cut.CutEditor`): ``F`` selects the next crop-box face (x-, x+,
  y-, y+, z-, z+ of the array's axes), then each clip plane, then nothing; ``X`` pushes the
  selection into the volume (cuts more), ``Z`` pulls it back, by 1/32 of the volume's largest side;
  ``V`` adds a clip plane through the centre of interest facing away from the eye (the near half is
  cut away: look inside), up to six; ``O`` removes the selected plane, or restores the whole box
  when a face is selected. The HUD names the box in the store's world units.
* **Probe** (:mod:`clipvol.scene.probe`): the first visible sample under the cursor - value, level
  and world position - read from the bricks the clip-texture holds (no I/O on the window's thread),
  at the finest level that holds every brick along the ray up to the hit.
* **Ruler**: ``U`` puts a ruler end at the probed point; two ends give their distance in the store's
  unit, a third starts a new ruler.
"""

from __future__ import annotations

import numpy as np

from ..scene.cut import FACES, CutEditor, render_to_world
from ..scene.probe import THRESHOLD, Prober, Ruler

__all__ = ["CutKeys", "CUT_KEY_HELP", "ResidentBricks"]

#: the cut / probe keys, for the viewer's key table (docs/guide.md and --help-keys)
CUT_KEY_HELP = (
    ("F", "select the next crop-box face (x-, x+, y-, y+, z-, z+), then each clip plane, then none"),
    ("X / Z", "push the selected face or plane into the volume / pull it back (1/32 of the volume)"),
    ("V", "add a clip plane through the centre of interest, facing away from the eye (at most 6)"),
    ("O", "remove the selected clip plane, or restore the whole box when a face is selected"),
    ("cursor", "probe: value, level and world position of the first visible sample under it (HUD)"),
    ("U", "ruler: put an end at the probed point; two ends give their distance in the store's unit"),
)


class _Missing(LookupError):
    """A brick along the ray is not resident at this level."""


class ResidentBricks:
    """``read_brick`` over the clip-texture's resident bricks (raises for one it does not hold)."""

    def __init__(self, clip_texture) -> None:
        self.clip = clip_texture
        self.pyramid = clip_texture.pyramid

    def read_brick(self, level: int, index) -> np.ndarray:
        b = self.clip.get_brick(level, tuple(int(v) for v in index))
        if b is None:
            raise _Missing((level, index))
        return b


class CutKeys:
    """Cut, probe and ruler state of one viewer over ``session`` (a :class:`RenderSession`)."""

    KEYS = ("F", "X", "Z", "V", "O", "U")

    def __init__(self, session) -> None:
        self.session = session
        pyr = session.pyramid
        loader = session.loader
        self.editor = CutEditor.for_pyramid(pyr, session.params.shape)
        self.to_world = render_to_world(pyr, getattr(loader, "frame", None))
        self.unit = getattr(loader, "unit", None) or ""
        self.ruler = Ruler()
        self.probe = None
        self.message = ""

    def handle_key(self, key: str, center=None, forward=None) -> bool:
        """Apply one of :attr:`KEYS`; ``center``/``forward`` (render frame) place a new plane (V).
        Returns whether the key was one of them; the caller then applies :meth:`shape`."""
        k = key.upper() if len(key) == 1 else key
        ed = self.editor
        if k == "F":
            self.message = f"cut: {ed.select()} selected"
        elif k in ("X", "Z"):
            if ed.selected < 0:
                self.message = "cut: nothing selected (F selects a box face or a plane)"
            else:
                inward = -1.0 if ed.selected < len(FACES) else 1.0  # faces: + is outwards; planes: + cuts more
                ed.move(inward if k == "X" else -inward)
                self.message = f"cut: {ed.selected_name()} moved"
        elif k == "V":
            if center is None or forward is None:
                return False
            self.message = "cut: plane added" if ed.add_plane(center, forward) else "cut: six clip planes already"
        elif k == "O":
            name = ed.selected_name()
            ed.remove_selected()
            self.message = f"cut: {name} removed" if name.startswith("plane") else "cut: whole box"
        elif k == "U":
            if self.probe is None:
                self.message = "ruler: nothing probed under the cursor"
            else:
                self.ruler.add(self.probe.world)
                self.message = self.ruler.describe(self.unit)
        else:
            return False
        return True

    def shape(self):
        """The current cut for :class:`RenderParams` (None: the whole volume)."""
        return self.editor.shape()

    def probe_pixel(self, camera, x: float, y: float, tf, *, step: float = 0.5, max_level: int | None = None):
        """Probe the pixel ``(x, y)`` of ``camera``'s frame (as rendered) from the resident bricks,
        finest level first; keeps and returns the :class:`~clipvol.scene.probe.Probe` (or None)."""
        sess = self.session
        prober = Prober(ResidentBricks(sess.clip_texture), cache_bricks=0)
        prober.to_world = self.to_world
        top = sess.pyramid.num_levels if max_level is None else int(max_level) + 1
        self.probe = None
        for level in range(top):
            try:
                self.probe = prober.pick_pixel(camera, x, y, tf, level=level, threshold=THRESHOLD, step=step,
                                               shape=sess.params.shape)
                break
            except _Missing:
                continue
        return self.probe

    def hud_lines(self) -> list[str]:
        """The HUD's cut, probe and ruler lines (only those with something to say)."""
        lines = []
        if self.shape() is not None or self.editor.selected >= 0:
            lines.append(self.editor.describe(self.to_world, self.unit))
        if self.probe is not None:
            lines.append(self.probe.describe(self.unit))
        if self.ruler.ends:
            lines.append(self.ruler.describe(self.unit))
        return lines
