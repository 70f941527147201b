"""What the ``"image"`` policy needs per frame, kept between frames: errors per transfer function,
the visibility estimate per view.

:class:`ImageLod` belongs to one :class:`~clipvol.render.action.ClipRenderAction`, which hands it a
factory for the coarse visibility pass's own action. It reads the
store's summary tables once (:func:`clipvol.bricking.summary.open_summary`; a store without them is a
:class:`~clipvol.bricking.summary.SummaryMissingError` naming ``clipvol summarize``), recomputes the
multiresolution errors only when the transfer function changes
(:func:`clipvol.scene.lod_error.lod_errors`), and re-runs the visibility estimate
(:class:`~clipvol.render.visibility.CpuVisibilityEstimator`, or the GL
:class:`~clipvol.render.visibility.VisibilityEstimator` with ``estimator="gl"``) only when the view
turned or moved noticeably, or the transfer function or shape changed.
"""

from __future__ import annotations

import numpy as np

from ..bricking.summary import SummaryMissingError, open_summary
from ..errors import ParameterError
from ..scene.lod_error import lod_errors
from ..scene.selection.policies.image_based import ImageBased
from ..scene.visibility import view_close
from .modes import mode_of
from .visibility import CpuVisibilityEstimator, VisibilityEstimator

__all__ = ["ImageLod", "REUSE_ANGLE_DEG"]

#: a visibility estimate is reused while the view direction turns less than this
REUSE_ANGLE_DEG = 3.0


def _tf_key(tf):
    return (tf.table.tobytes(), tf.value_range)


class ImageLod:
    """Summary tables, errors and visibility estimate of one render action (see the module docstring)."""

    def __init__(self, make_action, clip_texture, estimator: str = "cpu") -> None:
        loader = clip_texture.loader
        path = getattr(loader, "path", None)
        if path is None or not getattr(loader, "is_clipvol_store", True):
            raise SummaryMissingError(f"policy 'image': the loader {type(loader).__name__} has no summary tables; it "
                                      "needs a clipvol store (`clipvol brick` writes them, `clipvol summarize STORE` "
                                      "adds them to an existing store)")
        self.tables = open_summary(getattr(loader, "meta_path", path))  # a set's member: its own group
        self.make_action, self.clip_texture = make_action, clip_texture
        if estimator not in ("cpu", "gl"):
            raise ParameterError(f"estimator: expected 'cpu' or 'gl', got {estimator!r}")
        self.estimator_kind = estimator
        self.errors = None
        self._errors_key = None
        self.estimator = None
        self.layers = None
        self.estimates = 0
        self.cuts = 0  # greedy cuts made (the others were replayed)
        self.reuse_cut = True
        self._last = None  # (camera, errors, visibility, params, policy) of the last cut made
        lo, hi = clip_texture.pyramid.volume_box()
        self._diag = float(np.linalg.norm(hi - lo))
        self._centre = (lo + hi) / 2.0

    def errors_for(self, tf, classify: str = "mean"):
        """The per-brick errors under ``tf`` for coarse voxels classified by ``classify`` (the
        ``RenderParams.classify`` of consistent levels where it exists; see
        :func:`~clipvol.scene.lod_error.classification_bias`), re-evaluated when either changes."""
        key = (_tf_key(tf), classify)
        if key != self._errors_key:
            self.errors = lod_errors(self.tables, tf, classify)
            self._errors_key = key
        return self.errors

    def visibility_for(self, camera, tf, params):
        key = (_tf_key(tf), params.shape)
        if self.layers is not None and self.layers.reusable(camera, key, REUSE_ANGLE_DEG, 0.02, self._diag, self._centre):
            return self.layers
        if self.estimator is None:
            self.estimator = (CpuVisibilityEstimator(self.clip_texture.loader) if self.estimator_kind == "cpu"
                              else VisibilityEstimator(self.make_action, self.clip_texture))
        self.layers = self.estimator.estimate(camera, tf, params.shape, key)
        self.estimates += 1
        return self.layers

    def policy(self, camera, tf, params) -> ImageBased:
        """The frame's :class:`ImageBased` policy for ``camera``, ``tf`` and ``params``: the previous
        frame's cut is replayed while the view turned less than :data:`REUSE_ANGLE_DEG` and the eye
        moved less than 2 % of the volume diagonal - or turned less than that angle about the volume's
        centre at a distance within 2 % (an orbit; :func:`~clipvol.scene.visibility.view_close`) - since
        that cut was made, the errors, the visibility estimate and the parameters are the same
        objects, and no node the frustum culled then is in view now (:meth:`ImageBased.covers`)."""
        errors = self.errors_for(tf, getattr(params, "classify", "mean"))
        # MIP has no occlusion: a brick behind another can still hold the maximum
        vis = self.visibility_for(camera, tf, params) if params.visibility and mode_of(params.mode).classifies else None
        reuse = None
        last = self._last
        if self.reuse_cut and last is not None and last[1] is errors and last[2] is vis and last[3] == params \
                and last[4].recorded is not None and view_close(last[0], camera, REUSE_ANGLE_DEG, 0.02 * self._diag, self._centre, 0.02) \
                and last[4].covers(camera):
            reuse = last[4].recorded
        policy = ImageBased(params, errors=errors, visibility=vis, reuse=reuse)
        if reuse is None:
            self._last = (camera, errors, vis, params, policy)
            self.cuts += 1
        return policy

    def close(self) -> None:
        if self.estimator is not None:
            self.estimator.close()
            self.estimator = None
