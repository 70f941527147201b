"""``clipvol serve``: the live view in any browser, for data that lives on a server.

The server renders offscreen (EGL; Mesa llvmpipe on a machine without a GPU) and streams frames
to a page over one WebSocket per view; the page runs the notebook widget's own view
(:mod:`clipvol.app.live_view`) plus the controls a widget cell leaves to Python (view presets,
window, slices, crop box and clip plane, store choice). Three modules, one job each:

- :mod:`~clipvol.app.serve.state`: one browser's view, checked, and the camera it means (pure numpy);
- :mod:`~clipvol.app.serve.worker`: the one thread that draws (the EGL context, every store's
  :class:`~clipvol.app.session.RenderSession`, adaptive quality, encoding);
- :mod:`~clipvol.app.serve.server`: the aiohttp routes, the token, the limits, the asyncio loop.

It needs the ``serve`` extra: ``pip install 'clipvol[serve]'``.
"""

from __future__ import annotations

__all__ = ["run_server"]


def run_server(loaders, names, *, host: str = "127.0.0.1", port: int = 8642, token: str | None, size=(512, 512),
               memory_budget="512MB", texture_budget="256MB", threads: int | None = None, timeout: float = 30.0,
               moving_format: str = "jpeg", target_s: float = 0.1, max_views: int = 8, rate: float = 120.0,
               announce=print, stop=None) -> None:
    """Serve ``loaders`` (one per store, named ``names``) until Ctrl-C (or ``stop``, an asyncio event).

    Everything is closed on the way out, in order: the web server, then the render worker (its
    sessions' GL resources, their loader threads, the context). See :func:`clipvol.app.serve.server.serve`.
    """
    from .server import _aiohttp, check_exposure, serve
    from .worker import RenderWorker

    check_exposure(host, token)
    _aiohttp()  # the extra's error before any store is opened
    worker = RenderWorker(loaders, names, memory_budget=memory_budget, texture_budget=texture_budget, threads=threads,
                          timeout=timeout, target_s=target_s, moving_format=moving_format).start()
    try:
        serve(worker, host=host, port=port, token=token, size=size, max_views=max_views, rate=rate,
              announce=announce, stop=stop)
    finally:
        worker.close()
