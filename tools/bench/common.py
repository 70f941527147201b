"""What the benchmarks share: where they read and write, the data sets, and the raw-caster reference.

The benchmarks in this folder are scripts run from the repository (``python tools/bench/bench_render.py``),
not part of the installed package: they import the installed ``clipvol`` and this module (their
folder is the first entry of ``sys.path`` when run as scripts). Written once here:

* **paths** - :data:`REPO`, :data:`DATA` (``bench-data/``, git-ignored: stores built once and
  reused) and :data:`RESULTS` (``tools/bench/results/``: the CSV rows and plots that
  ``docs/benchmarks.md`` cites; every benchmark writes there by default);
* **data sets** - the procedural fractal as a store (float32, or quantised to 12 bits in
  uint16) and as an in-memory scene with its camera and table (:func:`fractal_scene`), the
  CT-like head in 12-bit words (:func:`ct_volume`, :func:`ct_store`), and the 640³ fractal store
  of the render and slice benchmarks (:func:`big_fractal_store`);
* **the reference outside clipvol's render path** - :class:`RawCaster`, a plain one-texture,
  one-pass moderngl ray caster drawing the same view, step, lattice and table, and the helpers
  that time clipvol's actions against it, warm and interleaved, medians of several rounds
  (:func:`interleaved_medians`, :func:`raw_runs`, :func:`sizes_main`).
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
#: stores the benchmarks build once and reuse (git-ignored)
DATA = REPO / "bench-data"
#: the rows and plots ``docs/benchmarks.md`` cites
RESULTS = Path(__file__).resolve().parent / "results"
#: the render and slice benchmarks' store: 640^3 float32 = 1.05 GB, built once with ``clipvol brick``
STORE = "fractal-640-b64.zarr"
STORE_SOURCE = "procedural:fractal?size=640"


# -- data sets ------------------------------------------------------------------------------------
def store_is_built(path: Path) -> bool:
    """A benchmark store cached under ``bench-data/`` is used again only if its build completed."""
    attrs = path / "zarr.json"
    return attrs.is_file() and bool(json.loads(attrs.read_text())["attributes"]["clipvol"].get("complete"))


def fractal_store(size: str, brick: int, data_dir: Path = DATA, dtype: str = "float32") -> Path:
    """The procedural fractal (seed 1) bricked with blosc lz4 + crc32c (cached by size, brick and
    dtype). ``uint16``: the same field quantised to 12 bits, like CT data (it compresses about
    twice as well as the float32 field, so the checksum covers fewer bytes)."""
    from clipvol.bricking.generators import parse_procedural
    from clipvol.bricking.pipeline import brick_volume

    path = data_dir / f"fractal-{size}-b{brick}-{dtype}-crc.zarr"
    if store_is_built(path):
        return path
    data_dir.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    url = f"procedural:fractal?size={size}&seed=1"
    source = url
    if dtype == "uint16":
        gen = parse_procedural(url)
        v = gen.region(0, (0, 0, 0), gen.shape)
        lo, hi = float(v.min()), float(v.max())
        source = np.rint((v - lo) / (hi - lo) * 4095).astype(np.uint16)
    elif dtype != "float32":
        raise ValueError(f"dtype: expected float32 or uint16, got {dtype!r}")
    brick_volume(source, path, brick=brick, codec="lz4", progress=True, overwrite=True)
    print(f"built {path} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
    return path


def big_fractal_store(data_dir: Path = DATA) -> Path | None:
    """``bench-data/fractal-640-b64.zarr`` (:data:`STORE_SOURCE`), bricked with ``clipvol brick`` the
    first time; None if that fails (the CLI has printed why)."""
    store = data_dir / STORE
    if not store_is_built(store):
        from clipvol.tools.cli import main as cli

        print(f"bricking {STORE_SOURCE} into {store} (once)", file=sys.stderr)
        if cli(["brick", STORE_SOURCE, str(store), "--quiet", "--overwrite"]) != 0:
            return None
    return store


def ct_volume(shape: tuple[int, int, int], seed: int = 0):
    """:func:`~clipvol.bricking.generators.ct_head` as 12-bit CT in uint16 words: its 8-bit values
    times 16 (0..4080), plus a uniform dither of the 4 low bits inside the head (the generator's
    noise, sigma 2 of 255, is 32 of 4095 here: the low bits of a real scan are noise, not zeros).
    The air outside stays exactly 0, as the generator makes it (a scanner's padding outside its
    field of view is constant too)."""
    import numpy as np

    from clipvol.bricking.generators import ct_head

    head = ct_head(shape, seed=seed)
    rng = np.random.default_rng(seed + 1)
    out = np.empty(head.shape, dtype=np.uint16)
    for z in range(0, head.shape[0], 32):  # slab by slab: no 8-byte temporaries of the whole volume
        h = head[z:z + 32]
        v = h.astype(np.uint16) << 4
        v += (rng.integers(0, 16, size=h.shape, dtype=np.uint16) * (h > 0)).astype(np.uint16)
        out[z:z + 32] = v
    return out


def ct_store(size: str, brick: int, data_dir: Path = DATA) -> Path:
    """The CT-like head (:func:`ct_volume`) bricked with blosc lz4 + crc32c like the fractal stores (cached)."""
    from clipvol.bricking.pipeline import brick_volume

    path = data_dir / f"ct-{size}-b{brick}-uint16-crc.zarr"
    if store_is_built(path):
        return path
    data_dir.mkdir(parents=True, exist_ok=True)
    shape = tuple(int(v) for v in size.split("x"))
    brick_volume(ct_volume(shape), path, brick=brick, codec="lz4", progress=True, overwrite=True)
    return path


def store_or_ct(store: Path | None, size: str = "256x256x256", brick: int = 32):
    """``(store, level-0 volume, label)`` of a benchmark's input: the clipvol store at ``store``
    (its level 0 read whole for the raw caster), else the CT-like head of ``size`` at ``brick``."""
    if store is not None:
        from clipvol.paging.open import open_store

        loader = open_store(store)
        volume = WholeVolume(loader).read_brick(0, (0, 0, 0))
        return store, volume, f"{store.name}, {loader.pyramid.brick_shape[0]}^3 bricks"
    shape = tuple(int(v) for v in size.split("x"))
    return ct_store(size, brick), ct_volume(shape), f"ct_head {size} uint16 (12 bit), {brick}^3 bricks"


class WarmScene:
    """A store opened for a warm benchmark: its loader and pyramid, a GL context, a clip-texture and a
    texture budget that hold every brick of every level (so each action's frames converge and stay
    resident), and the ``bone`` table over the store's value range. ``close()`` releases what it
    made: the actions and raw casters it handed out, the clip-texture, the context."""

    def __init__(self, store: Path, ctx=None) -> None:
        """``ctx``: a GL context to draw in (kept open by ``close()``: several scenes drawn in turn in
        one process share one, as moderngl draws in the context made current last); default: its own."""
        from clipvol.paging.cliptexture import ClipTexture
        from clipvol.paging.open import open_store
        from clipvol.render import create_context
        from clipvol.scene.transfer import TransferFunction

        self.loader = open_store(store)
        pyr = self.pyramid = self.loader.pyramid
        self._own_ctx = ctx is None
        self.ctx = create_context() if ctx is None else ctx
        # every brick with room to spare: a texture slot holds a brick and its one-voxel border (18^3
        # texels for a 16^3 brick, 1.42x), so 1.2x left a 512^3 head's level 0 (32^3 bricks of 16^3)
        # a 27^3 window: its full-resolution frame never converged
        self.budget = int(sum(pyr.num_bricks(L) for L in range(pyr.num_levels)) * pyr.brick_nbytes * 2.0) + (64 << 20)
        self.clip = ClipTexture(self.loader, self.budget, threads=2)
        self.tf = TransferFunction.preset("bone", value_range=pyr.value_range)
        self._made: list = []  # (object, its release method), released by close() in reverse

    def action(self, **params):
        """A ``ClipRenderAction`` on this scene's clip-texture with the whole budget for textures."""
        from clipvol.render.action import ClipRenderAction

        a = ClipRenderAction(self.ctx, self.clip, texture_budget=self.budget, **params)
        self._made.append(a.close)
        return a

    def converged_drawer(self, timeout: float = 600.0):
        """``draw(camera, params)``: a level-0 action's frame under ``params`` (what
        :class:`clipvol.app.converged.ConvergedPictures` renders its references with), raising
        where the frame did not converge within ``timeout`` s: a reference that stopped short would
        make every error measured against it wrong."""
        ref = self.action(policy="fixed", level=0)

        def draw(cam, params):
            ref.set_params(params)
            img = ref.render(cam, self.tf, wait=True, timeout=timeout)
            if not ref.last_frame_stats.converged:
                raise RuntimeError(f"the converged picture did not converge in {timeout:.0f} s ({cam.size[0]}^2)")
            return img

        return draw

    def converged_pictures(self, draw=None):
        """The converged pictures the LOD benchmarks measure error against (level 0 at step 0.25,
        2x2 rays a pixel, box-filtered; :class:`clipvol.app.converged.ConvergedPictures`), drawn by
        ``draw`` (default: :meth:`converged_drawer`)."""
        from clipvol.app.converged import ConvergedPictures
        from clipvol.scene.params import RenderParams

        draw = self.converged_drawer() if draw is None else draw
        return ConvergedPictures(draw, RenderParams(step=0.5), supersample=2, step=0.25)

    def raw_caster(self, volume=None) -> "RawCaster":
        """The :class:`RawCaster` of ``volume`` (default: the store's level 0 read whole)."""
        if volume is None:
            volume = WholeVolume(self.loader).read_brick(0, (0, 0, 0))
        raw = RawCaster(self.ctx, volume, self.pyramid.value_range)
        self._made.append(raw.release)
        return raw

    def close(self) -> None:
        for release in reversed(self._made):
            release()
        self._made = []
        self.clip.close()
        if self._own_ctx:
            self.ctx.release()


# -- the reference outside clipvol's render path -----------------------------------------------------
class WholeVolume:
    """A loader that serves level 0 of another loader as one brick (for the one-pass caster)."""

    def __init__(self, loader) -> None:
        from clipvol.bricking.pyramid import Pyramid

        p = loader.pyramid
        self._src = loader
        self._pyr = Pyramid((p.levels[0],), p.shape, p.dtype, p.value_range, p.fill_value, p.filter)

    @property
    def pyramid(self):
        return self._pyr

    def read_brick(self, level, index):
        p = self._src.pyramid
        out = np.empty(p.shape, dtype=p.dtype)
        g = p.grid(0)
        for bz in range(g[0]):
            for by in range(g[1]):
                for bx in range(g[2]):
                    (z0, y0, x0), (z1, y1, x1) = p.brick_voxel_box(0, (bz, by, bx))
                    brick = self._src.read_brick(0, (bz, by, bx))
                    out[z0:z1, y0:y1, x0:x1] = brick[: z1 - z0, : y1 - y0, : x1 - x0]
        return out


# -- the reference: a minimal raw one-texture ray caster (outside clipvol's render path) ----------
_RAW_VERT = """#version 330
out vec2 v_ndc;
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2) * 2.0 - 1.0;  // one full-screen triangle
    v_ndc = p;
    gl_Position = vec4(p, 0.0, 1.0);
}
"""
# Both plain casters' rays: the pixel's direction and where it enters [t0] and leaves [t1] the
# volume box (u_lo, u_hi); a ray that misses the box draws nothing.
_RAY_ENTRY = """vec3 dir = normalize(u_forward + v_ndc.x * u_half.x * u_right + v_ndc.y * u_half.y * u_up);
    vec3 inv = 1.0 / dir;
    vec3 ta = (u_lo - u_eye) * inv, tb = (u_hi - u_eye) * inv;
    float t0 = max(max(max(min(ta.x, tb.x), min(ta.y, tb.y)), min(ta.z, tb.z)), 0.0);
    float t1 = min(min(max(ta.x, tb.x), max(ta.y, tb.y)), max(ta.z, tb.z));
    if (!(t1 > t0)) discard;"""
_RAW_FRAG = """#version 330
in vec2 v_ndc;
out vec4 f_color;
uniform sampler3D u_vol;        // the whole volume, GL_LINEAR, clamp to edge
uniform sampler2D u_tf;         // the table, opacity corrected for the step on the CPU
uniform vec3 u_eye, u_right, u_up, u_forward;
uniform vec2 u_half;
uniform vec3 u_lo, u_hi;        // the volume box (world)
uniform float u_delta, u_t_scale, u_t_offset, u_opaque;
void main() {
    RAY_ENTRY
    vec4 acc = vec4(0.0);
    vec3 isz = 1.0 / (u_hi - u_lo);
    for (float t = ceil(t0 / u_delta) * u_delta; t < t1; t += u_delta) {
        float v = texture(u_vol, (u_eye + t * dir - u_lo) * isz).r;
        vec4 c = texture(u_tf, vec2(v * u_t_scale + u_t_offset, 0.5));
        acc += (1.0 - acc.a) * c.a * vec4(c.rgb, 1.0);
        if (acc.a >= u_opaque) break;
    }
    f_color = acc;
}
""".replace("RAY_ENTRY", _RAY_ENTRY)


#: the raw caster's early ray termination: a ray stops at this accumulated opacity. clipvol stops
#: at ``clipvol.render.paths.setup.OPAQUE`` (1 - 0.5/255, where what is left cannot move an 8-bit pixel
#: by more than one level); the benchmarks time the raw caster at both, so that each ratio can be
#: read against the plain caster and against a caster doing exactly clipvol's work.
RAW_OPAQUE = 0.9995


def _draw_screen(ctx, fbo, vao, h: int, w: int) -> np.ndarray:
    """Draw a plain caster's one screen triangle into its float framebuffer and read it back
    (``(h, w, 4)`` float32, first row at the top); the framebuffer bound before is bound again (a
    released framebuffer left bound breaks later ones; a fresh context has none)."""
    import moderngl

    previous = ctx.fbo
    fbo.use()
    fbo.clear(0.0, 0.0, 0.0, 0.0)
    ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
    vao.render(moderngl.TRIANGLES, vertices=3)
    ctx.finish()
    out = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4)[::-1]
    if previous is not None:
        previous.use()
    return out


class RawCaster:
    """A plain one-texture moderngl ray caster: one 3D texture, one table lookup, front to back.

    The benchmarks' reference *outside* clipvol's render path (the shader above is all there is:
    no bricks, no page table, no variants, no shape clipping), drawing the same view with the same
    step, lattice (``t = k * delta`` from the eye) and opacity-corrected table, so clipvol's
    frame time can be stated as a ratio to what a minimal caster costs on the same GL.
    It stops a ray at accumulated opacity ``opaque`` (:data:`RAW_OPAQUE` unless given).
    Perspective cameras only. ``volume``: ``(z, y, x)``, spacing 1; float32, or uint8 / uint16 held
    as a normalised 8 / 16-bit texture (a 1024^3 volume then fits in memory: 1 or 2 GiB), its
    texel times 255 / 65535 being the value.
    """

    def __init__(self, ctx, volume: np.ndarray, value_range) -> None:
        import moderngl

        self.ctx = ctx
        gl = {np.dtype(np.uint8): ("f1", 255.0), np.dtype(np.uint16): ("nu2", 65535.0)}.get(np.asarray(volume).dtype)
        if gl is None:
            vol = np.ascontiguousarray(volume, dtype=np.float32)
            gl = ("f4", 1.0)
        else:
            vol = np.ascontiguousarray(volume)
        self.norm = gl[1]  # value = texel * norm
        self.shape = vol.shape
        self.tex = ctx.texture3d(vol.shape[::-1], 1, vol, dtype=gl[0], alignment=1)
        self.tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.tex.repeat_x = self.tex.repeat_y = self.tex.repeat_z = False
        self.prog = ctx.program(vertex_shader=_RAW_VERT, fragment_shader=_RAW_FRAG)
        self.vao = ctx.vertex_array(self.prog, [])
        self.value_range = tuple(float(v) for v in value_range)
        self._fbo = None
        self._tf = None

    def render(self, cam, tf, step: float, opaque: float = RAW_OPAQUE) -> np.ndarray:
        """Draw ``cam``'s view; returns ``(h, w, 4)`` premultiplied float32 RGBA, row 0 at the top.
        ``opaque``: the accumulated opacity at which a ray stops."""
        import moderngl

        from clipvol.scene.transfer import correct_opacity

        ctx = self.ctx
        w, h = cam.size
        if self._fbo is None or self._fbo.size != (w, h):
            self._fbo = ctx.simple_framebuffer((w, h), components=4, dtype="f4")
        if self._tf is None:
            table = np.array(tf.table, dtype=np.float64)
            table[:, 3] = correct_opacity(table[:, 3], step)
            self._tf = ctx.texture((len(table), 1), 4, table.astype(np.float32).tobytes(), dtype="f4")
            self._tf.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._tf.repeat_x = self._tf.repeat_y = False
        lo, hi = tf.window(self.value_range)
        p = self.prog
        p["u_vol"].value, p["u_tf"].value = 0, 1
        self.tex.use(0)
        self._tf.use(1)
        p["u_eye"].value = tuple(float(v) for v in cam.eye)
        p["u_right"].value = tuple(float(v) for v in cam.right)
        p["u_up"].value = tuple(float(v) for v in cam.up)
        p["u_forward"].value = tuple(float(v) for v in cam.forward)
        ty = np.tan(np.radians(float(cam.fov_y)) / 2.0)
        p["u_half"].value = (float(ty * w / h), float(ty))
        n = np.array(self.shape[::-1], dtype=np.float64)
        p["u_lo"].value = (-0.5, -0.5, -0.5)
        p["u_hi"].value = tuple(float(v) for v in n - 0.5)
        p["u_delta"].value = float(step)
        p["u_opaque"].value = float(opaque)
        p["u_t_scale"].value = self.norm / (hi - lo)
        p["u_t_offset"].value = -lo / (hi - lo)
        return _draw_screen(ctx, self._fbo, self.vao, h, w)

    def release(self) -> None:
        for o in (self.tex, self.prog, self.vao, self._fbo, self._tf):
            if o is not None:
                o.release()


_LEVEL_FRAG = """#version 330
in vec2 v_ndc;
out vec4 f_color;
uniform sampler3D u_vol;        // one level, GL_LINEAR, clamp to edge: a value (.r), (mean, spread) (.rg)
                                // or premultiplied RGBA
uniform sampler2D u_tf;         // values: the table (straight RGBA, opacity per level-0 voxel), one row;
                                // (mean, spread): a table per spread row, opacity corrected for the step
uniform int u_mode;             // 0: a value; 1: classified already, (E[a c], E[a]); 2: (mean, spread)
uniform float u_rows, u_sigma_scale;  // mode 2: the table's rows, spread (raw) -> row coordinate squared
uniform vec3 u_eye, u_right, u_up, u_forward;
uniform vec2 u_half;
uniform vec3 u_lo, u_hi;        // the volume box (world): where rays are clipped
uniform vec3 u_tlo, u_tsize;    // the level's texel box (world): its texture coordinates
uniform float u_delta, u_ratio, u_t_scale, u_t_offset, u_opaque;
void main() {
    RAY_ENTRY
    vec4 acc = vec4(0.0);
    for (float t = ceil(t0 / u_delta) * u_delta; t < t1; t += u_delta) {
        vec4 v = texture(u_vol, (u_eye + t * dir - u_tlo) / u_tsize);
        vec3 rgb;
        float a;
        if (u_mode == 1) {  // straight colour E[a c] / E[a]; opacity E[a] corrected for the step
            a = v.a > 0.0 ? 1.0 - pow(1.0 - min(v.a, 1.0), u_ratio) : 0.0;
            rgb = v.a > 0.0 ? v.rgb / v.a : vec3(0.0);
        } else if (u_mode == 2) {  // the row of the sample's spread, bilinear
            float u = sqrt(clamp(v.g * u_sigma_scale, 0.0, 1.0)) * (u_rows - 1.0);
            vec4 c = texture(u_tf, vec2(v.r * u_t_scale + u_t_offset, (u + 0.5) / u_rows));
            a = c.a;
            rgb = c.rgb;
        } else {
            vec4 c = texture(u_tf, vec2(v.r * u_t_scale + u_t_offset, 0.5));
            a = 1.0 - pow(1.0 - min(c.a, 1.0), u_ratio);
            rgb = c.rgb;
        }
        acc += (1.0 - acc.a) * a * vec4(rgb, 1.0);
        if (acc.a >= u_opaque) break;
    }
    f_color = acc;
}
""".replace("RAY_ENTRY", _RAY_ENTRY)


class LevelCaster:
    """A plain one-texture moderngl ray caster of one pyramid level, outside clipvol's render path.

    Like :class:`RawCaster` (one full-screen triangle, samples at ``t = k * delta`` from the eye, front
    to back, a ray stops at ``opaque``) but the texture is any level's grid placed where the level's
    voxels lie (voxel ``j`` at ``spacing * (scale * j + translation)``), the rays clipped to the
    level-0 volume box; and the texture holds either a value per voxel (classified after trilinear
    interpolation by the table, as clipvol classifies a coarse voxel's mean) or a premultiplied RGBA
    per voxel, already classified (``(E[a c], E[a])`` of the fine voxels beneath it; interpolated,
    then its opacity corrected for the step: ``1 - (1 - A) ** ratio``). The second is what a perfect
    distribution per coarse voxel draws: the expectation of the classification over a trilinear mix
    of the eight voxels' distributions is the trilinear mix of their expectations.
    ``volume``: ``(z, y, x)`` float32 values (raw units), ``(z, y, x, 4)`` float32 RGBA, or
    ``(z, y, x, 2)`` (mean, spread) in raw units, classified by ``dist_table`` ``(rows, n, 4)``
    (straight RGBA per spread row, opacity corrected for the step it is drawn at; the rows'
    spreads ``SPREAD_MAX * (s / (rows - 1)) ** 2`` window widths, :mod:`clipvol.scene.consistent`).
    """

    def __init__(self, ctx, volume: np.ndarray, pyramid, level: int, dist_table: np.ndarray | None = None) -> None:
        import moderngl

        vol = np.ascontiguousarray(volume, dtype=np.float32)
        channels = vol.shape[3] if vol.ndim == 4 else 1
        self.mode = {1: 0, 4: 1, 2: 2}[channels]
        self.dist_table = None if dist_table is None else np.ascontiguousarray(dist_table, dtype=np.float32)
        self.ctx = ctx
        self.tex = ctx.texture3d(vol.shape[:3][::-1], channels, vol, dtype="f4", alignment=1)
        self.tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.tex.repeat_x = self.tex.repeat_y = self.tex.repeat_z = False
        self.prog = ctx.program(vertex_shader=_RAW_VERT, fragment_shader=_LEVEL_FRAG)
        self.vao = ctx.vertex_array(self.prog, [])
        lv = pyramid.levels[level]
        sp = np.array(pyramid.spacing[::-1], dtype=np.float64)
        scale = np.array(lv.scale[::-1], dtype=np.float64)
        self.tlo = sp * (np.array(lv.translation[::-1], dtype=np.float64) - scale / 2.0)
        self.tsize = sp * scale * np.array(vol.shape[:3][::-1], dtype=np.float64)
        self.box = pyramid.volume_box()
        self.ref = float(min(pyramid.spacing))  # the table's opacity is per level-0 voxel
        self.value_range = tuple(float(v) for v in pyramid.value_range)
        self._fbo = None
        self._tf = None

    def render(self, cam, tf, delta: float, opaque: float) -> np.ndarray:
        """Draw ``cam``'s view with samples ``delta`` apart (world units); ``(h, w, 4)`` premultiplied
        float32 RGBA, row 0 at the top."""
        import moderngl

        ctx = self.ctx
        w, h = cam.size
        if self._fbo is None or self._fbo.size != (w, h):
            self._fbo = ctx.simple_framebuffer((w, h), components=4, dtype="f4")
        if self._tf is None:
            table = np.asarray(tf.table, dtype=np.float32)[None] if self.mode != 2 else self.dist_table
            self._tf = ctx.texture((table.shape[1], table.shape[0]), 4, table.tobytes(), dtype="f4")
            self._tf.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._tf.repeat_x = self._tf.repeat_y = False
        lo, hi = tf.window(self.value_range)
        p = self.prog
        p["u_vol"].value, p["u_tf"].value = 0, 1
        self.tex.use(0)
        self._tf.use(1)
        p["u_mode"].value = self.mode
        if self.mode == 2:
            from clipvol.scene.consistent import SPREAD_MAX

            p["u_rows"].value = float(len(self.dist_table))
            p["u_sigma_scale"].value = 1.0 / (abs(hi - lo) * SPREAD_MAX)
        p["u_eye"].value = tuple(float(v) for v in cam.eye)
        p["u_right"].value = tuple(float(v) for v in cam.right)
        p["u_up"].value = tuple(float(v) for v in cam.up)
        p["u_forward"].value = tuple(float(v) for v in cam.forward)
        ty = np.tan(np.radians(float(cam.fov_y)) / 2.0)
        p["u_half"].value = (float(ty * w / h), float(ty))
        p["u_lo"].value = tuple(float(v) for v in self.box[0])
        p["u_hi"].value = tuple(float(v) for v in self.box[1])
        p["u_tlo"].value = tuple(float(v) for v in self.tlo)
        p["u_tsize"].value = tuple(float(v) for v in self.tsize)
        p["u_delta"].value = float(delta)
        p["u_ratio"].value = float(delta) / self.ref
        p["u_opaque"].value = float(opaque)
        p["u_t_scale"].value = 1.0 / (hi - lo)
        p["u_t_offset"].value = -lo / (hi - lo)
        return _draw_screen(ctx, self._fbo, self.vao, h, w)

    def release(self) -> None:
        for o in (self.tex, self.prog, self.vao, self._fbo, self._tf):
            if o is not None:
                o.release()


def fractal_scene(n: int, image: int, log=None):
    """The benchmarks' common set-up: ``procedural:fractal?size=n`` in memory (float32), its loader
    (64³ bricks), a camera that fills an ``image``² view with it (about one pixel per voxel at 512),
    the ``bone`` table, and a clip-texture whose budget holds every brick. Returns ``(vol, loader,
    camera, tf, budget, clip)``; the caller closes ``clip``."""
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.loaders.procedural import ProceduralLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction

    t0 = time.perf_counter()
    vol = ProceduralLoader(f"procedural:fractal?size={n}", brick=64).generator.region(0, (0, 0, 0), (n, n, n))
    vol = np.ascontiguousarray(vol, dtype=np.float32)
    if log is not None:
        log(f"{n}^3: generated in {time.perf_counter() - t0:.1f} s")
    loader = NumpyLoader(vol, brick=64, value_range=(float(vol.min()), float(vol.max())))
    pyr = loader.pyramid
    lo, hi = pyr.volume_box()
    centre = (lo + hi) / 2.0
    d = np.array([0.55, 0.45, 0.7])
    d /= np.linalg.norm(d)
    cam = Camera.perspective(tuple(centre - d * 1.05 * float(np.linalg.norm(hi - lo))), tuple(centre), up=(0, -1, 0),
                             fov_y=35, size=(image, image))
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    budget = int(sum(pyr.num_bricks(L) for L in range(pyr.num_levels)) * pyr.brick_nbytes * 1.2) + (64 << 20)
    return vol, loader, cam, tf, budget, ClipTexture(loader, budget, threads=2)


def raw_stops() -> dict:
    """The raw caster's two configurations: ``"raw"`` stopping at :data:`RAW_OPAQUE` and
    ``"raw_same_stop"`` stopping where clipvol stops (``OPAQUE``)."""
    from clipvol.render.paths.setup import OPAQUE

    return {"raw": RAW_OPAQUE, "raw_same_stop": OPAQUE}


def time_raw(raw, cam, tf, step: float, wall: dict, cpu: dict) -> np.ndarray:
    """One round of the raw caster at each of :func:`raw_stops` (timed as drawn and read back, like
    clipvol's frame), appended to ``wall`` / ``cpu`` under the stop's key; returns the image of
    ``"raw"``."""
    out = None
    for key, stop in raw_stops().items():
        t, c = time.perf_counter(), time.process_time()
        img = raw.render(cam, tf, step, stop)
        wall[key].append(time.perf_counter() - t)
        cpu[key].append(time.process_time() - c)
        out = img if key == "raw" else out
    return out


def interleaved_medians(raw, actions: dict, cam, tf, step: float, repeat: int) -> tuple[dict, dict]:
    """Median wall and process-CPU seconds of the raw caster (``"raw"`` and ``"raw_same_stop"``,
    :func:`raw_stops`) and each action, measured in ``repeat`` interleaved rounds (the shared
    machine's load hits every configuration alike), after one converged frame of each."""
    for a in actions.values():
        a.render(cam, tf, wait=True, timeout=600)
    stops = raw_stops()
    raw.render(cam, tf, step)
    wall = {k: [] for k in [*stops, *actions]}
    cpu = {k: [] for k in [*stops, *actions]}
    for _ in range(repeat):
        time_raw(raw, cam, tf, step, wall, cpu)
        for name, a in actions.items():
            t, c = time.perf_counter(), time.process_time()
            a.render(cam, tf, wait=False)
            wall[name].append(time.perf_counter() - t)
            cpu[name].append(time.process_time() - c)
    return ({k: statistics.median(v) for k, v in wall.items()}, {k: statistics.median(v) for k, v in cpu.items()})


def ratio_columns(mw: dict, mc: dict, names) -> dict:
    """Per action name: its median seconds, and its wall and CPU time over the raw caster's at each
    stop (``"raw"``, ``"raw_same_stop"`` in ``mw``/``mc``, from :func:`interleaved_medians`), as CSV
    columns."""
    row = {}
    for k in names:
        key = k.replace(" ", "_").replace("-", "_")
        row[f"{key}_s"] = round(mw[k], 4)
        row.update(stop_ratios(mw, mc, [k], key, digits=3))
    return row


def stop_ratios(mw: dict, mc: dict, names, key=None, digits=None) -> dict:
    """``{name}_over_{stop}`` and ``{name}_cpu_over_{stop}`` columns: each action's median wall and
    CPU time over the raw caster's at each of :func:`raw_stops` (``key``: the column name for a
    single action, default the action's name; ``digits``: rounding)."""
    out = {}
    for k in names:
        col = key or k
        for r in raw_stops():
            w, c = mw[k] / mw[r], mc[k] / mc[r]
            out[f"{col}_over_{r}"] = w if digits is None else round(w, digits)
            out[f"{col}_cpu_over_{r}"] = c if digits is None else round(c, digits)
    return out


def raw_ratio_line(mw: dict, mc: dict, names) -> str:
    """One log line: each action's median and its ratios to the raw caster, wall and CPU, at the
    raw caster's stop and at clipvol's."""
    return f"raw {mw['raw']:.3f} s (same stop {mw['raw_same_stop']:.3f} s); " + "; ".join(
        f"{k} {mw[k]:.3f} s = {mw[k] / mw['raw']:.2f}x raw (CPU {mc[k] / mc['raw']:.2f}x; same stop "
        f"{mw[k] / mw['raw_same_stop']:.2f}x, CPU {mc[k] / mc['raw_same_stop']:.2f}x)" for k in names)


def raw_runs(sizes, image: int, repeat: int, step: float, make_actions):
    """Per ``procedural:fractal`` volume of ``sizes`` (:func:`fractal_scene`): the render actions
    ``make_actions(ctx, n, clip, common)`` makes (``common``: full resolution at ``step`` under the
    scene's texture budget) timed against a :class:`RawCaster` of the same volume, interleaved,
    medians of ``repeat`` (:func:`interleaved_medians`). Yields ``(n, actions, wall, cpu)``; what a
    run made is released before the next."""
    from clipvol.render import create_context

    ctx = create_context()
    try:
        for n in sizes:
            vol, loader, cam, tf, budget, clip = fractal_scene(n, image)
            actions = make_actions(ctx, n, clip, dict(policy="fixed", level=0, step=step, texture_budget=budget))
            raw = RawCaster(ctx, vol, loader.pyramid.value_range)
            try:
                mw, mc = interleaved_medians(raw, actions, cam, tf, step, repeat)
                yield n, actions, mw, mc
            finally:
                for a in actions.values():
                    a.close()
                raw.release()
                clip.close()
    finally:
        ctx.release()


def sizes_main(argv, doc: str, run, default_out: Path, sizes_help: str) -> int:
    """The command line of a benchmark against the raw caster over fractal volumes of ``--sizes``:
    ``run(sizes, image, repeat, step)`` gives the CSV rows written to ``--out``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--sizes", default="128,256", help=sizes_help)
    ap.add_argument("--image", type=int, default=256, help="image edge in pixels")
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds (medians)")
    ap.add_argument("--step", type=float, default=0.5)
    ap.add_argument("--out", default=str(default_out))
    args = ap.parse_args(argv)
    rows = run([int(s) for s in args.sizes.split(",")], args.image, args.repeat, args.step)
    write_rows(args.out, rows)
    print(f"wrote {args.out}")
    return 0


def orbit_parser(doc: str, frames: int) -> argparse.ArgumentParser:
    """The flags of the benchmarks that orbit warm projected-size scenes (``--store`` repeatable,
    ``--head`` CT-like heads at 16^3 bricks, ``--data``, ``--frames``, ``--image``, ``--lod``);
    :func:`orbit_stores` turns the parsed ones into the stores to measure."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--store", type=Path, action="append", default=[], help="a clipvol store (repeatable)")
    ap.add_argument("--head", default="512", help="CT-like head edges, comma separated (16^3 bricks)")
    ap.add_argument("--data", type=Path, default=DATA, help="where the heads' stores are built once")
    ap.add_argument("--frames", type=int, default=frames)
    ap.add_argument("--image", type=int, default=32)
    ap.add_argument("--lod", type=float, default=0.1)
    return ap


def orbit_stores(args) -> list[tuple[Path, str]]:
    """``(store, label)`` of :func:`orbit_parser`'s ``--store`` and ``--head`` (built once)."""
    entries = [(s, s.name) for s in args.store]
    for n in (int(v) for v in args.head.split(",") if v.strip()):
        entries.append((ct_store(f"{n}x{n}x{n}", 16, args.data), f"ct_head {n}^3, 16^3 bricks"))
    return entries


def write_rows(path, rows: list[dict]) -> None:
    """``rows`` as a CSV at ``path`` (columns: every row's keys, in the order they first appear;
    a row without one leaves its cell empty)."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        w.writeheader()
        w.writerows(rows)


def save_rows(path: Path, rows: list[dict]) -> int:
    """:func:`write_rows` into ``path`` (its folder made), say where, and return 0 (a script's exit)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_rows(path, rows)
    print(f"wrote {path}")
    return 0


