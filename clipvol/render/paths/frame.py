"""What a draw path is handed (:class:`FrameContext`) and what it hands back (:class:`DrawStats`).

A draw path (:mod:`clipvol.render.paths`) reads everything a frame gives it from one frozen
:class:`FrameContext` - the camera, the transfer function and the (merged) cut, the parameters, the
pyramid, the GPU brick cache, the co-registered overlays' textures, the shader variant's
``#define``\\ s and what the action decided for the frame (empty-space leaps, distribution
classification, the pass of a refined frame) - and returns a :class:`DrawStats`: the image, the
time it took and what it drew. It neither reads nor writes the
:class:`~clipvol.render.action.ClipRenderAction`: the action builds the context, calls the path and
folds the statistics into its :class:`~clipvol.render.frame_stats.FrameStats`.

Why a context and not the action: a path that reaches into the action depends on whatever the
action holds at that moment (its parameters and cache are replaced by ``set_params``; its counters
are written by whichever path drew last), and a new path has to learn the action's insides to be
written at all. A context is the whole of a path's input in one value, built before the path runs;
a test can build one, and what a path drew is its return value, not a side effect.

What lasts across frames is not in the context: the path's own GL objects (the per-brick path's
opacity snapshots, the single pass's page-table texture) and the shared
:class:`~clipvol.render.paths.setup.DrawSetup` (the target, the colour tables, the compiled
programs) are given to a path once, when the action makes it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..refine import refine_levels

__all__ = ["FrameContext", "DrawStats", "level_ratios"]


def level_ratios(pyramid, step: float) -> np.ndarray:
    """Per level of ``pyramid``, the sample spacing ``step * min(scale)`` over the level-0 voxel
    size (the transfer function's reference length: a level's opacity is corrected by this ratio)."""
    ref = float(min(pyramid.spacing))
    return np.array([step * float(min(lv.scale)) / ref for lv in pyramid.levels])


@dataclass(frozen=True, slots=True, eq=False)
class FrameContext:
    """Everything one draw-path call reads: the frame's view and cut, and the action's state for it.

    Attributes
    ----------
    camera : Camera
        The camera this pass draws with (a refined frame's coarse pass: the coarse camera,
        :meth:`~clipvol.render.refine.Refine.coarse_camera`).
    tf : TransferFunction
        The frame's transfer function.
    items : sequence of DrawItem
        The cut, merged (:func:`~clipvol.scene.selection.merge_items`) and in visibility order
        (back to front) unless the path is the single pass, which needs no order. A merged cut
        comes as :class:`~clipvol.scene.selection.DrawItems` (its arrays are there to read; an
        element asked for is made into a ``DrawItem``), else as a list.
    params : RenderParams
        The frame's parameters.
    pyramid : Pyramid
        The volume's levels (brick shape, spacing, value range).
    cache : GpuBrickCache
        The per-level 3D textures the cut's bricks are resident in (``textures``, ``windows``,
        ``open_faces``, ``format``, the empty-space cells).
    residency_version : int
        The clip-texture's residency version this frame (with ``cache.generation``, what a path
        may key state kept between frames on: the same cut over the same slots).
    overlays : OverlayTextures
        The co-registered volumes' textures (:mod:`clipvol.render.overlay_binding`).
    defines : dict
        The ``#define``\\ s of the frame's volume shader variant (mode, NaN, distribution,
        shading, empty-space leaps, overlays).
    skipped_empty : bool
        The frame leaps over empty cells (``EMPTY_SKIP``): bind the cells' flags.
    distribution : bool
        Coarse samples are classified by their distribution (``DISTRIB``): bind its tables.
    refine_level : int or None
        In a refined frame (:mod:`clipvol.render.refine`), which pass this is: ``k`` draws at
        ``1 / 2**k`` of the image, 0 the image; None in a frame drawn in one pass.
    image_camera : Camera or None
        The image's camera, while a refined frame draws (the coarse passes cast its rays).
    """

    camera: object
    tf: object
    items: list
    params: object
    pyramid: object
    cache: object
    residency_version: int
    overlays: object
    defines: dict
    skipped_empty: bool = False
    distribution: bool = False
    refine_level: int | None = None
    image_camera: object = None

    @property
    def level_ratios(self) -> np.ndarray:
        """:func:`level_ratios` of this frame's pyramid and step."""
        return level_ratios(self.pyramid, self.params.step)

    @property
    def repeats_pass(self) -> bool:
        """Is this a refined frame's pass after its first (the same cut, the same residency: what a
        path derives from the cut alone may be kept from the pass before)?"""
        k = self.refine_level
        return k is not None and k < refine_levels(self.image_camera)

    def for_pass(self, refine_level: int, camera) -> "FrameContext":
        """This frame's context for pass ``refine_level`` of a refined frame, drawn with ``camera``."""
        return dataclasses.replace(self, camera=camera, refine_level=refine_level,
                                   image_camera=self.image_camera if self.image_camera is not None else self.camera)


@dataclass(frozen=True, slots=True)
class DrawStats:
    """What one draw-path call drew (:meth:`~clipvol.render.paths.setup.DrawPath.draw` returns it).

    Attributes
    ----------
    image : numpy.ndarray or None
        ``(h, w, 4)`` uint8 straight RGBA, row 0 at the top; None for a refined frame's coarse
        pass (its image stays on the GL for the next pass's mask).
    draw_s, readback_s : float
        Seconds from binding the target to the end of the draws (the wait on the GL included),
        and seconds turning the target into the image.
    finish_s : float
        Seconds of ``draw_s`` spent waiting on the GL to finish the draws (FrameStats' ``gpu``).
    boxes_drawn : int
        Proxy boxes drawn (the per-brick path: one per merged item; the single pass: 1).
    page_table_nodes : int
        The single pass: drawn nodes of the page table (the merged items); 0 for other paths.
    occlusion_passes : int
        The per-brick path: opacity snapshots taken for early ray termination across boxes.
    program : moderngl.Program or None
        The shader variant that drew.
    """

    image: np.ndarray | None
    draw_s: float
    readback_s: float
    finish_s: float = 0.0
    boxes_drawn: int = 0
    page_table_nodes: int = 0
    occlusion_passes: int = 0
    program: object = None
