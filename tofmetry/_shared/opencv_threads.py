"""OpenCV fits that give the same numbers on every run.

OpenCV's camera and stereo calibration (``cv2.calibrateCameraExtended``,
``cv2.stereoCalibrateExtended``) sum their normal equations over several threads; the order of
those sums follows the threads' timing, so the same corners give intrinsics that differ in the
12th digit from one run to the next (measured on the study's 40 checkerboard images with 2
threads: 6e-12 px; identical over four runs with one). Downstream fits amplify that: the study's
registered views differed by 1e-8 m between runs, enough to move the edge-trimmed maximum of its
model's deviations from 2.2 to 2.6 mm. A printed figure must not change when the same data are
run again, so those fits run on one OpenCV thread (they take milliseconds per call).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import cv2


@contextmanager
def one_opencv_thread() -> Iterator[None]:
    """Run the enclosed OpenCV calls on one thread, then restore the previous thread count."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(before)
