"""The interactive viewer (``clipvol view``): a GLFW window around the clip render action.

Only :mod:`clipvol.viewer.window` needs a display and GL; :mod:`~clipvol.viewer.controls` (input
to camera), :mod:`~clipvol.viewer.hud` (statistics as text) and :mod:`~clipvol.viewer.overlay`
(brick outlines) are pure numpy/pillow and are tested without a window.
"""
