"""Small files of the formats users hold, written by each format's own library (for the tests).

DICOM slices are written with pydicom's writer (``Dataset.save_as`` of a CT Image with the Image
Plane Module filled in), NIfTI with nibabel, so the readers under test meet real files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_dicom_series(
    folder: Path,
    vol: np.ndarray,
    *,
    spacing=(2.5, 0.8, 0.6),
    origin_lps=(-100.0, -120.0, 50.0),
    row_dir=(1.0, 0.0, 0.0),
    col_dir=(0.0, 1.0, 0.0),
    slope: float = 1.0,
    intercept: float = 0.0,
    series_uid: str | None = None,
    shuffle_seed: int | None = 0,
    name_prefix: str = "slice",
) -> list[Path]:
    """Write ``vol`` (z, y, x; uint16 or int16 stored values) as one file per z slice.

    Slice ``k`` sits at ``origin + k * spacing[0] * (row_dir x col_dir)`` (LPS, mm). Files are
    named in a shuffled order so a reader that sorts by name is caught.
    """
    import pydicom
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    series_uid = series_uid or generate_uid()
    study_uid = generate_uid()
    normal = np.cross(row_dir, col_dir)
    order = np.arange(vol.shape[0])
    if shuffle_seed is not None:
        np.random.default_rng(shuffle_seed).shuffle(order)
    out = []
    for n, k in enumerate(order):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID = CTImageStorage
        ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
        ds.Modality = "CT"
        ds.StudyInstanceUID = study_uid
        ds.SeriesInstanceUID = series_uid
        ds.InstanceNumber = int(n + 1)  # deliberately not the spatial order
        ds.PatientName = "Test^Phantom"
        pos = np.asarray(origin_lps, dtype=float) + k * spacing[0] * normal
        ds.ImagePositionPatient = [f"{v:.6f}" for v in pos]
        ds.ImageOrientationPatient = [f"{v:.6f}" for v in (*row_dir, *col_dir)]
        ds.PixelSpacing = [f"{spacing[1]:.6f}", f"{spacing[2]:.6f}"]
        ds.SliceThickness = f"{spacing[0]:.6f}"
        ds.RescaleSlope = f"{slope:g}"
        ds.RescaleIntercept = f"{intercept:g}"
        ds.set_pixel_data(np.ascontiguousarray(vol[k]), "MONOCHROME2", 16 if vol.dtype.itemsize == 2 else 8)
        f = folder / f"{name_prefix}{n:03d}.dcm"
        ds.save_as(f, enforce_file_format=True)
        out.append(f)
    return out
