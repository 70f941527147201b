"""What one frame of the clip render action did (:class:`FrameStats`), counted from its cut.

Kept apart from the action so that the report, the flythrough, the CLI and the tests read the
numbers of a frame without the GL side, and so that counting (per level, distinct bricks, failed
bricks) is written once, whichever draw path drew the frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..paging.readcount import split_reads
from ..rows import unique_rows
from .failures import failed_bricks

__all__ = ["FrameStats", "frame_stats"]


@dataclass(frozen=True, slots=True)
class FrameStats:
    """What one :meth:`~clipvol.render.action.ClipRenderAction.render` call did.

    Attributes
    ----------
    bricks_drawn : dict[int, int]
        Draw items per level (an ancestor drawn over several missing children counts once per child).
    bricks_distinct : int
        Distinct bricks drawn (each brick once, however many items sample it).
    texels_drawn : int
        Voxels of the bricks drawn (a sub-box drawn from an ancestor counts its whole brick once).
    bytes_uploaded, bricks_uploaded : int
        Texture sub-loads of this call (all passes).
    texture_bytes, texture_budget : int
        Bytes held by the brick textures (always <= the budget) and the budget.
    times : dict[str, float]
        Seconds spent in ``select``, ``upload``, ``wait``, ``draw``, ``readback`` and ``total``;
        ``gpu``: waiting on the GL (the frame's finish and read-back), ``host``: the rest of
        ``total`` but the loader waits - the host's own work (:attr:`host_ms`).
    converged : bool
        Every wanted brick was drawn at its own level.
    passes : int
        Select/upload passes made (more than one only with ``wait=True``).
    counts : Mapping
        The selection's counts (culled, refined, fallback): a dict, or for a kept cut a read-only
        :class:`~clipvol.scene.selection.kept_cut.KeptCounts` whose culled counts are completed
        when first read.
    bytes_read : int or None
        Bytes the loader read from storage during the call (chunk files or network responses,
        the clip-texture's prefetch included; :mod:`clipvol.paging.readcount`), ``None`` for a
        loader that does not count its reads.
    frame_bytes_read, prefetch_bytes_read : int or None
        Bytes read from storage since the previous frame, charged per brick by the loader thread
        that read them (:meth:`clipvol.paging.cliptexture.ClipTexture.take_reads`): those of the
        bricks this frame drew or wanted, and those of every other brick (the windows filled around
        the centre of interest). Each read is counted once, in one frame's figures, so the same
        work reports the same bytes (``bytes_read``, a difference of the loader's total between two
        instants, also holds whatever loader threads read meanwhile). ``None``: not counted.
    failed_bricks : tuple of FailedBrick
        Wanted bricks that failed to load, each with its cause and the ancestor drawn in its place
        (:mod:`clipvol.render.failures`); :attr:`unreplaced` are those drawn by nothing.
    replayed : bool
        The frame drew the last frame's cut again (:mod:`clipvol.render.frame_loop`, "Coherence").
    path : str or None
        The registered name of the draw path that drew the frame (:mod:`clipvol.render.paths`).
    boxes_drawn, page_table_nodes, occlusion_passes : int
        What that path drew (its :class:`~clipvol.render.paths.frame.DrawStats`): proxy boxes, the
        single pass's page-table nodes, the per-brick path's opacity snapshots (all passes of a
        refined frame).
    updated : bool
        The frame drew the kept projected-size cut updated for its camera, without a traversal from
        the root (:class:`~clipvol.scene.selection.kept_cut.KeptCut`).
    """

    bricks_drawn: dict[int, int]
    bricks_distinct: int
    texels_drawn: int
    bytes_uploaded: int
    bricks_uploaded: int
    texture_bytes: int
    texture_budget: int
    times: dict[str, float]
    converged: bool
    passes: int = 1
    items_drawn: int = 0
    counts: dict = field(default_factory=dict)
    bytes_read: int | None = None
    failed_bricks: tuple = ()
    frame_bytes_read: int | None = None
    prefetch_bytes_read: int | None = None
    replayed: bool = False
    path: str | None = None
    boxes_drawn: int = 0
    page_table_nodes: int = 0
    occlusion_passes: int = 0
    updated: bool = False

    @property
    def host_ms(self) -> float:
        """Milliseconds of the frame's own host work (selection, uploads, tables, GL calls), beside
        :attr:`gpu_ms`: on a GPU the frame is as fast as the larger of the two."""
        return 1e3 * float(self.times.get("host", self.times.get("total", 0.0)))

    @property
    def gpu_ms(self) -> float:
        """Milliseconds the frame waited on the GL: its draws finishing, and the read-back."""
        return 1e3 * float(self.times.get("gpu", 0.0))

    @property
    def unreplaced(self) -> tuple:
        """The failed bricks no verified ancestor stands in for: regions missing from the image."""
        return tuple(f for f in self.failed_bricks if not f.replaced)


def frame_stats(sel, plan, times: dict, cache, texture_budget: int, clip_texture,
                bytes_read: int | None = None, reads: dict | None = None) -> FrameStats:
    """The :class:`FrameStats` of a frame that drew selection ``sel`` after the frame loop's ``plan``
    (:class:`~clipvol.render.frame_loop.FrameLoop`), with GPU cache ``cache``."""
    keys = sel.item_keys()
    # (the cut's rows are joined only when some brick was read: a warm frame reads none)
    frame_read, other_read = split_reads(reads, np.concatenate([keys, sel.wanted_keys()]) if reads else keys[:0])
    per = np.bincount(keys[:, 0].astype(np.int64))  # bricks per level: a count, no sort of the cut
    levels = np.nonzero(per)[0]
    per_level = dict(zip(levels.tolist(), per[levels].tolist()))
    # a kept cut updated (not ordered) draws each node once from its own brick: its keys are distinct
    distinct = len(keys) if not getattr(sel, "ordered", True) else len(unique_rows(keys)) if len(keys) else 0
    return FrameStats(
        bricks_drawn=dict(sorted(per_level.items())), bricks_distinct=distinct,
        texels_drawn=distinct * cache.brick_texels, bytes_uploaded=plan.bytes_uploaded,
        bricks_uploaded=plan.bricks_uploaded, texture_bytes=cache.texture_bytes,
        texture_budget=texture_budget, times=times, converged=plan.converged, passes=plan.passes,
        items_drawn=len(sel.items), counts=sel.counts.copy(), failed_bricks=failed_bricks(sel, clip_texture),
        bytes_read=bytes_read, frame_bytes_read=frame_read, prefetch_bytes_read=other_read,
        replayed=bool(getattr(plan, "replayed", False)), updated=bool(getattr(plan, "updated", False)),
    )
