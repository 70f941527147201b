"""The volume data kind: a brick pyramid (``clipvol brick``, OME-Zarr, ``.npy``, ``procedural:``,
a loader plug-in or a numpy array) drawn by ray casting through the clip-texture.

The default kind of :mod:`clipvol.app.kinds`: it takes every source that no other kind claims,
so a source that is nothing clipvol knows reaches :func:`clipvol.paging.open.open_store`, whose
errors name what is wrong. Otherwise it is a kind like any other: its command-line hooks are
``clipvol.tools.volume_cli`` (named here, resolved by the CLI only), which turn the flags into
objects and call :func:`clipvol.app.render_png.render_to_png` and
:func:`clipvol.app.slice_files.slice_to_files`, both drawing through the sessions below.
"""

from __future__ import annotations

__all__ = ["VolumeKind"]


class VolumeKind:
    """Volumes: :func:`~clipvol.app.session.open_loader`, :class:`~clipvol.app.session.RenderSession`,
    :class:`~clipvol.app.notebook.VolumeView`; cutting planes through
    :class:`~clipvol.app.slice_session.SliceSession`."""

    name = "volume"
    cli = "clipvol.tools.volume_cli"

    def claims(self, source) -> bool:
        """Everything (the default kind is asked last)."""
        return True

    def open(self, source, **kwargs):
        from .session import open_loader

        return open_loader(source, **kwargs)

    def session(self, source, ctx, **kwargs):
        from .session import RenderSession

        return RenderSession(source, ctx, **kwargs)

    def show(self, source, **kwargs):
        from .notebook import VolumeView

        return VolumeView(source, **kwargs)
