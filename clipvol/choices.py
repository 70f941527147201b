"""The names and defaults the command line offers, in a module that imports nothing.

Why a module of its own: ``clipvol CMD --help`` builds CMD's parser, whose choices (draw modes,
draw paths, selection policies, views, transfer-function presets, camera paths) and shown defaults
(every :class:`~clipvol.scene.params.RenderParams` field that has a flag) were read from the scene
stage, which imports numpy when it is first touched (``clipvol/scene/__init__.py`` registers the
policies). Kept here, they cost the parser nothing to read. The scene stage reads the same names
from here (``RenderParams``' fields take their default and one-line help from :data:`PARAM_FIELDS`,
its validation the tuples below), so a choice is written once; the registries that are filled at
import time (the policies, the transfer-function presets, the viewer's policies) are checked equal
to these tuples by ``tests/cli/test_front_door_imports.py``.

A base-stage module: it imports nothing of clipvol and nothing else.
"""

from __future__ import annotations

__all__ = ["MODES", "ISO_COLORS", "BLENDS", "PATHS", "CLASSIFY", "POLICIES", "VIEWER_POLICIES", "VIEWS",
           "CAMERA_PATHS", "TF_PRESETS", "OPACITY_CURVES", "PARAM_FIELDS", "DEFAULT_CONNECT_TIMEOUT",
           "DEFAULT_READ_TIMEOUT"]

#: compositing modes of the volume action: emission-absorption, maximum / minimum intensity
#: projection, the mean along the ray (radiograph-like) and the first hit of an iso-value
MODES = ("composite", "mip", "minip", "average", "iso")
#: colourings of the iso-surface (see RenderParams.iso_color)
ISO_COLORS = ("tf", "depth")
#: how overlays (channels) combine with the primary at each sample (see RenderParams.blend)
BLENDS = ("over", "additive")
#: how the volume action draws a cut (see RenderParams.path)
PATHS = ("auto", "bricks", "single-pass")
#: how a coarse sample is classified (see RenderParams.classify)
CLASSIFY = ("distribution", "mean")
#: the built-in selection policies, sorted (:func:`clipvol.scene.policy_registry.policy_names`)
POLICIES = ("distance", "field-of-view", "fixed", "image", "plane", "projected-size", "roaming", "texel-budget")
#: the policies the interactive viewer can start with and cycle through (its M key cycles the first three)
VIEWER_POLICIES = ("projected-size", "roaming", "fixed", "image")
#: every name ``--view`` accepts: the anatomical sides and iso, then the array-frame aliases
#: (:data:`clipvol.scene.views.VIEW_CHOICES`)
VIEWS = ("anterior", "posterior", "left", "right", "superior", "inferior", "iso", "front", "back", "side", "top")
#: camera paths of the flythroughs and the report (:func:`clipvol.scene.paths.make_path`)
CAMERA_PATHS = ("orbit", "turntable", "fly", "zoom")
#: the transfer-function presets (:meth:`clipvol.scene.transfer.TransferFunction.names`)
TF_PRESETS = ("grey", "viridis", "magma", "inferno", "plasma", "bone", "demo", "diverging")
#: opacity curves over a window (:data:`clipvol.scene.transfer.OPACITY_CURVES`)
OPACITY_CURVES = ("ramp", "flat", "step")
#: seconds to connect to a remote store / without a byte before a request counts as stalled
#: (:mod:`clipvol.paging.bytesource` uses them)
DEFAULT_CONNECT_TIMEOUT = 10.0
DEFAULT_READ_TIMEOUT = 10.0

#: RenderParams field -> (default, one-line help): the fields that have a command-line flag
#: (:mod:`clipvol.tools.render_args`), whose help the flag shows; ``RenderParams`` declares each
#: of them with ``_field(name)``, which reads its default and help from here
PARAM_FIELDS: dict[str, tuple] = {
    "mode": ("composite",
             "composite (emission-absorption), maximum / minimum intensity projection, the mean along the ray "
             "(radiograph-like), or an iso-surface (with --iso-value)"),
    "iso_value": (None,
                  "--mode iso: the data value of the surface (the first point along each ray at or above it, lit "
                  "from the gradient)"),
    "policy": ("projected-size",
               "selection policy: which bricks at which level (default projected-size; the viewer starts with "
               "projected-size, roaming, fixed or image, and M cycles the first three)"),
    "lod_threshold": (1.0, "refine while a voxel projects to more than this many pixels"),
    "level": (None,
              "the one pyramid level (0 = finest, default 0) that --policy fixed draws, that slice draws everywhere "
              "and that export writes"),
    "distance_factor": (1.0,
                        "--policy distance: refine nodes closer to the eye than this many of their diagonals; "
                        "slice with --poi: draw each brick closer to the point than this many of its parent's diagonals"),
    "fov_fraction": (0.5, "--policy field-of-view: refine nodes subtending more than this fraction of the view"),
    "max_texels_drawn": (None, "most voxels of drawn bricks: refine the largest projected voxels first until it binds"),
    "texels_per_frame": (None, "most texels uploaded per frame (per pass while waiting)"),
    "texture_budget": (256 << 20, "GPU brick cache budget (serve: of each store)"),
    "step": (0.5, "sample spacing in voxels of the drawn level"),
    "refine_tolerance": (0.0,
                         "composite: rays at 1/4 and 1/2 of the image's resolution first, then a ray per pixel only "
                         "where the four coarser rays around it differ by more than this in a premultiplied channel "
                         "(0: a ray per pixel)"),
    "jitter": (False, "start every pixel's ray at a hashed offset (turns lattice rings into fine noise)"),
    "skip_empty": (True,
                   "composite: leap over cells of 8^3 voxels the transfer function makes transparent; iso: over "
                   "cells wholly below the iso-value (the same image)"),
    "path": ("auto",
             "single-pass: one ray-guided pass through a page table of the cut; bricks: one proxy box per (merged) "
             "brick; auto (default): the single pass for cuts of 4 boxes or more"),
    "background": ((0.0, 0.0, 0.0, 0.0), "straight RGBA r,g,b,a in [0, 1] behind the volume (default transparent)"),
    "block_budget": (None,
                     "--policy image: most bricks drawn, the most important refined first (default 128; none with "
                     "--max-error)"),
    "max_error": (None,
                  "--policy image (selected by it when --policy is left at its default): visible-error budget, "
                  "refine until the predicted share of pixels with CIELUV dE >= 6 against the converged picture is "
                  "at most this ('5%%' or 0.05)"),
    "visibility": (True, "--policy image: weight each brick's importance by its estimated visibility"),
    "shading": (False,
                "composite: Blinn-Phong gradient lighting, light at the eye (ignored for mip; the viewer's L key "
                "toggles it)"),
    # --light sets these four at once (its help is its own)
    "ambient": (0.3, ""),
    "diffuse": (0.7, ""),
    "specular": (0.3, ""),
    "shininess": (20.0, ""),
    "classify": ("distribution",
                 "coarse levels: apply the transfer function to the distribution of the level-0 voxels beneath each "
                 "coarse voxel where the store holds it (distribution, default), or to their mean"),
}
