"""What a zarr store holds, from its metadata: a clipvol store, or a plain OME-Zarr 0.4 / 0.5 image.

Why apart from reading: interpreting the metadata is done once, on opening, and decides everything
the read path then takes for granted - the pyramid, the array of each stored level, the leading
(time / channel) index to read, the world placement. A clipvol store's ``attrs['clipvol']`` is
parsed by :func:`clipvol.bricking.store.parse_metadata` and each level's array must match it
(its manifest is then verified by :meth:`IntegrityChecks._verify_manifest`). A plain OME-Zarr
image (0.4: ``multiscales`` at the top level of the attributes, usually zarr v2; 0.5: under
``"ome"``): the level-0 chunk shape is the brick shape; leading (time / channel) axes must have
size 1 per read (``t``, ``c`` choose one). A stored level is used only if it is the 2x (ceil)
down-sample of the previous one with the same chunk shape; from the first level that does not
conform, coarser levels are computed (:mod:`clipvol.loaders.zarr_levels`) with the image's filter
(its ``multiscales`` ``type`` if it is ``mean``, ``max`` or ``subsample``, else ``mean``). The value
range comes from ``omero.window`` (``min``/``max``), else the dtype's range for integers, else the
finite range of the coarsest stored level (sampled).

A mixin of :class:`~clipvol.loaders.zarr_store.ZarrLoader`: it sets the loader's own attributes
(``_arrays``, ``_pyramid``, ``_stored``, ...), which the read path uses without indirection.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from clipvol.bricking.pyramid import FILTERS, Int3, LevelInfo, Pyramid, level_shapes, level_transform
from clipvol.bricking.store import parse_metadata
from clipvol.bricking.store_files import StoreFileError
from clipvol.errors import InputFormatError, ParameterError, StoreFormatError, StoreIncompleteError

from .zarr_meta import ArrayMeta, array_meta, group_attributes, inside

__all__ = ["StoreOpening"]


class StoreOpening:
    """Opening a clipvol store (:meth:`_open_clipvol`) or a plain OME-Zarr image (:meth:`_open_ome`)."""

    def _open_set_member(self, axis: str, n: int) -> None:
        """Member ``t`` or ``c`` (default 0) of an image set written by ``clipvol brick`` of a 4-D
        input (:mod:`clipvol.bricking.channels`): its clipvol metadata, statistics and manifest from
        its member group, its bricks from the root's 4-D arrays at that index (chunks ``(1, b, b, b)``
        whose bytes are the member's 3-D chunks)."""
        from clipvol.bricking.channels import MEMBER_ATTR, member_path

        kind = "a channel set: c, z, y, x" if axis == "c" else "a time series: t, z, y, x"
        for name, v in self._want.items():
            if name != axis and v not in (None, 0):
                raise ParameterError(f"{name}: {self._where} has no {name!r} axis ({kind}), got {name}={v}")
        k = self._want[axis] or 0
        if isinstance(k, bool) or int(k) != k or not 0 <= k < n:
            what = "channels" if axis == "c" else "time steps"
            raise ParameterError(f"{axis}: expected 0..{n - 1} for {self._where} ({n} {what}), got {k!r}")
        k = int(k)
        self.meta_path = member_path(self.path, axis, k)
        where = f"{self._where} ({axis} = {k})"
        try:
            attrs = group_attributes(self.meta_path, where)
        except FileNotFoundError:
            raise InputFormatError(f"{where}: the member group {self.meta_path} is missing") from None
        mark = attrs.get(MEMBER_ATTR)
        if not isinstance(mark, dict) or mark.get("axis") != axis or mark.get("index") != k:
            raise InputFormatError(f"{where}: {self.meta_path} is not member {k} of the set "
                                   f"(attributes[{MEMBER_ATTR!r}] = {mark!r})")
        self._want = {"t": None, "c": None}  # consumed here
        self._chunk_lead, self._select = (k,), (k,)
        self._open_clipvol(attrs, lead=n)
        self.axes, self.lead_shape = (axis,), (n,)

    def _open_clipvol(self, attrs: dict, lead: int | None = None) -> None:
        """A clipvol store: its pyramid as ``attrs['clipvol']`` records it, each level's array
        checked against it (shape, chunks, dtype), then its manifest verified. An interrupted build
        is refused unless ``allow_incomplete`` (repair and resume open such stores). ``lead``: the
        length of the leading axis of an image set's arrays (``_open_set_member``); each level is then
        read as the 3-D view at ``_chunk_lead``. Before any of it, the metadata the manifest pins
        (each level's arrays, the multiscale transforms) is compared with the store's files
        (:meth:`IntegrityChecks._check_pinned_metadata`): the level descriptions everything after
        this trusts must be the ones the build wrote. (A set member's manifest pins its statistics'
        metadata; the set's 4-D level arrays at the root are not pinned by it.)"""
        from clipvol.bricking.channels import MEMBER_ATTR

        if lead is None and MEMBER_ATTR in attrs:
            mark = attrs[MEMBER_ATTR] if isinstance(attrs[MEMBER_ATTR], dict) else {}
            root = self.path.parent.parent.parent
            raise InputFormatError(f"{self._where}: member {mark.get('index')!r} of the image set {root}, not a store "
                                   f"by itself (its bricks are the set's); open {root} with "
                                   f"{mark.get('axis', 'c')}={mark.get('index', 0)!r}")
        self._check_pinned_metadata(attrs)
        meta = parse_metadata(attrs, self._where)
        if not meta.complete and not self._allow_incomplete:
            raise StoreIncompleteError(
                f"{self._where}: the store is incomplete (attrs['clipvol']['complete'] is false): its build was "
                "interrupted; re-run `clipvol brick` with the same arguments to resume it"
            )
        pyr = meta.pyramid
        self.frame = meta.frame  # the source's voxel-to-world affine (NIfTI, DICOM, ...) or None
        self.origin, self.unit = tuple(float(v) for v in meta.origin), meta.unit
        self.is_clipvol_store = True
        self._lead = 0
        for name, v in self._want.items():
            if v is not None and v != 0:
                raise ParameterError(f"{name}: this store has no {name!r} axis (a 3-D clipvol store), got {name}={v}")
        self._arrays: list[ArrayMeta] = []
        head = () if lead is None else (lead,)
        for L, lv in enumerate(pyr.levels):
            where = f"{self._where} level {L}"
            am = array_meta(self.path / str(L), where, self.path)
            if am.shape != head + lv.shape or am.chunks != (1,) * len(head) + pyr.brick_shape or am.shard is not None:
                raise StoreFormatError(f"{where}: expected shape {list(head + lv.shape)} and chunks "
                                       f"{list((1,) * len(head) + pyr.brick_shape)} (unsharded), got {list(am.shape)} "
                                       f"and {list(am.chunks)}")
            if head:  # the member's 3-D view: a (1, b, b, b) chunk holds the bytes of a (b, b, b) one
                am = replace(am, shape=am.shape[1:], chunks=am.chunks[1:])
            if am.shape != lv.shape or am.chunks != pyr.brick_shape:
                raise StoreFormatError(f"{where}: expected shape {list(lv.shape)} and chunks {list(pyr.brick_shape)}, "
                                       f"got {list(am.shape)} and {list(am.chunks)}")
            if am.dtype.newbyteorder("=") != pyr.dtype.newbyteorder("="):
                raise StoreFormatError(f"{where}: expected dtype {pyr.dtype}, got {am.dtype}")
            self._arrays.append(am)
        self._pyramid = replace(pyr, dtype=pyr.dtype.newbyteorder("="))
        self._stored = pyr.num_levels
        self._verify_manifest(attrs["clipvol"], warn=meta.complete or not self._allow_incomplete)

    def _open_ome(self, attrs: dict) -> None:
        """A plain OME-Zarr image: the stored levels that conform (see the module's docstring), the
        rest computed; its value range read or, for floats without ``omero.window``, sampled."""
        ome = attrs.get("ome") if isinstance(attrs.get("ome"), dict) else attrs
        ms_list = ome.get("multiscales")
        if not isinstance(ms_list, list) or not ms_list or not isinstance(ms_list[0], dict):
            raise InputFormatError(f"{self._where}: neither a clipvol store nor an OME-Zarr image "
                                   "(no 'clipvol' attributes and no 'multiscales' metadata)")
        ms = ms_list[0]
        datasets = ms.get("datasets")
        if not isinstance(datasets, list) or not datasets or not all(isinstance(d, dict) and isinstance(d.get("path"), str) for d in datasets):
            raise InputFormatError(f"{self._where}: OME-Zarr 'multiscales'[0]['datasets'] is malformed")
        self.is_clipvol_store = False
        self.trust = "unverified, foreign: an OME-Zarr image not written by clipvol brick (no manifest)"
        self.frame = None  # a plain OME-Zarr image: no affine beyond scale and translation
        first = array_meta(inside(self.path, datasets[0]["path"], f"{self._where} level 0"), f"{self._where} level 0",
                            self.path)
        nd = len(first.shape)
        if nd < 3 or nd > 5:
            raise InputFormatError(f"{self._where}: expected an image (t, c, z, y, x) with 3 to 5 axes, got shape "
                                   f"{list(first.shape)}")
        self._lead = nd - 3
        self._choose_lead(ms, first)
        brick: Int3 = tuple(first.chunks[-3:])  # type: ignore[assignment]
        expect = level_shapes(first.shape[-3:], brick)
        arrays = [first]
        for L, ds in enumerate(datasets[1:len(expect)], start=1):
            lpath = inside(self.path, ds["path"], f"{self._where} level {L}")  # outside the store: an error, not a skip
            try:
                am = array_meta(lpath, f"{self._where} level {L}", self.path)
            except StoreFileError:
                raise  # a level file that is not what it claims is refused, never skipped
            except (InputFormatError, FileNotFoundError):
                break
            if am.shape[-3:] != expect[L] or am.chunks[-3:] != brick or am.dtype != first.dtype or len(am.shape) != nd:
                break
            arrays.append(am)
        self._arrays = arrays
        self._stored = len(arrays)
        shapes = [a.shape[-3:] for a in arrays]
        filt = ms.get("type") if ms.get("type") in FILTERS else "mean"
        infos = self._ome_levels(ms, shapes)
        for L in range(len(infos), len(expect)):  # derived levels: transform of the filter from level 0
            scale, shift = level_transform(L, infos[0].scale, filt)
            infos.append(LevelInfo(expect[L], scale, tuple(t + d for t, d in zip(infos[0].translation, shift))))
        dtype = first.dtype.newbyteorder("=")
        vr = self._ome_value_range(ome, dtype)
        fill = first.fill_value if math.isfinite(first.fill_value) else 0.0
        self._pyramid = Pyramid(tuple(infos), brick, dtype, vr or (0.0, 0.0), fill, filt)
        if vr is None:
            self._prepare_hot_path()  # _coarsest_range reads bricks
            self._pyramid = replace(self._pyramid, value_range=self._coarsest_range())

    def _choose_lead(self, ms: dict, first: "ArrayMeta") -> None:
        """Resolve the requested ``t``/``c`` against the leading axes named in the metadata."""
        axes = ms.get("axes")
        names = []
        if isinstance(axes, list) and len(axes) == len(first.shape):
            names = [a.get("name") if isinstance(a, dict) else a for a in axes][: self._lead]
        if len(names) != self._lead or not all(isinstance(n, str) for n in names):
            names = ["t", "c"][2 - self._lead:] if self._lead else []  # OME order: t before c
        for name, v in self._want.items():
            if v is not None and name not in names and v != 0:
                raise ParameterError(f"{name}: {self._where} has no {name!r} axis (axes {names + ['z', 'y', 'x']}), "
                                     f"got {name}={v}")
        sel = []
        for name, size in zip(names, first.shape[: self._lead]):
            v = self._want.get(name) or 0
            if isinstance(v, bool) or int(v) != v or not 0 <= v < size:
                raise ParameterError(f"{name}: expected 0..{size - 1} for {self._where}, got {v!r}")
            sel.append(int(v))
        self._select = tuple(sel)
        lead_chunks = first.chunks[: self._lead]
        self._chunk_lead = tuple(v // ch for v, ch in zip(sel, lead_chunks))
        self._within = tuple(v % ch for v, ch in zip(sel, lead_chunks))
        self.axes = tuple(names)
        self.lead_shape = tuple(first.shape[: self._lead])

    def _ome_levels(self, ms: dict, shapes: list) -> list[LevelInfo]:
        out = []
        try:
            for ds, shape in zip(ms["datasets"], shapes):
                tr = {t["type"]: t for t in ds.get("coordinateTransformations", [])}
                sc = [float(v) for v in tr["scale"]["scale"]][-3:] if "scale" in tr else [1.0, 1.0, 1.0]
                tl = [float(v) for v in tr["translation"]["translation"]][-3:] if "translation" in tr else [0.0] * 3
                out.append(LevelInfo(shape, tuple(sc), tuple(tl)))
        except (KeyError, TypeError, ValueError) as e:
            raise InputFormatError(f"{self._where}: OME-Zarr coordinateTransformations are malformed ({type(e).__name__}: {e})") from None
        return out

    def _ome_value_range(self, ome: dict, dtype: np.dtype) -> tuple[float, float] | None:
        omero = ome.get("omero")
        chans = omero.get("channels") if isinstance(omero, dict) else None
        ci = self._select[self.axes.index("c")] if "c" in self.axes else 0
        first = chans[ci] if isinstance(chans, list) and len(chans) > ci else None
        win = first.get("window") if isinstance(first, dict) else None  # written by other tools: trust nothing
        if isinstance(win, dict):
            try:
                lo, hi = float(win["min"]), float(win["max"])
                if math.isfinite(lo) and math.isfinite(hi) and lo <= hi:
                    return lo, hi
            except (KeyError, TypeError, ValueError):
                pass
        if dtype.kind in "iu":
            info = np.iinfo(dtype)
            return float(info.min), float(info.max)
        return None

    def _coarsest_range(self, max_bricks: int = 64) -> tuple[float, float]:
        """Finite range of the coarsest *stored* level (levels derived on demand would read the
        whole volume), from at most ``max_bricks`` bricks spread evenly over it: an estimate, good
        enough to normalise a transfer function, that never makes opening a large image slow."""
        L = self._stored - 1
        lo, hi = math.inf, -math.inf
        g = self._pyramid.grid(L)
        n = math.prod(g)
        picks = np.unique(np.linspace(0, n - 1, min(n, max_bricks)).round().astype(np.int64))
        for idx in zip(*np.unravel_index(picks, g)):
            start, stop = self._pyramid.brick_voxel_box(L, idx)
            b = self.read_brick(L, idx)[tuple(slice(0, e - s) for s, e in zip(start, stop))]
            f = b[np.isfinite(b)]
            if f.size:
                lo, hi = min(lo, float(f.min())), max(hi, float(f.max()))
        return (lo, hi) if lo <= hi else (0.0, 0.0)
