"""A view that sees too few whole dots placed on the mat by its whole pattern (masked cross-correlation).

Low views see the mat at grazing incidence: its dots shrink to a few rows of pixels, the object
hides many, and fewer than the dot matching needs come out round and whole
(:func:`~tofmetry.reconstruct._mat_dots.seen_dots`). The pattern is still there, smeared along the
view. Here every support pixel takes part: its ray cut with the support plane puts its relative log
albedo on a metric grid of the plane (:func:`plane_image`), around the object's footprint (the mat
lies under the object); the printed layout is rasterised on the same grid; and the rotation and the
shift of the plane that line the two up are searched exhaustively, the rotation in steps, the shift
at once for every value by FFT (masked normalised cross-correlation, Padfield 2012: only the pixels
both images have count, so the table around the sheet and the object's shadow do not). Coarse
(6 mm cells, 3 deg steps, the whole turn), then fine (2 mm, 0.5 deg, around the best).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import fft, ndimage

from tofmetry._shared.dot_mat import DotMat, dot_mask
from tofmetry.reconstruct._mat_dots import plane_frame, seen_dots
from tofmetry.reconstruct._mat_locate import MatFix, contrast, fix_from_matches, guided_match, rotation_2d


def plane_image(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray, centre_xy: np.ndarray, half_m: float,
                cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The support's log albedo on a grid of the plane (:func:`plane_frame` x, y) centred on ``centre_xy``.

    Parameters
    ----------
    alb : (H, W) relative log IR albedo of the support's pixels, NaN elsewhere
    rays : (H, W, 2) normalised rays; plane : (4,) support plane, camera frame [m]
    centre_xy : (2,) grid centre in the plane frame [m]; half_m : half its side [m]; cell_m : cell [m]

    Returns
    -------
    image (n, n) mean log albedo per cell (0 where empty), mask (n, n) float (1 where seen); row = y, column = x
    """
    known = np.isfinite(alb)
    r = np.column_stack([rays[known], np.ones(int(known.sum()))])
    n = np.asarray(plane[:3], np.float64)
    q = r * (-float(plane[3]) / (r @ n))[:, None]
    G = plane_frame(plane)
    xy = q @ G[:2, :3].T + G[:2, 3] - centre_xy
    size = int(np.ceil(2 * half_m / cell_m))
    ij = np.floor((xy + half_m) / cell_m).astype(np.int64)
    ok = (ij >= 0).all(1) & (ij < size).all(1)
    flat = ij[ok, 1] * size + ij[ok, 0]
    cnt = np.bincount(flat, minlength=size * size).astype(np.float64)
    tot = np.bincount(flat, alb[known][ok], minlength=size * size)
    img = np.divide(tot, cnt, out=np.zeros_like(tot), where=cnt > 0).reshape(size, size)
    return img, (cnt > 0).reshape(size, size).astype(np.float64)


def mat_image(mat: DotMat, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The printed layout on a grid of ``cell_m`` cells (1 paper, 0 toner; row = v, column = u, from
    the sheet's corner (-w/2, -h/2)): image, mask (ones), and the grid's corner in the sheet frame [m]."""
    w, h = mat.size_m
    nu, nv = int(np.ceil(w / cell_m)), int(np.ceil(h / cell_m))
    u = (np.arange(nu) + 0.5) * cell_m - w / 2
    v = (np.arange(nv) + 0.5) * cell_m - h / 2
    U, V = np.meshgrid(u, v)
    a = np.radians(mat.yaw_deg)  # dot_mask takes world x, y of a sheet turned by its yaw: undo it
    x, y = np.cos(a) * U - np.sin(a) * V, np.sin(a) * U + np.cos(a) * V
    on, dot = dot_mask(mat, x.ravel(), y.ravel(), pixel_m=min(cell_m / 2, 0.001))
    img = np.where(dot, 0.0, 1.0).reshape(nv, nu)
    return img, on.reshape(nv, nu).astype(np.float64), np.array([-w / 2, -h / 2])


def masked_ncc(fixed: np.ndarray, fmask: np.ndarray, moving: np.ndarray, mmask: np.ndarray,
               min_overlap: float) -> np.ndarray:
    """Masked normalised cross-correlation of ``moving`` shifted over ``fixed`` (Padfield 2012), for
    every integer shift: ``out[dy, dx]`` (wrapped, ``fixed`` padded) compares ``fixed[y + dy, x + dx]``
    with ``moving[y, x]`` over the pixels both masks hold; -1 where they share fewer than ``min_overlap``."""
    sy, sx = fixed.shape[0] + moving.shape[0], fixed.shape[1] + moving.shape[1]
    shape = (fft.next_fast_len(sy), fft.next_fast_len(sx))

    def F(a):
        return fft.rfft2(a, shape)

    def corr(A, B):  # sum_x A[x + s] B[x]
        return fft.irfft2(A * np.conj(B), shape)

    f, m = fixed * fmask, moving * mmask
    Ff, Ff2, Fmf = F(f), F(f * f), F(fmask)
    Fm, Fm2, Fmm = F(m), F(m * m), F(mmask)
    n = np.round(corr(Fmf, Fmm))
    sf, sm = corr(Ff, Fmm), corr(Fmf, Fm)
    sff, smm, sfm = corr(Ff2, Fmm), corr(Fmf, Fm2), corr(Ff, Fm)
    with np.errstate(divide="ignore", invalid="ignore"):
        num = sfm - sf * sm / n
        den = np.sqrt(np.maximum(sff - sf * sf / n, 0) * np.maximum(smm - sm * sm / n, 0))
        out = num / den
    out[~np.isfinite(out) | (n < min_overlap)] = -1.0
    return out


def _search(view, vmask, matimg, matmask, angles_deg, min_overlap):
    """Best (ncc, angle, dy, dx) over ``angles_deg`` (the view turned about its grid centre; view cell
    (i, j) lands on mat cell (i + dy, j + dx), the shifts unwrapped from :func:`masked_ncc`'s), and
    each angle's best (ncc, angle)."""
    best = (-2.0, 0.0, 0, 0)
    scores = []
    c = ((view.shape[1] - 1) / 2, (view.shape[0] - 1) / 2)
    for a in angles_deg:
        M = cv2.getRotationMatrix2D(c, float(a), 1.0)
        rv = cv2.warpAffine(view, M, view.shape[::-1], flags=cv2.INTER_LINEAR)
        rm = cv2.warpAffine(vmask, M, view.shape[::-1], flags=cv2.INTER_NEAREST)
        s = masked_ncc(matimg, matmask, rv * rm, rm, min_overlap)
        k = int(np.argmax(s))
        dy, dx = np.unravel_index(k, s.shape)
        dy = dy - s.shape[0] if dy > s.shape[0] - view.shape[0] else dy  # negative shifts wrap round
        dx = dx - s.shape[1] if dx > s.shape[1] - view.shape[1] else dx
        scores.append((float(s.flat[k]), float(a)))
        if s.flat[k] > best[0]:
            best = (float(s.flat[k]), float(a), int(dy), int(dx))
    return best, scores


def locate_dense(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray, footprint_xy: np.ndarray,
                 mat: DotMat, min_ncc: float = 0.4, min_margin: float = 0.1) -> dict:
    """The plane's rotation and shift onto the mat from the whole pattern (module docstring).

    Parameters
    ----------
    alb, rays, plane : as :func:`plane_image`; footprint_xy : (2,) the object's footprint centre in
        :func:`plane_frame` [m] (the mat lies under it)
    min_ncc : the best correlation must reach this; min_margin : ... and beat every rotation more than
        10 deg away by this

    Returns
    -------
    dict: located, ncc, margin, and where located ``R`` (2, 2), ``t`` (2,) with ``sheet = R @ plane_xy + t`` [m]
    """
    w, h = mat.size_m
    half = 0.5 * float(np.hypot(w, h)) + 0.05
    out = {"located": False}
    for cell, angles in ((0.006, np.arange(0.0, 360.0, 3.0)), (0.002, None)):
        view, vmask = plane_image(alb, rays, plane, footprint_xy, half, cell)
        if vmask.sum() < 200:
            return out | {"reason": "too little of the support is seen around the object"}
        blur = 1.0
        view = ndimage.gaussian_filter(view, blur) / np.maximum(ndimage.gaussian_filter(vmask, blur), 1e-6) * vmask
        mimg, mmask, corner = mat_image(mat, cell)
        mimg = ndimage.gaussian_filter(mimg, blur)
        if angles is None:
            angles = out["angle_deg"] + np.arange(-3.0, 3.01, 0.5)
        (ncc, ang, dy, dx), scores = _search(view, vmask, mimg, mmask, angles, 0.15 * vmask.sum())
        if cell == 0.006:
            far = [s for s, a in scores if abs((a - ang + 180) % 360 - 180) > 10]
            margin = ncc - max(far, default=-1.0)
            out.update(ncc=round(ncc, 3), margin=round(margin, 3), angle_deg=ang)
            if ncc < min_ncc or margin < min_margin:
                return out | {"reason": f"the pattern does not line up clearly (correlation {ncc:.2f}, "
                                        f"{margin:.2f} above any other turn)"}
        else:
            out["angle_deg"] = ang
        # view cell (i, j) turned by ang about the grid centre lands on mat cell (i + dy, j + dx)
        R = rotation_2d(np.radians(-ang))  # cv2 turns the image counter-clockwise by ang with rows down
        c = view.shape[0] / 2 * cell  # the turn's centre (cv2's, the middle of the grid), in grid metres
        # plane xy -> grid metres (xy - footprint + half) -> turned about c -> + shift -> sheet (+ corner)
        t = R @ (-footprint_xy + half - c) + c + np.array([dx, dy]) * cell + corner
    out.update(located=True, R=R, t=t)
    return out


def locate_by_pattern(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray, footprint_xy: np.ndarray,
                      mat: DotMat, pattern_sigma: tuple[float, float], min_matched: int = 3) -> MatFix:
    """A view placed by the whole pattern (:func:`locate_dense`), then by the dots it sees near where
    that puts them (:func:`~tofmetry.reconstruct._mat_locate.guided_match`), when at least
    ``min_matched`` do. The pattern's own placement is as fine as its search (0.5 deg steps, 2 mm cells):
    ``pattern_sigma`` (deg, mm) is its 1-sigma when no dot refines it
    (``registration.mat_pattern_sigma_deg`` / ``_mm``). Measured against the truth on the family's
    held-out draws 89-109 (43 views so placed, in 19 runs, each seed once; mostly rocker arms lying
    flat): rotation RMS 0.186 deg, p90 0.29, at most 0.57 deg; the object's largest displacement p50
    1.5, p90 2.35, at most 3.4 mm (held-out draw 111's 7 such views, of one rocker arm, within 0.13
    deg / 2.0 mm). Until session 54 the turn's 1-sigma was 0.3 deg, which put such a view's p90 (1.645
    sigma, its tilt's with it) on the pose gate's 0.5 deg, in or out by a hundredth of a degree of
    tilt: a bunny of draw 106 was flagged for it, its view 0.10 deg / 1.3 mm off."""
    d = locate_dense(alb, rays, plane, footprint_xy, mat)
    if not d["located"]:
        return MatFix(False, reason=d.get("reason", "the pattern did not place it"))
    c, r = seen_dots(alb, rays, plane, contrast(mat), min_pixels=4, max_elongation=2.0)
    R, t, matched = guided_match(c, r, d["R"], d["t"], mat)
    if (matched >= 0).sum() >= min_matched:
        return fix_from_matches(c, R, t, matched, mat, plane, "pattern+dots")
    S = np.eye(4)
    S[:2, :2], S[:2, 3] = d["R"], d["t"]
    # its sigmas hold about the middle of the patch it correlated: the object's footprint, on the sheet
    return MatFix(True, S @ plane_frame(plane), len(c), int((matched >= 0).sum()), float("nan"), pattern_sigma[0],
                  pattern_sigma[1], how="pattern", centre_xy=d["R"] @ np.asarray(footprint_xy, np.float64) + d["t"])
