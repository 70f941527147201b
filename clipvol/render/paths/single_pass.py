"""The single-pass draw path (``RenderParams.path="single-pass"``): one ray per pixel through a page table.

The ray-guided path of BigVolumeViewer and the ray-guided renderers of the large-volume literature
(``shaders/raymarch.frag.glsl``): the selection's cut, merged like the per-brick path's boxes (a
complete sibling set is one node whose data is a block of finer bricks), becomes a per-level
**page table** (:mod:`clipvol.scene.page_table`: per node EMPTY, REFINED or DRAWN-from-level-``Ld``,
plus the faces filtering may cross), uploaded as one small integer texture. One proxy - the
volume's box - is drawn; each pixel's ray walks the table from the coarsest level down at its
current point, samples the node's box from the data level's toroidal texture on that level's
lattice, skips EMPTY nodes in one step, switches level at node faces and stops when opaque. No
framebuffer copies, no per-box set-up, no blending (one triangle under the scissor rectangle of the
volume's box). The shader is compiled per range of data levels the table uses.

A cut the table cannot express (more than :data:`MAX_SINGLE_PASS_LEVELS` levels, more than
:data:`MAX_PAGE_TABLE_ENTRIES` entries) or rays of more than :data:`MAX_SINGLE_PASS_RAY_SAMPLES`
samples (llvmpipe's loop cap) is not drawn here: :meth:`SinglePassPath.draw` returns None and the
action draws the frame per brick. The image equals the per-brick path's within 1 LSB.

References
----------
* M. Hadwiger, J. Beyer, W.-K. Jeong and H. Pfister, "Interactive Volume Exploration of Petascale
  Microscopy Data Streams Using a Visualization-Driven Virtual Memory Approach", IEEE TVCG 2012,
  and T. Fogal, A. Schiewe and J. Krüger, "An Analysis of Scalable GPU-Based Ray-Guided Volume
  Rendering", IEEE LDAV 2013 (ray-guided single-pass casting through a page table).
* T. Pietzsch, BigVolumeViewer (the Fiji / ImgLib2 GPU volume viewer, software, 2019 on):
  single-pass multiresolution casting through a cache of bricks addressed by a lookup texture.
"""

from __future__ import annotations

import numpy as np

from ...scene.page_table import update_page_table
from ...scene.selection import DrawItems
from ..uniforms import uset, vec3
from ..modes import mode_of
from .frame import DrawStats, FrameContext
from .setup import DrawPath, DrawSetup

__all__ = ["SinglePassPath", "MAX_SINGLE_PASS_LEVELS", "MAX_SINGLE_PASS_RAY_SAMPLES", "MAX_PAGE_TABLE_ENTRIES",
           "PAGE_TABLE_WIDTH", "PAGE_TABLE_WIDTH_LOG2", "SINGLE_PASS_SKIP_BLOCK"]

#: most pyramid levels (one texture unit each) and page-table entries
MAX_SINGLE_PASS_LEVELS = 16
#: most samples one ray may need (volume diagonal / finest step drawn). llvmpipe caps the
#: iterations of an outermost shader loop, nested loops included, at 65535 per SIMD group
#: (gallivm's loop limiter) and the group's iterations are the sum over nodes of its longest
#: segment, so a ray of more samples would be cut short there; such a frame is drawn per brick.
MAX_SINGLE_PASS_RAY_SAMPLES = 1 << 15
MAX_PAGE_TABLE_ENTRIES = 1 << 24
#: samples per empty-space cell lookup in the single pass's march (``SKIP_BLOCK``; the per-brick
#: path keeps the shader's default, 8). A SIMD rasteriser (llvmpipe) runs a loop's body with its
#: lanes masked, so each node a ray crosses costs at least one whole block (lookups and samples)
#: whatever its own length, and the last block of a node its full size: with the ray crossing
#: 4-5 merged nodes of 32-64 voxels (the MNI template at 16^3 bricks), blocks of 2 drew the still
#: 32^2 frame at 1.03x the raw caster against 1.24x with blocks of 8, its 512^2 full-resolution
#: frame at 0.90x against 1.15x, the 256^3 head's still 32^2 frame at 0.93x against 1.11x (one
#: process, interleaved; the whole change: tools/bench/bench_march_loops.py). The samples that
#: count are the same (a leap passes transparent samples only), so is the image.
SINGLE_PASS_SKIP_BLOCK = 2
#: entries per row of the page-table texture: a power of two, the shader's row and column of an
#: entry are a shift and a mask (``PT_WIDTH_LOG2``)
PAGE_TABLE_WIDTH_LOG2 = 10
PAGE_TABLE_WIDTH = 1 << PAGE_TABLE_WIDTH_LOG2


class SinglePassPath(DrawPath):
    """Draw the cut as one pass over the volume box through its page table."""

    name = "single-pass"
    wants_order = False  # the page table holds the cut in no order

    def __init__(self, setup: DrawSetup) -> None:
        super().__init__(setup)
        self._pt_tex = None
        # (items, GPU state, page table) of the frame before: kept while the frame loop draws the
        # same cut again (the same merged list) over the same slots, and for a refined frame's passes
        self._table = (None, None, None, None)  # (and the pyramid it is of)
        self._pt_data: np.ndarray | None = None  # what the page-table texture holds now
        self._pt_held = None  # the table whose entries it holds (None: not known to be one)
        self.rows_written = 0  # page-table rows the last frame wrote (0: the table was kept)
        self.tables_updated = 0  # tables updated from the one before, not built (benchmarks and tests)
        self.tables_built = 0  # tables built from nothing (benchmarks and tests)
        self._levels: tuple = (None, [])  # (items, their sorted data levels)
        # (GPU state, region, PageTable.faces) of the last table built: its items' open faces hold
        # while the slots are the same (build_page_table's known_faces)
        self._faces: tuple = (None, None, None)
        # what the frame before drew with: its table's and levels' uniform bytes, the scissor
        # rectangle of its camera, its table's region bound (each kept while what it reads is the same)
        self._uniforms: tuple | None = None
        self._rect: tuple | None = None
        self._regions: tuple = (None, 0)

    def _page_table_texture(self, entries: np.ndarray, changed: np.ndarray | None = None, held=None):
        """The page-table texture (R32UI, :data:`PAGE_TABLE_WIDTH` entries per row) holding
        ``entries``. ``changed``: the entries that differ from ``held``'s (an updated table,
        :func:`~clipvol.scene.page_table.update_page_table`): where the texture holds ``held``,
        only the rectangles of those entries' rows are written. Else the band of rows that
        differ from what it holds is written (a sub-write; none when nothing changed), the whole
        table when it grew or is new."""
        rows = max(1, -(-len(entries) // PAGE_TABLE_WIDTH))
        if changed is not None and held is not None and self._pt_held is held and self._pt_data is not None \
                and self._pt_tex is not None and self._pt_tex.size[1] >= rows:
            self._write_changed(entries, changed)
            return self._pt_tex
        data = np.zeros(rows * PAGE_TABLE_WIDTH, dtype=np.uint32)
        data[:len(entries)] = entries
        grid = data.reshape(rows, PAGE_TABLE_WIDTH)
        if self._pt_tex is None or self._pt_tex.size[1] < rows:
            if self._pt_tex is not None:
                self._pt_tex.release()
            self._pt_tex = self.ctx.texture((PAGE_TABLE_WIDTH, rows), 1, dtype="u4")
            self._pt_tex.filter = (self.mgl.NEAREST, self.mgl.NEAREST)
            self._pt_data = None
        old = self._pt_data
        if old is None or len(old) < rows:
            r0, r1 = 0, rows
        else:
            changed_rows = np.nonzero(np.any(old[:rows] != grid, axis=1))[0]
            r0, r1 = (int(changed_rows[0]), int(changed_rows[-1]) + 1) if len(changed_rows) else (0, 0)
        if r1 > r0:
            self._pt_tex.write(np.ascontiguousarray(grid[r0:r1]).tobytes(), viewport=(0, r0, PAGE_TABLE_WIDTH, r1 - r0))
            if old is None or len(old) < rows:
                old = self._pt_data = np.zeros((self._pt_tex.size[1], PAGE_TABLE_WIDTH), dtype=np.uint32)
            old[r0:r1] = grid[r0:r1]
        self.rows_written = r1 - r0
        return self._pt_tex

    def _upload(self, table, changed: np.ndarray | None = None, prev=None):
        """Make the page-table texture hold ``table`` (its entries ``changed`` from ``prev``'s where
        it was updated from ``prev``: :meth:`_page_table_texture`)."""
        tex = self._page_table_texture(table.entries, changed, prev)
        self._pt_held = table
        self.tables_updated += changed is not None
        self.tables_built += changed is None
        return tex

    def _write_changed(self, entries: np.ndarray, changed: np.ndarray) -> None:
        """Write the ``changed`` entries (sorted) into the texture and its copy: one rectangle per
        run of consecutive rows holding them, spanning their columns (no compare of the table)."""
        held = self._pt_data.reshape(-1)
        held[changed] = entries[changed]
        self.rows_written = 0
        if not len(changed):
            return
        row, col = changed // PAGE_TABLE_WIDTH, changed % PAGE_TABLE_WIDTH
        starts = np.concatenate([[0], np.nonzero(np.diff(row) > 1)[0] + 1])  # runs of consecutive rows
        ends = np.concatenate([starts[1:], [len(row)]])
        for a, b in zip(starts.tolist(), ends.tolist()):
            r0, r1 = int(row[a]), int(row[b - 1]) + 1
            x0, x1 = int(col[a:b].min()), int(col[a:b].max()) + 1
            block = np.ascontiguousarray(self._pt_data[r0:r1, x0:x1])
            self._pt_tex.write(block.tobytes(), viewport=(x0, r0, x1 - x0, r1 - r0))
            self.rows_written += r1 - r0

    def draw(self, frame: FrameContext) -> DrawStats | None:
        """One pass over the volume box through the cut's page table; None when this cut or pyramid
        cannot be drawn that way (the per-brick path then draws it)."""
        mgl, ctx = self.mgl, self.ctx
        cam, items, params, pyr, cache = frame.camera, frame.items, frame.params, frame.pyramid, frame.cache
        nlev = pyr.num_levels
        if nlev > MAX_SINGLE_PASS_LEVELS:
            return None
        vlo, vhi = pyr.volume_box()
        arr = DrawItems.from_items(items)  # the merged cut's arrays (no DrawItem objects made)
        if self._levels[0] is not items:  # the data levels of the cut (kept with a kept cut's list)
            self._levels = (items, np.unique(arr.rows[:, 0]).tolist())
        data_levels = self._levels[1]  # only these get a march in the shader's level chain
        finest = params.step * min(float(min(pyr.levels[L].scale)) for L in data_levels)
        if float(np.linalg.norm(vhi - vlo)) / finest > MAX_SINGLE_PASS_RAY_SAMPLES:
            return None
        # items come merged (complete sibling sets are one node of the table, no face inside)
        # the table of the frame before, where the cut and the slots are the same: a refined frame's
        # later pass, or a cut the frame loop drew again (the same merged list object)
        state = (cache.generation, frame.residency_version)
        again = self._table[0] is items and (frame.repeats_pass or self._table[1] == state)
        changed = prev = None
        if again:
            table = self._table[2]
        else:
            region = getattr(cache, "region", None)  # (open faces read it too)
            known = self._faces[2] if self._faces[0] == state and self._faces[1] is region else None
            # updated from the frame before's where its layout holds (the entries that changed)
            prev = self._table[2] if self._table[3] is pyr else None
            hold = known is not None and prev is not None and prev.faces is known  # (prev's faces: these slots)
            table, changed = update_page_table(prev, items, pyr, cache.open_faces, known_faces=known, faces_hold=hold)
            if table is not None:
                self._faces = (state, region, table.faces)
        self._table = (items, state, table, pyr)
        if table is None or len(table.entries) > MAX_PAGE_TABLE_ENTRIES:
            return None
        fbo, previous, t0 = self.setup.begin(frame, mode_of(params.mode).clear)
        defines = dict(frame.defines, NUM_LEVELS=nlev, LEVEL_LO=min(data_levels), LEVEL_HI=max(data_levels),
                       PT_WIDTH_LOG2=PAGE_TABLE_WIDTH_LOG2, SKIP_BLOCK=SINGLE_PASS_SKIP_BLOCK)
        prog, vao = self.setup.program("screen.vert", "raymarch.frag", defines)
        origin = self.setup.frame_uniforms(prog, frame)
        uset(prog, "u_vol_lo", vec3(vlo - origin))
        uset(prog, "u_vol_hi", vec3(vhi - origin))
        sp = np.array(pyr.spacing[::-1], dtype=np.float64)
        B = np.array(pyr.brick_shape[::-1], dtype=np.float64)
        uniforms = self._table_uniforms(frame, table, origin)
        for name, data in uniforms.items():
            u = prog.get(name, None)
            if u is not None:  # a variant may keep only an array's first elements (the levels it draws)
                u.write(data[:len(data) // nlev * max(1, u.array_length)])
        uset(prog, "u_brick", vec3(B))
        uset(prog, "u_top", nlev - 1)
        uset(prog, "u_nudge", 1e-3 * float(sp.min()))
        uset(prog, "u_max_regions", self._max_regions(pyr, table, items, arr, vlo, vhi))
        self.setup.loop_uniforms(prog)
        uset(prog, "u_page_table", 2)
        uset(prog, "u_tf", 1)
        if again and self._pt_data is not None:
            self.rows_written = 0
        else:
            self._upload(table, None if again else changed, prev)
        self._pt_tex.use(location=2)
        if mode_of(params.mode).classifies:
            self.setup.tf_texture(frame).use(location=1)
        self.setup.bind_distribution(prog, frame)
        self.setup.bind_occupancy(prog, frame)
        for L, tex in enumerate(cache.textures):
            if tex is not None:
                uset(prog, f"u_level{L}", 3 + L)
                tex.use(location=3 + L)
        ctx.disable(mgl.BLEND | mgl.CULL_FACE)
        self.setup.depth_test(frame)  # on only in the fine pass of a refined frame
        rect = self._scissor(cam, vlo, vhi)
        if rect[2] and rect[3]:  # else the volume is off the image: nothing to draw
            ctx.scissor = tuple(rect)
            vao.render(mgl.TRIANGLES, vertices=3)
            ctx.scissor = None
        return self.setup.read_back(frame, previous, mode_of(params.mode).classifies, t0, boxes_drawn=1,
                                    page_table_nodes=len(items), program=prog)

    def _scissor(self, cam, vlo, vhi):
        """The scissor rectangle of the volume's box, kept while the camera (the same object: a
        still view) and the pass's origin in the target are the same."""
        key = (cam, tuple(int(v) for v in self.setup.origin))
        kept = self._rect
        if kept is not None and kept[0][0] is cam and kept[0][1] == key[1]:
            return kept[1]
        rect = self.setup.scissor_rects(cam, vlo, vhi)[0]
        self._rect = (key, rect)
        return rect

    def _max_regions(self, pyr, table, items, arr, vlo, vhi) -> int:
        """The most regions a ray crosses: 1 where the table holds one DRAWN node whose box is the
        volume's (a merged resident cut), else a bound from the grids (kept with the table)."""
        if self._regions[0] is table:
            return self._regions[1]
        one = int(np.sum((table.entries & 3) == 2)) == 1 and len(items) == 1 and np.allclose(arr.lo[0], vlo) \
            and np.allclose(arr.hi[0], vhi)
        n = 1 if one else int(16 + sum(sum(pyr.grid(L)) for L in range(pyr.num_levels)))
        self._regions = (table, n)
        return n

    def _table_uniforms(self, frame: FrameContext, table, origin) -> dict:
        """The page table's and the levels' uniform bytes, kept while the table's layout (its
        boxes, bases and data bricks: all they read of it; an updated table keeps them), the origin
        they are relative to, the step and the GPU windows are the same (a still view; a kept
        cut's table); the empty-space cells' are asked every frame."""
        key = (origin.tobytes(), frame.params.step, tuple(None if w is None else tuple(w) for w in frame.cache.windows))
        layout = b"".join(np.ascontiguousarray(a).tobytes() for a in (table.base, table.c0, table.size, table.d0))
        kept = self._uniforms
        if kept is not None and kept[0] == layout and kept[1] == key and kept[2] is frame.cache \
                and kept[3] is frame.pyramid:
            uniforms = kept[4]
        else:
            uniforms = self._level_uniforms(frame, table, origin)
            self._uniforms = (layout, key, frame.cache, frame.pyramid, uniforms)
        if frame.skipped_empty:  # (the empty-space cells' layout: asked every frame)
            f32 = lambda v: np.ascontiguousarray(v, dtype=np.float32).tobytes()  # noqa: E731
            occ = [self.setup.occupancy_uniforms(frame, L) for L in range(frame.pyramid.num_levels)]
            uniforms = dict(uniforms, u_lv_occ_size=f32([o[0] for o in occ]), u_lv_occ_z0=f32([o[1] for o in occ]))
        return uniforms

    def _level_uniforms(self, frame: FrameContext, table, origin) -> dict:
        """The page table's and the levels' uniform bytes (:meth:`_table_uniforms`)."""
        params, pyr, cache = frame.params, frame.pyramid, frame.cache
        nlev = pyr.num_levels
        vlo, _ = pyr.volume_box()
        sp = np.array(pyr.spacing[::-1], dtype=np.float64)
        B = np.array(pyr.brick_shape[::-1], dtype=np.float64)
        c0 = table.c0[:, ::-1].astype(np.float64)  # (nlev, 3) x, y, z
        ext = np.array([B * 2.0**L * sp for L in range(nlev)])
        scale = np.array([lv.scale[::-1] for lv in pyr.levels], dtype=np.float64)
        trans = np.array([lv.translation[::-1] for lv in pyr.levels], dtype=np.float64)
        win = np.array([(wnd[::-1] if wnd is not None else (1, 1, 1)) for wnd in cache.windows], dtype=np.float64)
        f32 = lambda v: np.ascontiguousarray(v, dtype=np.float32).tobytes()  # noqa: E731
        i32 = lambda v: np.ascontiguousarray(v, dtype=np.int32).tobytes()  # noqa: E731
        uniforms = {
            "u_pt_base": i32(table.base), "u_pt_size": i32(table.size[:, ::-1]), "u_pt_c0": i32(table.c0[:, ::-1]),
            "u_pt_origin": f32(vlo + c0 * ext - origin), "u_pt_ext": f32(ext),
            "u_lv_d0": i32(table.d0[:, ::-1]), "u_lv_grid": i32([pyr.grid(L)[::-1] for L in range(nlev)]),
            "u_lv_vox0": f32(trans + table.d0[:, ::-1] * B * scale - origin), "u_lv_inv_scale": f32(1.0 / scale),
            "u_lv_win": i32(win), "u_lv_inv_tex_size": f32(1.0 / (win * B)),
            "u_lv_delta": f32([params.step * float(min(lv.scale)) for lv in pyr.levels]),
        }
        return uniforms

    def release(self) -> None:
        if self._pt_tex is not None:
            self._pt_tex.release()
        self._pt_tex = None
        self._pt_data = None
        self._pt_held = None
        self._table = (None, None, None, None)
        self._faces = (None, None, None)
