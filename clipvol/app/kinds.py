"""Data kinds: one interface for every kind of data clipvol opens, pages, selects, draws and reports.

A volume (a brick pyramid, :mod:`clipvol.app.volume_kind`) and a point cloud (an octree of
points, :mod:`clipvol.app.point_kind`) share the pipeline's shape - a store on disk, a loader the
clip-texture pages from, a selection by projected size, a render action, a report of error
against cost - but differ in every part. Rather than asking ``is this a point store?`` wherever
a command or front end forks, each kind is one object that says whether a source is its own
(:meth:`DataKind.claims`) and how to open it, make its session, show it in a notebook and run
the command-line commands on it; the commands and :func:`show` ask :func:`kind_of` and hand
over. This is napari's layer design (one layer interface per data kind, a visual behind each,
napari ``layers/base/base.py``) applied to out-of-core kinds.

Where to add a data kind (meshes, say): write ``clipvol/app/mesh_kind.py`` with a class that
satisfies :class:`DataKind` and add one line to :data:`KINDS`. Its command-line hooks
(:class:`KindCommands`) are an object of its own module when they need no ``clipvol.tools``
helper, or the dotted name of a ``clipvol.tools`` module when they do: only the CLI resolves
that name (the entry-point convention), so this stage never imports the CLI.

The volume is the default kind: a source that no other kind claims is a volume (or an error of
the volume opener, which names what is wrong). Apart from being asked last it is a kind like the
others, with the same hooks: every command hands every source to its kind's hook
(``clipvol.tools.volume_cli`` for a volume, ``clipvol.tools.point_cli`` for points).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

from ..errors import InputFormatError
from .point_kind import PointKind
from .volume_kind import VolumeKind

__all__ = ["DataKind", "KindCommands", "KINDS", "DEFAULT_KIND", "kind_of", "open_data", "show"]


@runtime_checkable
class KindCommands(Protocol):
    """The command-line hooks of a data kind: each returns the command's exit status.

    A kind without a hook for a command (no ``slice`` for points, say) is refused by that command
    with a message naming the source and the kind. ``info`` and ``check`` read ``args.store``;
    ``render``, ``slice`` and ``view`` read ``args.source``; ``report`` gets the source and output
    folder, because ``clipvol report VOLUME --points POINTS`` reports a second store into a
    sub-folder.
    """

    def info(self, args) -> int: ...

    def check(self, args) -> int: ...

    def render(self, args) -> int: ...

    def slice(self, args) -> int: ...

    def view(self, args) -> int: ...

    def report(self, args, source, out) -> int: ...


@runtime_checkable
class DataKind(Protocol):
    """One kind of data: how to recognise its stores, open them, draw them and run commands on them.

    Attributes
    ----------
    name : str
        The registry key; error messages say ``a {name} store``.
    cli : KindCommands or str
        The command-line hooks, or the dotted name of the ``clipvol.tools`` module that holds them
        (see the module docstring).
    show : callable or None
        ``show(source, **kwargs)``: an interactive notebook view of the source (what
        :func:`show` returns), or None for a kind without one.
    """

    name: str
    cli: Any
    show: Any

    def claims(self, source) -> bool:
        """True if ``source`` (a path, URL, loader or array) is data of this kind. Cheap (reads
        at most a small metadata file) and never raises: a malformed store of this kind is
        claimed and its opener reports what is wrong."""
        ...

    def open(self, source, **kwargs):
        """The loader the clip-texture pages this source from."""
        ...

    def session(self, source, ctx, **kwargs):
        """Loader, clip-texture and render action as one closable object (a context manager)."""
        ...


#: every data kind, by name; the default kind comes first and is tried last (it takes what no
#: other kind claims). A new kind is one line here.
KINDS: dict[str, DataKind] = {
    "volume": VolumeKind(),
    "points": PointKind(),
}
DEFAULT_KIND = "volume"


def kind_of(source) -> DataKind:
    """The kind that claims ``source``: the first kind of :data:`KINDS` other than the default
    that claims it, else the default (volume)."""
    for name, kind in KINDS.items():
        if name != DEFAULT_KIND and kind.claims(source):
            return kind
    return KINDS[DEFAULT_KIND]


def open_data(source, **kwargs):
    """The loader of ``source``, whatever its kind: ``(kind, loader)``.

    :func:`clipvol.open_store` opens volumes only (a loader it returns has a brick pyramid), and
    refuses another kind's store by name; this opens any kind.
    """
    kind = kind_of(source)
    return kind, kind.open(source, **kwargs)


def show(source, **kwargs):
    """Show a store, ``procedural:...`` URL, ``.npy`` path, loader or 3-D numpy array in a notebook.

    The view is the one of the kind that claims ``source`` (:func:`kind_of`); for a volume it is
    a :class:`clipvol.app.notebook.VolumeView`.

    Parameters
    ----------
    source
        What to show; a numpy array is viewed in place (bricked in memory, ``brick`` voxels).
    **kwargs
        ``size=(w, h)``, ``tf``, ``mode`` (``'composite'``, ``'mip'``, ``'minip'``, ``'average'`` or
        ``'iso'`` with ``iso_value``; volumes), ``memory_budget``,
        ``texture_budget``, ``threads``, ``lod_threshold``, ``timeout`` (seconds per frame),
        ``brick``, ``labels`` (R/L, A/P, S/I letters on a patient-frame store's images, default
        True), ``store`` (where a NIfTI / DICOM / HDF5 / MRC input is bricked, default
        ``./NAME.zarr``), ``crop`` (two world corners ``(x, y, z)``), ``crop_voxels`` (level-0
        ``(start, stop)`` ``(z, y, x)``), ``clip_planes`` (up to six ``(x, y, z, nx, ny, nz)`` in
        world units, the side the normal points to kept); see
        :class:`~clipvol.app.notebook.VolumeView`. ``tf`` defaults to ``grey`` for a store with a
        patient frame and ``viridis`` otherwise.

    Returns
    -------
    VolumeView
        Displays itself as the interactive widget when it is the cell's value.

    Raises
    ------
    InputFormatError
        The source's kind has no notebook view (a point store).
    """
    kind = kind_of(source)
    view = getattr(kind, "show", None)
    if view is None:
        raise InputFormatError(f"{source}: a {kind.name} store; clipvol.show does not show this kind yet "
                               "(draw it with `clipvol render`)")
    return view(source, **kwargs)
