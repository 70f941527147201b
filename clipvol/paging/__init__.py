"""Stage 2, paging: bricks from a store into main memory around a centre of interest.

Holds the loader contract every data source implements (``loader``), how a store path or URL
becomes a loader (``open``), the toroidal window arithmetic (``toroidal``), the prioritised load
queue with its retry timing (``queue``), the regions of interest a render action hands the
clip-texture (``region``) and the slab geometry of slices (``slab``), the bytes-read counter the
loaders increment where they read (``readcount``), and the clip-texture itself (``cliptexture``:
slots, windows, loader threads). It may import the bricking stage (pyramid geometry, store format) and
nothing above it: no camera, no transfer function, no GL.
"""
