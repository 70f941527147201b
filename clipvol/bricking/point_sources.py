"""Point inputs of ``clipvol brick-points``: scattered points with scalar values, read in chunks.

A :class:`PointSource` hands out its points as chunks ``(xyz, values)``: ``xyz`` ``(n, 3)``
float64 world ``(x, y, z)`` and ``values`` ``(n, k)`` float32, one column per value name. The
octree build (:mod:`clipvol.bricking.points`) streams every source twice (bounds, then partition),
so no source is ever held in memory whole, except the formats whose reader cannot stream (a mesh
through ``meshio``, which reads the whole file; ``.ply`` through ``plyfile``, memory-mapped for
binary files). Formats:

* ``.npy``: an ``(N, 3 + k)`` float array (columns ``x, y, z`` then the values, named
  ``v0, v1, ...`` unless named on the command line) or a structured array with fields ``x, y, z``;
  read with positional file reads (no memory map, so resident memory does not grow with N).
* ``.csv`` (pandas, chunked) and ``.parquet`` (pyarrow, by record batch): columns named on the
  command line (``x, y, z`` by default).
* ``.ply``: vertex properties ``x, y, z`` and the named values.
* unstructured meshes (``.vtu``, ``.vtk``, ``.xdmf``, ``.msh``, ...) through ``meshio``: the mesh's
  vertices and their point data (connectivity is discarded, as in Meredith & Ma's method).
* :class:`ClusteredPointSource`: procedural clustered points (a particle simulation's look) for
  tests and benchmarks, generated chunk by chunk from a seed.

Every error a user can cause names the file and what was expected: a missing column (with the
columns that exist), NaN, infinite or absurd (beyond :data:`MAX_COORDINATE`) coordinates (with
the first bad row), an empty input.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

#: largest coordinate magnitude accepted: the store keeps float32 offsets from the cube's origin
#: (float32 ends at 3.4e38) and the octree squares distances in float64 (which ends at 1.8e308:
#: 1e300 would square to inf); 1e30 keeps both finite with room for the cube's extent
MAX_COORDINATE = 1e30

from ..errors import InputFormatError, InputNotFoundError, ParameterError
from .formats import require

__all__ = [
    "PointSource",
    "ArrayPointSource",
    "NpyPointSource",
    "CsvPointSource",
    "ParquetPointSource",
    "PlyPointSource",
    "MeshPointSource",
    "ClusteredPointSource",
    "open_point_source",
    "MESH_SUFFIXES",
]

#: rows per chunk handed to the octree build
CHUNK_ROWS = 1 << 20
MESH_SUFFIXES = (".vtu", ".vtk", ".xdmf", ".xmf", ".msh", ".vtp", ".med", ".inp", ".mesh", ".obj", ".off", ".stl")

Chunk = tuple[np.ndarray, np.ndarray]


class PointSource:
    """Points with values, read chunk by chunk.

    Attributes
    ----------
    name : str
        The input (a path or a description) that errors name.
    value_names : tuple of str
        One name per value column.
    count : int
        Number of points.
    """

    name: str = ""
    value_names: tuple[str, ...] = ()
    count: int = 0

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        """Yield ``(xyz float64 (n, 3), values float32 (n, k))`` chunks covering every point once."""
        raise NotImplementedError

    def _chunk(self, xyz, values, first_row: int) -> Chunk:
        """Validate one chunk: finite coordinates, float types; names the file and the first bad row."""
        xyz = np.ascontiguousarray(xyz, dtype=np.float64).reshape(-1, 3)
        values = np.ascontiguousarray(values, dtype=np.float32).reshape(len(xyz), len(self.value_names))
        with np.errstate(invalid="ignore"):
            bad = ~np.all(np.isfinite(xyz) & (np.abs(xyz) <= MAX_COORDINATE), axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputFormatError(
                f"{self.name}: expected finite x, y, z coordinates of magnitude <= {MAX_COORDINATE:g}, "
                f"got {tuple(float(v) for v in xyz[i])} at row {first_row + i}"
            )
        return xyz, values


def _pick(name: str, available: Sequence[str], wanted: Sequence[str], what: str) -> None:
    missing = [w for w in wanted if w not in available]
    if missing:
        raise InputFormatError(
            f"{name}: no {what} named {', '.join(repr(m) for m in missing)}; it has {', '.join(map(str, available)) or 'none'}"
        )


def _check_nonempty(src: PointSource) -> None:
    if src.count < 1:
        raise InputFormatError(f"{src.name}: expected at least one point, got an empty input")
    if not src.value_names:
        raise InputFormatError(f"{src.name}: expected at least one value column besides x, y, z; name one with --value")


class ArrayPointSource(PointSource):
    """Points already in memory (tests, small data): ``xyz`` ``(n, 3)`` and ``values`` ``(n, k)``."""

    def __init__(self, xyz, values, value_names: Sequence[str] | None = None, name: str = "array") -> None:
        self.xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        v = np.asarray(values, dtype=np.float32)
        if v.ndim == 1:
            v = v[:, None]
        if len(v) != len(self.xyz):
            raise ParameterError(f"{name}: expected one value row per point, got {len(v)} values for {len(self.xyz)} points")
        self.values = v
        self.name = name
        self.value_names = tuple(value_names) if value_names else tuple(f"v{i}" for i in range(v.shape[1]))
        self.count = len(self.xyz)
        _check_nonempty(self)

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        for a in range(0, self.count, rows):
            yield self._chunk(self.xyz[a:a + rows], self.values[a:a + rows], a)


class NpyPointSource(PointSource):
    """A ``.npy`` file: ``(N, 3 + k)`` floats or a structured array with ``x, y, z`` fields."""

    def __init__(self, path, value_names: Sequence[str] | None = None, xyz_names=("x", "y", "z")) -> None:
        self.path = Path(path)
        self.name = str(path)
        from .npy import npy_header

        shape, dtype, fortran, self._offset = npy_header(self.path)  # not a .npy, objects, truncated: one line
        if fortran:
            raise InputFormatError(f"{path}: expected a C-ordered .npy array, got a Fortran-ordered one")
        self._dtype = dtype
        if dtype.fields is not None:
            fields = list(dtype.names)
            _pick(self.name, fields, list(xyz_names), "coordinate field")
            vals = list(value_names) if value_names else [n for n in fields if n not in xyz_names]
            _pick(self.name, fields, vals, "value field")
            self._xyz_fields, self._value_fields = list(xyz_names), vals
            self.value_names = tuple(vals)
            self.count = int(shape[0]) if shape else 0
            self._cols = None
        else:
            if dtype.kind not in "iuf" or len(shape) != 2 or shape[1] < 3:
                raise InputFormatError(
                    f"{path}: expected an (N, 3 + k) numeric array or a structured array with x, y, z fields, "
                    f"got shape {shape} dtype {dtype}"
                )
            k = shape[1] - 3
            self._ncols = int(shape[1])
            # plain columns are named v0, v1, ...; --value v2 picks column 3 + 2
            avail = [f"v{i}" for i in range(k)]
            names = list(value_names) if value_names else avail
            _pick(self.name, avail, names, "value column")
            self._cols = [avail.index(n) for n in names]
            self.value_names = tuple(names)
            self.count = int(shape[0])
        _check_nonempty(self)

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        structured = self._dtype.fields is not None
        row_items = 1 if structured else self._ncols
        row_bytes = self._dtype.itemsize * row_items
        with open(self.path, "rb") as f:
            for a in range(0, self.count, rows):
                n = min(rows, self.count - a)
                f.seek(self._offset + a * row_bytes)
                block = np.fromfile(f, dtype=self._dtype, count=n * row_items)
                if len(block) != n * row_items:
                    raise InputFormatError(f"{self.name}: file ends inside row {a + len(block) // row_items}, "
                                           f"expected {self.count} rows")
                if structured:
                    xyz = np.stack([block[c] for c in self._xyz_fields], axis=1)
                    vals = np.stack([block[c] for c in self._value_fields], axis=1)
                else:
                    block = block.reshape(n, row_items)
                    xyz = block[:, :3]
                    vals = block[:, [3 + c for c in self._cols]]
                yield self._chunk(xyz, vals, a)


class CsvPointSource(PointSource):
    """A ``.csv`` file with a header row, read ``rows`` at a time with pandas."""

    def __init__(self, path, value_names: Sequence[str], xyz_names=("x", "y", "z")) -> None:
        pd = require("pandas", "points")

        self.path, self.name = Path(path), str(path)
        header = list(pd.read_csv(self.path, nrows=0).columns)
        self._xyz = list(xyz_names)
        _pick(self.name, header, self._xyz, "coordinate column")
        vals = list(value_names) if value_names else [c for c in header if c not in self._xyz]
        _pick(self.name, header, vals, "value column")
        self.value_names = tuple(vals)
        self.count = sum(len(c) for c in pd.read_csv(self.path, usecols=[self._xyz[0]], chunksize=CHUNK_ROWS))
        _check_nonempty(self)

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        pd = require("pandas", "points")

        a = 0
        for df in pd.read_csv(self.path, usecols=self._xyz + list(self.value_names), chunksize=rows):
            try:
                xyz = df[self._xyz].to_numpy(dtype=np.float64)
                vals = df[list(self.value_names)].to_numpy(dtype=np.float32)
            except ValueError as e:
                raise InputFormatError(f"{self.name}: expected numeric columns near row {a}: {e}") from None
            yield self._chunk(xyz, vals, a)
            a += len(df)


class ParquetPointSource(PointSource):
    """A ``.parquet`` file, read one record batch at a time with pyarrow."""

    def __init__(self, path, value_names: Sequence[str], xyz_names=("x", "y", "z")) -> None:
        pq = require("pyarrow.parquet", "points")

        self.path, self.name = Path(path), str(path)
        self._file = pq.ParquetFile(self.path)
        cols = list(self._file.schema_arrow.names)
        self._xyz = list(xyz_names)
        _pick(self.name, cols, self._xyz, "coordinate column")
        vals = list(value_names) if value_names else [c for c in cols if c not in self._xyz]
        _pick(self.name, cols, vals, "value column")
        self.value_names = tuple(vals)
        self.count = int(self._file.metadata.num_rows)
        _check_nonempty(self)

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        a = 0
        for batch in self._file.iter_batches(batch_size=rows, columns=self._xyz + list(self.value_names)):
            xyz = np.stack([batch.column(c).to_numpy(zero_copy_only=False) for c in self._xyz], axis=1)
            vals = np.stack([batch.column(c).to_numpy(zero_copy_only=False) for c in self.value_names], axis=1)
            yield self._chunk(xyz, vals, a)
            a += len(xyz)


class PlyPointSource(PointSource):
    """A ``.ply`` file's ``vertex`` element (binary files are memory-mapped by plyfile)."""

    def __init__(self, path, value_names: Sequence[str], xyz_names=("x", "y", "z")) -> None:
        PlyData = require("plyfile", "points").PlyData

        self.path, self.name = Path(path), str(path)
        try:
            ply = PlyData.read(str(self.path), mmap=True)
        except Exception as e:  # plyfile raises several types for a malformed header
            raise InputFormatError(f"{path}: not a readable .ply file ({type(e).__name__}: {e})") from None
        if "vertex" not in ply:
            raise InputFormatError(f"{path}: expected a 'vertex' element, got {', '.join(e.name for e in ply.elements)}")
        self._v = ply["vertex"].data
        props = list(self._v.dtype.names)
        self._xyz = list(xyz_names)
        _pick(self.name, props, self._xyz, "vertex property")
        vals = list(value_names) if value_names else [p for p in props if p not in self._xyz and p not in ("nx", "ny", "nz")]
        _pick(self.name, props, vals, "vertex property")
        self.value_names = tuple(vals)
        self.count = len(self._v)
        _check_nonempty(self)

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        for a in range(0, self.count, rows):
            b = self._v[a:a + rows]
            yield self._chunk(np.stack([b[c] for c in self._xyz], axis=1), np.stack([b[c] for c in self.value_names], axis=1), a)


class MeshPointSource(PointSource):
    """An unstructured mesh read by ``meshio``: its vertices and their point data.

    ``meshio`` reads the whole file, so this source is bounded by memory (say so to users with
    meshes larger than memory: convert to ``.parquet`` or ``.npy`` first).
    """

    def __init__(self, path, value_names: Sequence[str]) -> None:
        meshio = require("meshio", "points")

        self.path, self.name = Path(path), str(path)
        try:
            mesh = meshio.read(str(self.path))
        except Exception as e:  # meshio raises ReadError, KeyError, ValueError... for bad files
            raise InputFormatError(f"{path}: meshio could not read it ({type(e).__name__}: {e})") from None
        data = {k: np.asarray(v) for k, v in mesh.point_data.items()}
        vals = list(value_names) if value_names else [k for k, v in data.items() if v.ndim == 1]
        _pick(self.name, list(data), vals, "point data array")
        for k in vals:
            if data[k].ndim != 1 and not (data[k].ndim == 2 and data[k].shape[1] == 1):
                raise InputFormatError(f"{path}: point data {k!r} has shape {data[k].shape}; expected one scalar per vertex")
        pts = np.asarray(mesh.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise InputFormatError(f"{path}: expected 2-D or 3-D vertices, got shape {pts.shape}")
        if pts.shape[1] == 2:
            pts = np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)
        self._xyz = pts
        self._vals = np.stack([data[k].reshape(-1) for k in vals], axis=1) if vals else np.zeros((len(pts), 0))
        self.value_names = tuple(vals)
        self.count = len(pts)
        _check_nonempty(self)

    def chunks(self, rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
        for a in range(0, self.count, rows):
            yield self._chunk(self._xyz[a:a + rows], self._vals[a:a + rows], a)


class ClusteredPointSource(PointSource):
    """Procedural clustered points, like the particles of a cosmology or plasma simulation.

    ``count`` points in ``[0, 1]^3``: a fraction in Gaussian clusters of varied size (centres and
    widths drawn from ``seed``), the rest uniform background. The value is the local density
    proxy ``exp(-r^2 / 2 s^2)`` of the nearest cluster, so it is smooth in space. Chunk ``i`` is
    generated from ``(seed, i)``: two passes give the same points without storing them.
    """

    def __init__(self, count: int, seed: int = 0, clusters: int = 64, background: float = 0.2,
                 chunk_rows: int = CHUNK_ROWS) -> None:
        if int(count) < 1:
            raise ParameterError(f"count: expected >= 1 points, got {count}")
        self.count = int(count)
        self.seed = int(seed)
        self.name = f"clustered:{count}"
        self.value_names = ("density",)
        self._rows = int(chunk_rows)
        g = np.random.default_rng(self.seed)
        self._c = g.uniform(0.15, 0.85, (clusters, 3))
        self._s = 0.01 * np.exp(g.uniform(0.0, 2.0, clusters))
        self._w = g.dirichlet(np.ones(clusters))
        self._bg = float(background)

    def chunks(self, rows: int | None = None) -> Iterator[Chunk]:
        rows = self._rows  # fixed, so chunk i is the same points whatever the caller asks
        for i, a in enumerate(range(0, self.count, rows)):
            n = min(rows, self.count - a)
            g = np.random.default_rng((self.seed, i))
            nb = int(round(n * self._bg))
            which = g.choice(len(self._c), size=n - nb, p=self._w)
            xyz = np.concatenate([
                self._c[which] + g.normal(size=(n - nb, 3)) * self._s[which, None],
                g.uniform(0.0, 1.0, (nb, 3)),
            ])
            np.clip(xyz, 0.0, 1.0, out=xyz)
            k = np.concatenate([which, g.integers(0, len(self._c), nb)])
            r2 = ((xyz - self._c[k]) ** 2).sum(1)
            val = np.exp(-r2 / (2.0 * (2.0 * self._s[k]) ** 2))
            yield self._chunk(xyz, val[:, None], a)


def open_point_source(path, values: Sequence[str] | None = None, xyz: Sequence[str] = ("x", "y", "z")) -> PointSource:
    """Open ``path`` as a :class:`PointSource` chosen by its suffix (``clustered:N`` is procedural)."""
    text = str(path)
    if text.startswith("clustered:"):
        try:
            n = int(float(text.split(":", 1)[1]))
        except ValueError:
            raise ParameterError(f"{text}: expected clustered:N with N a number of points") from None
        return ClusteredPointSource(n)
    p = Path(path)
    if not p.exists():
        raise InputNotFoundError(f"{p}: no such file")
    suffix = p.suffix.lower()
    vals = list(values or [])
    if suffix == ".npy":
        return NpyPointSource(p, vals or None, tuple(xyz))
    if suffix == ".csv":
        return CsvPointSource(p, vals, tuple(xyz))
    if suffix in (".parquet", ".pq"):
        return ParquetPointSource(p, vals, tuple(xyz))
    if suffix == ".ply":
        return PlyPointSource(p, vals, tuple(xyz))
    if suffix in MESH_SUFFIXES:
        return MeshPointSource(p, vals)
    raise InputFormatError(
        f"{p}: unknown point format (suffix {suffix or 'none'!r}); expected .npy, .csv, .parquet, .ply or a mesh "
        f"({', '.join(MESH_SUFFIXES)})"
    )
