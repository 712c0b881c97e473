"""All file I/O lives here: one module per format.

* :mod:`~tofmetry.io.capture` — capture folders (the data contract)
* :mod:`~tofmetry.io.datasets` — wall and scan datasets
* :mod:`~tofmetry.io.intrinsics_json` — ``intrinsics.json``
* :mod:`~tofmetry.io.images` — single depth/IR/colour images (PNG/TIFF/NPY/JPG)
* :mod:`~tofmetry.io.ply` — binary PLY clouds and meshes
* :mod:`~tofmetry.io.mesh` — PLY/OBJ/STL cloud-or-mesh loading (Open3D)
* :mod:`~tofmetry.io.calibration_file` — the versioned depth calibration file (.npz + JSON header)
* :mod:`~tofmetry.io.iai_kinect2` — iai_kinect2 / OpenCV ``!!opencv-matrix`` YAML calibration files
* :mod:`~tofmetry.io.board_dataset` — board datasets (``board.json`` + ``poses/NNNN``), iai_kinect2 import/export
* :mod:`~tofmetry.io.azure_kinect` — Azure Kinect ``.mkv`` recordings and their factory calibration
* :mod:`~tofmetry.io.tum`, :mod:`~tofmetry.io.open3d_rgbd` — TUM and Open3D RGB-D folders
* :mod:`~tofmetry.io.e57` — E57 point clouds (pye57)
* :mod:`~tofmetry.io.mat_json` — ``mat.json``, the layout of a printed dot mat
* :mod:`~tofmetry.io.registry` — importer / exporter registry behind ``tofmetry import|export``
"""

from tofmetry.io._atomic import atomic_dir, atomic_write_bytes, atomic_write_json, read_json
from tofmetry.io.capture import (Capture, CaptureMeta, CaptureWriter, CutRecordingWarning, EmptyFrameWarning, read_capture,
                                 write_capture)
from tofmetry.io.datasets import ScanDataset, Station, WallDataset, write_stations_csv
from tofmetry.io.intrinsics_json import read_intrinsics, write_intrinsics
from tofmetry.io.ply import read_ply, write_ply

__all__ = [
    "atomic_dir", "atomic_write_bytes", "atomic_write_json", "read_json",
    "Capture", "CaptureMeta", "CaptureWriter", "CutRecordingWarning", "EmptyFrameWarning", "read_capture", "write_capture",
    "ScanDataset", "Station", "WallDataset", "write_stations_csv",
    "read_intrinsics", "write_intrinsics", "read_ply", "write_ply",
]
