"""OME-TIFF (``.ome.tif``, ``.ome.tiff``): the TIFF reader of ``sources`` plus the OME voxel size.

Light-sheet and confocal microscopes write OME-TIFF (Goldberg et al., *The Open Microscopy
Environment (OME) Data Model and XML file*, 2005): the voxel size is in the OME-XML of the first
page, ``Pixels`` attributes ``PhysicalSizeX/Y/Z`` with ``PhysicalSize*Unit`` (default µm).
tifffile (Gohlke, *tifffile*, 2024) reads the pixels and hands over the XML; this module only reads
those attributes. Voxels are read as for any TIFF (memory-mapped when uncompressed, else page by
page).
"""

from __future__ import annotations

from pathlib import Path
from xml.etree import ElementTree

__all__ = ["open_ome_tiff", "ome_spacing", "OME_SUFFIXES"]

OME_SUFFIXES = (".ome.tif", ".ome.tiff")
_UNITS = {"µm": "micrometer", "um": "micrometer", "nm": "nanometer", "mm": "millimeter", "Å": "angstrom", "m": "meter"}


def ome_spacing(xml: str) -> tuple[tuple[float, float, float] | None, str | None]:
    """``((z, y, x), unit)`` from an OME-XML document's first ``Pixels`` (None where absent)."""
    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError:
        return None, None
    px = next((el for el in root.iter() if el.tag.endswith("}Pixels") or el.tag == "Pixels"), None)
    if px is None:
        return None, None
    try:
        vals = [float(px.attrib[f"PhysicalSize{a}"]) for a in "ZYX"]
    except (KeyError, ValueError):
        return None, None
    if min(vals) <= 0:
        return None, None
    units = {px.attrib.get(f"PhysicalSize{a}Unit", "µm") for a in "ZYX"}
    if len(units) != 1:
        return None, None  # mixed units: let the user say (--spacing, --unit)
    return (vals[0], vals[1], vals[2]), _UNITS.get(units.pop(), "micrometer")


def open_ome_tiff(path: Path):
    """A TIFF source with its OME voxel size and unit."""
    import tifffile

    from ..source_types import _open_tiff

    src = _open_tiff(Path(path))
    try:
        with tifffile.TiffFile(path) as tf:
            xml = tf.ome_metadata
    except (OSError, ValueError, tifffile.TiffFileError):
        xml = None
    if xml:
        sp, unit = ome_spacing(xml)
        if sp is not None:
            src.spacing, src.unit = sp, unit
    return src
