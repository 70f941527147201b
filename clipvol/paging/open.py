"""``open_store``: one call from a path or URL to the right loader.

Users name data the way they think of it - a store directory, a ``.npy`` file, a
``procedural:fractal?size=512`` URL - and get a :class:`~clipvol.paging.loader.Loader`. Third-party
loaders plug in through the ``clipvol.loaders`` entry-point group: a package that declares
``myformat = "mypkg.loader:MyLoader"`` makes ``open_store("myformat:...")`` call
``MyLoader("myformat:...", **kwargs)`` with the full URL.
"""

from __future__ import annotations

import re
from importlib.metadata import entry_points
from pathlib import Path

from ..errors import InputFormatError, InputNotFoundError, ParameterError
from .bytesource import is_remote_url
from .loader import Loader

__all__ = ["open_store", "loader_plugins"]

ENTRY_POINT_GROUP = "clipvol.loaders"
_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.\-_]*):(?!\\)")


def loader_plugins() -> dict[str, object]:
    """Entry points of the ``clipvol.loaders`` group, by name (bundled ones included)."""
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def open_store(path_or_url: str | Path, **kwargs) -> Loader:
    """Open a data source as a loader.

    Parameters
    ----------
    path_or_url : str or Path
        * a directory holding a zarr group (``zarr.json`` or ``.zgroup``): a clipvol store or a
          plain OME-Zarr image -> :class:`clipvol.loaders.zarr_store.ZarrLoader`;
        * a ``.npy`` file -> :class:`clipvol.loaders.numpy_array.NumpyLoader` (memory-mapped);
        * ``procedural:NAME?...`` -> :class:`clipvol.loaders.procedural.ProceduralLoader`;
        * ``s3://...``, ``https://...``, ``gs://...`` or any other fsspec URL of a clipvol store or
          OME-Zarr image -> :class:`clipvol.loaders.zarr_remote.RemoteZarrLoader` (read-only;
          ``cache=DIR`` keeps fetched chunks on disk, ``storage_options={...}`` go to fsspec);
        * ``SCHEME:...`` -> the ``clipvol.loaders`` entry point named ``SCHEME``, called with the
          full URL and ``kwargs``.
    **kwargs
        Passed to the loader (e.g. ``brick=32`` for the numpy and procedural loaders).

    Raises
    ------
    InputNotFoundError
        The path does not exist.
    InputFormatError
        The path exists but is no format clipvol knows, or the URL's scheme has no loader.
    """
    text = str(path_or_url)
    m = _SCHEME.match(text) if isinstance(path_or_url, str) else None
    if m and len(m.group(1)) > 1 and not Path(text).exists():
        scheme = m.group(1)
        if scheme == "procedural":
            from ..loaders.procedural import ProceduralLoader

            return _construct(ProceduralLoader, text, kwargs)
        plugins = loader_plugins()
        if scheme not in plugins and is_remote_url(text):
            from ..loaders.zarr_remote import RemoteZarrLoader

            return _construct(RemoteZarrLoader, text, kwargs)
        if scheme not in plugins:
            raise InputFormatError(
                f"{text}: no loader for the scheme {scheme!r}; expected a path, 'procedural:...', or one of the "
                f"installed '{ENTRY_POINT_GROUP}' plug-ins: {', '.join(sorted(plugins)) or 'none'}"
            )
        return plugins[scheme].load()(text, **kwargs)
    path = Path(path_or_url)
    if not path.exists():
        raise InputNotFoundError(f"{path}: no such file or directory")
    if path.is_file() and path.name in ("zarr.json", ".zgroup"):
        path = path.parent
    if path.is_dir():
        if (path / "zarr.json").exists() or (path / ".zgroup").exists():  # what they are: the loader checks
            from ..bricking.store_kind import store_kind

            kind = store_kind(path)
            if kind not in (None, "volume"):  # another data kind's store: clipvol.app.kinds opens it
                raise InputFormatError(
                    f"{path}: a {kind} store (clipvol.kind = {kind!r}), not a volume; open it with "
                    "clipvol.app.kinds.open_data or draw it with `clipvol render` / `clipvol view`"
                )
            from ..loaders.zarr_store import ZarrLoader

            from ..bricking.channels import image_set, set_version

            found = image_set(path)
            if found is not None and set_version(path) == 1:  # an older 4-D brick: one store per member
                return _open_member(path, *found, kwargs)
            return _construct(ZarrLoader, path, kwargs)
        raise InputFormatError(f"{path}: expected a zarr store (a directory with zarr.json or .zgroup), found neither")
    if path.suffix.lower() == ".npy":
        from ..loaders.numpy_array import NumpyLoader

        return _construct(NumpyLoader, path, kwargs)
    from ..bricking.formats import readable_formats

    raise InputFormatError(f"{path}: unknown format (suffix {path.suffix or 'none'!r}); expected {readable_formats()}")


def _construct(loader_class, where, kwargs: dict):
    """``loader_class(where, **kwargs)``, refusing in one line the keywords it does not take (a
    command's ``--brick`` for a store whose bricks were fixed when it was built) instead of
    Python's ``TypeError``."""
    import inspect

    try:
        params = inspect.signature(loader_class).parameters
    except (TypeError, ValueError):
        return loader_class(where, **kwargs)
    if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        extra = sorted(k for k in kwargs if k not in params)
        if extra:
            k = extra[0]
            raise ParameterError(f"{where}: {k} (--{k.replace('_', '-')}): not an option of a {loader_class.__name__} "
                                 f"source, which takes {', '.join(n for n in list(params)[1:]) or 'no options'}; "
                                 f"drop --{k.replace('_', '-')}")
    return loader_class(where, **kwargs)


def _open_member(path: Path, axis: str, n: int, kwargs: dict):
    """Member ``c`` or ``t`` (default 0) of an image set (:mod:`clipvol.bricking.channels`), its
    loader reporting the set's axis (``axes == ("c",)``, ``lead_shape == (n,)``)."""
    from ..loaders.zarr_store import ZarrLoader

    kwargs = dict(kwargs)
    want = {"c": kwargs.pop("c", None), "t": kwargs.pop("t", None)}
    kind = "a channel set: c, z, y, x" if axis == "c" else "a time series: t, z, y, x"
    for name, v in want.items():
        if name != axis and v not in (None, 0):
            raise ParameterError(f"{name}: {path} has no {name!r} axis ({kind}), got {name}={v}")
    k = 0 if want[axis] is None else want[axis]
    if isinstance(k, bool) or int(k) != k or not 0 <= k < n:
        what = "channels" if axis == "c" else "time steps"
        raise ParameterError(f"{axis}: expected 0..{n - 1} for {path} ({n} {what}), got {k!r}")
    loader = _construct(ZarrLoader, path / axis / str(int(k)), kwargs)
    loader.axes, loader.lead_shape = (axis,), (n,)
    loader.set_root = path  # where the other members are opened from (clipvol.app.timeseries.series_loaders)
    return loader
