"""The point data kind: scattered points in an octree store (``clipvol brick-points``), drawn as
splats at a screen-space tolerance (Meredith & Ma, *Multiresolution view-dependent splat based
volume rendering of large irregular data*, 2001).

A point store says ``clipvol.kind = "points"`` in its group attributes
(:func:`clipvol.bricking.store_kind.store_kind`); its loader is
:class:`clipvol.loaders.point_store.PointStoreLoader`, its session
:class:`clipvol.app.point_session.PointSession`. The command-line hooks use the CLI's
transfer-function flags, so they live in ``clipvol.tools.point_cli``, named here and resolved by
the CLI only.
"""

from __future__ import annotations

__all__ = ["PointKind"]


class PointKind:
    """Point clouds: :class:`~clipvol.loaders.point_store.PointStoreLoader` and
    :class:`~clipvol.app.point_session.PointSession`; no notebook view yet (``show`` is None)."""

    name = "points"
    cli = "clipvol.tools.point_cli"
    show = None

    def claims(self, source) -> bool:
        """A point store's path, or a point-store loader."""
        if hasattr(source, "nodes") and hasattr(source, "to_paging"):
            return True
        if not isinstance(source, (str, bytes)) and not hasattr(source, "__fspath__"):
            return False
        from ..bricking.store_kind import store_kind

        return store_kind(source) == "points"

    def open(self, source, **kwargs):
        from .point_session import open_point_loader

        if kwargs:
            from ..errors import ParameterError

            raise ParameterError(f"{source}: a point store takes no loader options, got {', '.join(sorted(kwargs))}")
        return open_point_loader(source)

    def session(self, source, ctx, **kwargs):
        from .point_session import PointSession

        return PointSession(source, ctx, **kwargs)
