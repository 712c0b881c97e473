"""The printed dots one view sees on its support: found in the IR albedo, centred on the support plane.

Step 2 of placing a view on a dot mat (:mod:`~tofmetry.reconstruct._mat_locate`): on the support,
the relative log IR albedo splits toner from paper; each dark blob wholly surrounded by paper is a
dot. Its pixels' rays are cut with the support plane (not their measured points: a ToF camera reads
dark toner a few millimetres farther than the paper, which would shift every dot away from the
camera); the dot's centre and radius are the centroid and second moments of those cuts.

With ``sub_pixel`` (:func:`seen_dots`; off by default) the centre weighs each pixel of the blob grown
by one by the share of it the toner covers (:func:`toner_share`). On noise-free grazing views of one
dot it is 0.07-0.14 mm RMS off the printed centre where the blob's centroid is 0.56-1.17 mm
(``tests/reconstruct/test_mat_locate.py``). On the virtual sensor's scans (a plaque's 239 dots at
0.83 m, session 50), of the dots printed apart from the others, 0.31-0.60 mm against 0.68-0.78 mm.
But the placements it gives sit farther out along the view: on four development draws, with the
overlapping dots left out (:meth:`~tofmetry._shared.dot_mat.DotMat.overlapping`), the dots'
residual RMS fell from 0.72-1.22 to 0.48-0.82 mm while the views' common displacement of the object
toward the camera grew by 0.03-0.23 mm. On 40 family draws before that rule, the placements'
rotation was better on 28 and their displacement at the object worse on 25, the models neither
better nor worse. Until that shift is understood the blob's centroid stays the default.

Frames: pixel (u, v); camera x right, y down, z forward; the plane frame (:func:`plane_frame`) has
z along the plane's normal toward the camera and its origin at the foot of the camera centre.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage


def plane_frame(plane: np.ndarray) -> np.ndarray:
    """(4, 4) camera to a frame of the support plane: z its normal (toward the camera), x the camera's
    x projected on it, origin the foot of the camera centre."""
    n = np.asarray(plane[:3], np.float64)
    n = n / np.linalg.norm(n)
    x = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - n[1] * n
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(n, x), n])
    o = -float(plane[3]) * n
    G = np.eye(4)
    G[:3, :3], G[:3, 3] = R, -R @ o
    return G


def albedo_image(index: np.ndarray, shape: tuple[int, int], ground: np.ndarray, log_alb: np.ndarray) -> np.ndarray:
    """(H, W) relative log IR albedo of the support's pixels (NaN elsewhere), median-filtered 3 x 3
    over them (the speckle of a grazing, far support)."""
    H, W = shape
    g = ground & np.isfinite(log_alb)
    img = np.full(H * W, np.nan)
    img[index[g]] = log_alb[g]
    img = img.reshape(H, W)
    pad = np.pad(img, 1, mode="edge")
    stack = np.sort(np.stack([pad[a:a + H, b:b + W] for a in range(3) for b in range(3)]), axis=0)  # NaN last
    cnt = np.isfinite(stack).sum(0)
    lo = np.take_along_axis(stack, np.maximum((cnt - 1) // 2, 0)[None], 0)[0]
    hi = np.take_along_axis(stack, np.maximum(cnt // 2, 0)[None], 0)[0]
    med = (lo + hi) / 2
    med[~np.isfinite(img)] = np.nan
    return med


def dot_moments(ray: np.ndarray, nrm: np.ndarray, d: float, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A dot's centre (2,) and second moments (2, 2) on the plane ``nrm . p + d = 0`` [m], in its frame
    ``G`` (:func:`plane_frame`): its pixels' rays ``ray`` (M, 3) cut with the plane, each pixel weighing
    its footprint there (far pixels cover more: ``Z^3 / (n . ray)``). ``ray`` may be (M, 4): its last
    column then weighs each pixel further (the share of it the dot covers, :func:`toner_share`)."""
    ray = np.asarray(ray, np.float64)
    share = ray[:, 3] if ray.shape[1] > 3 else 1.0
    ray = ray[:, :3]
    q = ray * (-d / (ray @ nrm))[:, None]  # the rays cut with the plane
    xy = q @ G[:2, :3].T + G[:2, 3]
    w = q[:, 2] ** 2 / np.abs(ray @ nrm) * q[:, 2] * share
    w = w / w.sum()
    c = w @ xy
    return c, (xy - c).T @ ((xy - c) * w[:, None])


def toner_share(alb: np.ndarray, blob: np.ndarray, contrast: float, grow: int = 2) -> np.ndarray | None:
    """(h, w) share of each pixel of a window the dot's toner covers, 0 outside the dot grown by one
    pixel; None where the window's paper around it is not all seen.

    A pixel that the dot's edge crosses reads between paper and toner in linear albedo, in
    proportion to the share of it the toner covers (the sensor integrates over the pixel); the
    thresholded blob counts it whole or not at all (a pixel is dark beyond half the contrast in log
    albedo: about 72 % toner), and its centre moves by up to a pixel's footprint, 4-8 mm on a
    grazing mat at 1.5 m. Weighed by the share, the centre is the toner's own.

    Parameters
    ----------
    alb : (h, w) relative log IR albedo of a window around the dot (NaN where not support)
    blob : (h, w) bool, the dot's thresholded pixels, at least ``grow + 1`` pixels from the window's border
    contrast : ``ln(paper / toner)`` (:func:`~tofmetry.reconstruct._mat_locate.contrast`)
    grow : the paper's level is the median of the ring ``grow + 1`` pixels out
    """
    edge = ndimage.binary_dilation(blob)
    ring = ndimage.binary_dilation(blob, iterations=grow + 1) & ~ndimage.binary_dilation(blob, iterations=grow)
    known = np.isfinite(alb)
    if not (known[edge].all() and (ring & known).sum() >= 4):
        return None
    paper = float(np.median(alb[ring & known]))
    share = np.clip((1.0 - np.exp(np.where(edge, alb, paper) - paper)) / (1.0 - np.exp(-contrast)), 0.0, 1.0)
    share[blob] = np.maximum(share[blob], 1e-3)  # a noisy toner pixel still counts a little
    return np.where(edge, share, 0.0)


#: each pixel's 4 neighbours over a whole image, as (this pixel's slice, its neighbour's slice)
_NEIGHBOURS = ((np.s_[1:, :], np.s_[:-1, :]),  # the one above
               (np.s_[:-1, :], np.s_[1:, :]),  # below
               (np.s_[:, 1:], np.s_[:, :-1]),  # to the left
               (np.s_[:, :-1], np.s_[:, 1:]))  # to the right


def _filled_blobs(dark: np.ndarray, lab: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Each dark blob with its holes: ``(filled, alone)``, ``filled`` (H, W) int, the blob's label on its
    pixels and on the pixels it encloses, 0 elsewhere; ``alone`` (n + 1,) bool, whether that is what
    :func:`scipy.ndimage.binary_fill_holes` gives on the blob by itself.

    A hole of blob ``k`` is a 4-connected patch of the pixels that are not dark which touches neither
    the image's border nor any blob but ``k``. A patch between two or more blobs (a dot printed
    inside another's ring, or one that two dots close together) may be a hole of one of them or of
    none; the blobs it touches are left for the caller to fill one by one (``alone`` False).

    Parameters
    ----------
    dark : (H, W) bool; lab : (H, W) int, ``dark``'s 4-connected labels 1..n (:func:`scipy.ndimage.label`)
    """
    back, nb = ndimage.label(~dark)
    owner = np.zeros(nb + 1, np.int64)  # the one blob a patch touches; -1: more than one
    keys = []  # each (patch, blob) next to each other, as patch * (n + 1) + blob
    for here, there in _NEIGHBOURS:
        a, b = back[here], lab[there]
        m = (a > 0) & (b > 0)
        keys.append(a[m].astype(np.int64) * (n + 1) + b[m])
    patch, blob = np.divmod(np.unique(np.concatenate(keys)), n + 1)
    count = np.bincount(patch, minlength=nb + 1)
    owner[patch] = blob
    owner[count > 1] = -1
    edge = np.unique(np.concatenate([back[0], back[-1], back[:, 0], back[:, -1]]))
    owner[edge] = 0
    shared = count > 1
    shared[edge] = False
    alone = np.ones(n + 1, bool)
    alone[blob[shared[patch]]] = False
    return np.where(lab > 0, lab, np.maximum(owner, 0)[back]), alone


def seen_dots(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray, contrast: float, min_pixels: int = 6,
              max_elongation: float = 1.4, paper_window: int = 31, with_rays: bool = False,
              sub_pixel: bool = False) -> tuple:
    """The printed dots one view sees on its support (module docstring).

    Parameters
    ----------
    alb : (H, W) relative log IR albedo of the support's pixels, NaN elsewhere (:func:`albedo_image`)
    rays : (H, W, 2) each pixel's normalised ray (x, y): the point is ``Z (x, y, 1)``
    plane : (4,) support plane (unit normal toward the camera, ``n . p + d = 0``) [m], camera frame
    contrast : ``ln(paper / toner)`` of the mat's albedos; a pixel darker than the paper around it
        (the brightest within ``paper_window`` px) by more than half of it is toner
    min_pixels, max_elongation : a dot covers at least this many pixels, and its second moments in the
        plane differ by at most this ratio of axes (dots printed over each other are left out)

    with_rays : also return each dot's pixels' rays
    sub_pixel : each dot's centre weighed by the share of each pixel its toner covers
        (:func:`toner_share`; the blob's pixels whole where the paper around it is not all seen);
        its radius and roundness stay the blob's. Off by default (module docstring)

    Returns
    -------
    centres : (K, 2) in :func:`plane_frame`'s x, y [m]; radii : (K,) [m]; with ``with_rays``, then
    per dot (M, 4) its pixels' rays ``(x, y, 1)`` and their weights (:func:`dot_moments`)
    """
    H, W = alb.shape
    known = np.isfinite(alb)
    empty = (np.zeros((0, 2)), np.zeros(0)) + (([],) if with_rays else ())
    if known.sum() < 100:
        return empty
    # the brightest within the window: cv2's dilation is scipy's maximum_filter (mode "nearest"), faster
    paper = cv2.dilate(np.where(known, alb, -np.inf), np.ones((paper_window, paper_window), np.uint8),
                       borderType=cv2.BORDER_REPLICATE)
    dark = known & (alb < paper - contrast / 2)
    bright = known & ~dark
    lab, n = ndimage.label(dark)
    if n == 0:
        return empty
    filled, alone = _filled_blobs(dark, lab, n)
    size = np.bincount(filled.ravel(), minlength=n + 1)
    # a blob not wholly on paper: a pixel next to it (4-connected), outside it, is not paper
    off_paper = np.zeros(n + 1, bool)
    for here, there in _NEIGHBOURS:
        a, b = filled[here], filled[there]
        off_paper[a[(a > 0) & (a != b) & ~bright[there]]] = True
    flat = np.flatnonzero(filled)  # each blob's pixels in row-major order, as np.nonzero gives them
    owner = filled.ravel()[flat]
    order = np.argsort(owner, kind="stable")
    flat = flat[order]
    bounds = np.searchsorted(owner[order], np.arange(1, n + 2))
    nrm = np.asarray(plane[:3], np.float64)
    G = plane_frame(plane)
    centres, radii, kept = [], [], []
    for k, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        r0, r1 = max(sl[0].start - 1, 0), min(sl[0].stop + 1, H)
        c0, c1 = max(sl[1].start - 1, 0), min(sl[1].stop + 1, W)
        if r0 == 0 or c0 == 0 or r1 == H or c1 == W:
            continue  # touches the image's border: not wholly seen
        if alone[k]:  # its holes (pixels without depth inside a dark dot) filled above
            if size[k] < min_pixels or off_paper[k]:
                continue
            rr, cc = np.divmod(flat[bounds[k - 1]:bounds[k]], W)
            blob = None
        else:  # a patch it touches touches another blob too: filled on its own
            blob = ndimage.binary_fill_holes(lab[r0:r1, c0:c1] == k)
            if blob.sum() < min_pixels:
                continue
            rim = ndimage.binary_dilation(blob) & ~blob
            if not bright[r0:r1, c0:c1][rim].all():
                continue  # not wholly on paper: the object, a hole or the sheet's edge next to it
            rr, cc = np.nonzero(blob)
            rr, cc = rr + r0, cc + c0
        ray = np.column_stack([rays[rr, cc], np.ones(len(rr))])
        c, cov = dot_moments(ray, nrm, float(plane[3]), G)
        lam = np.linalg.eigvalsh(cov)
        if lam[0] <= 0 or np.sqrt(lam[1] / lam[0]) > max_elongation:
            continue
        if sub_pixel:  # the centre weighed by the share of each pixel the toner covers (toner_share)
            if blob is None:
                blob = filled[r0:r1, c0:c1] == k
            R0, R1, C0, C1 = max(r0 - 3, 0), min(r1 + 3, H), max(c0 - 3, 0), min(c1 + 3, W)
            grown = np.zeros((R1 - R0, C1 - C0), bool)
            grown[r0 - R0:r1 - R0, c0 - C0:c1 - C0] = blob
            share = toner_share(alb[R0:R1, C0:C1], grown, contrast)
            if share is not None:
                er, ec = np.nonzero(share > 0)
                ray = np.column_stack([rays[er + R0, ec + C0], np.ones(len(er)), share[er, ec]])
                c = dot_moments(ray, nrm, float(plane[3]), G)[0]
        centres.append(c)
        radii.append(np.sqrt(2.0 * lam.sum()))
        kept.append(ray if ray.shape[1] > 3 else np.c_[ray, np.ones(len(ray))])
    return (np.array(centres).reshape(-1, 2), np.array(radii)) + ((kept,) if with_rays else ())
