"""Stage 6, the interactive viewer (``clipvol view``): a GLFW window around a headless session.

Only :mod:`clipvol.viewer.window` needs a display and GL; :mod:`~clipvol.viewer.controls` (input to
camera and render parameters) and :mod:`~clipvol.viewer.hud` (statistics as text) are pure
numpy/pillow and are tested without a window. Everything the window shows comes from
:mod:`clipvol.app` (session, brick outlines), which never imports this package.
"""
