"""Stage 5, application: headless sessions over the render actions.

Holds the session that ties a loader, its clip-texture and a render action together
(``session``), the offscreen flythrough that writes frames and per-frame statistics
(``flythrough``) and the report of image error against run time (``report``). It may import every
stage below (render, scene, paging, bricking) but never the window: the CLI, the report, a notebook
and the viewer all stand on it.
"""
