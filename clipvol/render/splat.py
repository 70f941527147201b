"""``SplatRenderAction``: view-dependent Gaussian splats of a point octree (Meredith & Ma 2001).

Per frame (:meth:`SplatRenderAction.render`), the volume action's loop with points for bricks:

1. **Select** - :func:`clipvol.scene.splat_select.select_splat_nodes`: from the root, cull by the
   frustum and stop at the first node whose splats (projected node size / cbrt(points)) are at most
   the tolerance; a wanted node not yet in the clip-texture is stood in for by its nearest resident
   ancestor. ``wait=True`` asks the clip-texture for the missing nodes and waits for them
   (``ClipTexture.wait_for``) until the cut is converged, nothing more can arrive, or ``timeout``.
2. **Gather** - the drawn nodes' points come out of the clip-texture's slots (rows whose fourth
   column is 1, see :class:`clipvol.loaders.point_store.PointStoreLoader`), each with its node's
   splat size ``h``; positions are made relative to the eye in float64, then rounded to float32.
3. **Draw** - one GL point per data point with a Gaussian footprint (``shaders/splat.*.glsl``),
   sorted by view depth and blended back to front with premultiplied ``(ONE, ONE_MINUS_SRC_ALPHA)``
   through the same 1-D transfer-function texture as the volume; opacity is corrected for the
   splat's path length ``h`` relative to ``opacity_unit`` (default: the store's mean point spacing,
   so a dense lattice renders like the ray caster with ``unit`` = voxel size). MIP: the splat cores
   write their value with the ``MAX`` blend equation, mapped by the transfer function on read-back.
4. **Read back** - ``(h, w, 4)`` uint8 straight RGBA over ``background``, row 0 at top;
   :attr:`last_frame_stats` holds nodes and points drawn, the tolerance and time per stage.

Points larger than the driver's largest point size are drawn at that size (counted in
``clamped``); a finer tolerance avoids it. Sorting is per point (exact for equal splat sizes; the
Meredith & Ma sort nodes only and note that per-point order barely shows).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..scene.point_gradient import wls_gradients
from ..scene.splat_select import SplatSelection, select_splat_nodes
from .paths.setup import premultiplied_to_uint8
from .glsl import load_shader
from .modes import modes_with
from .target import FloatTarget

__all__ = ["SplatRenderAction", "SplatFrameStats"]

_GL_PROGRAM_POINT_SIZE = 0x8642


@dataclass
class SplatFrameStats:
    """Statistics of the last frame."""

    nodes_drawn: int = 0
    points_drawn: int = 0
    nodes_per_depth: dict[int, int] = field(default_factory=dict)
    wanted: int = 0
    missing: int = 0
    tolerance_px: float = 0.0
    clamped: int = 0
    converged: bool = False
    passes: int = 0
    times: dict[str, float] = field(default_factory=dict)


class SplatRenderAction:
    """Render a point store held by a clip-texture as splats.

    Parameters
    ----------
    ctx : moderngl.Context
        The GL context (offscreen EGL is enough).
    clip_texture : ClipTexture
        Built on a :class:`clipvol.loaders.point_store.PointStoreLoader`.
    tolerance : float or str
        Largest splat on screen: a fraction of the screen's linear size (``0.05``), ``"5%"`` or ``"12px"``.
    mode : {"composite", "mip"}
    value : int or str
        Which value column to draw (index or name).
    opacity_unit : float, optional
        World length the transfer function's opacity is defined for (default: the store's point spacing).
    background : 4 floats
        Straight RGBA behind the points.
    shading : bool
        Composite only: Blinn-Phong lighting with the light at the eye from each point's gradient,
        estimated by weighted least squares over its node's points
        (:func:`clipvol.scene.point_gradient.wls_gradients`, after Meredith & Ma section 3.2) and
        kept per node while it is drawn.
    light : 4 floats
        ``(ambient, diffuse, specular, shininess)``, as the volume's ``RenderParams``.
    """

    def __init__(self, ctx, clip_texture, *, tolerance=0.05, mode: str = "composite", value=0,
                 opacity_unit: float | None = None, background=(0.0, 0.0, 0.0, 0.0), shading: bool = False,
                 light=(0.3, 0.7, 0.3, 20.0)) -> None:
        import moderngl

        self._mgl = moderngl
        self.ctx = ctx
        self.clip = clip_texture
        self.loader = clip_texture.loader
        if not hasattr(self.loader, "nodes"):
            raise ParameterError(f"clip_texture: expected one over a point store loader, got {type(self.loader).__name__}")
        if mode not in modes_with("splats"):  # the modes whose splat shader is splat.frag.glsl's (render/modes)
            raise ParameterError(f"mode: expected one of {', '.join(modes_with('splats'))}, got {mode!r}")
        self.mode = mode
        self.tolerance = tolerance
        names = self.loader.meta.value_names
        if isinstance(value, str):
            if value not in names:
                raise ParameterError(f"value: expected one of {', '.join(names)}, got {value!r}")
            value = names.index(value)
        if not (0 <= int(value) < len(names)):
            raise ParameterError(f"value: expected 0..{len(names) - 1}, got {value!r}")
        self.value = int(value)
        unit = self.loader.meta.point_spacing if opacity_unit is None else float(opacity_unit)
        if not (np.isfinite(unit) and unit > 0):
            raise ParameterError(f"opacity_unit: expected a length > 0, got {opacity_unit!r}")
        self.opacity_unit = float(unit)
        bg = tuple(float(v) for v in background)
        if len(bg) != 4 or not all(0.0 <= v <= 1.0 for v in bg):
            raise ParameterError(f"background: expected four values in [0, 1] (r, g, b, a), got {background!r}")
        self.background = bg
        self.shading = bool(shading)
        lt = tuple(float(v) for v in light)
        if len(lt) != 4 or not all(np.isfinite(v) and v >= 0 for v in lt) or lt[3] <= 0:
            raise ParameterError(f"light: expected (ambient, diffuse, specular, shininess) >= 0, shininess > 0, got {light!r}")
        self.light = lt
        self._grads: OrderedDict[int, np.ndarray] = OrderedDict()  # node id -> (count, 3) gradients
        self.prog = ctx.program(vertex_shader=load_shader("splat.vert"), fragment_shader=load_shader("splat.frag"))
        rng = ctx.info.get("GL_POINT_SIZE_RANGE") or ctx.info.get("GL_ALIASED_POINT_SIZE_RANGE") or (1.0, 64.0)
        self._max_size = float(rng[1])
        self._target = FloatTarget(ctx)
        self._tf_tex = None
        self._tf_key = None
        self._vbo = None
        self._vao = None
        self.last_frame_stats = SplatFrameStats()
        self.last_selection: SplatSelection | None = None

    # -- selection ------------------------------------------------------------------------------
    def _resident(self, ids: np.ndarray) -> np.ndarray:
        out = np.zeros(len(ids), bool)
        if not len(ids):
            return out
        levels, idx = self.loader.brick_of_nodes(ids)
        for L in np.unique(levels):
            m = levels == L
            out[m] = self.clip.resident_mask(int(L), idx[m])
        return out

    def select(self, camera) -> SplatSelection:
        """The cut for ``camera`` with the clip-texture's residency (no drawing)."""
        return select_splat_nodes(self.loader.nodes, camera, self.tolerance, self._resident)

    # -- frame ----------------------------------------------------------------------------------
    def render(self, camera, transfer_function, wait: bool = False, timeout: float | None = None) -> np.ndarray:
        """One frame as ``(h, w, 4)`` uint8 straight RGBA (see the module docstring)."""
        t0 = time.perf_counter()
        deadline = None if timeout is None else t0 + float(timeout)
        passes = 0
        while True:
            passes += 1
            sel = self.select(camera)
            if not wait or sel.converged:
                break
            levels, idx = self.loader.brick_of_nodes(sel.missing)
            keys = [(int(L), tuple(int(v) for v in i)) for L, i in zip(levels, idx)]
            left = None if deadline is None else max(0.0, deadline - time.perf_counter())
            self.clip.wait_for(keys, timeout=left)
            again = self.select(camera)
            if again.converged or len(again.missing) >= len(sel.missing) or (deadline is not None and time.perf_counter() >= deadline):
                sel = again
                passes += 1
                break
        t1 = time.perf_counter()
        pos, val, h, grad = self._gather(sel, camera)
        t2 = time.perf_counter()
        image, clamped = self._draw(camera, transfer_function, pos, val, h, grad)
        t3 = time.perf_counter()
        depths = self.loader.nodes.depth[sel.draw]
        u, c = np.unique(depths, return_counts=True)
        self.last_selection = sel
        self.last_frame_stats = SplatFrameStats(
            nodes_drawn=len(sel.draw), points_drawn=len(val), nodes_per_depth={int(a): int(b) for a, b in zip(u, c)},
            wanted=len(sel.wanted), missing=len(sel.missing), tolerance_px=sel.tolerance_px, clamped=clamped,
            converged=sel.converged, passes=passes,
            times={"select": t1 - t0, "gather": t2 - t1, "draw": t3 - t2},
        )
        return image

    def draw_points(self, camera, transfer_function, xyz, values, h, gradients=None) -> np.ndarray:
        """Draw the given points (world ``xyz`` (n, 3), raw ``values`` (n,), splat sizes ``h``), no selection.

        The same splats as :meth:`render` for points that do not come from the octree's cut: drawing
        every point (:meth:`clipvol.loaders.point_store.PointStoreLoader.leaf_points`) is the full-detail
        picture the report and the benchmark measure the tolerance's error against.
        """
        pos = np.asarray(xyz, np.float64).reshape(-1, 3) - np.asarray(camera.eye, np.float64)
        val = np.asarray(values, np.float32).reshape(-1)
        hh = np.broadcast_to(np.asarray(h, np.float64), val.shape)
        ok = np.isfinite(val)
        g = np.zeros((len(val), 3)) if gradients is None else np.asarray(gradients, np.float64).reshape(-1, 3)
        image, _ = self._draw(camera, transfer_function, pos[ok], val[ok], hh[ok], g[ok])
        return image

    def _gather(self, sel: SplatSelection, camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points of the drawn nodes: eye-relative float64 positions, values, splat sizes."""
        nodes = self.loader.nodes
        origin = np.asarray(self.loader.meta.origin, np.float64)
        levels, idx = self.loader.brick_of_nodes(sel.draw)
        hs = nodes.edges(sel.draw) / np.cbrt(np.maximum(nodes.count[sel.draw], 1))
        rows, hh, gg = [], [], []
        lit = self.shading and self.mode == "composite"
        for L in np.unique(levels):
            m = levels == L
            res, bricks = self.clip.get_bricks(int(L), idx[m])  # nodes evicted since the selection: next frame
            r = bricks[:, 0].reshape(-1, bricks.shape[-1])
            keep = r[:, 3] > 0.5
            rows.append(r[keep])
            hh.append(np.repeat(hs[m][res], bricks.shape[2])[keep])
            if lit:
                gg.append(self._node_gradients(sel.draw[m][res], bricks[:, 0]).reshape(-1, 3)[keep])
        if not rows:
            return np.zeros((0, 3)), np.zeros(0, np.float32), np.zeros(0), np.zeros((0, 3))
        r = np.concatenate(rows)
        h = np.concatenate(hh)
        g = np.concatenate(gg) if lit else np.zeros((len(r), 3))
        ok = np.isfinite(r[:, 4 + self.value])  # NaN / Inf values are not drawn (as the volume's samples)
        if not ok.all():
            r, h, g = r[ok], h[ok], g[ok]
        pos = r[:, :3].astype(np.float64) + (origin - np.asarray(camera.eye, np.float64))
        return pos, r[:, 4 + self.value], h, g

    #: most points whose gradients are kept between frames
    GRADIENT_CACHE_POINTS = 4_000_000

    def _node_gradients(self, ids: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``(len(ids), max_points, 3)`` gradients of the drawn value at each node's points (cached per node)."""
        out = np.zeros(rows.shape[:2] + (3,))
        todo = [i for i, nid in enumerate(ids.tolist()) if nid not in self._grads]
        if todo:
            t = np.array(todo)
            sub = rows[t]
            counts = (sub[:, :, 3] > 0.5).sum(axis=1)
            g = wls_gradients(sub[:, :, :3], sub[:, :, 4 + self.value], counts)
            for j, i in enumerate(todo):
                self._grads[int(ids[i])] = g[j, :counts[j]].astype(np.float32)
        for i, nid in enumerate(ids.tolist()):
            gi = self._grads[nid]
            self._grads.move_to_end(nid)
            out[i, :len(gi)] = gi
        held = sum(len(v) for v in self._grads.values()) if len(self._grads) * self.loader.max_points > self.GRADIENT_CACHE_POINTS else 0
        while held > self.GRADIENT_CACHE_POINTS and len(self._grads) > len(ids):
            held -= len(self._grads.popitem(last=False)[1])
        return out

    def _ensure(self, size, tf):
        mgl = self._mgl
        self._target.ensure(size)
        table = np.ascontiguousarray(np.asarray(tf.table, dtype=np.float32))
        key = table.tobytes()
        if self._tf_key != key:
            if self._tf_tex is not None:
                self._tf_tex.release()
            self._tf_tex = self.ctx.texture((table.shape[0], 1), 4, key, dtype="f4")
            self._tf_tex.filter = (mgl.LINEAR, mgl.LINEAR)
            self._tf_tex.repeat_x = self._tf_tex.repeat_y = False
            self._tf_key = key

    def _draw(self, camera, tf, pos, val, h, grad=None) -> tuple[np.ndarray, int]:
        mgl = self._mgl
        ctx = self.ctx
        w, hgt = camera.size
        self._ensure((w, hgt), tf)
        lo, hi = tf.window(self.loader.meta.value_ranges[self.value])
        V = camera.view_matrix().copy()
        V[:3, 3] = 0.0  # positions are already relative to the eye
        M = camera.projection_matrix() @ V
        depth = -(pos @ V[2, :3])  # distance along the view direction
        if self.mode == "composite":
            order = np.argsort(-depth, kind="stable")  # back to front
            pos, val, h, depth = pos[order], val[order], h[order], depth[order]
        else:
            order = slice(None)
        k = float(camera.pixels_per_unit(1.0))
        sigma_px = 0.5 * h * k / (1.0 if camera.orthographic else np.maximum(depth, 1e-6))
        clamped = int(np.count_nonzero(6.0 * sigma_px > self._max_size))
        data = np.zeros((len(val), 8), np.float32)
        data[:, :3] = pos
        data[:, 3] = val
        data[:, 4] = h
        if grad is not None and len(val):
            data[:, 5:8] = grad[order]
        previous = ctx.fbo
        self._target.fbo.use()
        ctx.viewport = (0, 0, w, hgt)
        ctx.clear(0.0, 0.0, 0.0, 0.0)
        ctx.disable(mgl.DEPTH_TEST | mgl.CULL_FACE)
        ctx.enable_direct(_GL_PROGRAM_POINT_SIZE)
        ctx.enable(mgl.BLEND)
        if self.mode == "mip":
            ctx.blend_equation = mgl.MAX
            ctx.blend_func = mgl.ONE, mgl.ONE
        else:
            ctx.blend_equation = mgl.FUNC_ADD
            ctx.blend_func = mgl.ONE, mgl.ONE_MINUS_SRC_ALPHA
        prog = self.prog
        prog["u_vp"].write(M.T.astype(np.float32).tobytes())
        prog["u_px_per_unit"].value = k
        prog["u_ortho"].value = 1 if camera.orthographic else 0
        prog["u_window"].value = (float(lo), float(hi))
        prog["u_max_size"].value = self._max_size
        prog["u_unit"].value = self.opacity_unit
        prog["u_mip"].value = 1 if self.mode == "mip" else 0
        prog["u_shading"].value = 1 if (self.shading and self.mode == "composite") else 0
        prog["u_light"].value = self.light
        prog["u_tf"].value = 0
        self._tf_tex.use(location=0)
        if len(data):
            if self._vbo is None or self._vbo.size < data.nbytes:
                if self._vbo is not None:
                    self._vao.release()
                    self._vbo.release()
                self._vbo = ctx.buffer(reserve=max(data.nbytes, 1 << 16))
                self._vao = ctx.vertex_array(prog, [(self._vbo, "3f 1f 1f 3f", "in_pos", "in_value", "in_h", "in_grad")])
            self._vbo.write(data.tobytes())
            self._vao.render(mgl.POINTS, vertices=len(data))
        ctx.finish()
        raw = np.frombuffer(self._target.fbo.read(components=4, dtype="f4"), np.float32).reshape(hgt, w, 4)[::-1]
        ctx.blend_equation = mgl.FUNC_ADD
        ctx.disable(mgl.BLEND)
        ctx.disable_direct(_GL_PROGRAM_POINT_SIZE)
        self._target.restore(previous)  # a released framebuffer left bound breaks later ones
        err = ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error after drawing splats: expected GL_NO_ERROR, got {err}")
        r, g, b, ba = self.background
        bgp = np.array([r * ba, g * ba, b * ba, ba])
        if self.mode == "mip":
            hit = raw[..., 3] > 0.5
            t = raw[..., 0].astype(np.float64)
            rgba = tf.lookup(lo + t * (hi - lo), (lo, hi))
            a = np.where(hit, rgba[..., 3], 0.0)
            prem = np.concatenate([rgba[..., :3] * a[..., None], a[..., None]], axis=-1)
        else:
            prem = raw.astype(np.float64)
        prem = prem + (1.0 - prem[..., 3:4]) * bgp
        return premultiplied_to_uint8(prem), clamped

    def close(self) -> None:
        """Release the GL objects (the clip-texture is the caller's)."""
        for o in (self._vao, self._vbo, self._tf_tex, self.prog):
            if o is not None:
                o.release()
        self._target.release()
        self._vao = self._vbo = self._tf_tex = None
        self.prog = None

    def __enter__(self) -> "SplatRenderAction":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
