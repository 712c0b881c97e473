"""Sample regions for the materials analysis: parsing/validation and automatic grey-board segmentation.

Regions JSON (read by the CLI with :func:`tofmetry.io.read_json`, parsed here)::

    {"regions": [{"name": "white_1", "rect": [u0, v0, u1, v1], "reference": true}, ...]}

``rect`` = pixel bounds, ``u1``/``v1`` exclusive. At least one region must be a reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from tofmetry.errors import EstimationError, FormatError, InputError


@dataclass(frozen=True)
class Region:
    """A rectangular sample region of the image.

    Attributes
    ----------
    name : str
    rect : (u0, v0, u1, v1) int pixel bounds, u1/v1 exclusive
    reference : bool, part of the reference (white) set
    level : int or None, grey class (0 = brightest) when found automatically
    """

    name: str
    rect: tuple[int, int, int, int]
    reference: bool = False
    level: int | None = None

    @property
    def slices(self) -> tuple[slice, slice]:
        u0, v0, u1, v1 = self.rect
        return slice(v0, v1), slice(u0, u1)

    @property
    def centre(self) -> tuple[float, float]:
        u0, v0, u1, v1 = self.rect
        return (u0 + u1 - 1) / 2.0, (v0 + v1 - 1) / 2.0

    def to_dict(self) -> dict:
        d = {"name": self.name, "rect": list(self.rect), "reference": self.reference}
        if self.level is not None:
            d["level"] = self.level
        return d


def regions_from_dict(d: dict, shape: tuple[int, int], source: str = "regions") -> list[Region]:
    """Parse and validate a regions document against an image of ``shape`` (H, W).

    Raises
    ------
    FormatError on a malformed document, InputError on a rect outside the image or empty.
    """
    if not isinstance(d, dict) or not isinstance(d.get("regions"), list) or not d["regions"]:
        raise FormatError(f"{source}: expected {{\"regions\": [{{\"name\": ..., \"rect\": [u0, v0, u1, v1], "
                          "\"reference\": true|false}, ...]}} with at least one region")
    h, w = shape
    out, names = [], set()
    for i, r in enumerate(d["regions"]):
        if not isinstance(r, dict) or "rect" not in r:
            raise FormatError(f"{source}: region {i} must be an object with 'name' and 'rect'")
        name = str(r.get("name", f"region_{i}"))
        if name in names:
            raise FormatError(f"{source}: duplicate region name {name!r}")
        names.add(name)
        rect = r["rect"]
        if not (isinstance(rect, list) and len(rect) == 4 and all(isinstance(x, (int, float)) and float(x).is_integer() for x in rect)):
            raise FormatError(f"{source}: region {name!r}: rect must be 4 integers [u0, v0, u1, v1], found {rect!r}")
        u0, v0, u1, v1 = (int(x) for x in rect)
        if not (0 <= u0 < u1 <= w and 0 <= v0 < v1 <= h):
            raise InputError(f"{source}: region {name!r} rect {[u0, v0, u1, v1]} is outside the {w}x{h} image or empty "
                             f"(need 0 <= u0 < u1 <= {w}, 0 <= v0 < v1 <= {h}; u1, v1 exclusive)")
        out.append(Region(name, (u0, v0, u1, v1), bool(r.get("reference", False))))
    if not any(r.reference for r in out):
        raise InputError(f"{source}: no region is marked \"reference\": true (the white regions the plane is fitted on)")
    return out


def regions_to_dict(regions: list[Region]) -> dict:
    return {"regions": [r.to_dict() for r in regions]}


def _gap_clusters(values: np.ndarray, gap: float) -> np.ndarray:
    """1-D clustering: sorted values split where consecutive values differ by more than ``gap``.

    Returns labels with 0 = the cluster of highest values.
    """
    order = np.argsort(-values)
    lab = np.empty(values.size, np.int64)
    k = 0
    for j, i in enumerate(order):
        if j and values[order[j - 1]] - values[i] > gap:
            k += 1
        lab[i] = k
    return lab


def _falloff_exponent(lnA: np.ndarray, lncos: np.ndarray, gap: float) -> tuple[float, np.ndarray]:
    """Exponent ``a`` of an illumination falloff ``cos(theta)^a`` making the grey classes tightest."""
    best = (np.inf, 0.0, None)
    for a in np.arange(0.0, 10.01, 0.25):
        v = lnA - a * lncos
        lab = _gap_clusters(v, gap)
        sse = sum(((v[lab == k] - v[lab == k].mean()) ** 2).sum() for k in np.unique(lab))
        if sse < best[0] - 1e-12:
            best = (sse, float(a), lab)
    return best[1], best[2]


def auto_grey_board_regions(ir: np.ndarray, depth: np.ndarray, rays: np.ndarray, *, edge_threshold: float = 0.04,
                            class_gap: float = 0.12, margin: float = 0.2, min_side_px: int = 8) -> tuple[list[Region], dict]:
    """Find the squares of a grey-level checkerboard from the IR amplitude.

    Method: edges where the log-amplitude gradient exceeds ``edge_threshold`` [ln/px]
    (a step between adjacent grey levels is >= 0.25 in ln); the connected edge-free areas
    that are nearly full rectangles of a common size are squares. Squares are placed on a
    lattice (board roughly parallel to the image axes, as in the study); lattice cells
    without a square (e.g. a white square merged with a white wall) are added from the
    lattice. Each region is the square shrunk by ``margin`` of its side on each border
    (away from mixed pixels at edges). Grey classes: log amplitudes corrected for an
    illumination falloff ``cos(theta)^a`` (``a`` chosen so the classes are tightest),
    split where they differ by more than ``class_gap``; class 0 (brightest) = reference.

    Parameters
    ----------
    ir : (H, W) float IR amplitude (mean over frames)
    depth : (H, W) depth [mm] (0 = invalid, excluded)
    rays : (H, W, 2) normalised ray table of the camera

    Returns
    -------
    regions : list of Region, named ``L<class>_<row>_<col>``
    info : dict with the lattice, falloff exponent and counts
    """
    a = np.asarray(ir, np.float64)
    valid = (np.asarray(depth) > 0) & (a > 0)
    if valid.sum() < 100:
        raise EstimationError("grey board: too few pixels with IR amplitude and depth")
    lnA = np.log(np.where(valid, a, 1.0))
    lnA = ndimage.uniform_filter(lnA, 3)
    gu = ndimage.sobel(lnA, axis=1) / 8.0
    gv = ndimage.sobel(lnA, axis=0) / 8.0
    flat = valid & (np.hypot(gu, gv) < edge_threshold)
    flat = ndimage.binary_erosion(flat, iterations=2)
    lab, n = ndimage.label(flat)
    if n == 0:
        raise EstimationError("grey board: no uniform area found in the IR image")
    objs = ndimage.find_objects(lab)
    areas = ndimage.sum_labels(np.ones_like(lab), lab, np.arange(1, n + 1))
    cands = []
    for k, sl in enumerate(objs):
        hh, ww = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
        if min(hh, ww) < min_side_px:
            continue
        fill = areas[k] / (hh * ww)
        if fill >= 0.85 and max(hh, ww) / min(hh, ww) <= 1.5:
            cands.append((sl, areas[k]))
    if len(cands) < 3:
        raise EstimationError(f"grey board: found {len(cands)} square-like areas in the IR image, need >= 3 "
                              "(is the board in view, parallel to the image axes, with distinct grey levels?)")
    med_area = np.median([c[1] for c in cands])
    squares = [c[0] for c in cands if 0.5 * med_area <= c[1] <= 2.0 * med_area]
    cu = np.array([(s[1].start + s[1].stop - 1) / 2 for s in squares])
    cv = np.array([(s[0].start + s[0].stop - 1) / 2 for s in squares])
    side_u = np.median([s[1].stop - s[1].start for s in squares])
    side_v = np.median([s[0].stop - s[0].start for s in squares])
    # lattice pitch: nearest-neighbour centre distance along each axis
    du = np.abs(cu[:, None] - cu[None, :])
    dv = np.abs(cv[:, None] - cv[None, :])
    same_row = dv < 0.5 * side_v
    same_col = du < 0.5 * side_u
    pu = np.where(same_row & (du > 0.5 * side_u), du, np.inf).min(axis=1)
    pv = np.where(same_col & (dv > 0.5 * side_v), dv, np.inf).min(axis=1)
    pitch_u = float(np.median(pu[np.isfinite(pu)])) if np.isfinite(pu).any() else side_u + 4
    pitch_v = float(np.median(pv[np.isfinite(pv)])) if np.isfinite(pv).any() else side_v + 4
    i0 = np.argmin(cu + cv)
    col = np.rint((cu - cu[i0]) / pitch_u).astype(int)
    row = np.rint((cv - cv[i0]) / pitch_v).astype(int)
    # least-squares lattice: centre = origin + index * pitch
    Au = np.column_stack([np.ones_like(cu), col])
    Av = np.column_stack([np.ones_like(cv), row])
    (ou, pu_f), (ov, pv_f) = np.linalg.lstsq(Au, cu, rcond=None)[0], np.linalg.lstsq(Av, cv, rcond=None)[0]
    half_u = max(1, int(round(side_u * (0.5 - margin))))
    half_v = max(1, int(round(side_v * (0.5 - margin))))
    h, w = a.shape
    found = set(zip(row.tolist(), col.tolist()))
    cells = [(r, c) for r in range(row.min(), row.max() + 1) for c in range(col.min(), col.max() + 1)]
    rects, keys = [], []
    for r, c in cells:
        u, v = ou + c * pu_f, ov + r * pv_f
        u0, v0 = int(round(u)) - half_u, int(round(v)) - half_v
        rect = (u0, v0, u0 + 2 * half_u + 1, v0 + 2 * half_v + 1)
        if rect[0] < 0 or rect[1] < 0 or rect[2] > w or rect[3] > h:
            continue
        if valid[rect[1]:rect[3], rect[0]:rect[2]].mean() < 0.9:
            continue
        rects.append(rect)
        keys.append((r - row.min(), c - col.min(), (r, c) in found))
    lnmean = np.array([np.log(a[r[1]:r[3], r[0]:r[2]][valid[r[1]:r[3], r[0]:r[2]]]).mean() for r in rects])
    cen = [((r[0] + r[2] - 1) // 2, (r[1] + r[3] - 1) // 2) for r in rects]
    xy = np.array([rays[v, u] for u, v in cen])
    lncos = -0.5 * np.log1p((xy ** 2).sum(axis=1))
    expo, classes = _falloff_exponent(lnmean, lncos, class_gap)
    regions = [Region(f"L{int(k)}_{r}_{c}", rect, reference=bool(k == 0), level=int(k))
               for rect, (r, c, _), k in zip(rects, keys, classes)]
    info = {"n_squares_found": len(squares), "n_cells": len(regions), "n_filled_from_lattice": sum(not f for *_, f in keys),
            "lattice_rows": int(row.max() - row.min() + 1), "lattice_cols": int(col.max() - col.min() + 1),
            "pitch_px": [pu_f, pv_f], "falloff_exponent": expo, "n_classes": int(classes.max() + 1)}
    return regions, info
