"""The slice render action: multiresolution cutting planes over the clip-texture and the GPU cache.

After LaMar, Hamann & Joy, *Multiresolution cutting planes*: a plane of any orientation is drawn
at full resolution near a point of interest and coarser away from it, from the very bricks, per
level 3D textures and budgets the volume action uses. Per frame (:meth:`SliceAction.render`):

0. **Page** - the slice's region (:func:`~clipvol.scene.slice_region.slice_region`: per level, the
   bricks within half a voxel of the plane that the slice's cut draws or blends towards, widened
   towards the next slice while the plane scrolls) is handed to the clip-texture, which then reads that slab
   rather than filling cubes (``follow_plane = False`` keeps the cubes). Where the full-resolution
   slab holds no more bytes than this region (the chunk sizes a store's manifest records, or
   without one a brick's bytes each: :func:`~clipvol.scene.slice_region.stored_sizes`), the slice
   is drawn at full resolution (``level=0``, :attr:`SliceAction.last_params`): a better image for
   no more bytes read. Likewise, where the cover by distance alone holds no more bytes than the one
   with coarser data where it looks the same (step 1), distance alone draws: the rule never makes
   a slice read more than it would without it.
1. **Select** - the frame loop (:class:`~clipvol.render.frame_loop.FrameLoop`) runs the slice's
   cut (:func:`~clipvol.scene.slice_cover.slice_cut`) with an orthographic camera that sees
   exactly the slice's pixels: with a point of interest, the per-brick cover
   (:mod:`clipvol.scene.slice_cover`: each part of the plane at the finest level whose brick lies
   within ``distance_factor`` of its parent's diagonals of the point, with per-corner blend ratios for
   the tiles next to coarser boxes; on a store with summary tables a coarser brick where its data
   is within :attr:`SliceAction.exact_tol` CIELUV Delta E of level 0's under the slice's colours,
   :mod:`clipvol.scene.slice_exact`); without one, the ``"plane"`` policy's one level
   (:class:`~clipvol.scene.selection.policies.plane.PlaneCut`). Bricks still loading are drawn
   from their nearest resident ancestor (coarser fallback, as the volume does).
2. **Upload** - the cache's sub-loads, plus the parent bricks ("low tiles") of the tiles that
   blend, within the same ``texels_per_frame`` budget.
3. **Draw** - per tile, the plane's polygon inside the node box (a triangle fan) into a float32
   target. The fragment shader (``shaders/slice.frag.glsl``) samples the node's level texture
   trilinearly at the pixel's world point and, where the tile's trilinearly interpolated corner
   ratio is above 0, its parent's level too, and mixes them: the paper's high/low tiles with
   per-vertex ratios, done per pixel. Tiles partition the plane, so no blending between draws.
4. **Read back** - the values (``raw = a * texel + b`` in float64, NaN where no tile covers the
   pixel: outside the volume, or nothing resident yet), mapped to RGBA through a transfer
   function's colours or a grey window/level; every covered pixel is opaque.

References
----------
E. LaMar, B. Hamann, K. I. Joy, "Multiresolution cutting planes" (the copy we work from states no
year or venue).

Why one module of this size: the plane's cut, its slab region, the draw and the read-back of
values share one frame's state; the plane geometry is :mod:`clipvol.scene.plane` and the region
:mod:`clipvol.scene.slice_region`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import interrupts
from ..errors import ParameterError
from ..scene.params import RenderParams
from ..scene.plane import Plane, default_pixel_size, default_size
from ..paging.readcount import bytes_read_of, split_reads
from ..bricking.summary import SummaryMissingError, open_summary
from ..scene.slice_cover import slice_cut
from ..scene.slice_exact import DEFAULT_TOL, accumulated_errors, grey_window_colours, stand_ins, window_grey
from ..scene.slice_region import region_bytes, slice_region, stored_sizes
from .failures import failed_bricks
from .frame_loop import FrameLoop
from .glsl import load_shader
from ..scene.consistent import expected_colours
from .gpu_cache import GpuBrickCache
from .target import FloatTarget
from .uniforms import vec3 as _vec

__all__ = ["SliceAction", "SliceStats", "window_level_grey"]

#: :attr:`SliceAction.summary` before the store's tables are looked for
_UNREAD = object()


@dataclass(frozen=True, slots=True)
class SliceStats:
    """What one :meth:`SliceAction.render` call did.

    Attributes
    ----------
    tiles_per_level : dict[int, int]
        Tiles drawn per level (a tile drawn from an ancestor counts at the ancestor's level).
    tiles : int
        Tiles drawn.
    blended : int
        Tiles that blend towards their parent (low tile) somewhere.
    bricks_needed : int
        Distinct bricks the drawn slice reads: the tiles' bricks and the low tiles' parents.
    bytes_needed : int
        ``bricks_needed`` times the bytes of one brick in memory: what a loader must read for
        this slice (LaMar, Hamann & Joy's "data transferred").
    bytes_loaded : int
        Bytes of the bricks the clip-texture's loader threads loaded during the call (in memory,
        its prefetch included).
    bytes_uploaded, bricks_uploaded : int
        Texture sub-loads of the call.
    converged : bool
        Every wanted tile (and low tile) was drawn at its own level.
    balance_splits : int
        Leaves split to balance the cut.
    times : dict[str, float]
        Seconds in ``select`` (selection, balancing, ratios), ``upload``, ``wait``, ``draw``,
        ``readback`` and ``total``.
    bytes_read : int or None
        Bytes the loader read from storage during the call (chunk files or network responses,
        counted where they are read: :mod:`clipvol.paging.readcount`); ``None`` for a loader that
        does not count.
    region_bricks : int
        Bricks of the region of interest handed to the clip-texture (0 with cube windows).
    frame_bytes_read, prefetch_bytes_read : int or None
        Bytes read from storage since the previous slice for the bricks this slice drew (tiles and
        blend parents) or wanted, and for every other brick (the prefetch), each read counted
        once (see :class:`clipvol.render.frame_stats.FrameStats`); ``None``: not counted.
    """

    tiles_per_level: dict[int, int]
    tiles: int
    blended: int
    bricks_needed: int
    bytes_needed: int
    bytes_loaded: int
    bytes_uploaded: int
    bricks_uploaded: int
    converged: bool
    balance_splits: int
    times: dict = field(default_factory=dict)
    bytes_read: int | None = None
    region_bricks: int = 0
    #: wanted bricks that failed to load, with cause and stand-in (:mod:`clipvol.render.failures`)
    failed_bricks: tuple = ()
    frame_bytes_read: int | None = None
    prefetch_bytes_read: int | None = None

    @property
    def unreplaced(self) -> tuple:
        """The failed bricks no verified ancestor stands in for: regions missing from the slice."""
        return tuple(f for f in self.failed_bricks if not f.replaced)

    def as_dict(self) -> dict:
        """JSON-ready dict (``clipvol slice --stats``)."""
        return dict(tiles_per_level={str(k): v for k, v in self.tiles_per_level.items()}, tiles=self.tiles,
                    blended=self.blended, bricks_needed=self.bricks_needed, bytes_needed=self.bytes_needed,
                    bytes_loaded=self.bytes_loaded, bytes_uploaded=self.bytes_uploaded,
                    bricks_uploaded=self.bricks_uploaded, converged=self.converged,
                    balance_splits=self.balance_splits, times=dict(self.times), bytes_read=self.bytes_read,
                    frame_bytes_read=self.frame_bytes_read, prefetch_bytes_read=self.prefetch_bytes_read,
                    region_bricks=self.region_bricks,
                    failed_bricks=[dict(level=f.level, index=list(f.index), cause=f.cause,
                                        stand_in=None if f.stand_in is None else [f.stand_in[0], list(f.stand_in[1])])
                                   for f in self.failed_bricks])


def window_level_grey(values: np.ndarray, center: float, width: float) -> np.ndarray:
    """``(h, w, 4)`` uint8 grey RGBA of ``values`` for a window ``center``/``width`` (clinicians'
    window/level: ``C - W/2`` is black, ``C + W/2`` white); NaN pixels are transparent."""
    g = window_grey(values, center, width)
    ok = np.isfinite(g)
    g8 = np.rint(np.where(ok, g, 0.0) * 255.0).astype(np.uint8)
    return np.stack([g8, g8, g8, np.where(ok, 255, 0).astype(np.uint8)], axis=-1)


class SliceAction:
    """Draw cutting planes of a :class:`~clipvol.paging.cliptexture.ClipTexture`.

    Parameters
    ----------
    ctx : moderngl.Context
    clip_texture : ClipTexture
    params : RenderParams, optional
        ``focus`` (the point of interest), ``distance_factor``, ``lod_threshold``, ``level`` (a
        fixed level; 0 = full resolution), ``texture_budget``, ``texels_per_frame``; the policy is
        always ``"plane"``.
    cache : GpuBrickCache, optional
        Share the volume action's GPU cache (same textures, same budget) instead of making one.
    **kwargs
        :class:`~clipvol.scene.params.RenderParams` fields applied over ``params``.
    """

    def __init__(self, ctx, clip_texture, params: RenderParams | None = None, *, cache: GpuBrickCache | None = None,
                 **kwargs) -> None:
        import moderngl

        self._mgl = moderngl
        self.ctx = ctx
        self.clip_texture = clip_texture
        self.pyramid = clip_texture.pyramid
        kwargs["policy"] = "plane"
        self.params = RenderParams.from_kwargs(params, **kwargs).check_for(self.pyramid)
        self._own_cache = cache is None
        self.cache = cache if cache is not None else GpuBrickCache(
            ctx, self.pyramid, self.params.texture_budget, spread_levels=getattr(clip_texture, "spread_levels", ()))
        self.frame_loop = FrameLoop(clip_texture, self.cache)
        self.program = ctx.program(vertex_shader=load_shader("slice.vert"), fragment_shader=load_shader("slice.frag"))
        self.program["u_volume"].value = 0
        self.program["u_volume_low"].value = 1
        self._target = FloatTarget(ctx)
        self.last_stats: SliceStats | None = None
        #: the parameters the last slice was drawn with: ``params``, or ``level=0`` where the
        #: full-resolution slice reads no more bytes from storage (:meth:`render`)
        self.last_params: RenderParams = self.params
        self.last_selection = None
        self.last_camera = None
        self.last_values: np.ndarray | None = None
        self.last_levels: np.ndarray | None = None
        self.last_ratios: np.ndarray | None = None
        self.last_spreads: np.ndarray | None = None
        #: blend high and low tiles at level changes (False shows the seams: the paper's Fig. 6a)
        self.blend = True
        #: page the slab the slice crosses (:func:`~clipvol.scene.slice_region.slice_region`); False
        #: leaves the clip-texture's cube windows (what a volume view pages) in place
        self.follow_plane = True
        self._last_plane: Plane | None = None
        #: (plane, pixel size, size, scroll-ahead, parameters, colours) -> the parameters, region and
        #: stand-ins drawn: a slice drawn again (a window redrawing, a viewer waiting for bricks)
        #: prices no region twice
        self._region_memo = None
        #: (plane, pixel size, size, parameters, colours) -> the slice's cover (clipvol.scene.slice_cover)
        self._cover_memo = None
        #: a coarser brick draws where the store's summary tables show its data within this CIELUV
        #: Delta E of level 0's under the slice's colours (:mod:`clipvol.scene.slice_exact`); None:
        #: the cover decides by distance alone. No effect without summary tables
        self.exact_tol: float | None = DEFAULT_TOL
        #: the store's summary tables (:class:`~clipvol.bricking.summary.SummaryTables`), read from a
        #: clipvol store on disk at the first slice; None: none (a procedural or in-memory source, a
        #: store without them). A caller may set tables of its own before the first slice
        self.summary = _UNREAD
        #: (colours, tolerance, tables) -> per level the bricks that may stand for their children
        self._stand_in_memo = None

    def set_params(self, params: RenderParams) -> None:
        """Use ``params`` from the next frame on (policy forced to ``"plane"``)."""
        from dataclasses import replace

        if not isinstance(params, RenderParams):
            raise ParameterError(f"params: expected a RenderParams, got {type(params).__name__}")
        params = replace(params, policy="plane").check_for(self.pyramid)
        if params.texture_budget != self.params.texture_budget and self._own_cache:
            self.cache.release()
            self.cache = GpuBrickCache(self.ctx, self.pyramid, params.texture_budget,
                                       spread_levels=getattr(self.clip_texture, "spread_levels", ()))
            self.frame_loop = FrameLoop(self.clip_texture, self.cache)
        self.params = params

    # -- the frame ---------------------------------------------------------------------------------
    def render(self, plane: Plane, size=None, pixel_size: float | None = None, *, transfer_function=None,
               window: tuple[float, float] | None = None, wait: bool = False, timeout: float | None = None,
               return_values: bool = False):
        """Draw ``plane``; returns ``(h, w, 4)`` uint8 RGBA (and the float32 values if ``return_values``).

        Parameters
        ----------
        plane : Plane
        size : (w, h), optional
            Pixels; default: enough to cover the plane's cut through the volume.
        pixel_size : float, optional
            World units per pixel; default the level-0 voxel size in the plane.
        transfer_function : TransferFunction, optional
            Colours of the values (its opacity is not used: a slice is opaque).
        window : (center, width), optional
            Grey window/level instead of a transfer function (default: the data's value range).
        wait, timeout
            Wait (at most ``timeout`` seconds) until the wanted tiles and low tiles are drawn.
        return_values : bool
            Also return the resampled values, ``(h, w)`` float32, NaN where no tile covers a pixel.
        """
        interrupts.check()  # a Ctrl-C swallowed inside the previous slice stops a series of them here
        if not isinstance(plane, Plane):
            raise ParameterError(f"plane: expected a clipvol Plane, got {type(plane).__name__}")
        pyr = self.pyramid
        px = default_pixel_size(pyr, plane) if pixel_size is None else float(pixel_size)
        if not (math.isfinite(px) and px > 0):
            raise ParameterError(f"pixel_size: expected a finite size > 0 (world units), got {pixel_size!r}")
        vlo, vhi = pyr.volume_box()
        if not plane.crosses(vlo, vhi)[0]:
            raise ParameterError(f"plane: expected a plane that meets the volume {tuple(vlo)}..{tuple(vhi)}, "
                                 f"got origin {plane.origin} normal {plane.normal}")
        size = default_size(pyr, plane, px) if size is None else tuple(int(v) for v in size)
        if len(size) != 2 or not all(1 <= v <= 16384 for v in size):
            raise ParameterError(f"size: expected (w, h) with 1..16384 pixels per side, got {size!r}")
        t_start = time.perf_counter()
        loaded0 = self.clip_texture.stats.bytes_loaded
        read0 = bytes_read_of(self.clip_texture.loader)
        region_bricks = 0
        params = self.params
        if window is None and transfer_function is None:  # the grey window over the value range
            lo_v, hi_v = pyr.value_range
            window = ((lo_v + hi_v) / 2.0, max(hi_v - lo_v, 1e-300))
        colours = self._colours_key(transfer_function, window)
        stand_in = self._stand_in(colours, params, transfer_function)
        if self.follow_plane:
            ahead = self._scroll_step(plane)
            # the colours count only where they decide (summary tables, a tolerance, a point of interest)
            rule = None if stand_in is None else (colours, self.exact_tol)
            key = (plane, float(px), tuple(size), float(ahead), params, rule)
            if self._region_memo is not None and self._region_memo[0] == key:  # the same slice drawn again
                params, region, stand_in = self._region_memo[1:]
            else:
                region = slice_region(pyr, plane, params, px, size=size, ahead=ahead, stand_in=stand_in)
                sizes = self._stored_sizes() if params.level is None else None
                if sizes is not None:
                    # the fewest bytes, the finer picture where they tie: the full-resolution slice, the
                    # cover by distance alone (a parent standing in over children that hold only the
                    # fill costs bytes they do not), this slice (slice_region, slice_exact)
                    options = [(self._full_resolution_params(), None)]
                    if stand_in is not None:
                        options.append((params, None))
                    best = region_bytes(region, sizes)
                    for p, s in reversed(options):
                        r = slice_region(pyr, plane, p, px, size=size, ahead=ahead)
                        cost = region_bytes(r, sizes)
                        if cost <= best:
                            params, region, stand_in, best = p, r, s, cost
                self._region_memo = (key, params, region, stand_in)
            self.clip_texture.set_region(region)
            region_bricks = region.nbricks
        self._last_plane = plane
        self.last_params = params
        cam = plane.camera(size, px).fit_depth(vlo, vhi)
        deadline = None if timeout is None else t_start + float(timeout)
        policy = self._policy(params, plane, px, size, colours, stand_in)
        up_bytes = up_bricks = 0
        times = dict(select=0.0, upload=0.0, wait=0.0)
        while True:
            left = None if deadline is None else max(0.0, deadline - time.perf_counter())
            plan = self.frame_loop.run(cam, params, policy=policy, wait=wait, timeout=left)
            for k in times:
                times[k] += plan.times.get(k, 0.0)
            up_bytes += plan.bytes_uploaded
            up_bricks += plan.bricks_uploaded
            t0 = time.perf_counter()
            sel = plan.selection
            low, missing_low = self._reserve_low_tiles(sel, policy.node_data if self.blend else {})
            up_bytes += self.cache.commit()
            up_bricks += self.cache.bricks_uploaded
            times["upload"] += time.perf_counter() - t0
            converged = plan.converged and not missing_low
            if not wait or converged:
                break
            ct = self.clip_texture
            # only parents that may still arrive in RAM (a parent held in RAM but without a free GPU
            # slot this frame cannot be waited for: the tile is then drawn unblended)
            waitable = [k for k in missing_low
                        if bool(np.asarray(ct.in_window_mask(k[0], np.array([k[1]])))[0])
                        and not bool(np.asarray(ct.resident_mask(k[0], np.array([k[1]])))[0])
                        and ct.state(k[0], k[1]).name in ("QUEUED", "LOADING")]
            left = None if deadline is None else deadline - time.perf_counter()
            if not waitable or (left is not None and left <= 0):
                break
            t0 = time.perf_counter()
            self.clip_texture.wait_for(waitable, timeout=left)
            times["wait"] += time.perf_counter() - t0
        if self.follow_plane and not converged:
            # what this slice still wants comes first, and what balancing wants beyond the region is read
            # now: a viewer that never waits still converges over the next frames
            self.clip_texture.prioritize(sel.missing_wanted() + list(missing_low))
        values, levels, ratios, draw_t, read_t = self._draw(plane, size, px, sel, low)
        times["draw"], times["readback"] = draw_t, read_t
        if window is not None:
            rgba = window_level_grey(values, float(window[0]), float(window[1]))
        elif transfer_function is not None:
            rgb = transfer_function.lookup(values, pyr.value_range)[..., :3]
            if self.params.classify == "distribution" and self.cache.spread_levels:
                # a coarse pixel shows the colour the level-0 voxels beneath it show on average
                spread = self.last_spreads
                some = np.isfinite(values) & (spread > 0)
                if some.any():
                    rgb[some] = expected_colours(transfer_function, values[some], spread[some], pyr.value_range)
            ok = np.isfinite(values)
            rgba = np.concatenate([np.rint(np.clip(rgb, 0, 1) * 255), np.where(ok, 255, 0)[..., None]], axis=-1)
            rgba = np.where(ok[..., None], rgba, 0).astype(np.uint8)
        times["total"] = time.perf_counter() - t_start
        per_level: dict[int, int] = {}
        for it in sel.items:
            per_level[it.level] = per_level.get(it.level, 0) + 1
        needed = {(it.level, tuple(it.index)) for it in sel.items} | set(low.values())
        keys = [(L, *idx) for L, idx in needed] + sel.wanted_keys().tolist()
        frame_read, other_read = split_reads(self.clip_texture.take_reads(), keys)
        self.last_selection, self.last_camera = sel, cam  # the camera that maps world points to its pixels
        #: blend parents that could not be made drawable: their tiles are drawn unblended (not converged)
        self.last_missing_low = list(missing_low)
        self.last_values, self.last_levels, self.last_ratios = values, levels, ratios
        self.last_stats = SliceStats(
            tiles_per_level=dict(sorted(per_level.items())), tiles=len(sel.items), blended=len(low),
            bricks_needed=len(needed), bytes_needed=len(needed) * pyr.brick_nbytes,
            bytes_loaded=self.clip_texture.stats.bytes_loaded - loaded0, bytes_uploaded=up_bytes,
            bricks_uploaded=up_bricks, converged=converged, balance_splits=int(sel.counts.get("balance_splits", 0)),
            times=times, bytes_read=None if read0 is None else bytes_read_of(self.clip_texture.loader) - read0,
            region_bricks=region_bricks, failed_bricks=failed_bricks(sel, self.clip_texture),
            frame_bytes_read=frame_read, prefetch_bytes_read=other_read)
        return (rgba, values) if return_values else rgba

    def _policy(self, params: RenderParams, plane: Plane, px: float, size, colours=None, stand_in=None):
        """The slice's cut (:func:`~clipvol.scene.slice_cover.slice_cut`), its cover computed once
        per plane, pixel size, image size, parameters and colours (``stand_in``: the bricks that may
        stand for their children under ``colours``, :meth:`_stand_in`)."""
        if params.focus is None or params.level is not None:
            return slice_cut(self.pyramid, plane, params, px, size)
        key = (plane, float(px), tuple(size), params, None if stand_in is None else (colours, self.exact_tol))
        if self._cover_memo is None or self._cover_memo[0] != key:
            self._cover_memo = (key, slice_cut(self.pyramid, plane, params, px, size, stand_in=stand_in).cover)
        return slice_cut(self.pyramid, plane, params, px, size, cover=self._cover_memo[1])

    def _colours_key(self, transfer_function, window) -> tuple:
        """What the slice's colours depend on (:meth:`render`'s grey ``window``, else the transfer
        function's table), as a hashable key."""
        if window is not None:
            return ("window", float(window[0]), float(window[1]))
        return ("tf", transfer_function.table.tobytes(), tuple(transfer_function.value_range or ()))

    def _summary_tables(self):
        """The store's summary tables (:attr:`summary`), read once from a clipvol store on disk; None
        for any other source or a store without (complete) tables."""
        if self.summary is _UNREAD:
            self.summary = None
            loader = self.clip_texture.loader
            path = getattr(loader, "meta_path", getattr(loader, "path", None))
            if path is not None and getattr(loader, "is_clipvol_store", False):
                if isinstance(path, Path) or (isinstance(path, str) and "://" not in path and Path(path).is_dir()):
                    try:
                        self.summary = open_summary(path)
                    except SummaryMissingError:
                        pass  # no tables: the cover decides by distance alone
        return self.summary

    def _stand_in(self, colours: tuple, params: RenderParams, transfer_function=None):
        """Per level, the bricks whose data may stand for their children's under ``colours``
        (:func:`~clipvol.scene.slice_exact.stand_ins`), or None: no tolerance, no tables, or a slice
        without a point of interest (one level everywhere)."""
        if self.exact_tol is None or params.focus is None or params.level is not None:
            return None
        tables = self._summary_tables()
        if tables is None:
            return None
        key = (colours, float(self.exact_tol), id(tables))
        if self._stand_in_memo is None or self._stand_in_memo[0] != key:
            if colours[0] == "window":
                cmap = grey_window_colours(colours[1], colours[2])
            else:
                tf, rng = transfer_function, self.pyramid.value_range
                cmap = lambda v: tf.lookup(v, rng)[..., :3]  # noqa: E731 - opaque: colours alone
            self._stand_in_memo = (key, stand_ins(accumulated_errors(tables, cmap), self.exact_tol))
        return self._stand_in_memo[1]

    def _stored_sizes(self):
        """The clip-texture's loader's chunk sizes (:func:`~clipvol.scene.slice_region.stored_sizes`),
        read from its manifest once per loader."""
        loader = self.clip_texture.loader
        kept = getattr(self, "_sizes", None)
        if kept is None or kept[0] is not loader:
            kept = self._sizes = (loader, stored_sizes(loader))
        return kept[1]

    def _full_resolution_params(self) -> RenderParams:
        """``params`` at ``level=0``, the same object while ``params`` is (the frame loop keys its
        kept cut on the parameters' identity)."""
        kept = getattr(self, "_full_params", None)
        if kept is None or kept[0] is not self.params:
            kept = (self.params, RenderParams.from_kwargs(self.params, level=0).check_for(self.pyramid))
            self._full_params = kept
        return kept[1]

    def _scroll_step(self, plane: Plane) -> float:
        """How far (world units, signed along the normal) the plane moved since the last slice, when it
        kept its orientation and moved less than a level-0 brick: a scroll, whose next slab is then
        prefetched. 0 for the first slice, a turn or a jump."""
        last = self._last_plane
        if last is None:
            return 0.0
        n = np.asarray(plane.normal, dtype=np.float64)
        if float(np.asarray(last.normal) @ n) < 1.0 - 1e-9:
            return 0.0
        step = float((np.asarray(plane.origin) - np.asarray(last.origin)) @ n)
        reach = float(np.abs(n) @ (np.asarray(self.pyramid.brick_shape[::-1]) * np.asarray(self.pyramid.spacing[::-1])))
        return step if abs(step) <= reach else 0.0

    def render_in_view(self, volume_action, camera, transfer_function, plane: Plane, *, opacity: float = 1.0,
                       cut: bool = True, wait: bool = False, timeout: float | None = None) -> np.ndarray:
        """The plane drawn inside a 3D view of the volume, so users see where the slice lies.

        A separate pass beside the volume action (which is not changed): with ``cut`` the volume is
        rendered with one extra clip plane that removes the half-space in front of the plane (on the
        camera's side), then the slice's tiles are drawn through ``camera`` - each pixel's ray meets
        the plane in the fragment shader - coloured by ``transfer_function`` and laid over the
        volume with ``opacity`` (1: opaque; below 1 and ``cut=False``: a translucent plane over the
        whole volume, not depth-sorted against it). Returns ``(h, w, 4)`` uint8 straight RGBA.
        """
        from dataclasses import replace

        from ..scene.geometry import Shape

        if not (0.0 <= float(opacity) <= 1.0):
            raise ParameterError(f"opacity: expected a value in [0, 1], got {opacity!r}")
        pyr = self.pyramid
        vlo, vhi = pyr.volume_box()
        if not plane.crosses(vlo, vhi)[0]:
            raise ParameterError(f"plane: expected a plane that meets the volume {tuple(vlo)}..{tuple(vhi)}, "
                                 f"got origin {plane.origin} normal {plane.normal}")
        vparams = volume_action.params
        if cut:
            n = np.asarray(plane.normal)
            s = -1.0 if float(n @ (np.asarray(camera.eye) - np.asarray(plane.origin))) > 0 else 1.0
            clip = tuple((s * n).tolist()) + (float(-s * n @ np.asarray(plane.origin)),)
            shape = vparams.shape
            box = shape.box if shape is not None else None
            planes = (tuple(shape.planes) if shape is not None else ()) + (clip,)
            volume_action.set_params(replace(vparams, shape=Shape(box=box, planes=planes)))
        try:
            vol = volume_action.render(camera, transfer_function, wait=wait, timeout=timeout)
        finally:
            volume_action.set_params(vparams)
        # tiles: the plane's cut through the volume at about the view's pixel size at the plane
        w, h = camera.size
        if camera.orthographic:
            px = float(camera.height) / h
        else:
            depth = max(float((np.asarray(plane.origin) - camera.eye) @ camera.forward), 1e-9)
            px = 2.0 * depth * math.tan(math.radians(float(camera.fov_y)) / 2.0) / h
        px = max(px, default_pixel_size(pyr, plane))
        size = default_size(pyr, plane, px)
        cam = plane.camera(size, px).fit_depth(vlo, vhi)
        policy = self._policy(self.params, plane, px, size)
        plan = self.frame_loop.run(cam, self.params, policy=policy, wait=wait, timeout=timeout)
        low, _ = self._reserve_low_tiles(plan.selection, policy.node_data if self.blend else {})
        self.cache.commit()
        values, _, _, _, _ = self._draw(plane, (w, h), px, plan.selection, low, view=camera.fit_depth(vlo, vhi))
        ok = np.isfinite(values)
        rgb = transfer_function.lookup(values, pyr.value_range)[..., :3]
        a_s = np.where(ok, float(opacity), 0.0)[..., None]
        va = vol[..., 3:4].astype(np.float64) / 255.0
        prem = a_s * rgb + (1.0 - a_s) * vol[..., :3].astype(np.float64) / 255.0 * va
        alpha = a_s + (1.0 - a_s) * va
        with np.errstate(invalid="ignore", divide="ignore"):
            straight = np.where(alpha > 0, prem / np.maximum(alpha, 1e-300), 0.0)
        out = np.concatenate([straight, alpha], axis=-1)
        return np.rint(np.clip(out, 0.0, 1.0) * 255.0).astype(np.uint8)

    def _reserve_low_tiles(self, sel, node_data) -> tuple[dict, list]:
        """For each item drawn at its own node with blend ratios: reserve (upload) its parent brick.

        Returns ``{item position: (level + 1, parent index)}`` for the items that can blend now,
        and the parents that could not be made drawable (those items are drawn unblended).
        """
        pyr = self.pyramid
        want: dict[int, tuple] = {}
        for i, it in enumerate(sel.items):
            key = (int(it.level), tuple(int(v) for v in it.index))
            if key not in node_data or it.level + 1 >= pyr.num_levels:
                continue
            lo, hi = pyr.node_box(it.level, np.array(it.index))
            if tuple(lo.tolist()) != tuple(it.lo) or tuple(hi.tolist()) != tuple(it.hi):
                continue  # a sub-box drawn from an ancestor: no blending while it loads
            want[i] = (it.level + 1, tuple(int(v) // 2 for v in it.index))
        ok_keys: set = set()
        missing = []
        by_level: dict[int, list] = {}
        for k in set(want.values()):
            by_level.setdefault(k[0], []).append(k[1])
        for L, keys in by_level.items():
            mask = self.cache.resident_mask(L, np.array(keys, dtype=np.int64))
            for k, m in zip(keys, mask):
                (ok_keys.add if m else missing.append)((L, k))
        return {i: k for i, k in want.items() if k in ok_keys}, missing

    def _brick_uniforms(self, suffix: str, level: int, index, plane_origin: np.ndarray, clamp) -> None:
        pyr, prog = self.pyramid, self.program
        lv = pyr.levels[level]
        B = np.asarray(pyr.brick_shape, dtype=np.int64)
        scale = np.asarray(lv.scale[::-1], dtype=np.float64)
        trans = np.asarray(lv.translation[::-1], dtype=np.float64)
        win = np.asarray(self.cache.windows[level], dtype=np.int64)
        bidx = np.asarray(index, dtype=np.int64)
        first = trans + bidx[::-1] * B[::-1] * scale
        prog["u_o_minus_b" + suffix].value = _vec(plane_origin - first)
        prog["u_inv_scale" + suffix].value = _vec(1.0 / scale)
        prog["u_slot_origin" + suffix].value = _vec(((bidx % win) * B)[::-1])
        prog["u_inv_tex_size" + suffix].value = _vec(1.0 / (win[::-1] * B[::-1]))
        prog["u_clamp_lo" + suffix].value = _vec(clamp[0])
        prog["u_clamp_hi" + suffix].value = _vec(clamp[1])

    def _clamps(self, keys) -> dict:
        """Per brick ``(level, index)``: brick-local voxel bounds ``(lo, hi)`` (``(x, y, z)``), half a
        voxel beyond the faces whose neighbours are on the GPU (seamless filtering), else clamped to
        the brick's own voxel centres."""
        B = np.asarray(self.pyramid.brick_shape, dtype=np.float64)
        by_level: dict[int, set] = {}
        for L, idx in keys:
            by_level.setdefault(int(L), set()).add(tuple(int(v) for v in idx))
        out = {}
        for L, idxs in by_level.items():
            arr = np.array(sorted(idxs), dtype=np.int64)
            of = self.cache.open_faces(L, arr)  # (n, 3 zyx, 2)
            lo = np.where(of[:, :, 0], -0.5, 0.0)[:, ::-1]
            hi = np.where(of[:, :, 1], B - 0.5, B - 1.0)[:, ::-1]
            for k, a, b in zip(arr, lo, hi):
                out[(L, tuple(int(v) for v in k))] = (a, b)
        return out

    def _draw(self, plane: Plane, size, px: float, sel, low: dict, view=None):
        mgl, ctx, prog = self._mgl, self.ctx, self.program
        w, h = size
        t0 = time.perf_counter()
        origin = np.asarray(plane.origin, dtype=np.float64)
        # one vertex buffer for every tile's triangle fan, in NDC
        items = sel.items
        ranges: list = [None] * len(items)
        tris = np.zeros((0, 4))
        n = 0
        if items:
            lo = np.array([it.lo for it in items], dtype=np.float64)
            hi = np.array([it.hi for it in items], dtype=np.float64)
            polys, counts = plane.box_polygons(lo, hi)
            if view is None:
                pix = plane.to_pixels(polys.reshape(-1, 3), size, px).reshape(len(items), 6, 2)
                ndc = np.stack([pix[..., 0] / w * 2.0 - 1.0, 1.0 - pix[..., 1] / h * 2.0,
                                np.zeros(pix.shape[:2]), np.ones(pix.shape[:2])], axis=-1)
            else:  # clip coordinates of the 3D view (GL clips what lies behind the eye)
                vp = view.view_projection()
                hom = np.concatenate([polys, np.ones(polys.shape[:2] + (1,))], axis=-1)
                ndc = hom @ vp.T
                ndc[..., 2] = 0.0 * ndc[..., 3]  # no depth test: the plane is the only surface drawn
            chunks = []
            for i, (it, k) in enumerate(zip(items, counts)):
                if k < 3 or self.cache.textures[it.level] is None:
                    continue
                fan = np.repeat(np.arange(1, k - 1), 3)
                fan[0::3] = 0
                fan[2::3] += 1
                chunks.append(ndc[i, fan])
                ranges[i] = (n, len(fan))
                n += len(fan)
            if chunks:
                tris = np.concatenate(chunks)
        clamps = self._clamps([(int(it.level), it.index) for it in items]
                              + [low[i] for i in sorted(low)])
        fbo = self._target.ensure((int(w), int(h)))
        previous = ctx.fbo
        fbo.use()
        ctx.viewport = (0, 0, int(w), int(h))
        fbo.clear(0.0, 0.0, -1.0, 0.0)
        ctx.disable(mgl.BLEND | mgl.DEPTH_TEST | mgl.CULL_FACE)
        vbo = vao = None
        if n:
            vbo = ctx.buffer(tris.astype(np.float32).tobytes())
            vao = ctx.vertex_array(prog, [(vbo, "4f", "in_clip")])
            prog["u_viewport"].value = (float(w), float(h))
            prog["u_in_view"].value = view is not None
            if view is not None:
                prog["u_ortho"].value = bool(view.orthographic)
                prog["u_normal"].value = _vec(plane.normal)
                prog["u_eye_rel"].value = _vec(np.asarray(view.eye, dtype=np.float64) - origin)
                prog["u_cam_forward"].value = _vec(view.forward)
                prog["u_cam_right"].value = _vec(view.right)
                prog["u_cam_up"].value = _vec(view.up)
                if view.orthographic:
                    prog["u_cam_half"].value = (float(view.width) / 2.0, float(view.height) / 2.0)
                else:
                    ty = math.tan(math.radians(float(view.fov_y)) / 2.0)
                    prog["u_cam_half"].value = (ty * w / h, ty)
            prog["u_pixel"].value = float(px)
            prog["u_right"].value = _vec(plane.right)
            prog["u_up"].value = _vec(plane.up)
            for i, (it, rg) in enumerate(zip(sel.items, ranges)):
                if rg is None:
                    continue
                L = int(it.level)
                self.cache.textures[L].use(location=0)
                prog["u_level"].value = float(L)
                self._brick_uniforms("", L, it.index, origin, clamps[(L, tuple(int(v) for v in it.index))])
                parent = low.get(i)
                if parent is not None:
                    PL, pidx = parent
                    self.cache.textures[PL].use(location=1)
                    self._brick_uniforms("_low", PL, pidx, origin, clamps[(PL, tuple(pidx))])
                    r = sel.node_data[(L, tuple(int(v) for v in it.index))]
                    prog["u_ratio"].write(np.asarray(r, dtype=np.float32).reshape(-1).tobytes())
                    nlo = np.asarray(it.lo, dtype=np.float64)
                    nhi = np.asarray(it.hi, dtype=np.float64)
                    prog["u_node_lo"].value = _vec(nlo - origin)
                    prog["u_node_inv_ext"].value = _vec(1.0 / np.maximum(nhi - nlo, 1e-300))
                    prog["u_blend"].value = True
                else:
                    self.cache.textures[L].use(location=1)  # a valid binding; never sampled
                    prog["u_blend"].value = False
                vao.render(mgl.TRIANGLES, vertices=rg[1], first=rg[0])
        ctx.finish()
        t1 = time.perf_counter()
        raw = np.frombuffer(fbo.read(components=4, dtype="f4"), dtype=np.float32).reshape(int(h), int(w), 4)[::-1]
        if vao is not None:
            vao.release()
            vbo.release()
        self._target.restore(previous)
        err = ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error after drawing the slice: expected GL_NO_ERROR, got {err}")
        covered = raw[..., 1] > 0.5
        fmt = self.cache.format
        #: per pixel the spread of the value (raw units; 0 at level 0 and for stores without one)
        self.last_spreads = np.where(covered, fmt.a * np.maximum(raw[..., 1].astype(np.float64) - 1.0, 0.0), 0.0)
        with np.errstate(invalid="ignore", over="ignore"):
            v64 = np.where(covered, fmt.a * raw[..., 0].astype(np.float64) + fmt.b, np.nan)
            if self.pyramid.dtype.kind in "iu":
                # the GPU's normalised-integer -> float conversion is good to about one float32 ulp
                # of the texel, i.e. of a * texel before the offset b cancels: snap values that close
                # to an integer back onto it (so a slice through voxel centres of integer data is
                # exact); interpolated values keep their fraction
                r = np.rint(v64)
                eps = 4 * float(np.finfo(np.float32).eps)
                tol = eps * (np.abs(fmt.a * raw[..., 0].astype(np.float64)) + abs(fmt.b) + np.maximum(np.abs(r), 1.0))
                v64 = np.where(np.abs(v64 - r) <= tol, r, v64)
            values = v64.astype(np.float32)
        levels = np.where(covered, np.rint(raw[..., 2]), -1).astype(np.int16)
        ratios = np.where(covered, raw[..., 3], 0.0).astype(np.float32)
        return values, levels, ratios, t1 - t0, time.perf_counter() - t1

    def close(self) -> None:
        """Release the action's GL objects (and its cache, unless it was shared)."""
        if self._own_cache and self.cache is not None:
            self.cache.release()
        if self.program is not None:
            self.program.release()
        self._target.release()
        self.program = None

    def __enter__(self) -> "SliceAction":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
