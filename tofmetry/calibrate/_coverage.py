"""Board coverage of the image from the detected corners: the union of each view's corner hull,
8 x 8 cells holding a corner, and the four image-corner regions, which count as reached when the
hulls cover some of them or a detected corner lies in them.

A board seen whole (checkerboard) puts its hull into an image corner region when it is pushed
there; a partial view (ChArUco, the board overhanging the image) puts its detected corners there
while its hull, cut by the image border some way inside the board, may cover only a sliver of the
region: the corners themselves say that the lens was measured there (see
:func:`uncovered_corner_regions`).
"""

from __future__ import annotations

import cv2
import numpy as np

from tofmetry.calibrate._ray_error import CORNER_FRAC, corner_regions

#: A corner region counts as covered when this fraction of it lies inside some board's corner hull...
CORNER_COVERED_FRAC = 0.1
#: ... or when at least this many detected corners (all views together) lie in it.
CORNER_MIN_DETECTED = 1


def coverage_mask(corners: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: union of the convex hulls of each image's detected corners (the covered area).

    Parameters
    ----------
    corners : list of (N_v, 2) detected corners [px], one per view (any subset of the board)
    shape : (H, W) image size [px]
    """
    h, w = shape
    m = np.zeros((h, w), np.uint8)
    for c in corners:
        hull = cv2.convexHull(np.asarray(c, np.float32).reshape(-1, 1, 2))
        cv2.fillConvexPoly(m, np.round(hull).astype(np.int32), 1)
    return m.astype(bool)


def corner_coverage(corners: list[np.ndarray], shape: tuple[int, int], cells: int = 8) -> float:
    """Fraction of a ``cells x cells`` grid over the image holding at least one corner."""
    h, w = shape
    occ = np.zeros((cells, cells), bool)
    for c in corners:
        c = np.asarray(c).reshape(-1, 2)
        iu = np.clip((c[:, 0] * cells / w).astype(int), 0, cells - 1)
        iv = np.clip((c[:, 1] * cells / h).astype(int), 0, cells - 1)
        occ[iv, iu] = True
    return float(occ.mean())


def corner_region_coverage(mask: np.ndarray, frac: float = CORNER_FRAC) -> dict:
    """Fraction of each image-corner region (``frac`` of width and height) inside ``mask``.

    Parameters
    ----------
    mask : (H, W) bool, e.g. :func:`coverage_mask`

    Returns
    -------
    dict region name -> covered fraction in [0, 1].
    """
    m = np.asarray(mask, bool)
    h, w = m.shape
    v, u = np.mgrid[0:h, 0:w]
    return {k: float(m[r].mean()) for k, r in corner_regions(u, v, w, h, frac).items()}


def corner_region_corners(corners: list[np.ndarray], shape: tuple[int, int], frac: float = CORNER_FRAC) -> dict:
    """Number of detected corners (all views together) in each image-corner region.

    Parameters
    ----------
    corners : list of (N_v, 2) detected corners [px]; shape : (H, W) image size [px]

    Returns
    -------
    dict region name -> count.
    """
    h, w = shape
    c = np.concatenate([np.asarray(x, np.float64).reshape(-1, 2) for x in corners]) if len(corners) else np.zeros((0, 2))
    return {k: int(m.sum()) for k, m in corner_regions(c[:, 0], c[:, 1], w, h, frac).items()}


def uncovered_corner_regions(covered_fraction: dict, n_corners: dict) -> list:
    """Image-corner regions no board reached: covered by the corner hulls below
    :data:`CORNER_COVERED_FRAC` and holding fewer than :data:`CORNER_MIN_DETECTED` detected corners.

    Parameters
    ----------
    covered_fraction : :func:`corner_region_coverage`; n_corners : :func:`corner_region_corners`

    Returns
    -------
    list of region names, in the order of ``covered_fraction``.
    """
    return [k for k, v in covered_fraction.items()
            if v < CORNER_COVERED_FRAC and n_corners.get(k, 0) < CORNER_MIN_DETECTED]
