"""The GPU side of overlays (:mod:`clipvol.scene.overlay`): one float32 3-D texture and one colour table per overlay.

The render action calls :meth:`OverlayTextures.sync` when its parameters change (it checks each
overlay against the primary and reads the chosen level once) and :meth:`OverlayTextures.bind` once
per frame after the frame's uniforms (textures on units ``FIRST_UNIT + 2k`` and ``+ 2k + 1``, the
affine (a 3x3 matrix and an offset: any voxel-to-world affine of the overlay, flips and permutations
exactly) from a position relative to the frame origin ``O`` to texture coordinates, the table
mapping, and the overlay's own sample spacing: the step fraction times its smallest voxel edge, from
which the shader refines the primary's lattice where the primary's drawn level is coarser). The
shader side is the ``OVERLAY`` variant of ``shaders/volume_common.glsl``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..scene.transfer import corrected_tables
from ..scene.overlay import (check_overlay, cull_outside, label_indices, overlay_box, overlay_level,
                             overlay_texture_transform, overlay_voxel, read_level)

__all__ = ["OverlayTextures", "FIRST_UNIT", "overlay_defines"]

#: widest row of a label overlay's colour table (ids present beyond it go on further rows)
LABEL_TABLE_WIDTH = 4096


def overlay_defines(overlays, blend: str = "over") -> dict:
    """The shader ``#define``\\ s of ``overlays``: ``OVERLAY`` (their number), ``OVERLAYk_LABELS``
    for each label overlay ``k`` and ``OVERLAYk_CLASSIFIED`` for each other overlay sampled
    ``"classified"`` (see ``shaders/volume_common.glsl``)."""
    if not overlays:
        return {}
    out: dict = {"OVERLAY": len(overlays), "OVERLAY_ADDITIVE": blend == "additive"}
    out.update({f"OVERLAY{k}_LABELS": True for k, ov in enumerate(overlays) if ov.labels})
    out.update({f"OVERLAY{k}_CLASSIFIED": True for k, ov in enumerate(overlays)
                if not ov.labels and ov.sampling == "classified"})
    return out

#: texture unit of the first overlay's volume (0: the primary's level, 1: its table, 2: the occlusion copy)
FIRST_UNIT = 3


class OverlayTextures:
    """Per overlay of the current parameters: its volume texture (one level) and its colour table."""

    def __init__(self, ctx, primary_loader) -> None:
        self.ctx = ctx
        self.primary_loader = primary_loader
        self._volumes: dict[int, tuple] = {}  # id(overlay) -> (overlay, texture, level)
        self._tables: dict[int, tuple] = {}  # id(overlay) -> (key, texture)

    def sync(self, overlays) -> None:
        """Check ``overlays`` against the primary and upload the ones not yet on the GPU; release the rest."""
        import moderngl

        for ov in overlays:
            check_overlay(ov, self.primary_loader)
        keep = {id(ov) for ov in overlays}
        for k in [k for k in self._volumes if k not in keep]:
            self._volumes.pop(k)[1].release()
        for k in [k for k in self._tables if k not in keep]:
            self._tables.pop(k)[1].release()
        max3d = int(self.ctx.info.get("GL_MAX_3D_TEXTURE_SIZE", 2048))
        for ov in overlays:
            if id(ov) in self._volumes:
                continue
            L = overlay_level(ov.loader.pyramid, ov.texture_budget, max3d)
            data = read_level(ov.loader, L, dtype=None if ov.labels else np.float32)
            nbytes = data.size * 4
            if nbytes > ov.texture_budget:
                raise ParameterError(f"overlay {ov.name}: texture_budget: expected at least {nbytes} bytes for its "
                                     f"coarsest level {L} {data.shape}, got {ov.texture_budget}")
            label_table = None
            if ov.labels:  # ids -> their index among the ids present (exact in float32), nearest only
                data, label_table = label_indices(data, ov.tf)
            tex = self.ctx.texture3d(data.shape[::-1], 1, np.ascontiguousarray(data, dtype=np.float32).tobytes(), dtype="f4")
            filt = moderngl.NEAREST if ov.labels else moderngl.LINEAR
            tex.filter = (filt, filt)
            tex.repeat_x = tex.repeat_y = tex.repeat_z = False  # clamp to edge
            self._volumes[id(ov)] = (ov, tex, L)
            if label_table is not None:
                self._tables[id(ov)] = (("labels",), self._label_texture(label_table))

    def cull_outside(self, transparent, overlays):
        """The primary's transparent-brick filter, culling only bricks clear of every overlay's box."""
        return cull_outside(transparent, self.primary_loader.pyramid, [overlay_box(ov, self.primary_loader) for ov in overlays])

    def levels(self) -> dict[str, int]:
        """Name of each overlay -> the level drawn."""
        return {ov.name: L for ov, _, L in self._volumes.values()}

    @property
    def texture_bytes(self) -> int:
        return sum(int(np.prod(t.size)) * 4 for _, t, _ in self._volumes.values())

    def _label_texture(self, table: np.ndarray):
        """Straight RGBA per id index, :data:`LABEL_TABLE_WIDTH` per row (fetched, never filtered)."""
        import moderngl

        n = len(table)
        w = min(max(n, 1), LABEL_TABLE_WIDTH)
        h = -(-max(n, 1) // w)
        data = np.zeros((h * w, 4), dtype=np.float32)
        data[:n] = table
        tex = self.ctx.texture((w, h), 4, data.tobytes(), dtype="f4")
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return tex

    def _table(self, ov, ratios) -> object:
        import moderngl


        if ov.labels:  # made with the volume; its opacity is corrected in the shader
            return self._tables[id(ov)][1]

        table = np.ascontiguousarray(np.asarray(ov.tf.table, dtype=np.float32))
        key = (table.tobytes(), tuple(float(r) for r in ratios))
        old = self._tables.get(id(ov))
        if old is not None and old[0] == key:
            return old[1]
        if old is not None:
            old[1].release()
        rows = corrected_tables(table, ratios)
        tex = self.ctx.texture((rows.shape[1], len(rows)), 4, rows.astype(np.float32).tobytes(), dtype="f4")
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex.repeat_x = tex.repeat_y = False
        self._tables[id(ov)] = (key, tex)
        return tex

    def bind(self, prog, overlays, origin, ratios) -> None:
        """Bind the overlays' textures and set their uniforms for a frame whose origin is ``origin`` (x, y, z).

        ``ratios``: the primary's per-level step over its level-0 voxel (``RenderAction.level_ratios``);
        level 0's gives the step fraction, from which each overlay's own step (``u_ovk_step``) follows.
        """
        O = np.asarray(origin, dtype=np.float64)
        pyr = self.primary_loader.pyramid
        step = float(ratios[0]) * float(min(pyr.spacing)) / float(min(pyr.levels[0].scale))  # voxels of a level
        u = prog.get("u_ov_inv_ref", None)
        if u is not None:  # label overlays: opacity per the primary's smallest level-0 voxel
            u.value = 1.0 / float(min(self.primary_loader.pyramid.spacing))
        for k, ov in enumerate(overlays):
            _, tex, L = self._volumes[id(ov)]
            m = overlay_texture_transform(ov, L, self.primary_loader)  # drawing frame -> texture coordinate
            a = m[:3, :3]
            b = m[:3, :3] @ O + m[:3, 3]  # the shader's p is relative to the frame origin O
            lo, hi = (0.0, 1.0) if ov.labels else ov.tf.window(ov.loader.pyramid.value_range)
            if hi > lo:
                tm = (1.0 / (hi - lo), -lo / (hi - lo))
            else:  # zero-width window: a step at lo
                tm = (1e30, -lo * 1e30 + 0.5)
            tex.use(location=FIRST_UNIT + 2 * k)
            self._table(ov, ratios).use(location=FIRST_UNIT + 2 * k + 1)
            values = {f"u_ov{k}_tex": FIRST_UNIT + 2 * k, f"u_ov{k}_tf": FIRST_UNIT + 2 * k + 1,
                      f"u_ov{k}_step": step * overlay_voxel(ov, L, self.primary_loader),
                      f"u_ov{k}_a": tuple(float(v) for v in a.T.reshape(-1)),  # column-major mat3
                      f"u_ov{k}_b": tuple(float(v) for v in b),
                      f"u_ov{k}_t": (float(np.clip(tm[0], -3e38, 3e38)), float(np.clip(tm[1], -3e38, 3e38)))}
            for name, v in values.items():
                u = prog.get(name, None)
                if u is not None:
                    u.value = v

    def release(self) -> None:
        for _, tex, _ in self._volumes.values():
            tex.release()
        for _, tex in self._tables.values():
            tex.release()
        self._volumes.clear()
        self._tables.clear()
