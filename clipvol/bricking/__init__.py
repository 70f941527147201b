"""Stage 1, bricking: from a source volume to a multiresolution store on disk.

Holds the sources a volume is read from (``sources``), the pyramid geometry and its downsampling
filters (``pyramid``), closed-form synthetic volumes (``generators``), per-brick statistics
(``stats``), the store format and its metadata (``store``) and the streamed, resumable build
(``pipeline``, behind ``clipvol brick``). It imports only ``clipvol.errors`` / ``clipvol.units``
and itself: everything above reads stores, nothing here knows about paging, cameras or GL.
"""
