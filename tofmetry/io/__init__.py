"""All file I/O lives here: one module per format.

* :mod:`~tofmetry.io.capture` — capture folders (the data contract)
* :mod:`~tofmetry.io.datasets` — wall and scan datasets
* :mod:`~tofmetry.io.intrinsics_json` — ``intrinsics.json``
* :mod:`~tofmetry.io.images` — single depth/IR/colour images (PNG/TIFF/NPY/JPG)
* :mod:`~tofmetry.io.ply` — binary PLY clouds and meshes
"""

from tofmetry.io._atomic import atomic_dir, atomic_write_bytes, atomic_write_json, read_json
from tofmetry.io.capture import Capture, CaptureMeta, CaptureWriter, EmptyFrameWarning, read_capture, write_capture
from tofmetry.io.datasets import ScanDataset, Station, WallDataset, write_stations_csv
from tofmetry.io.intrinsics_json import read_intrinsics, write_intrinsics
from tofmetry.io.ply import read_ply, write_ply

__all__ = [
    "atomic_dir", "atomic_write_bytes", "atomic_write_json", "read_json",
    "Capture", "CaptureMeta", "CaptureWriter", "EmptyFrameWarning", "read_capture", "write_capture",
    "ScanDataset", "Station", "WallDataset", "write_stations_csv",
    "read_intrinsics", "write_intrinsics", "read_ply", "write_ply",
]
