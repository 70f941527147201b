"""Cutting a volume open in the user's terms: a crop box and clip planes given in the store's world
frame (or in voxels of level 0) turned into the renderer's :class:`~clipvol.scene.geometry.Shape`.

clipvol draws in the array's own axes scaled to world units (the *render frame*: the centre of
level-0 voxel ``(x, y, z)`` sits at ``(x, y, z) * spacing``, see :mod:`clipvol.bricking.worldframe`),
while a user reads positions in the store's world frame (``clipvol info``: patient RAS+ millimetres
for NIfTI and DICOM, scaled array axes otherwise). This module is the one place that converts
between them, so ``clipvol render``/``view``, the viewer's keys and ``clipvol.show`` cut the same
region for the same numbers:

* a point maps through the affine ``render -> world`` (:func:`render_to_world`), exactly;
* a clip plane ``(point, normal)`` in the world frame keeps ``normal . (p - point) >= 0`` and maps
  to a render-frame plane ``(a, b, c, d)`` exactly (planes stay planes under an affine map);
* a world box is an axis-aligned render box when the store's axes are aligned with its world frame
  (any permutation or flip, the usual case); for an oblique store its six faces become six clip
  planes, so the cut is exact there too (and then leaves no room for further planes).

:class:`CutEditor` holds the cut the viewer's keys edit (a box face or a plane moved step by step)
and reports it in world terms for the HUD. Pure numpy, no GL; after OpenGL Volumizer's shape
geometry (Bhaniramka & Demange, *OpenGL Volumizer: A Toolkit for High Quality Volume Rendering of
Large Data Sets*, 2002).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from .geometry import MAX_PLANES, Shape

__all__ = ["render_to_world", "world_to_render", "point_to_render", "direction_to_render", "plane_to_render", "voxel_box_to_render", "world_box_to_render",
           "cut_shape", "outside_bricks", "CutEditor", "FACES"]

#: the crop box's faces in the order the viewer's key cycles them (render-frame axis, 0 = low side)
FACES = (("x", 0), ("x", 1), ("y", 0), ("y", 1), ("z", 0), ("z", 1))


def render_to_world(pyramid, frame=None) -> np.ndarray:
    """4x4 matrix taking render-frame points ``(x, y, z, 1)`` to the store's world frame.

    Without a ``frame`` (a store with no affine) the world frame is the render frame itself.
    """
    sp = np.array(pyramid.spacing[::-1], dtype=np.float64)
    if frame is None:
        return np.eye(4)
    a = np.asarray(frame.matrix if hasattr(frame, "matrix") else frame.affine, dtype=np.float64)
    scale = np.eye(4)
    scale[:3, :3] = np.diag(1.0 / sp)  # render -> level-0 voxel index
    return a @ scale


def world_to_render(pyramid, frame=None) -> np.ndarray:
    """The inverse of :func:`render_to_world`."""
    return np.linalg.inv(render_to_world(pyramid, frame))


def _points(m: np.ndarray, p) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def point_to_render(pyramid, frame, point, what: str = "point") -> np.ndarray:
    """Render-frame ``(x, y, z)`` of a world point ``(x, y, z)`` (the store's frame, e.g. RAS+ mm).

    The one conversion of every point a user types (``clipvol slice --origin/--poi``, crops,
    clip planes), so a point means the same place whatever the storage order of the array.
    """
    q = np.asarray(point, dtype=np.float64).reshape(-1)
    if q.shape != (3,) or not np.all(np.isfinite(q)):
        raise ParameterError(f"{what}: expected a finite point x,y,z, got {tuple(q.tolist())}")
    return _points(world_to_render(pyramid, frame), q)


def direction_to_render(pyramid, frame, direction, what: str = "direction", normal: bool = False) -> np.ndarray:
    """Unit render-frame direction of a world direction ``(x, y, z)``.

    A plane's ``normal=True`` maps by the inverse transpose (it stays perpendicular to the plane
    under a shear); an in-plane direction (an image's up) by the linear part itself.
    """
    d = np.asarray(direction, dtype=np.float64).reshape(-1)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.any(d != 0):
        raise ParameterError(f"{what}: expected a finite, non-zero vector x,y,z, got {tuple(d.tolist())}")
    m = render_to_world(pyramid, frame)[:3, :3]
    r = m.T @ d if normal else np.linalg.solve(m, d)
    return r / np.linalg.norm(r)


def plane_to_render(pyramid, frame, point, normal, what: str = "clip plane") -> tuple[float, float, float, float]:
    """Render-frame ``(a, b, c, d)`` (unit normal) of the world half-space ``normal . (p - point) >= 0``."""
    q = np.asarray(point, dtype=np.float64).reshape(-1)
    n = np.asarray(normal, dtype=np.float64).reshape(-1)
    if q.shape != (3,) or n.shape != (3,) or not (np.all(np.isfinite(q)) and np.all(np.isfinite(n))):
        raise ParameterError(f"{what}: expected a finite point x,y,z and normal nx,ny,nz, got {tuple(q)}, {tuple(n)}")
    if not np.any(n != 0):
        raise ParameterError(f"{what}: expected a non-zero normal, got {tuple(n)}")
    m = render_to_world(pyramid, frame)
    # normal . (M p + t - q) = (M^T normal) . p + normal . (t - q)
    nr = m[:3, :3].T @ n
    d = float(n @ (m[:3, 3] - q))
    length = float(np.linalg.norm(nr))
    return (*(float(v) for v in nr / length), d / length)


def voxel_box_to_render(pyramid, start, stop) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Render box of level-0 voxels ``start..stop`` (``(z, y, x)``, stop exclusive): their cells."""
    shape = pyramid.shape
    start = tuple(int(v) for v in start)
    stop = tuple(int(v) for v in stop)
    for a, b, n, axis in zip(start, stop, shape, "zyx"):
        if not 0 <= a < b <= n:
            raise ParameterError(f"--crop-voxels: {axis} range {a}:{b}: expected 0 <= start < stop <= {n} (level 0 "
                                 f"is {shape[2]}x{shape[1]}x{shape[0]} voxels, x, y, z)")
    sp = np.array(pyramid.spacing[::-1], dtype=np.float64)
    lo = (np.array(start[::-1], dtype=np.float64) - 0.5) * sp
    hi = (np.array(stop[::-1], dtype=np.float64) - 0.5) * sp
    return tuple(map(float, lo)), tuple(map(float, hi))


def _aligned(m3: np.ndarray) -> bool:
    """True when every render axis maps onto one world axis (a permutation with flips and scales)."""
    nz = np.abs(m3) > 1e-9 * np.abs(m3).max()
    return bool(np.all(nz.sum(axis=0) == 1) and np.all(nz.sum(axis=1) == 1))


def world_box_to_render(pyramid, frame, corner_a, corner_b):
    """A world box (two opposite corners ``(x, y, z)``) in the render frame.

    Returns ``(box, planes)``: an axis-aligned render ``box`` and no planes when the store's axes are
    aligned with its world frame, else ``box=None`` and the six faces as render-frame planes.
    """
    a = np.asarray(corner_a, dtype=np.float64).reshape(-1)
    b = np.asarray(corner_b, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or b.shape != (3,) or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ParameterError(f"--crop: expected two finite corners x,y,z, got {tuple(a)} and {tuple(b)}")
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    m = world_to_render(pyramid, frame)
    if _aligned(m[:3, :3]):
        corners = _points(m, np.stack([lo, hi]))
        return (tuple(map(float, corners.min(axis=0))), tuple(map(float, corners.max(axis=0)))), ()
    planes = []
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        planes.append(plane_to_render(pyramid, frame, lo, e, "--crop"))
        planes.append(plane_to_render(pyramid, frame, hi, -e, "--crop"))
    return None, tuple(planes)


def cut_shape(pyramid, frame=None, *, crop=None, crop_voxels=None, clip_planes=()) -> Shape | None:
    """The :class:`Shape` of a crop box and clip planes given in the store's terms, or None for no cut.

    Parameters
    ----------
    pyramid : Pyramid
        The store's pyramid (spacing and level-0 shape).
    frame : WorldFrame, optional
        The store's voxel-to-world affine (``loader.frame``); None: the world is the render frame.
    crop : pair of (x, y, z), optional
        Two opposite corners of the crop box in the world frame.
    crop_voxels : pair of (z, y, x), optional
        ``(start, stop)`` level-0 voxel indices (stop exclusive): the cells of those voxels.
    clip_planes : sequence of (x, y, z, nx, ny, nz)
        World point and normal of each plane; the side the normal points to is kept.
    """
    if crop is not None and crop_voxels is not None:
        raise ParameterError("--crop: expected either --crop (world units) or --crop-voxels, got both")
    box, planes = None, []
    if crop is not None:
        box, face_planes = world_box_to_render(pyramid, frame, *crop)
        planes.extend(face_planes)
    elif crop_voxels is not None:
        box = voxel_box_to_render(pyramid, *crop_voxels)
    for k, spec in enumerate(clip_planes):
        v = np.asarray(spec, dtype=np.float64).reshape(-1)
        if v.shape != (6,):
            raise ParameterError(f"--clip-plane #{k + 1}: expected x,y,z,nx,ny,nz, got {spec!r}")
        planes.append(plane_to_render(pyramid, frame, v[:3], v[3:], f"--clip-plane #{k + 1}"))
    if len(planes) > MAX_PLANES:
        extra = " (the crop box of a store oblique to its world frame takes six of them)" if crop is not None and box is None else ""
        raise ParameterError(f"--clip-plane: expected at most {MAX_PLANES} clip planes in all{extra}, got {len(planes)}")
    if box is not None:  # a box wholly outside the volume draws nothing: say so instead of an empty image
        vlo, vhi = pyramid.volume_box()
        if np.any(np.asarray(box[1]) < vlo) or np.any(np.asarray(box[0]) > vhi):
            raise ParameterError(f"--crop: the box {box[0]}..{box[1]} (render frame) lies outside the volume "
                                 f"{tuple(vlo)}..{tuple(vhi)}")
    if box is None and not planes:
        return None
    return Shape(box=box, planes=tuple(planes))


@dataclass
class CutEditor:
    """The cut the viewer's keys edit: a crop box (render frame) and up to six clip planes.

    ``select()`` cycles through the box's six faces, then the planes, then nothing; ``move(steps)``
    moves the selected face or plane along its normal by ``steps`` times :attr:`step` (a face
    never passes the opposite one nor leaves the volume); ``add_plane`` puts a plane through a
    point facing a direction (the viewer: through the centre of interest, facing the camera).
    """

    volume_lo: np.ndarray
    volume_hi: np.ndarray
    step: float
    box_lo: np.ndarray = field(default=None)  # type: ignore[assignment]
    box_hi: np.ndarray = field(default=None)  # type: ignore[assignment]
    planes: list = field(default_factory=list)
    selected: int = -1  # -1: nothing; 0..5: a face of FACES; 6..: plane selected - 6

    def __post_init__(self) -> None:
        self.volume_lo = np.asarray(self.volume_lo, dtype=np.float64)
        self.volume_hi = np.asarray(self.volume_hi, dtype=np.float64)
        if not self.step > 0:
            raise ParameterError(f"step: expected a distance > 0, got {self.step}")
        self.box_lo = self.volume_lo.copy() if self.box_lo is None else np.asarray(self.box_lo, dtype=np.float64)
        self.box_hi = self.volume_hi.copy() if self.box_hi is None else np.asarray(self.box_hi, dtype=np.float64)
        self.planes = [tuple(map(float, p)) for p in self.planes]

    @classmethod
    def for_pyramid(cls, pyramid, shape: Shape | None = None, steps: int = 32) -> "CutEditor":
        """An editor over ``pyramid``'s volume box starting from ``shape`` (moves of 1/``steps`` of the largest side)."""
        lo, hi = pyramid.volume_box()
        ed = cls(lo, hi, float(np.max(hi - lo)) / steps)
        if shape is not None:
            if shape.box is not None:
                ed.box_lo = np.maximum(np.asarray(shape.box[0]), lo)
                ed.box_hi = np.minimum(np.asarray(shape.box[1]), hi)
            ed.planes = [tuple(p) for p in shape.planes]
        return ed

    def shape(self) -> Shape | None:
        """The current cut as a :class:`Shape` (None when it cuts nothing)."""
        full = np.all(self.box_lo <= self.volume_lo) and np.all(self.box_hi >= self.volume_hi)
        if full and not self.planes:
            return None
        box = None if full else (tuple(self.box_lo), tuple(self.box_hi))
        return Shape(box=box, planes=tuple(self.planes))

    def select(self) -> str:
        """Select the next face or plane (after the last plane: nothing); returns its name."""
        n = len(FACES) + len(self.planes)
        self.selected = self.selected + 1 if self.selected + 1 < n else -1
        return self.selected_name()

    def selected_name(self) -> str:
        if self.selected < 0:
            return "none"
        if self.selected < len(FACES):
            axis, side = FACES[self.selected]
            return f"box {axis}{'+' if side else '-'}"
        return f"plane {self.selected - len(FACES) + 1}"

    def move(self, steps: float) -> None:
        """Move the selected face (positive: outwards) or plane (positive: along its kept side's normal)."""
        if self.selected < 0:
            return
        if self.selected < len(FACES):
            axis, side = FACES[self.selected]
            k = "xyz".index(axis)
            if side:
                self.box_hi[k] = float(np.clip(self.box_hi[k] + steps * self.step, self.box_lo[k], self.volume_hi[k]))
            else:
                self.box_lo[k] = float(np.clip(self.box_lo[k] - steps * self.step, self.volume_lo[k], self.box_hi[k]))
            return
        i = self.selected - len(FACES)
        a, b, c, d = self.planes[i]
        self.planes[i] = (a, b, c, d - steps * self.step * float(np.linalg.norm((a, b, c))))

    def add_plane(self, point, normal) -> bool:
        """Add a plane through ``point`` keeping the side ``normal`` points to; False when six are there."""
        if len(self.planes) >= MAX_PLANES:
            return False
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        self.planes.append((*map(float, n), -float(n @ np.asarray(point, dtype=np.float64))))
        self.selected = len(FACES) + len(self.planes) - 1
        return True

    def remove_selected(self) -> None:
        """Remove the selected plane, or reset the box when a face is selected."""
        if self.selected >= len(FACES):
            del self.planes[self.selected - len(FACES)]
            self.selected = -1
        elif self.selected >= 0:
            self.box_lo, self.box_hi = self.volume_lo.copy(), self.volume_hi.copy()

    def describe(self, to_world: np.ndarray | None = None, unit: str = "") -> str:
        """One HUD line: the box in world units (through ``to_world``, the render-to-world matrix)
        and the planes. A box along the array's axes of a store oblique to its world frame is given
        by its two corners instead of per-axis ranges."""
        if self.shape() is None:
            return "cut: none (F selects a box face, V adds a plane)"
        m = np.eye(4) if to_world is None else to_world
        corners = _points(m, np.stack([self.box_lo, self.box_hi]))
        u = f" {unit}" if unit else ""
        if _aligned(m[:3, :3]):
            lo, hi = corners.min(axis=0), corners.max(axis=0)
            box = "x,y,z " + ",".join(f"{a:.4g}:{b:.4g}" for a, b in zip(lo, hi))
        else:
            box = " to ".join("(" + ", ".join(f"{v:.4g}" for v in c) + ")" for c in corners)
        return f"cut: box {box}{u}, {len(self.planes)} plane(s); selected {self.selected_name()}"


def outside_bricks(pyramid, shape: Shape | None):
    """The clip-texture's ``outside`` test for ``shape`` (see ``ClipTexture.set_outside``): bricks
    never read because no sample inside the cut can use one of their voxels; None for no cut.

    A sample inside the cut interpolates voxels up to one voxel away, and a drawn brick's
    neighbours are sampled across its faces, so a brick counts as outside only when its octree
    node grown by one voxel of its level on every side lies wholly outside the cut.
    """
    if shape is None or shape.is_everything:
        return None
    scales = [np.array(lv.scale[::-1], dtype=np.float64) for lv in pyramid.levels]

    def outside(level: int, keys: np.ndarray) -> np.ndarray:
        lo, hi = pyramid.node_box(level, np.asarray(keys).reshape(-1, 3))
        return shape.boxes_outside(lo - scales[level], hi + scales[level])

    return outside
