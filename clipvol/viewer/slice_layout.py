"""The viewer's slice mode: axial, coronal and sagittal slices beside the 3D view, in a 2x2 grid.

A clinician or microscopist reads a volume first as slices (multi-planar reformatting). The three
slice panels are drawn by a :class:`~clipvol.render.slice_action.SliceAction` that shares the volume
action's GPU cache and clip-texture, so switching modes re-uses every brick already loaded. Each
slice is multiresolution after LaMar, Hamann & Joy ("Multiresolution cutting planes"): full
resolution near the point of interest, coarser away from it, balanced and blended at level changes.

Interaction (the window forwards its events here while the mode is on):

* scroll over a slice panel steps that plane along its normal by one level-0 voxel per notch;
* a click on a slice panel sets the point of interest there: the other two planes move through it
  and the clip-texture's centre of interest follows it;
* a drag on a slice panel tilts that plane about its own up and right axes (an oblique plane);
* the 3D panel orbits as in the normal mode; it shows the volume cut open at the axial plane, with
  the plane drawn in it (:meth:`SliceAction.render_in_view`), so users see where they are.

The layout composes one RGBA image on the CPU (panels are small; no extra GL state in the
window), and :meth:`SliceLayout.hud_lines` gives the level of each panel's tiles and the bytes read.
This module holds no GLFW code, so it is tested offscreen.
"""

from __future__ import annotations

import math

import numpy as np

from ..render.frame_loop import FrameLoop
from ..render.slice_action import SliceAction
from ..scene.params import RenderParams
from ..scene.plane import AXES, Plane
from ..app.slice_session import leave_out_cut

__all__ = ["SliceLayout", "PANELS"]

#: panel names in grid order: top-left, top-right, bottom-left, bottom-right
PANELS = ("axial", "coronal", "sagittal", "3d")
#: radians of tilt per pixel dragged
TILT_PER_PIXEL = 0.005


class SliceLayout:
    """Three slices and the 3D view of a :class:`~clipvol.app.session.RenderSession`."""

    def __init__(self, session) -> None:
        self.session = session
        self.pyramid = pyr = session.pyramid
        self.active = False
        frame = getattr(session.loader, "frame", None)
        from ..scene.views import anatomical_plane, is_anatomical

        if is_anatomical(frame):  # the patient's planes, radiological display (clipvol.scene.views)
            self.planes = {name: anatomical_plane(pyr, frame, name) for name in AXES}
        else:
            self.planes = {name: Plane.axis(pyr, name) for name in AXES}
        lo, hi = pyr.volume_box()
        self.poi = (lo + hi) / 2.0
        self.action = SliceAction(session.ctx, session.clip_texture, self._params(),
                                  cache=session.action.cache)
        # three planes and a volume view share one clip-texture each frame: its cube windows around the
        # point of interest serve them all (one plane's slab region would evict the others' bricks)
        self.action.follow_plane = False
        self.stats: dict = {}
        self.size = (2, 2)

    def _params(self) -> RenderParams:
        return RenderParams(policy="plane", focus=tuple(float(v) for v in self.poi),
                            texture_budget=self.session.params.texture_budget)

    # -- geometry of the grid ---------------------------------------------------------------------
    def panel_rect(self, name: str, size) -> tuple[int, int, int, int]:
        """``(x0, y0, w, h)`` in framebuffer pixels (row 0 at the top) of panel ``name``."""
        w, h = (int(v) for v in size)
        pw, ph = max(w // 2, 1), max(h // 2, 1)
        i = PANELS.index(name)
        return (i % 2) * pw, (i // 2) * ph, pw, ph

    def panel_at(self, x: float, y: float, size) -> tuple[str, float, float]:
        """The panel under framebuffer point ``(x, y)`` and the point in that panel's pixels."""
        for name in PANELS:
            x0, y0, pw, ph = self.panel_rect(name, size)
            if x0 <= x < x0 + pw and y0 <= y < y0 + ph:
                return name, x - x0, y - y0
        return "3d", x, y

    def pixel_size(self, name: str, panel) -> float:
        """World units per pixel that fit the plane's cut through the volume into the panel."""
        lo, hi = self.pyramid.volume_box()
        pl = self.planes[name]
        umin, umax, vmin, vmax = pl.footprint(lo, hi)
        if math.isnan(umin):
            return float(min(self.pyramid.spacing))
        pw, ph = panel
        return max(2 * max(abs(umin), abs(umax)) / pw, 2 * max(abs(vmin), abs(vmax)) / ph, 1e-12)

    def point_at(self, name: str, px: float, py: float) -> np.ndarray:
        """World point of panel pixel ``(px, py)`` (row 0 at the top) of slice panel ``name``."""
        _, _, pw, ph = self.panel_rect(name, self.size)
        pl = self.planes[name]
        s = self.pixel_size(name, (pw, ph))
        return (np.asarray(pl.origin) + (px - pw / 2.0) * s * pl.right + (ph / 2.0 - py) * s * np.asarray(pl.up))

    # -- interaction ------------------------------------------------------------------------------
    def _clamp_origin(self, pl: Plane, origin) -> Plane:
        lo, hi = self.pyramid.volume_box()
        return Plane(tuple(np.clip(np.asarray(origin, dtype=np.float64), lo, hi)), pl.normal, pl.up)

    def step_plane(self, name: str, notches: float) -> None:
        """Move plane ``name`` by ``notches`` level-0 voxels along its normal (kept inside the volume)."""
        pl = self.planes[name]
        n = np.asarray(pl.normal)
        voxel = float(np.abs(n) @ np.asarray(self.pyramid.spacing[::-1]))
        self.planes[name] = self._clamp_origin(pl, np.asarray(pl.origin) + notches * voxel * n)

    def set_poi(self, point) -> None:
        """Point of interest: every plane moves through it, the clip-texture's centre follows it."""
        lo, hi = self.pyramid.volume_box()
        self.poi = np.clip(np.asarray(point, dtype=np.float64), lo, hi)
        for name, pl in self.planes.items():
            self.planes[name] = Plane(tuple(self.poi), pl.normal, pl.up)
        self.session.set_center(self.poi)

    def click(self, name: str, px: float, py: float) -> None:
        if name != "3d":
            self.set_poi(self.point_at(name, px, py))

    def tilt(self, name: str, dx: float, dy: float) -> None:
        """Rotate plane ``name``: horizontal drags about its up axis, vertical drags about its right axis."""
        if name == "3d":
            return
        pl = self.planes[name]
        n, u, r = np.asarray(pl.normal), np.asarray(pl.up), pl.right
        a, b = dx * TILT_PER_PIXEL, dy * TILT_PER_PIXEL
        n1 = math.cos(a) * n + math.sin(a) * r  # about up
        n2 = math.cos(b) * n1 - math.sin(b) * u  # about right
        u2 = math.cos(b) * u + math.sin(b) * n1
        self.planes[name] = Plane(pl.origin, tuple(n2), tuple(u2))

    # -- drawing ----------------------------------------------------------------------------------
    def render(self, camera_for_size, size, *, wait: bool = False, timeout: float | None = None) -> np.ndarray:
        """The 2x2 grid as ``(h, w, 4)`` uint8; ``camera_for_size((w, h))`` gives the 3D panel's camera.

        The viewer draws what is resident (``wait=False``) and refines over the next frames;
        ``wait=True`` waits for each panel's bricks (offscreen use, tests)."""
        self.size = (int(size[0]), int(size[1]))
        w, h = self.size
        out = np.zeros((h, w, 4), dtype=np.uint8)
        out[..., 3] = 255
        sess = self.session
        cache = sess.action.cache
        if self.action.cache is not cache:  # the volume action rebuilt its cache (new budget)
            self.action.cache = cache
            self.action.frame_loop = FrameLoop(sess.clip_texture, cache)
        params = self._params()
        if params != self.action.params:
            self.action.params = params
        lo_v, hi_v = self.pyramid.value_range
        for name in PANELS:
            x0, y0, pw, ph = self.panel_rect(name, size)
            if name == "3d":
                # the 3D view cut open at the axial plane, the plane drawn in it (orientation)
                sess.set_center(self.poi)
                img = self.action.render_in_view(sess.action, camera_for_size((pw, ph)), sess.transfer_function,
                                                 self.planes["axial"], wait=wait, timeout=timeout)
                from ..app.annotate import present

                img = present(img, None, getattr(sess.loader, "frame", None), labels=False)  # a mirrored store: un-mirrored
                self.stats[name] = sess.frame_stats
            else:
                pl = self.planes[name]
                lo, hi = self.pyramid.volume_box()
                if not pl.crosses(lo, hi)[0]:
                    continue
                px = self.pixel_size(name, (pw, ph))
                img = self.action.render(pl, (pw, ph), px, window=((lo_v + hi_v) / 2.0, max(hi_v - lo_v, 1e-30)),
                                         wait=wait, timeout=timeout)
                img, _ = leave_out_cut(img, None, sess.params.shape, pl, px)  # the volume's crop cuts its planes too
                self.stats[name] = self.action.last_stats
            a = img[..., 3:4].astype(np.float32) / 255.0
            out[y0:y0 + ph, x0:x0 + pw, :3] = np.rint(img[..., :3] * a).astype(np.uint8)
            if name != "3d":  # a yellow cross at the point of interest, if it lies in this plane
                pl = self.planes[name]
                if abs(pl.signed_distance(self.poi)[0]) < 0.5 * float(max(self.pyramid.spacing)):
                    c, r = pl.to_pixels(self.poi, (pw, ph), self.pixel_size(name, (pw, ph)))[0].astype(int)
                    for dr, dc in [(0, k) for k in range(-6, 7)] + [(k, 0) for k in range(-6, 7)]:
                        if 0 <= r + dr < ph and 0 <= c + dc < pw and abs(dr + dc) > 1:
                            out[y0 + r + dr, x0 + c + dc, :3] = (255, 220, 0)
        return out

    def hud_lines(self) -> list[str]:
        """One line per slice panel: its tiles per level and the bytes its tiles read."""
        lines = [f"slices: point of interest ({', '.join(f'{v:.0f}' for v in self.poi)})"]
        frame = getattr(self.session.loader, "frame", None)
        for name in PANELS[:3]:
            st = self.stats.get(name)
            if st is None:
                continue
            levels = " ".join(f"L{L}:{n}" for L, n in st.tiles_per_level.items())
            edges = ""
            if frame is not None:  # the panel's right and top edges in the patient frame
                from ..scene.orientation import view_labels

                lab = view_labels(frame.affine, self.planes[name].right, self.planes[name].up, frame.frame)
                edges = f"  [right {lab['right']}, top {lab['top']}]"
            lines.append(f"{name}: {levels}  {st.bytes_needed / 1e6:.1f} MB" + edges
                         + ("" if st.converged else "  (loading)"))
        lines.append(f"loaded {self.session.clip_texture.stats.bytes_loaded / 1e6:.0f} MB")
        return lines

    def close(self) -> None:
        self.action.close()
