"""The viewer's input mapping, free of any window: mouse and keys in, camera and settings out.

Everything the window does with input goes through here, so it can be tested without a window
or a GL context (``tests/test_controls.py``):

* :class:`OrbitControls` turns mouse drags, wheel steps and WASD/QE motion into a camera. It keeps
  a target (the point looked at, which is also the clip-texture's **centre of interest**), a
  distance and two angles around world up ``-y`` (so the first view looks like ``vol.max(axis=0)``).
  Left drag orbits, right/middle drag pans so the point under the cursor follows it exactly (at the
  target's depth), the wheel zooms by a constant factor per step, and WASD/QE move eye and target
  together (fly / roam: the centre of interest moves through the data and the per-level windows
  follow it, as in OpenGL Volumizer's volume roaming).
* :class:`ViewState` holds the renderer settings the keys toggle (selection mode, fixed level, LOD
  threshold, MIP/composite, transfer-function preset, brick outlines, HUD) and
  :meth:`ViewState.handle_key` applies one key.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..choices import VIEWER_POLICIES
from ..errors import ParameterError
from ..scene.camera import Camera
from ..scene.paths import fit_distance, volume_center

__all__ = ["OrbitControls", "ViewState", "KeyState", "KEY_HELP", "MODES", "ALL_MODES", "MOVE_KEYS"]

UP = np.array([0.0, -1.0, 0.0])

#: every mode a ViewState may hold: M's cycle plus the image-based policy (L, and < > for its budget);
#: named in :mod:`clipvol.choices` for ``clipvol view --policy``
ALL_MODES = VIEWER_POLICIES
#: selection modes cycled by M
MODES = ALL_MODES[:3]

#: WASD/QE: (forward, right, up) unit steps in the camera's frame
MOVE_KEYS = {
    "W": (1.0, 0.0, 0.0),
    "S": (-1.0, 0.0, 0.0),
    "D": (0.0, 1.0, 0.0),
    "A": (0.0, -1.0, 0.0),
    "E": (0.0, 0.0, 1.0),
    "Q": (0.0, 0.0, -1.0),
}

#: the viewer's keys, shown by --help-keys and in the guide
KEY_HELP = (
    ("left drag", "orbit around the centre of interest"),
    ("right / middle drag", "pan"),
    ("wheel", "zoom"),
    ("W A S D / Q E", "fly: move camera and centre of interest (forward/left/back/right, down/up)"),
    ("M", "selection mode: projected-size -> roaming -> fixed level"),
    ("[ ]", "fixed level finer / coarser (switches to fixed mode)"),
    ("G", "image-based level of detail on / off (needs the store's summary tables)"),
    ("< >", "block budget of image-based LOD halved / doubled (switches it on)"),
    ("+ / -", "LOD threshold up (coarser, faster) / down (finer)"),
    ("I", "MIP / composite"),
    ("N", "gradient lighting on / off (composite)"),
    ("T", "next colour map over the same window"),
    ("Left / Right", "move the transfer-function window down / up (5 % of the data range)"),
    ("Up / Down", "widen / narrow the transfer-function window"),
    ("drag on the HUD histogram", "left: move the window; right: widen / narrow it"),
    ("Shift+S (or Ctrl+S)", "save the transfer function as JSON (read back with --tf FILE.json)"),
    ("C", "save the camera as JSON (read back with --camera FILE.json)"),
    ("B", "brick outlines coloured by level"),
    ("P / Shift+P", "screenshot (PNG) with / without the HUD, into --screenshot-dir"),
    ("H", "HUD on / off"),
    ("R", "reset the view"),
    ("L", "slice mode: axial, coronal, sagittal and 3D; wheel steps a slice, click sets the point of "
          "interest, drag tilts a slice"),
    ("Esc", "quit"),
)


def _basis(forward: np.ndarray, world_up: np.ndarray = UP) -> tuple[np.ndarray, np.ndarray]:
    """Camera ``right`` and ``up`` for a unit ``forward`` (right = forward x up, right-handed)."""
    right = np.cross(forward, world_up)
    n = np.linalg.norm(right)
    if n < 1e-12:  # looking straight along world up: any right will do
        right = np.array([1.0, 0.0, 0.0])
    else:
        right /= n
    up = np.cross(right, forward)
    return right, up / np.linalg.norm(up)


@dataclass
class OrbitControls:
    """An orbit / pan / zoom / fly camera rig around a target point.

    Parameters
    ----------
    target : array_like
        ``(x, y, z)`` point looked at, the centre of interest.
    distance : float
        Eye distance from ``target`` (> 0).
    azimuth, elevation : float
        Degrees about world up (``-y``) and above the horizontal plane; azimuth 0, elevation 0
        looks along ``+z``. Elevation is kept in ``[-89, 89]``.
    fov_y : float
        Vertical field of view, degrees.
    bounds : (lo, hi), optional
        World box ``(x, y, z)`` the target is kept inside (the volume box) and that the camera's
        depth range is fitted to.
    rotate_speed : float
        Degrees per pixel of drag.
    zoom_step : float
        Distance factor per wheel step (> 1).
    rotation : (3, 3) array, optional
        Turns the rig's own frame (up ``-y``, first eye on the ``-z`` side) into the data's: for a
        patient-frame store, :meth:`for_pyramid` with ``up``/``front`` (superior / anterior) makes
        the rig orbit head-up and start from the front. None: the identity.
    """

    target: np.ndarray
    distance: float
    azimuth: float = 0.0
    elevation: float = 0.0
    fov_y: float = 35.0
    bounds: tuple[np.ndarray, np.ndarray] | None = None
    rotate_speed: float = 0.3
    zoom_step: float = 1.15
    min_distance: float = 1e-6
    rotation: np.ndarray | None = None
    _home: tuple = field(default=(), repr=False)

    def __post_init__(self) -> None:
        self.target = np.asarray(self.target, dtype=np.float64).copy()
        if self.target.shape != (3,) or not np.all(np.isfinite(self.target)):
            raise ParameterError(f"target: expected a finite (x, y, z) point, got {self.target!r}")
        self.distance = float(self.distance)
        if not (np.isfinite(self.distance) and self.distance > 0):
            raise ParameterError(f"distance: expected a finite value > 0, got {self.distance!r}")
        if not 0.0 < float(self.fov_y) < 180.0:
            raise ParameterError(f"fov_y: expected degrees in (0, 180), got {self.fov_y!r}")
        if not float(self.zoom_step) > 1.0:
            raise ParameterError(f"zoom_step: expected a factor > 1, got {self.zoom_step!r}")
        if self.bounds is not None:
            lo, hi = (np.asarray(b, dtype=np.float64) for b in self.bounds)
            self.bounds = (lo, hi)
        self.elevation = float(np.clip(self.elevation, -89.0, 89.0))
        if self.rotation is not None:
            m = np.asarray(self.rotation, dtype=np.float64)
            if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-6):
                raise ParameterError(f"rotation: expected an orthonormal 3x3 matrix, got {self.rotation!r}")
            self.rotation = m
        self._home = (self.target.copy(), self.distance, self.azimuth, self.elevation)

    @classmethod
    def for_pyramid(cls, pyramid, size=(640, 480), fov_y: float = 35.0, azimuth: float = 30.0, elevation: float = 25.0,
                    up=None, front=None) -> "OrbitControls":
        """A rig looking at the whole volume of ``pyramid`` from ``azimuth``/``elevation``.

        ``up`` and ``front`` (data directions, e.g. superior and anterior from
        :func:`clipvol.scene.orientation.anatomical_axes`) orient the rig: world up becomes ``up``
        and azimuth 0, elevation 0 looks from ``front``.
        """

        rotation = None
        if up is not None and front is not None:
            u = np.asarray(up, dtype=np.float64)
            u = u / np.linalg.norm(u)
            f = np.asarray(front, dtype=np.float64)
            f = f - (f @ u) * u
            f = f / np.linalg.norm(f)
            rotation = np.stack([np.cross(u, f), -u, -f], axis=1)  # rig x, y (= -up), z (= -front)
        lo, hi = pyramid.volume_box()
        return cls(
            target=volume_center(pyramid),
            distance=fit_distance(pyramid, fov_y, size),
            azimuth=azimuth,
            elevation=elevation,
            fov_y=fov_y,
            bounds=(lo, hi),
            min_distance=0.25 * float(min(pyramid.spacing)),
            rotation=rotation,
        )

    # -- state ----------------------------------------------------------------------------------
    @property
    def direction(self) -> np.ndarray:
        """Unit vector from the target to the eye."""
        az = np.radians(self.azimuth)
        el = np.radians(self.elevation)
        d = np.array([np.cos(el) * np.sin(az), -np.sin(el), -np.cos(el) * np.cos(az)])
        return d if self.rotation is None else self.rotation @ d

    @property
    def world_up(self) -> np.ndarray:
        """The data direction shown upwards (``-y`` unless a ``rotation`` says otherwise)."""
        return UP.copy() if self.rotation is None else self.rotation @ UP

    @property
    def eye(self) -> np.ndarray:
        """Eye position ``(x, y, z)``."""
        return self.target + self.distance * self.direction

    @property
    def forward(self) -> np.ndarray:
        return -self.direction

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(forward, right, up)`` unit vectors of the current view (as the Camera has them)."""
        f = self.forward
        r, u = _basis(f, self.world_up)
        return f, r, u

    @property
    def center_of_interest(self) -> np.ndarray:
        """The target clamped into the volume box (what goes to ``ClipTexture.set_center``)."""
        if self.bounds is None:
            return self.target.copy()
        return np.clip(self.target, self.bounds[0], self.bounds[1])

    def camera(self, size=(640, 480)):
        """The :class:`~clipvol.scene.camera.Camera` of the current view for an image of ``size``."""

        cam = Camera.perspective(tuple(self.eye), tuple(self.target), up=tuple(self.world_up), fov_y=self.fov_y, size=tuple(size))
        if self.bounds is not None:
            cam = cam.fit_depth(self.bounds[0], self.bounds[1])
        return cam

    def set_camera(self, cam) -> None:
        """Look as ``cam`` does (a saved bookmark): its target, distance, direction and field of view.

        The rig keeps its world up (``-y``, or the patient's superior for a store with anatomical
        axes); a camera rolled about its view direction comes back unrolled.
        An orthographic camera gives its centre as the target at the rig's current distance.
        """
        if cam.ortho:
            target = np.asarray(cam.center, dtype=np.float64)
            d = -np.asarray(cam.forward, dtype=np.float64)
            dist = self.distance
        else:
            target = np.asarray(cam.target, dtype=np.float64)
            v = np.asarray(cam.eye, dtype=np.float64) - target
            dist = float(np.linalg.norm(v))
            d = v / dist
            self.fov_y = float(cam.fov_y)
        if self.rotation is not None:  # into the rig's own frame (the rotation is orthonormal)
            d = np.asarray(self.rotation).T @ d
        self.target = target.copy()
        self.distance = dist
        self.elevation = float(np.clip(np.degrees(np.arcsin(np.clip(-d[1], -1.0, 1.0))), -89.0, 89.0))
        self.azimuth = float(np.degrees(np.arctan2(d[0], -d[2])) % 360.0)

    def reset(self) -> None:
        """Back to the view the rig was created with."""
        t, d, a, e = self._home
        self.target, self.distance, self.azimuth, self.elevation = t.copy(), d, a, e

    # -- input --------------------------------------------------------------------------------
    def orbit(self, dx: float, dy: float) -> None:
        """Left drag by ``(dx, dy)`` pixels (``dy`` down): the data turns with the cursor."""
        self.azimuth = (self.azimuth - self.rotate_speed * float(dx)) % 360.0
        self.elevation = float(np.clip(self.elevation + self.rotate_speed * float(dy), -89.0, 89.0))

    def pixel_size(self, height: int) -> float:
        """World size of one pixel at the target's depth for an image ``height`` pixels tall."""
        return 2.0 * self.distance * np.tan(np.radians(self.fov_y) / 2.0) / float(height)

    def pan(self, dx: float, dy: float, size=(640, 480)) -> None:
        """Right/middle drag by ``(dx, dy)`` pixels: the point at the target follows the cursor."""
        _, r, u = self.basis()
        s = self.pixel_size(size[1])
        self.target = self.target - r * (float(dx) * s) + u * (float(dy) * s)
        self._clamp()

    def zoom(self, steps: float) -> None:
        """Wheel ``steps`` (positive = towards the target): distance / ``zoom_step**steps``."""
        steps = float(np.clip(steps, -100.0, 100.0))
        self.distance = float(np.clip(self.distance / self.zoom_step**steps, self.min_distance, 1e300))

    def move(self, forward: float = 0.0, right: float = 0.0, up: float = 0.0, amount: float = 1.0) -> None:
        """Fly: translate eye and target together along the view's axes by ``amount`` world units.

        ``(forward, right, up)`` is a direction in the camera's frame (e.g. from :data:`MOVE_KEYS`);
        the target (the centre of interest) is kept inside the volume box.
        """
        f, r, u = self.basis()
        v = f * forward + r * right + u * up
        n = np.linalg.norm(v)
        if n == 0:
            return
        self.target = self.target + v / n * float(amount)
        self._clamp()

    def move_keys(self, pressed, dt: float, speed: float) -> bool:
        """Apply the held WASD/QE keys (names in ``pressed``) for ``dt`` seconds at ``speed`` units/s.

        Returns whether anything moved.
        """
        step = np.zeros(3)
        for k in pressed:
            step += MOVE_KEYS.get(k, (0.0, 0.0, 0.0))
        if not step.any():
            return False
        n = np.linalg.norm(step)
        self.move(*(step / n), amount=float(speed) * float(dt))
        return True

    def _clamp(self) -> None:
        if self.bounds is not None:
            self.target = np.clip(self.target, self.bounds[0], self.bounds[1])


@dataclass(kw_only=True)
class KeyState:
    """What the keys every viewer shares change (:func:`apply_common_key`): MIP or composite,
    lighting, the colour map (``tf_index`` into the subclass's ``tf_presets``), the HUD, and the
    one-shot requests (screenshot, reset, quit) with the message the HUD shows."""

    render_mode: str = "composite"
    #: the modes ``I`` cycles through (a viewer whose renderer draws more widens it)
    render_modes: tuple[str, ...] = ("composite", "mip")
    shading: bool = False
    tf_index: int = 0
    hud: bool = True
    screenshot: bool = False
    quit: bool = False
    reset: bool = False
    message: str = ""

    @property
    def tf_name(self) -> str:
        return self.tf_presets[self.tf_index % len(self.tf_presets)]


@dataclass
class ViewState(KeyState):
    """Renderer settings the viewer's keys change.

    Parameters
    ----------
    num_levels : int
        Levels of the data (bounds the fixed level).
    tf_presets : tuple of str
        Transfer-function presets ``T`` cycles through.
    """

    num_levels: int
    tf_presets: tuple[str, ...] = ("grey", "viridis", "magma", "bone")
    mode: str = "projected-size"
    level: int = 0
    lod_threshold: float = 1.0
    block_budget: int = 128
    outlines: bool = False

    def __post_init__(self) -> None:
        if int(self.num_levels) < 1:
            raise ParameterError(f"num_levels: expected >= 1, got {self.num_levels!r}")
        if self.mode not in ALL_MODES:
            raise ParameterError(f"mode: expected one of {', '.join(ALL_MODES)}, got {self.mode!r}")
        from ..scene.params import MODES

        if self.render_mode not in MODES:
            raise ParameterError(f"render_mode: expected one of {', '.join(MODES)}, got {self.render_mode!r}")
        if not self.tf_presets:
            raise ParameterError("tf_presets: expected at least one preset name")
        self.level = int(np.clip(self.level, 0, self.num_levels - 1))

    def handle_key(self, key: str) -> bool:
        """Apply one key (``'M'``, ``'['``, ``'+'``, ...; letters upper case). Returns whether it was used.

        ``P`` sets :attr:`screenshot`, ``Esc`` (``'ESCAPE'``) sets :attr:`quit` and ``R`` sets
        :attr:`reset`; the window acts on those flags and clears them.
        """
        k = key.upper() if len(key) == 1 else key
        if k == "M":
            self.mode = MODES[(MODES.index(self.mode) + 1) % len(MODES)] if self.mode in MODES else MODES[0]
            self.message = f"mode {self.mode}" + (f" (level {self.level})" if self.mode == "fixed" else "")
        elif k in ("[", "]"):
            self.level = int(np.clip(self.level + (1 if k == "]" else -1), 0, self.num_levels - 1))
            self.mode = "fixed"
            self.message = f"fixed level {self.level}"
        elif k in ("+", "="):
            self.lod_threshold = min(self.lod_threshold * 2.0, 256.0)
            self.message = f"LOD threshold {self.lod_threshold:g} px"
        elif k in ("-", "_"):
            self.lod_threshold = max(self.lod_threshold / 2.0, 1.0 / 16.0)
            self.message = f"LOD threshold {self.lod_threshold:g} px"
        elif k == "G":
            self.mode = "projected-size" if self.mode == "image" else "image"
            self.message = f"mode {self.mode}" + (f" (block budget {self.block_budget})" if self.mode == "image" else "")
        elif k in ("<", ",", ">", "."):
            grow = k in (">", ".")
            self.block_budget = int(np.clip(self.block_budget * 2 if grow else self.block_budget // 2, 1, 1 << 16))
            self.mode = "image"
            self.message = f"image-based LOD, block budget {self.block_budget}"
        elif k == "B":
            self.outlines = not self.outlines
            self.message = "outlines " + ("on" if self.outlines else "off")
        else:
            return apply_common_key(self, k)
        return True


def apply_common_key(state, k: str) -> bool:
    """The keys every viewer shares, on a :class:`KeyState`: ``I`` the next render mode, ``N`` lighting,
    ``T`` next colour map, ``H`` HUD, ``P`` screenshot, ``R`` reset view, ``Esc`` quit. Returns
    whether ``k`` (upper case) was one of them."""
    if k == "I":  # the next of render_modes (composite <-> MIP unless the viewer widens it)
        modes = state.render_modes
        state.render_mode = modes[(modes.index(state.render_mode) + 1) % len(modes)] \
            if state.render_mode in modes else modes[0]
        state.message = state.render_mode
    elif k == "N":
        state.shading = not state.shading
        state.message = "lighting " + ("on" if state.shading else "off")
    elif k == "T":
        state.tf_index = (state.tf_index + 1) % len(state.tf_presets)
        state.message = f"transfer function {state.tf_name}"
    elif k == "H":
        state.hud = not state.hud
    elif k == "P":
        state.screenshot = True
    elif k == "R":
        state.reset = True
    elif k == "ESCAPE":
        state.quit = True
    else:
        return False
    return True
