"""The GPU brick cache: per-level 3D textures addressed toroidally, filled by sub-loads under a budget.

Why this layout (see ``docs/rendering.md`` for the measurement)
----------------------------------------------------------------
Each pyramid level gets **one 3D texture** of ``w = (wz, wy, wx)`` bricks (``w = min(W, grid)``
per axis, one ``W`` for every level, like the clip-texture's clipmap). Brick ``b`` lives in slot
``b mod w``. The texture is sampled with ``REPEAT`` wrapping, so the texel after the last one of
slot ``w - 1`` is the first one of slot ``0`` - which, toroidally, holds brick ``b + 1``. Hardware
trilinear filtering is therefore seamless across the faces of neighbouring bricks of a level
without any ghost border, and a brick is uploaded with one ``texture.write(viewport=...)`` of
exactly its own voxels (no copy into an atlas with borders, no re-upload of neighbours). Where a
neighbour is *not* on the GPU (not loaded, evicted, or outside the grid), the shader clamps the
brick-local coordinate to the brick's own voxel centres on that face (``CLAMP_TO_EDGE`` per brick).
A face counts as open only if every existing brick of the 3x3 slab behind it is on the GPU, so the
edge and corner texels that trilinear filtering touches are correct too.

The window shapes follow the render action's region of interest (:meth:`GpuBrickCache.follow_region`,
:mod:`clipvol.render.region_windows`): with no region every level has its cube; a slice's region -
a slab, wide in the plane and thin across it - gets textures of its own shape within the same
budget, so its fine part is on the GPU whole instead of aliasing in a cube.

The one GPU seam (pygfx habit)
------------------------------
Per frame the render action calls :meth:`GpuBrickCache.begin_frame`, hands the cache (a residency
object) to the selection, then calls :meth:`GpuBrickCache.commit`, the only place that writes
textures. ``resident_mask`` answers "drawable this frame": on the GPU already, or in the
clip-texture's RAM and still inside this frame's ``texels_per_frame`` upload budget. A ``True``
answer *reserves* the brick's slot for the frame, so two bricks that share a slot are never both
drawn and a slot drawn this frame is never overwritten in the same frame. Eviction is positional
(a new brick replaces the previous occupant of its slot); since only unreserved slots are written,
an evicted brick was not drawn this frame, and the window always holds the most recently used
brick of each slot.

Cells for empty-space skipping
------------------------------
Beside each level texture the cache keeps, per cell of ``cell_edges`` voxels of every slot, the
cell's ``[min, max]`` (:mod:`clipvol.scene.occupancy`), written by :meth:`GpuBrickCache.commit`
with the brick's texels, so a cell's range always describes what its slot holds. They are
computed here, once per upload, from the brick's texels (80-155 µs for a 64³ brick), unless the
clip-texture already took them in its loader threads (``ClipTexture(cells_on_load=True)``,
:meth:`ClipTexture.cell_ranges`; off by default, since it slows a fill); then the upload only
copies them.
:meth:`GpuBrickCache.occupancy_texture` turns them into one byte per cell for a transfer function
(the ranges widened over the 26 neighbouring cells of the toroidal window, so trilinear filtering
across a face is covered) - recomputed for every level when the table or its window changes, and
for the levels that received bricks otherwise - in one small ``r8`` 3D texture, the levels stacked
along z, each at the same toroidal addressing as its level texture divided by the cell edge.

Texture formats: ``uint8``/``int8`` as normalised ``r8``, ``uint16``/``int16`` as normalised
``r16`` (signed types shifted to unsigned), ``float16``/``float32`` as ``r32f`` raw values (NaN and
Inf kept; the shader treats non-finite samples as transparent), every other type (32/64-bit
integers, ``float64``) - and float data whose range float32 arithmetic would lose (denormal or
zero-width ranges, magnitudes beyond 1e30) - as ``r32f`` normalised over the data's value range.
:class:`TextureFormat` gives ``(a, b)`` with ``raw = a * texel + b``; the shader maps a texel
straight to the transfer function's coordinate with a scale and offset computed in float64, so
``raw`` itself never has to exist in float32.

Why one module of this size: the per-level textures, slot reservations, neighbour clamps, cell
ranges and region windows share the slot tables every draw path reads each frame; the pure rules
live apart (:mod:`.region_windows`, :mod:`clipvol.scene.occupancy`, :mod:`clipvol.scene.page_table`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bricking.pyramid import NEIGHBOUR_OFFSETS, Pyramid
from ..errors import ParameterError
from ..paging.cliptexture import BrickState
from ..rows import unique_rows
from ..scene.consistent import spread_support
from ..scene.occupancy import cell_edges, cell_ranges, occupancy, widen
from ..scene.selection.cut import DrawItems
from .region_windows import region_gpu_windows

#: per face ``(axis, side)`` in :meth:`GpuBrickCache.open_faces`'s order, the row of its neighbour in
#: ``NEIGHBOUR_OFFSETS`` and the rows of the 3x3 slab behind it (made once: a call asks for a few
#: bricks on most frames, where building these per face cost most of the call)
_FACE = np.array([int(np.flatnonzero(np.all(NEIGHBOUR_OFFSETS == np.eye(3, dtype=np.int64)[a] * d, axis=1))[0])
                  for a in range(3) for d in (-1, 1)])
_SLAB = np.array([np.flatnonzero(NEIGHBOUR_OFFSETS[:, a] == d) for a in range(3) for d in (-1, 1)])

__all__ = ["GpuBrickCache", "TextureFormat", "texture_format", "t_scale_offset", "texel_to_raw", "allocate_gpu_windows"]


@dataclass(frozen=True, slots=True)
class TextureFormat:
    """How bricks of one dtype are stored: moderngl ``dtype``, bytes per texel, and ``raw = a*texel + b``."""

    gl_dtype: str
    itemsize: int
    a: float
    b: float

    def __post_init__(self) -> None:
        if self.gl_dtype not in ("f1", "nu2", "f4") or self.itemsize not in (1, 2, 4):
            raise ParameterError(f"TextureFormat: expected gl_dtype f1/nu2/f4, got {self.gl_dtype!r}")


def texture_format(dtype, value_range: tuple[float, float]) -> TextureFormat:
    """The :class:`TextureFormat` for bricks of ``dtype`` whose finite values lie in ``value_range``."""
    dt = np.dtype(dtype)
    if dt == np.uint8:
        return TextureFormat("f1", 1, 255.0, 0.0)
    if dt == np.int8:
        return TextureFormat("f1", 1, 255.0, -128.0)
    if dt == np.uint16:
        return TextureFormat("nu2", 2, 65535.0, 0.0)
    if dt == np.int16:
        return TextureFormat("nu2", 2, 65535.0, -32768.0)
    lo, hi = (float(v) for v in value_range)
    if dt in (np.float16, np.float32) and 1e-30 < hi - lo and max(abs(lo), abs(hi)) < 1e30:
        return TextureFormat("f4", 4, 1.0, 0.0)  # raw values: no conversion on upload
    # normalised over the data's range: 64-bit types, and floats whose range float32 arithmetic
    # on the GPU would lose (denormal or zero-width ranges, magnitudes near the float32 limit)
    return TextureFormat("f4", 4, (hi - lo) if hi > lo else 1.0, lo)


def t_scale_offset(fmt: TextureFormat, window: tuple[float, float]) -> tuple[float, float]:
    """``(scale, offset)`` with ``t = texel * scale + offset`` for the transfer function's ``window``.

    Folded in float64 so that ``raw = a * texel + b`` never exists in float32. A zero-width window
    is a step at ``lo`` (0 below, 0.5 at, 1 above; the shader clamps). For the integer formats
    (``r8``/``r16``, whose raw values are whole numbers) the step is one unit of ``t`` per raw
    unit: a texel's float32 rounding error (~1e-7 of its value) then moves ``t`` by far less than a
    table entry. A steeper step would amplify that rounding error past the table: a constant
    uint16 volume, whose window is zero wide, would map its one value below the window and draw
    nothing. Float formats keep a steep step: their raw values can differ by far less than one.
    """
    lo, hi = (float(v) for v in window)
    if hi > lo:
        scale, offset = fmt.a / (hi - lo), (fmt.b - lo) / (hi - lo)
    elif fmt.gl_dtype in ("f1", "nu2"):
        scale, offset = fmt.a, fmt.b - lo + 0.5
    else:
        big = 1e30 / max(abs(fmt.a), 1e-300)
        scale, offset = fmt.a * big, (fmt.b - lo) * big + 0.5
    return float(np.clip(scale, -3e38, 3e38)), float(np.clip(offset, -3e38, 3e38))


def texel_to_raw(fmt: TextureFormat, texel) -> np.ndarray:
    """float64 data values of texels read back (MIP): ``a * texel + b``, rounded to whole numbers
    for the integer formats, whose stored values are whole: the float32 texel carries a rounding
    error that would otherwise put a value just below or above itself (and a zero-width window's
    step then draws it as nothing, or as the top of the table)."""
    raw = fmt.a * np.asarray(texel, dtype=np.float64)
    if fmt.gl_dtype in ("f1", "nu2"):
        raw = np.rint(raw)
    return raw + fmt.b


def spread_texels(spread: np.ndarray, fmt: TextureFormat) -> np.ndarray:
    """A brick's spread (:mod:`clipvol.bricking.spread`, raw units >= 0) in the texel units of
    ``fmt``: ``raw = a * texel`` (no offset: a spread is a difference of values). The 8- and 16-bit
    formats store it as it is (its type is the unsigned one of the data's width), float formats
    as float32 ``spread / a``."""
    if fmt.gl_dtype == "f1":
        return np.ascontiguousarray(spread, dtype=np.uint8)
    if fmt.gl_dtype == "nu2":
        return np.ascontiguousarray(spread, dtype=np.uint16)
    if fmt.a == 1.0:
        return np.ascontiguousarray(spread, dtype=np.float32)
    return (spread.astype(np.float64) / fmt.a).astype(np.float32)


def convert_brick(brick: np.ndarray, fmt: TextureFormat) -> np.ndarray:
    """``brick`` in the texel representation of ``fmt`` (C-contiguous, ready for ``texture.write``)."""
    dt = brick.dtype
    if dt == np.uint8 or dt == np.uint16:
        return np.ascontiguousarray(brick)
    if dt == np.int8:
        return (brick.astype(np.int16) + 128).astype(np.uint8)
    if dt == np.int16:
        return (brick.astype(np.int32) + 32768).astype(np.uint16)
    if fmt.a == 1.0 and fmt.b == 0.0 and dt == np.float32:
        return np.ascontiguousarray(brick)
    if fmt.a == 1.0 and fmt.b == 0.0 and dt == np.float16:
        return brick.astype(np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        return ((brick.astype(np.float64) - fmt.b) / fmt.a).astype(np.float32)


#: the neighbour set of a level's drawn bricks is a dilation of their occupancy over their bounding
#: box of up to this many cells (4 MB of bools, a few ms); bricks scattered wider go row by row
DILATE_MAX_CELLS = 1 << 22

#: largest single texture (bytes); Mesa's llvmpipe refuses 3D textures of about 2 GiB
MAX_TEXTURE_BYTES = 1 << 30


def allocate_gpu_windows(pyramid: Pyramid, budget: int, itemsize: int, max_texture_size: int = 2048,
                         max_texture_bytes: int = MAX_TEXTURE_BYTES) -> list[tuple[int, int, int] | None]:
    """Window shape ``(wz, wy, wx)`` in bricks per level (``None``: no texture) within ``budget`` bytes.

    One ``W`` for all levels, ``w = min(W, grid)`` per axis, the largest ``W`` whose textures fit
    (each texture also at most ``max_texture_size`` texels per axis and ``max_texture_bytes``).
    If even ``W = 1`` does not fit every level, coarse levels are served first and the finest
    levels get no texture (they are then drawn coarser). Raises :class:`ParameterError` when the
    budget cannot hold one brick of the coarsest level.
    """
    brick_bytes = int(np.prod(pyramid.brick_shape)) * itemsize
    nlev = pyramid.num_levels
    if budget < brick_bytes:
        raise ParameterError(
            f"texture_budget: expected at least one brick of the coarsest level "
            f"({brick_bytes} bytes for brick shape {pyramid.brick_shape}), got {budget} bytes"
        )
    wmax = [max(1, max_texture_size // b) for b in pyramid.brick_shape]

    max_bricks = max(1, max_texture_bytes // brick_bytes)

    def capped(w: list[int]) -> tuple[int, int, int]:
        while w[0] * w[1] * w[2] > max_bricks:  # shrink the longest axis until the texture fits
            a = int(np.argmax(w))
            w[a] = max(1, w[a] - 1)
        return tuple(w)  # type: ignore[return-value]

    def shapes(W: int) -> list[tuple[int, int, int]]:
        return [capped([min(W, g, m) for g, m in zip(pyramid.grid(L), wmax)]) for L in range(nlev)]

    def total(W: int) -> int:
        return sum(int(np.prod(s)) for s in shapes(W)) * brick_bytes

    if total(1) > budget:
        out: list[tuple[int, int, int] | None] = [None] * nlev
        left = budget
        for L in range(nlev - 1, -1, -1):
            if left < brick_bytes:
                break
            out[L] = (1, 1, 1)
            left -= brick_bytes
        return out
    top = max(max(pyramid.grid(L)) for L in range(nlev))
    lo, hi = 1, top
    while lo < hi:  # largest W with total(W) <= budget (total is monotone in W)
        mid = (lo + hi + 1) // 2
        if total(mid) <= budget:
            lo = mid
        else:
            hi = mid - 1
    return shapes(lo)  # type: ignore[return-value]


def _item_keys(items) -> np.ndarray:
    """``(n, 4)`` int64 ``(level, z, y, x)`` of a frame's draw items: a
    :class:`~clipvol.scene.selection.Selection`'s (its items' array), or a list of draw items'."""
    return DrawItems.from_items(getattr(items, "items", items)).rows


class GpuBrickCache:
    """Bricks of every level in per-level toroidal 3D textures, within ``texture_budget`` bytes.

    Parameters
    ----------
    ctx : moderngl.Context
    pyramid : Pyramid
    texture_budget : int
        Bytes of texture memory for bricks; :attr:`texture_bytes` never exceeds it.
    spread_levels : tuple of int
        Levels whose bricks carry their spread (:attr:`ClipTexture.spread_levels`): their textures
        hold two channels, mean and spread (``.rg``), in the same texel units; the budget then counts
        every level at two channels (conservative: level 0 keeps one).
    """

    def __init__(self, ctx, pyramid: Pyramid, texture_budget: int, spread_levels=()) -> None:
        self.ctx = ctx
        self.pyramid = pyramid
        self.texture_budget = int(texture_budget)
        self.format = texture_format(pyramid.dtype, pyramid.value_range)
        #: levels whose textures hold (mean, spread) per voxel (consistent coarse levels)
        self.spread_levels: tuple[int, ...] = tuple(int(L) for L in spread_levels)
        #: bytes per voxel the budget counts (two channels with a spread)
        self.texel_bytes = self.format.itemsize * (2 if self.spread_levels else 1)
        max3d = int(ctx.info.get("GL_MAX_3D_TEXTURE_SIZE", 2048))
        self.windows = allocate_gpu_windows(pyramid, self.texture_budget, self.texel_bytes, max3d)
        #: the region the windows were last fitted to (a Region is immutable: the same object, the same fit)
        self._fitted_region: object = None
        #: the cube windows of the budget: what a view without a region of interest gets back
        self.cube_windows = list(self.windows)
        self._max3d = max3d
        self.brick_texels = int(np.prod(pyramid.brick_shape))
        self.textures: list = []
        self._slot_key: list[np.ndarray | None] = []  # per level (wz, wy, wx, 3) brick index held, -1 = empty
        import moderngl

        B = pyramid.brick_shape
        for L, w in enumerate(self.windows):
            if w is None:
                self.textures.append(None)
                self._slot_key.append(None)
                continue
            size = (w[2] * B[2], w[1] * B[1], w[0] * B[0])  # GL (width, height, depth) = (x, y, z)
            tex = ctx.texture3d(size, self._channels(L), dtype=self.format.gl_dtype)
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            tex.repeat_x = tex.repeat_y = tex.repeat_z = True
            self.textures.append(tex)
            self._slot_key.append(np.full(tuple(w) + (3,), -1, dtype=np.int64))
        self.texture_bytes = sum(
            int(np.prod(w)) * self.brick_texels * self.format.itemsize * self._channels(L)
            for L, w in enumerate(self.windows) if w is not None
        )
        self._clip = None
        #: per level, the brick holding each slot this frame ((w..., 3) int64, -1: free): an array, not
        #: a dict, so a full-resolution cut reserves thousands of slots without a tuple each
        self._reserved: list[np.ndarray | None] = [None if k is None else np.full_like(k, -1) for k in self._slot_key]
        self._pending: dict[tuple[int, tuple[int, int, int]], np.ndarray] = {}
        self._upload_left: int | None = None
        self._allow = None
        self.bytes_uploaded = 0  # of the last commit
        self.texels_uploaded = 0
        self.bricks_uploaded = 0
        self.total_texels_uploaded = 0
        #: bumped whenever a slot's content changes (an upload, a reshaped level, a release): what the
        #: frame derived from the slots (merged boxes, page table, open faces) holds while it stays
        self.generation = 0
        self._nb_cache: tuple | None = None  # (items, neighbours) of the current frame
        # empty-space skipping below the brick (module docstring, "Cells"): per level the cells'
        # value ranges (+inf/-inf: nothing known yet), the occupancy texture, what it shows
        self.cell_edges = cell_edges(B)
        self._cell_lo: list[np.ndarray | None] = []
        self._cell_hi: list[np.ndarray | None] = []
        #: per spread level, the largest spread of each cell (raw units; widens its range for DISTRIB)
        self._cell_sp: dict[int, np.ndarray | None] = {}
        self.occupancy_levels: list[tuple[tuple[int, int, int], int] | None] = []  # ((cx, cy, cz) cells, z0)
        z0 = 0
        for L, w in enumerate(self.windows):
            if w is None or self.cell_edges is None:
                self._cell_lo.append(None)
                self._cell_hi.append(None)
                self.occupancy_levels.append(None)
                continue
            cells = tuple(int(wa * b // e) for wa, b, e in zip(w, B, self.cell_edges))  # (z, y, x)
            if self._channels(L) == 2:
                self._cell_sp[L] = np.zeros(cells, dtype=np.float32)
            self._cell_lo.append(np.full(cells, np.inf, dtype=np.float32))
            self._cell_hi.append(np.full(cells, -np.inf, dtype=np.float32))
            self.occupancy_levels.append((cells[::-1], z0))
            z0 += cells[0]
        self._occ_tex = None
        self._occ_key = None
        self._occ_dirty: dict[int, set] = {}  # level -> slots written since the flags were derived
        self._occ_flags: list[np.ndarray | None] = [None] * len(self.windows)  # the flags, as uploaded
        #: per level, (cells holding data, of them empty) under the last transfer function
        self.occupancy_counts: list[tuple[int, int]] = [(0, 0)] * len(self.windows)

    def _channels(self, level: int) -> int:
        """Components of ``level``'s texture: 2 (mean, spread) for a spread level, else 1."""
        return 2 if level in self.spread_levels else 1

    # -- per frame ---------------------------------------------------------------------------------
    def begin_frame(self, clip_texture, texels_per_frame: int | None, allow=None) -> "GpuBrickCache":
        """Start a frame: forget reservations, set this frame's upload budget; returns the residency object.

        ``allow``: if given, a set of ``(level, index)``; only those bricks may be uploaded this
        frame (the render action's coarse-first choice, see :meth:`plan_uploads`).
        """
        self._clip = clip_texture
        self._nb_cache = None
        self.follow_region(getattr(clip_texture, "region", None))
        for r in self._reserved:
            if r is not None:
                r.fill(-1)
        self._pending = {}
        self._allow = allow
        self._upload_left = None if texels_per_frame is None else int(texels_per_frame)
        return self

    @property
    def region(self):
        """The region of interest of the clip-texture this frame reads (None: none): with the slots
        (:attr:`generation`), what :meth:`open_faces` answers from."""
        return getattr(self._clip, "region", None)

    def follow_region(self, region) -> list[int]:
        """Fit the level textures to ``region`` (a :class:`~clipvol.paging.region.Region` or ``None``
        for the cube windows) within :attr:`texture_budget`; returns the levels reshaped.

        Called by :meth:`begin_frame` with the clip-texture's region, so a slice's wide, thin slab
        fits its textures as it fits the clip-texture's windows (:mod:`clipvol.render.region_windows`).
        A reshaped level gets a new, empty texture (its bricks are uploaded again); a level whose
        shape already spans its region is left alone, so scrolling a plane reallocates nothing.
        """
        if region is self._fitted_region:  # called every frame: an unchanged region needs no fitting
            return []
        self._fitted_region = region
        B = self.pyramid.brick_shape
        brick_bytes = self.brick_texels * self.texel_bytes
        grids = [self.pyramid.grid(L) for L in range(self.pyramid.num_levels)]
        shapes = region_gpu_windows(
            grids, self.cube_windows, None if region is None else region.bricks, self.windows,
            self.texture_budget // brick_bytes, max_axis=tuple(max(1, self._max3d // b) for b in B),
            max_bricks=max(1, MAX_TEXTURE_BYTES // brick_bytes))
        changed = [L for L, (a, b) in enumerate(zip(shapes, self.windows)) if a != b]
        for L in changed:
            self._reshape_level(L, shapes[L])
        if changed:
            self.texture_bytes = sum(int(np.prod(w)) * brick_bytes for w in self.windows if w is not None)
            self._restack_cells()
        return changed

    def _reshape_level(self, level: int, w: tuple[int, int, int]) -> None:
        """A new, empty texture of ``w`` bricks for ``level`` (its slot keys, reservations and cells too)."""
        import moderngl

        B = self.pyramid.brick_shape
        if self.textures[level] is not None:
            self.textures[level].release()
        tex = self.ctx.texture3d((w[2] * B[2], w[1] * B[1], w[0] * B[0]), self._channels(level),
                                 dtype=self.format.gl_dtype)
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex.repeat_x = tex.repeat_y = tex.repeat_z = True
        self.textures[level] = tex
        self.generation += 1
        self.windows[level] = tuple(int(v) for v in w)
        self._slot_key[level] = np.full(tuple(w) + (3,), -1, dtype=np.int64)
        self._reserved[level] = np.full_like(self._slot_key[level], -1)
        self._pending = {k: v for k, v in self._pending.items() if k[0] != level}
        if self.cell_edges is not None:
            cells = tuple(int(wa * b // e) for wa, b, e in zip(w, B, self.cell_edges))
            self._cell_lo[level] = np.full(cells, np.inf, dtype=np.float32)
            self._cell_hi[level] = np.full(cells, -np.inf, dtype=np.float32)
            if self._channels(level) == 2:
                self._cell_sp[level] = np.zeros(cells, dtype=np.float32)
            self._occ_flags[level] = None
            self._occ_dirty.pop(level, None)
            self.occupancy_counts[level] = (0, 0)

    def _restack_cells(self) -> None:
        """Lay the levels' cells out again along z of the occupancy texture (made anew on next use)."""
        if self.cell_edges is None:
            return
        z0 = 0
        for L, lo in enumerate(self._cell_lo):
            if lo is None:
                continue
            self.occupancy_levels[L] = (lo.shape[::-1], z0)
            z0 += lo.shape[0]
        if self._occ_tex is not None:
            self._occ_tex.release()
            self._occ_tex = None
        self._occ_key = None  # every level's flags derived again into the new texture

    def plan_uploads(self, texels_per_frame: int, items=()) -> set:
        """After a dry selection with an unlimited budget: the bricks to upload this frame.

        Candidates are the bricks the dry run would have uploaded plus the not-yet-uploaded
        ancestors (held in RAM) of its draw ``items``. Coarse levels go first - they are the fallback
        of everything finer, so a frame never shows a hole for want of upload budget - then the
        order the selection asked for them; at most ``texels_per_frame`` texels (at least one
        brick). Forgets the dry run's pending uploads.
        """
        cand = list(self._pending)
        seen = set(cand)
        top = self.pyramid.num_levels - 1
        keys = _item_keys(items)
        anc: dict[int, list[np.ndarray]] = {}
        for L in np.unique(keys[:, 0]).tolist():
            idx = keys[keys[:, 0] == L, 1:]
            for A in range(L + 1, top + 1):
                anc.setdefault(A, []).append(idx >> (A - L))
        for L, parts in anc.items():
            if self.windows[L] is None:
                continue
            arr = unique_rows(np.concatenate(parts))
            ok = ~self.on_gpu_mask(L, arr) & np.asarray(self._clip.resident_mask(L, arr), dtype=bool)
            for k in arr[ok]:
                key = (L, tuple(int(i) for i in k))
                if key not in seen:
                    seen.add(key)
                    cand.append(key)
        cand.sort(key=lambda k: -k[0])  # stable: selection order within a level
        n = max(1, int(texels_per_frame) // self.brick_texels)
        self._pending = {}
        return set(cand[:n])

    def _slots(self, level: int, idx: np.ndarray) -> np.ndarray:
        return idx % np.asarray(self.windows[level], dtype=np.int64)

    def on_gpu(self, level: int, index) -> bool:
        """Brick ``index`` ``(bz, by, bx)`` is in its slot of the level's texture now (one brick, no
        array set-up: ``merge_items`` asks this for every culled sibling of a full-resolution cut)."""
        keys = self._slot_key[level]
        if keys is None:
            return False
        bz, by, bx = (int(v) for v in index)
        wz, wy, wx = self.windows[level]
        return keys[bz % wz, by % wy, bx % wx].tolist() == [bz, by, bx]

    def on_gpu_mask(self, level: int, indices) -> np.ndarray:
        """``(n,)`` bool: brick ``indices[i]`` is in its slot of the level's texture now."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        keys = self._slot_key[level]
        if keys is None or len(idx) == 0:
            return np.zeros(len(idx), dtype=bool)
        s = self._slots(level, idx)
        return np.all(keys[s[:, 0], s[:, 1], s[:, 2]] == idx, axis=1)

    def in_window_mask(self, level: int, indices) -> np.ndarray:
        """The clip-texture's window, restricted to levels that have a texture."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        if self.windows[level] is None:
            return np.zeros(len(idx), dtype=bool)
        return np.asarray(self._clip.in_window_mask(level, idx), dtype=bool) | self.on_gpu_mask(level, idx)

    def resident_mask(self, level: int, indices) -> np.ndarray:
        """Drawable this frame (on the GPU, or in RAM within the upload budget); reserves the slots."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        out = np.zeros(len(idx), dtype=bool)
        if self.windows[level] is None or len(idx) == 0:
            return out
        gpu = self.on_gpu_mask(level, idx)
        ram = np.asarray(self._clip.resident_mask(level, idx), dtype=bool)
        slots = self._slots(level, idx)
        reserved = self._reserved[level]
        holder = reserved[slots[:, 0], slots[:, 1], slots[:, 2]]  # (n, 3); -1: free
        todo = gpu | ram
        # Fast path, the steady state: a brick on the GPU whose slot no other candidate of this call
        # asks for and that is free or already its own takes it (no budget, no order to respect).
        # Everything else goes through the loop below, in order.
        if gpu.any():
            w = np.asarray(self.windows[level], dtype=np.int64)
            skey = (slots[:, 0] * w[1] + slots[:, 1]) * w[2] + slots[:, 2]
            cand = np.nonzero(todo)[0]
            _, inv, cnt = np.unique(skey[cand], return_inverse=True, return_counts=True)
            alone = np.zeros(len(idx), dtype=bool)
            alone[cand] = cnt[inv.reshape(-1)] == 1
            fast = gpu & alone & ((holder[:, 0] < 0) | np.all(holder == idx, axis=1))
            if fast.any():
                sf = slots[fast]
                reserved[sf[:, 0], sf[:, 1], sf[:, 2]] = idx[fast]
                out[fast] = True
                todo[fast] = False
        for i in np.nonzero(todo)[0].tolist():
            key = (int(idx[i, 0]), int(idx[i, 1]), int(idx[i, 2]))
            sz, sy, sx = (int(v) for v in slots[i])
            held = reserved[sz, sy, sx]
            if held[0] >= 0:
                out[i] = bool(np.all(held == idx[i]))
                continue
            if not gpu[i]:
                if self._allow is not None and (level, key) not in self._allow:
                    continue
                if self._upload_left is not None and self._upload_left < self.brick_texels:
                    continue
                data = self._clip.get_brick(level, key)
                if data is None:
                    continue
                self._pending[(level, key)] = data
                if self._upload_left is not None:
                    self._upload_left -= self.brick_texels
            reserved[sz, sy, sx] = idx[i]
            out[i] = True
        return out

    def reserve_on_gpu(self, level: int, indices) -> bool:
        """Are all of ``indices`` (``(n, 3)`` bricks of ``level``) on the GPU? If so, reserve their
        slots for this frame, as :meth:`resident_mask` would, and return True; else reserve nothing.

        A kept cut's check (:meth:`~clipvol.render.frame_loop.FrameLoop.update`) asks only this:
        :meth:`resident_mask` answers the same where every brick is on the GPU (distinct bricks on
        the GPU hold distinct slots), but sorts the slots to find conflicts and asks the
        clip-texture about RAM - ~12 ms a frame over a 13 742-brick cut.
        """
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        if len(idx) == 0:
            return True
        if self.windows[level] is None or not self.on_gpu_mask(level, idx).all():
            return False
        slots = self._slots(level, idx)
        reserved = self._reserved[level]
        holder = reserved[slots[:, 0], slots[:, 1], slots[:, 2]]
        if not np.all((holder[:, 0] < 0) | np.all(holder == idx, axis=1)):
            return False  # (never after begin_frame: the slots are all free then)
        reserved[slots[:, 0], slots[:, 1], slots[:, 2]] = idx
        return True

    def on_gpu_with_neighbours(self, level: int, indices) -> bool:
        """Are all of ``indices`` (``(n, 3)`` bricks of ``level``) and every existing same-level
        neighbour of theirs (26-neighbourhood) on the GPU? Asks only the GPU's slots (no RAM, no
        reservation): a kept cut checks the bricks it newly draws with it, where a whole check
        (:meth:`reserve_on_gpu`, :meth:`missing_neighbours`) would go over every brick of the cut
        (a False here sends the caller to that whole check, which knows more: failed bricks, slots
        held by other bricks)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        if not len(idx):
            return True
        if self.windows[level] is None:
            return False
        grid = np.asarray(self.pyramid.grid(level), dtype=np.int64)
        nb = (idx[:, None, :] + NEIGHBOUR_OFFSETS[None]).reshape(-1, 3)
        nb = nb[np.all((nb >= 0) & (nb < grid), axis=1)]
        return bool(self.on_gpu_mask(level, nb).all())

    def reserve_neighbours(self, items) -> None:
        """After the selection: also upload the same-level neighbours of the drawn bricks that are in RAM.

        They are never drawn this frame (their slots were free), but with them on the GPU the drawn
        bricks filter seamlessly across their faces instead of clamping (screen edges, level
        transitions). Uses only what is left of this frame's upload budget. ``items``: the
        :class:`~clipvol.scene.selection.Selection` (its key arrays are used) or a list of draw items.
        """
        for level, nb in sorted(self._neighbours(items).items(), reverse=True):
            nb = nb[~self.on_gpu_mask(level, nb)]
            if len(nb):
                self.resident_mask(level, nb)

    def _neighbours(self, items) -> dict[int, np.ndarray]:
        """Per level, the existing same-level neighbours (26-neighbourhood, the bricks themselves
        included) of the drawn bricks, in lexicographic order.

        Computed once per item list (the selection's items are asked for twice per frame: to
        reserve the neighbours, then to test convergence), as a 3x3x3 dilation of the bricks'
        occupancy over their bounding box: a full-resolution cut of 4 096 bricks is a few array
        operations on a 18^3 grid, not 110 000 candidate rows to sort.
        """
        if self._nb_cache is not None and self._nb_cache[0] is items:
            return self._nb_cache[1]
        keys = _item_keys(items)
        out = {}
        for level in np.unique(keys[:, 0]).tolist():
            if self.windows[level] is None:
                continue
            grid = np.asarray(self.pyramid.grid(level), dtype=np.int64)
            idx = keys[keys[:, 0] == level, 1:]
            lo = np.maximum(idx.min(axis=0) - 1, 0)
            hi = np.minimum(idx.max(axis=0) + 2, grid)
            if np.prod((hi - lo).astype(np.float64)) > DILATE_MAX_CELLS:  # scattered wide: row by row
                nb = (idx[:, None, :] + NEIGHBOUR_OFFSETS[None]).reshape(-1, 3)
                out[level] = unique_rows(nb[np.all((nb >= 0) & (nb < grid), axis=1)])
                continue
            occ = np.zeros(tuple(hi - lo), dtype=bool)
            occ[tuple((idx - lo).T)] = True
            for axis in range(3):  # separable: grow by one brick along each axis in turn
                grown = occ.copy()
                lead = [slice(None)] * 3
                lag = [slice(None)] * 3
                lead[axis], lag[axis] = slice(1, None), slice(None, -1)
                grown[tuple(lead)] |= occ[tuple(lag)]
                grown[tuple(lag)] |= occ[tuple(lead)]
                occ = grown
            out[level] = np.argwhere(occ).astype(np.int64) + lo
        self._nb_cache = (items, out)
        return out

    def missing_neighbours(self, items) -> list[tuple[int, tuple[int, int, int]]]:
        """Neighbours of the drawn bricks that the drawn bricks' filtering would use but that are not
        on the GPU: inside the clip-texture's window, not failed, and their slot not held this frame
        by another brick, not left out by the clip-texture's region of interest. A frame is only
        converged when this is empty (else it changes later)."""

        out = []
        for level, nb in self._neighbours(items).items():
            nb = nb[~self.on_gpu_mask(level, nb)]
            if not len(nb):
                continue
            nb = nb[np.asarray(self._clip.in_window_mask(level, nb), dtype=bool)]
            slots = self._slots(level, nb)
            held = self._reserved[level][slots[:, 0], slots[:, 1], slots[:, 2]]
            nb = nb[(held[:, 0] < 0) | np.all(held == nb, axis=1)]  # its slot not held by another brick
            for key in map(tuple, nb.tolist()):
                # failed, or left unread by the clip-texture's region (a slice's slab): never coming
                if self._clip.state(level, key) in (BrickState.FAILED, BrickState.ABSENT):
                    continue
                out.append((level, key))
        return out

    def pending_keys(self) -> list[tuple[int, tuple[int, int, int]]]:
        """``(level, index)`` of the bricks reserved for upload by the current frame."""
        return [(level, tuple(key)) for level, key in self._pending]

    def commit(self) -> int:
        """Upload every brick reserved for upload this frame (texture sub-loads); returns bytes written."""
        B = self.pyramid.brick_shape
        nbytes = 0
        for (level, key), data in self._pending.items():
            tex = self.textures[level]
            slot = tuple(int(k) % w for k, w in zip(key, self.windows[level]))
            texels = convert_brick(np.asarray(data), self.format)
            if self._channels(level) == 2:  # (mean, spread) interleaved, in the same texel units
                texels = np.stack([texels, self._spread_texels(level, key)], axis=-1)
            tex.write(
                texels,
                viewport=(slot[2] * B[2], slot[1] * B[1], slot[0] * B[0], B[2], B[1], B[0]),
                alignment=1,
            )
            self._slot_key[level][slot] = key
            nbytes += texels.nbytes
        self._commit_cells()
        n = len(self._pending)
        if n:
            self.generation += 1
        self._pending = {}
        self.bytes_uploaded = nbytes
        self.bricks_uploaded = n
        self.texels_uploaded = n * self.brick_texels
        self.total_texels_uploaded += self.texels_uploaded
        return nbytes

    def _spread_texels(self, level: int, key) -> np.ndarray:
        """The spread of brick ``key`` of ``level`` in the texel units of :attr:`format` (``raw =
        a * texel``: a spread has no offset); zeros when the clip-texture holds none."""
        sp = self._clip.get_spread(level, key) if hasattr(self._clip, "get_spread") else None
        if sp is None:
            dt = {"f1": np.uint8, "nu2": np.uint16}.get(self.format.gl_dtype, np.float32)
            return np.zeros(self.pyramid.brick_shape, dtype=dt)
        return spread_texels(np.asarray(sp), self.format)

    def _commit_cells(self) -> None:
        """Copy the cells' value ranges of the bricks being uploaded into their slots' cells, per
        level in one call to the clip-texture (:meth:`ClipTexture.cell_ranges`) and one fancy-indexed
        write; a brick whose source has none gets them computed here."""
        by_level: dict[int, list] = {}
        for (level, key), data in self._pending.items():
            if self._cell_lo[level] is not None:
                by_level.setdefault(level, []).append((key, data))
        for level, entries in by_level.items():
            keys = np.array([k for k, _ in entries], dtype=np.int64)
            n = len(keys)
            K = tuple(b // e for b, e in zip(self.pyramid.brick_shape, self.cell_edges))
            lo = np.empty((n, *K), dtype=np.float32)
            hi = np.empty((n, *K), dtype=np.float32)
            got = self._clip.cell_ranges(level, keys) if hasattr(self._clip, "cell_ranges") else None
            have = np.zeros(n, dtype=bool) if got is None else got[0]
            if got is not None:
                lo[have], hi[have] = got[1], got[2]
            for i in np.nonzero(~have)[0].tolist():
                lo[i], hi[i] = cell_ranges(np.asarray(entries[i][1]), self.cell_edges)
            s = keys % np.asarray(self.windows[level], dtype=np.int64)
            w = self.windows[level]
            sp_cells = self._cell_sp.get(level)
            if sp_cells is not None:  # each cell's largest spread (raw units)
                sp = np.zeros((n, *K), dtype=np.float32)
                for i, k in enumerate(keys.tolist()):
                    got_sp = self._clip.get_spread(level, tuple(k)) if hasattr(self._clip, "get_spread") else None
                    if got_sp is not None:
                        sp[i] = cell_ranges(np.asarray(got_sp), self.cell_edges)[1]
                sp_cells.reshape(w[0], K[0], w[1], K[1], w[2], K[2])[s[:, 0], :, s[:, 1], :, s[:, 2], :] = sp
            for arr, v in ((self._cell_lo[level], lo), (self._cell_hi[level], hi)):
                # (w * K) per axis viewed as (wz, Kz, wy, Ky, wx, Kx): a slot's cells are one block
                arr.reshape(w[0], K[0], w[1], K[1], w[2], K[2])[s[:, 0], :, s[:, 1], :, s[:, 2], :] = v
            self._occ_dirty.setdefault(level, set()).update(map(tuple, s.tolist()))

    def open_faces(self, level: int, indices, dense: bool | None = None) -> np.ndarray:
        """``(n, 3, 2)`` bool ``[axis (z, y, x), side (low, high)]``: may sampling cross that face?

        True only if the face neighbour exists and every existing brick of the 3x3 slab behind the
        face is on the GPU (trilinear filtering near edges and corners reads those texels) or out of
        every sample's reach (outside the slab of the clip-texture's region of interest).

        Answered on a grid over the bricks' bounding box (one slot check per cell, the slabs by a
        separable erosion) when that box is not much larger than the bricks asked (``dense``; a
        full-resolution cut asks thousands of bricks, and 27 gathered neighbours each cost 11 ms
        for 3 000), else per brick and neighbour. ``dense`` forces either way (tests).
        """
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        n = len(idx)
        out = np.zeros((n, 3, 2), dtype=bool)
        if n == 0 or self.windows[level] is None:
            return out
        grid = np.asarray(self.pyramid.grid(level), dtype=np.int64)
        w = np.asarray(self.windows[level], dtype=np.int64)
        lo = idx.min(axis=0) - 1
        shape = idx.max(axis=0) + 2 - lo  # the bricks and their 26-neighbourhoods
        if dense is None:
            dense = float(np.prod(shape.astype(np.float64))) <= 64.0 * n + 4096.0
        if not dense:
            return self._open_faces_per_brick(level, idx, grid, w)
        axes = [np.arange(lo[a], lo[a] + shape[a]) for a in range(3)]
        inside = [(v >= 0) & (v < grid[a]) for a, v in enumerate(axes)]
        exists = inside[0][:, None, None] & inside[1][None, :, None] & inside[2][None, None, :]
        keys = self._slot_key[level]
        held = keys[np.ix_(*(v % w[a] for a, v in enumerate(axes)))]  # (S, 3): the brick in each cell's slot
        good = (held[..., 0] == axes[0][:, None, None]) & (held[..., 1] == axes[1][None, :, None]) \
            & (held[..., 2] == axes[2][None, None, :])
        good |= ~exists  # a neighbour that does not exist is never read
        away = ~good
        if away.any() and self._clip is not None and hasattr(self._clip, "out_of_reach_mask"):
            # a neighbour outside the slab of the clip-texture's region (a slice) is never sampled
            cells = np.argwhere(away) + lo
            good[away] = np.asarray(self._clip.out_of_reach_mask(level, cells), dtype=bool)
        b = idx - lo
        padded = np.pad(good, 1, constant_values=True)
        for a in range(3):
            slab = padded  # every cell's 3x3 slab across axis a is good
            for o in (x for x in range(3) if x != a):
                lead = [slice(None)] * 3
                lead[o] = slice(2, None)
                lag = [slice(None)] * 3
                lag[o] = slice(None, -2)
                mid = [slice(None)] * 3
                mid[o] = slice(1, -1)
                slab = slab[tuple(lead)] & slab[tuple(mid)] & slab[tuple(lag)]
                pad = [(0, 0)] * 3
                pad[o] = (1, 1)
                slab = np.pad(slab, pad, constant_values=True)
            slab = slab[1:-1, 1:-1, 1:-1]
            for side, d in ((0, -1), (1, 1)):
                f = b.copy()
                f[:, a] += d
                out[:, a, side] = exists[f[:, 0], f[:, 1], f[:, 2]] & slab[f[:, 0], f[:, 1], f[:, 2]] & (w[a] >= 2)
        return out

    def _open_faces_per_brick(self, level: int, idx: np.ndarray, grid: np.ndarray, w: np.ndarray) -> np.ndarray:
        """:meth:`open_faces` brick by brick, from each brick's 27 neighbours (bricks scattered wide)."""
        out = np.zeros((len(idx), 3, 2), dtype=bool)
        keys = self._slot_key[level]
        offs = NEIGHBOUR_OFFSETS
        nb = idx[:, None, :] + offs[None]  # (n, 27, 3)
        exists = np.all((nb >= 0) & (nb < grid), axis=2)
        s = nb % w
        ok = np.all(keys[s[..., 0], s[..., 1], s[..., 2]] == nb, axis=2) | ~exists  # (n, 27)
        if self._clip is not None and hasattr(self._clip, "out_of_reach_mask"):
            away = exists & ~ok
            if away.any():
                ok[away] = np.asarray(self._clip.out_of_reach_mask(level, nb[away]), dtype=bool)
        # every face at once: its neighbour's existence and its 3x3 slab (a slab neighbour that
        # duplicates a wrapped slot, w < 3 on an axis, is never both held)
        out[:] = (exists[:, _FACE] & np.all(ok[:, _SLAB], axis=2)).reshape(-1, 3, 2) & (w >= 2)[None, :, None]
        return out

    def occupancy_texture(self, tf, data_range, distribution: bool = False):
        """The ``r8`` 3D texture of every level's cell flags for ``tf`` (1: may be visible, 0: every
        sample assigned to the cell is transparent), levels stacked along z at
        :attr:`occupancy_levels`; None without cells (an odd brick extent).

        Every level is derived again when the table's opacity or its window changed since the last
        call; otherwise only the cells that bricks written since then can change - each written
        slot's cells and the layer before them (:func:`~clipvol.scene.occupancy.widen` looks one
        cell ahead) - or the whole level when more than an eighth of its slots were written.
        """
        if self.cell_edges is None:
            return None
        import moderngl

        key = (np.asarray(tf.table)[:, 3].tobytes(), tuple(float(v) for v in tf.window(data_range)), bool(distribution))
        if self._occ_tex is None:
            used = [lv for lv in self.occupancy_levels if lv is not None]
            size = (max(c[0] for c, _ in used), max(c[1] for c, _ in used), sum(c[2] for c, _ in used))
            self._occ_tex = self.ctx.texture3d(size, 1, dtype="f1")
            self._occ_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        whole = key != self._occ_key
        todo = range(len(self.windows)) if whole else sorted(self._occ_dirty)
        for L in todo:
            lv = self.occupancy_levels[L]
            if lv is None:
                continue
            lo, hi = self._cell_lo[L], self._cell_hi[L]
            if distribution and self._cell_sp.get(L) is not None:
                # DISTRIB reads the table up to spread_support(spread) beyond a sample's mean
                w_lo, w_hi = tf.window(data_range)
                width = max(abs(float(w_hi) - float(w_lo)), 1e-30)
                reach = (spread_support(self._cell_sp[L] / width) * width).astype(np.float32)
                lo, hi = lo - reach, hi + reach
            slots = self._occ_dirty.get(L, ())
            if whole or self._occ_flags[L] is None or len(slots) * 8 > int(np.prod(self.windows[L])):
                flags = occupancy(*widen(lo, hi), tf, data_range)
            else:
                flags = self._occ_flags[L]
                K = np.asarray(lo.shape) // np.asarray(self.windows[L])  # cells per brick (z, y, x)
                for slot in slots:
                    # the slot's cells, the layer before them, and the layer after (read only)
                    axes = [np.arange(s * k - 1, (s + 1) * k + 1) % n for s, k, n in zip(slot, K, lo.shape)]
                    box = np.ix_(*axes)
                    wl, wh = lo[box], hi[box]
                    for ax in range(3):  # widen() without the wrap, within the box
                        head = [slice(None)] * 3
                        head[ax] = slice(0, -1)
                        tail = [slice(None)] * 3
                        tail[ax] = slice(1, None)
                        wl = np.minimum(wl[tuple(head)], wl[tuple(tail)])
                        wh = np.maximum(wh[tuple(head)], wh[tuple(tail)])
                    flags[np.ix_(*(x[:-1] for x in axes))] = occupancy(wl, wh, tf, data_range)
            self._occ_flags[L] = flags
            has_data = lo <= hi
            self.occupancy_counts[L] = (int(has_data.sum()), int((has_data & (flags == 0)).sum()))
            (cx, cy, cz), z0 = lv
            self._occ_tex.write(np.ascontiguousarray(flags) * np.uint8(255), viewport=(0, 0, z0, cx, cy, cz),
                                alignment=1)
        self._occ_key = key
        self._occ_dirty = {}
        return self._occ_tex

    def empty_fraction(self) -> float:
        """Of the cells holding data (every level), the fraction the last derived flags mark empty."""
        total = sum(c[0] for c in self.occupancy_counts)
        return sum(c[1] for c in self.occupancy_counts) / total if total else 0.0

    def release(self) -> None:
        self.generation += 1
        for t in self.textures:
            if t is not None:
                t.release()
        self.textures = [None] * len(self.windows)
        if self._occ_tex is not None:
            self._occ_tex.release()
            self._occ_tex = None
