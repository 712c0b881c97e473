"""Each view placed on a printed dot mat of known layout: the study's flat targets, found automatically.

The study registered its views on flat targets placed around the object, picked by hand (§5: 2 cm
of registration error). A :class:`~tofmetry._shared.dot_mat.DotMat` under the object is a target
whose layout is known, so each view can be placed on it alone, without a chain of pairwise
registrations, whatever the object's shape (a vase of revolution, a thin plaque, a featureless dome):

1. **The support plane** (the view's segmentation) gives the camera's tilt and height above the mat.
2. **The dots**: on the support, the relative log IR albedo (:func:`~tofmetry.reconstruct._photometric.log_albedo`)
   splits toner from paper (a pixel darker than the paper around it by half their contrast is toner);
   each dark blob wholly surrounded by paper is a dot.
   Its pixels' rays are cut with the support plane (not their measured points: a ToF camera reads
   dark toner a few millimetres farther than the paper, which would shift every dot away from the
   camera), and the dot's centre and radius are the centroid and second moments of those cuts
   [m, in the plane]. Blobs that are not round (dots printed over each other) are left out.
3. **The match**: pairs of seen dots against pairs of printed dots of the same spacing and radii;
   each pair of pairs gives a rigid motion of the plane, scored by the seen dots it brings within
   ``match_mm`` of a printed dot of their radius; the best is refitted on its matches
   (least squares, twice).

The result is the camera's pose in the mat's frame (z up, origin at the sheet's centre, x along its
width) with the dots' residuals, their count and the in-plane uncertainty they imply.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from tofmetry._shared.dot_mat import DotMat


@dataclass
class MatFix:
    """One view placed on the mat.

    Attributes
    ----------
    located : whether the view was placed (``reason`` says why not)
    camera_to_mat : (4, 4) camera to mat frame [m] (z up, origin at the sheet's centre)
    n_dots : dots seen (round, wholly on paper); n_matched : of them, matched to printed dots
    rms_mm : RMS distance of the matched dots' centres to the printed ones after the fit [mm]
    sigma_deg, sigma_mm : 1-sigma of the in-plane turn [deg] and shift [mm] those residuals imply
    how : "dots" (matched to the layout), "pattern+dots" (the whole pattern placed it and the dots
        seen refined it), "pattern" (the whole pattern alone); "" when not placed
    pattern_scale, pattern_scale_sigma : the matched dots' size relative to the printed layout, minus
        1, and its 1-sigma (a similarity fit; NaN without matched dots): the depth camera's scale
        at the mat (:func:`fix_from_matches`)
    tilt_sigma_deg : 1-sigma of the placement's tilt (its larger axis) [deg], NaN where not judged;
    tilt_deg : how far the dots turned it from the depth's support plane [deg]
        (:mod:`~tofmetry.reconstruct._mat_tilt`)
    noise_mm : 1-sigma per axis of a matched dot's centre that ``sigma_deg``, ``sigma_mm`` and
        ``pattern_scale_sigma`` rest on [mm] (:func:`fix_from_matches`, then
        :func:`with_pooled_noise`); NaN without matched dots
    centre_xy : (2,) the matched dots' centroid on the sheet [m], about which ``sigma_mm`` holds
        (NaN without matched dots)
    """

    located: bool
    camera_to_mat: np.ndarray = field(default_factory=lambda: np.eye(4))
    n_dots: int = 0
    n_matched: int = 0
    rms_mm: float = float("nan")
    sigma_deg: float = float("nan")
    sigma_mm: float = float("nan")
    reason: str = ""
    how: str = ""
    pattern_scale: float = float("nan")
    pattern_scale_sigma: float = float("nan")
    tilt_sigma_deg: float = float("nan")
    tilt_deg: float = 0.0
    noise_mm: float = float("nan")
    centre_xy: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))

    @property
    def rotation_sigma_deg(self) -> float:
        """1-sigma of the placement's rotation [deg]: its turn about the vertical and its tilt
        (:attr:`tilt_sigma_deg`, 0 where not judged) together."""
        return float(np.hypot(self.sigma_deg, np.nan_to_num(self.tilt_sigma_deg)))

    @property
    def residual_dof(self) -> int:
        """Degrees of freedom of the dots' residuals: 2 per matched dot less the 3 of the in-plane fit."""
        return max(2 * self.n_matched - 3, 0) if np.isfinite(self.noise_mm) else 0

    def sigma_at_mm(self, point_m: np.ndarray) -> float:
        """1-sigma of the placement's displacement of ``point_m`` (3,) (mat frame [m]) [mm]: the shift
        at the dots' centroid, and the rotation (turn and tilt) times the point's distance from it."""
        c = np.r_[self.centre_xy, 0.0]
        lever = float(np.linalg.norm(np.asarray(point_m, np.float64) - c)) if np.isfinite(c).all() else 0.0
        return float(np.hypot(self.sigma_mm, np.radians(self.rotation_sigma_deg) * lever * 1e3))

    def to_dict(self) -> dict:
        return {"located": self.located, "how": self.how, "n_dots": self.n_dots, "n_matched": self.n_matched,
                "rms_mm": round(self.rms_mm, 3), "sigma_deg": round(self.sigma_deg, 4),
                "sigma_mm": round(self.sigma_mm, 3), "reason": self.reason,
                "pattern_scale_pct": round(100 * self.pattern_scale, 4),
                "pattern_scale_sigma_pct": round(100 * self.pattern_scale_sigma, 4),
                "tilt_sigma_deg": round(self.tilt_sigma_deg, 4), "tilt_from_dots_deg": round(self.tilt_deg, 4),
                "dot_noise_mm": round(self.noise_mm, 3),
                "camera_to_mat": self.camera_to_mat.tolist() if self.located else None}


def contrast(mat: DotMat) -> float:
    """``ln(paper / toner)``: how much darker the dots read in log albedo."""
    return float(np.log(mat.light / max(mat.dark, 1e-3)))


def rotation_2d(theta_rad: float) -> np.ndarray:
    """(2, 2) rotation by ``theta_rad`` (counter-clockwise in x, y)."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    return np.array([[c, -s], [s, c]])


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
    its footprint there (far pixels cover more: ``Z^3 / (n . ray)``)."""
    q = ray * (-d / (ray @ nrm))[:, None]  # the rays cut with the plane
    xy = q @ G[:2, :3].T + G[:2, 3]
    w = q[:, 2] ** 2 / np.abs(ray @ nrm) * q[:, 2]
    w = w / w.sum()
    c = w @ xy
    return c, (xy - c).T @ ((xy - c) * w[:, None])


def seen_dots(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray, contrast: float, min_pixels: int = 6,
              max_elongation: float = 1.4, paper_window: int = 31, with_rays: bool = False) -> tuple:
    """The printed dots one view sees on its support (module docstring, step 2).

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

    Returns
    -------
    centres : (K, 2) in :func:`plane_frame`'s x, y [m]; radii : (K,) [m]; with ``with_rays``, then
    per dot (M, 3) its pixels' rays ``(x, y, 1)``
    """
    H, W = alb.shape
    known = np.isfinite(alb)
    empty = (np.zeros((0, 2)), np.zeros(0)) + (([],) if with_rays else ())
    if known.sum() < 100:
        return empty
    paper = ndimage.maximum_filter(np.where(known, alb, -np.inf), size=paper_window, mode="nearest")
    dark = known & (alb < paper - contrast / 2)
    bright = known & ~dark
    lab, n = ndimage.label(dark)
    if n == 0:
        return empty
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
        blob = ndimage.binary_fill_holes(lab[r0:r1, c0:c1] == k)  # pixels without depth inside a dark dot
        if blob.sum() < min_pixels:
            continue
        rim = ndimage.binary_dilation(blob) & ~blob
        if not bright[r0:r1, c0:c1][rim].all():
            continue  # not wholly on paper: the object, a hole or the sheet's edge next to it
        rr, cc = np.nonzero(blob)
        ray = np.column_stack([rays[rr + r0, cc + c0], np.ones(len(rr))])
        c, cov = dot_moments(ray, nrm, float(plane[3]), G)
        lam = np.linalg.eigvalsh(cov)
        if lam[0] <= 0 or np.sqrt(lam[1] / lam[0]) > max_elongation:
            continue
        centres.append(c)
        radii.append(np.sqrt(2.0 * lam.sum()))
        kept.append(ray)
    return (np.array(centres).reshape(-1, 2), np.array(radii)) + ((kept,) if with_rays else ())


def _rigid_2d(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation (2, 2) and shift (2,) taking points ``a`` (K, 2) onto ``b`` (K, 2)."""
    ca, cb = a.mean(0), b.mean(0)
    M = (a - ca).T @ (b - cb)
    th = np.arctan2(M[0, 1] - M[1, 0], M[0, 0] + M[1, 1])
    R = rotation_2d(th)
    return R, cb - R @ ca


def match_dots(seen_c: np.ndarray, seen_r: np.ndarray, mat: DotMat, match_mm: float = 4.0,
               radius_mm: float = 3.0, max_pairs: int = 600) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rigid motion of the plane that takes the seen dots onto the printed ones (module docstring, step 3).

    Parameters
    ----------
    seen_c : (K, 2) [m]; seen_r : (K,) [m]; mat : the printed layout
    match_mm : a seen dot matches a printed one within this distance [mm]
    radius_mm : ... and radius difference [mm]
    max_pairs : pairs of seen dots tried (the nearest pairs first: they are the likeliest both seen right)

    Returns
    -------
    R : (2, 2); t : (2,) [m] (``mat = R @ seen + t``); matched : (K,) index of the printed dot, -1 where none
    """
    C, Rad = mat.dots()
    K = len(seen_c)
    none = (np.eye(2), np.zeros(2), np.full(K, -1))
    if K < 3:
        return none
    tol, rtol = match_mm * 1e-3, radius_mm * 1e-3
    tree = cKDTree(C)
    # printed pairs by spacing (closer than the farthest seen pair)
    dmax = float(np.max(np.linalg.norm(seen_c[:, None] - seen_c[None], axis=2))) + tol
    pi, pj = np.array(sorted(tree.query_pairs(dmax))).reshape(-1, 2).T
    if pi.size == 0:
        return none
    pi, pj = np.concatenate([pi, pj]), np.concatenate([pj, pi])  # both orders
    pd = np.linalg.norm(C[pi] - C[pj], axis=1)
    order = np.argsort(pd)
    pi, pj, pd = pi[order], pj[order], pd[order]
    si, sj = np.triu_indices(K, 1)
    sd = np.linalg.norm(seen_c[si] - seen_c[sj], axis=1)
    keep = np.argsort(sd)[:max_pairs]
    hyp_a, hyp_b = [], []
    for a, b, d in zip(si[keep], sj[keep], sd[keep]):
        lo, hi = np.searchsorted(pd, [d - tol, d + tol])
        cand = np.arange(lo, hi)
        cand = cand[(np.abs(Rad[pi[cand]] - seen_r[a]) <= rtol) & (np.abs(Rad[pj[cand]] - seen_r[b]) <= rtol)]
        for c in cand:
            hyp_a.append((a, b))
            hyp_b.append((pi[c], pj[c]))
    if not hyp_a:
        return none
    A, B = np.array(hyp_a), np.array(hyp_b)
    va = seen_c[A[:, 1]] - seen_c[A[:, 0]]
    vb = C[B[:, 1]] - C[B[:, 0]]
    th = np.arctan2(vb[:, 1], vb[:, 0]) - np.arctan2(va[:, 1], va[:, 0])
    cs, sn = np.cos(th), np.sin(th)
    mid_a = (seen_c[A[:, 0]] + seen_c[A[:, 1]]) / 2
    mid_b = (C[B[:, 0]] + C[B[:, 1]]) / 2
    t = mid_b - np.stack([cs * mid_a[:, 0] - sn * mid_a[:, 1], sn * mid_a[:, 0] + cs * mid_a[:, 1]], 1)
    # score every hypothesis on every seen dot at once
    px = cs[:, None] * seen_c[None, :, 0] - sn[:, None] * seen_c[None, :, 1] + t[:, 0, None]
    py = sn[:, None] * seen_c[None, :, 0] + cs[:, None] * seen_c[None, :, 1] + t[:, 1, None]
    d, j = tree.query(np.stack([px, py], -1).reshape(-1, 2), distance_upper_bound=tol)
    j = j.reshape(len(A), K)
    ok = np.isfinite(d.reshape(len(A), K))
    ok &= np.abs(Rad[np.minimum(j, len(C) - 1)] - seen_r[None]) <= rtol
    best = int(np.argmax(ok.sum(1)))
    R = rotation_2d(th[best])
    tt = t[best]
    matched = np.where(ok[best], j[best], -1)
    for _ in range(2):  # refit on the matches, match again
        m = matched >= 0
        if m.sum() < 3:
            break
        R, tt = _rigid_2d(seen_c[m], C[matched[m]])
        d, j = tree.query(seen_c @ R.T + tt, distance_upper_bound=tol)
        matched = np.where(np.isfinite(d) & (np.abs(Rad[np.minimum(j, len(C) - 1)] - seen_r) <= rtol), j, -1)
    return R, tt, matched


def locate_on_mat(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray | None, mat: DotMat, min_matched: int = 6,
                  match_mm: float = 4.0, min_share: float = 0.5) -> MatFix:
    """One view's camera pose on the mat (module docstring); ``alb``, ``rays``, ``plane`` as :func:`seen_dots`.

    A view is placed when at least ``min_matched`` of the dots it sees, and at least ``min_share`` of
    them, match the layout. Measured: a view of 41 dots of another mat's layout matched 6 by chance
    (the best of thousands of pair hypotheses); the views of the right mat matched 80-100 %."""
    if plane is None:
        return MatFix(False, reason="no support plane was found in the view")
    c, r = seen_dots(alb, rays, plane, contrast(mat))
    if len(c) < min_matched:
        return MatFix(False, n_dots=len(c), reason=f"{len(c)} round dot(s) seen wholly on the mat's paper "
                                                    f"(at least {min_matched} needed): is the mat in view?")
    R, t, matched = match_dots(c, r, mat, match_mm)
    m = matched >= 0
    if m.sum() < max(min_matched, min_share * len(c)):
        return MatFix(False, n_dots=len(c), n_matched=int(m.sum()),
                      reason=f"{int(m.sum())} of the {len(c)} dots seen match the mat's layout (at least "
                             f"{min_matched} and {100 * min_share:.0f} % needed): another mat, or its description "
                             "is wrong?")
    return fix_from_matches(c, R, t, matched, mat, plane)


def fix_from_matches(c: np.ndarray, R: np.ndarray, t: np.ndarray, matched: np.ndarray, mat: DotMat,
                     plane: np.ndarray, how: str = "dots") -> MatFix:
    """The :class:`MatFix` of seen dots ``c`` (K, 2) matched (``matched`` (K,), -1: none) by ``sheet =
    R @ c + t``, with their residuals and the uncertainty they imply.

    The dots' size against the printed layout (``pattern_scale``: the least-squares scale of the
    matched centres about their centroid, the rotation held) measures the depth camera's scale on
    the mat. The dots are the cuts of their rays with the support plane, and central projection
    onto a plane the depth puts ``(1 + g)`` times too far is a homothety about the camera's foot: a
    depth gain ``g`` (or a focal length ``g`` too short) makes the pattern ``g`` too large, which
    is what it does to the object's points. A range offset ``e`` of the ground makes it ``e / H``
    too large (``H`` the camera's height). Its 1-sigma is the dots' residual per axis over the
    root of their spread about their centroid.

    The residual per axis is the dots' sum of squares over its degrees of freedom (2 per dot less
    the fit's 3): three dots fit by three parameters leave a residual that says little about their
    noise (family draw 86: 0.26 mm RMS from three dots of a view 0.69 deg off, where the other
    views' dots scattered by 1.2 mm). :func:`with_pooled_noise` weighs it with the scan's other views."""
    m = matched >= 0
    C = mat.dots()[0][matched[m]]
    res = c[m] @ R.T + t - C
    ss = float(np.sum(res ** 2))
    rms = float(np.sqrt(ss / max(m.sum(), 1)))
    cc = c[m] - c[m].mean(0)
    spread = float(np.sum(cc ** 2))
    dof = 2 * int(m.sum()) - 3
    s_axis = float(np.sqrt(ss / dof)) if dof > 0 else float("nan")  # per axis
    # printed = (1 + k) R seen about the centroids: the seen pattern is 1 / (1 + k) the printed size
    scale = spread / float(np.sum((C - C.mean(0)) * (cc @ R.T))) - 1.0 if spread > 0 else float("nan")
    S = np.eye(4)
    S[:2, :2], S[:2, 3] = R, t
    T = S @ plane_frame(plane)
    return MatFix(True, T, len(c), int(m.sum()), rms * 1e3, float(np.degrees(s_axis / np.sqrt(max(spread, 1e-12)))),
                  float(s_axis / np.sqrt(m.sum()) * 1e3), how=how, pattern_scale=scale,
                  pattern_scale_sigma=float(s_axis / np.sqrt(spread)) if spread > 0 else float("nan"),
                  noise_mm=s_axis * 1e3, centre_xy=C.mean(0))


def pooled_dot_noise(fixes) -> tuple[float, int]:
    """(1-sigma per axis of a dot's centre [mm], its degrees of freedom) pooled over the placements
    ``fixes`` (iterable of :class:`MatFix`) that matched dots: their residuals' sums of squares over
    their degrees of freedom together. (NaN, 0) when none has any."""
    use = [f for f in fixes if f.located and f.residual_dof > 0]
    dof = sum(f.residual_dof for f in use)
    return (float(np.sqrt(sum(f.noise_mm ** 2 * f.residual_dof for f in use) / dof)) if dof else float("nan")), dof


def with_pooled_noise(fix: MatFix, pooled_mm: float, prior_dof: float = 6.0) -> MatFix:
    """``fix`` with its sigmas resting on its dots' noise weighed with the scan's (``pooled_mm``,
    :func:`pooled_dot_noise`) as ``prior_dof`` degrees of freedom: a view of many dots keeps its
    own, a view of three takes mostly the scan's (a scaled-inverse-chi-square posterior's mean).

    ``prior_dof`` = 6 (three dots' worth): over the 206 mat placements of family draw 86 the turn's
    error over its 1-sigma had an RMS of 1.05 with it (1.13 on the dots' own noise alone), and the
    two views of 3-5 dots fell within 2.6 sigma (13.6 before)."""
    if not (fix.located and np.isfinite(fix.noise_mm) and fix.noise_mm > 0 and np.isfinite(pooled_mm)):
        return fix
    s = float(np.sqrt((fix.noise_mm ** 2 * fix.residual_dof + prior_dof * pooled_mm ** 2)
                      / (fix.residual_dof + prior_dof)))
    k = s / fix.noise_mm
    return replace(fix, sigma_deg=fix.sigma_deg * k, sigma_mm=fix.sigma_mm * k,
                   pattern_scale_sigma=fix.pattern_scale_sigma * k, noise_mm=s)


def guided_match(c: np.ndarray, r: np.ndarray, R: np.ndarray, t: np.ndarray, mat: DotMat, match_mm: float = 6.0,
                 radius_mm: float = 4.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seen dots ``c``, ``r`` matched near where an approximate motion (``sheet = R @ c + t``) puts
    them, and the motion refitted on them (twice); returns (R, t, matched (K,), -1: none)."""
    C, Rad = mat.dots()
    tree = cKDTree(C)
    matched = np.full(len(c), -1)
    for _ in range(2):
        if len(c) == 0:
            break
        d, j = tree.query(c @ R.T + t, distance_upper_bound=match_mm * 1e-3)
        ok = np.isfinite(d)
        ok[ok] &= np.abs(Rad[j[ok]] - r[ok]) <= radius_mm * 1e-3
        matched = np.where(ok, j, -1)
        if ok.sum() < 3:
            break
        R, t = _rigid_2d(c[ok], C[j[ok]])
    return R, t, matched
