"""Each view placed on a printed dot mat of known layout: the study's flat targets, found automatically.

The study registered its views on flat targets placed around the object, picked by hand (§5: 2 cm
of registration error). A :class:`~tofmetry._shared.dot_mat.DotMat` under the object is a target
whose layout is known, so each view can be placed on it alone, without a chain of pairwise
registrations, whatever the object's shape (a vase of revolution, a thin plaque, a featureless dome):

1. **The support plane** (the view's segmentation) gives the camera's tilt and height above the mat.
2. **The dots**: on the support, the relative log IR albedo (:func:`~tofmetry.reconstruct._photometric.log_albedo`)
   splits toner from paper (a pixel darker than the paper around it by half their contrast is toner);
   each dark blob wholly surrounded by paper is a dot.
   Its pixels' rays are cut with the support plane, and the dot's centre and radius are taken on
   it (:mod:`~tofmetry.reconstruct._mat_dots`). Blobs that are not round (dots
   printed over each other) are left out.
3. **The match**: pairs of seen dots against pairs of printed dots of the same spacing and radii;
   each pair of pairs gives a rigid motion of the plane, scored by the seen dots it brings within
   ``match_mm`` of a printed dot of their radius; the best is refitted on its matches
   (least squares, twice). A seen dot that matches a printed dot overlapping another is left out
   of the fit (:data:`OVERLAPPING`): the two read as one blob whose centre lies between theirs
   (2.9 mm RMS off on a plaque's scan, where the dots printed apart read 0.3-0.8 mm). On four
   development draws leaving them out lowered the dots' residual RMS from 1.27-1.50 to 0.72-1.22 mm.

The result is the camera's pose in the mat's frame (z up, origin at the sheet's centre, x along its
width) with the dots' residuals, their count and the in-plane uncertainty they imply.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from tofmetry._shared.dot_mat import DotMat
from tofmetry.reconstruct._mat_dots import plane_frame, seen_dots


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
                "centre_xy": [round(float(x), 5) for x in self.centre_xy] if np.isfinite(self.centre_xy).all() else None,
                "camera_to_mat": self.camera_to_mat.tolist() if self.located else None}


def contrast(mat: DotMat) -> float:
    """``ln(paper / toner)``: how much darker the dots read in log albedo."""
    return float(np.log(mat.light / max(mat.dark, 1e-3)))


def rotation_2d(theta_rad: float) -> np.ndarray:
    """(2, 2) rotation by ``theta_rad`` (counter-clockwise in x, y)."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    return np.array([[c, -s], [s, c]])


def _rigid_2d(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation (2, 2) and shift (2,) taking points ``a`` (K, 2) onto ``b`` (K, 2)."""
    ca, cb = a.mean(0), b.mean(0)
    M = (a - ca).T @ (b - cb)
    th = np.arctan2(M[0, 1] - M[1, 0], M[0, 0] + M[1, 1])
    R = rotation_2d(th)
    return R, cb - R @ ca


#: ``matched`` of a seen dot that matches a printed dot overlapping another (:meth:`DotMat.overlapping`):
#: seen and matched, but left out of every fit (its blob's centre lies between the two dots')
OVERLAPPING = -2


def _apart(matched: np.ndarray, overlapping: np.ndarray) -> np.ndarray:
    """``matched`` (K,) with the seen dots matched to an overlapping printed dot set to :data:`OVERLAPPING`."""
    hit = (matched >= 0) & overlapping[np.maximum(matched, 0)]
    return np.where(hit, OVERLAPPING, matched)


class _Printed:
    """The printed dots' centres ``C`` (M, 2) [m] in a tree, and a raster of the cells (``cell`` [m]) a
    dot's box of half-side ``tol`` [m] reaches: a point off those has no dot within ``tol``. Most of the
    points :func:`match_dots` asks about lie far from any dot (the mat is about 2 % covered within 4
    mm of a centre), and the raster answers them without the tree."""

    def __init__(self, C: np.ndarray, tol: float, cell: float = 0.002):
        self.C, self.tol, self.cell = C, float(tol), float(cell)
        self.tree = cKDTree(C)
        self.lo = C.min(0) - tol
        self.shape = (np.floor((C.max(0) + tol - self.lo) / cell) + 1).astype(int)
        self.near = np.zeros(self.shape, bool)
        a = np.floor((C - tol - self.lo) / cell).astype(int)
        b = np.floor((C + tol - self.lo) / cell).astype(int) + 1
        for (a0, a1), (b0, b1) in zip(a, b):
            self.near[a0:b0, a1:b1] = True

    def query(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """As ``cKDTree(C).query(p, distance_upper_bound=tol)`` for ``p`` (N, 2) [m]: the distance to the
        nearest dot and its index, ``inf`` and ``len(C)`` where none lies within ``tol``."""
        i = np.floor((p - self.lo) / self.cell).astype(int)
        inside = np.all((i >= 0) & (i < self.shape), axis=1)
        ask = np.flatnonzero(inside)
        ask = ask[self.near[i[ask, 0], i[ask, 1]]]
        d, j = np.full(len(p), np.inf), np.full(len(p), len(self.C))
        if len(ask):
            d[ask], j[ask] = self.tree.query(p[ask], distance_upper_bound=self.tol)
        return d, j


def _matches(R: np.ndarray, t: np.ndarray, seen_c: np.ndarray, seen_r: np.ndarray, printed: _Printed, Rad: np.ndarray,
             rtol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(ok, j)`` (H, k) of the seen dots ``seen_c`` (k, 2) [m] moved by H hypotheses ``R @ c + t`` (``R``
    (H, 2, 2), ``t`` (H, 2) [m]): whether a printed dot (``printed``, radii ``Rad`` [m]) lies within its
    ``tol`` with a radius within ``rtol`` [m] of the seen one's ``seen_r`` (k,) [m], and its index
    (``len(Rad)`` where none)."""
    x, y = seen_c[None, :, 0], seen_c[None, :, 1]
    P = np.stack([R[:, 0, :1] * x + R[:, 0, 1:] * y + t[:, :1], R[:, 1, :1] * x + R[:, 1, 1:] * y + t[:, 1:]], -1)
    d, j = printed.query(P.reshape(-1, 2))
    j = j.reshape(P.shape[:2])
    ok = np.isfinite(d.reshape(P.shape[:2])) & (np.abs(Rad[np.minimum(j, len(Rad) - 1)] - seen_r[None]) <= rtol)
    return ok, j


def _best_hypothesis(R: np.ndarray, t: np.ndarray, seen_c: np.ndarray, seen_r: np.ndarray, printed: _Printed,
                     Rad: np.ndarray, rtol: float, block: int = 8) -> tuple[int, np.ndarray, np.ndarray]:
    """The hypothesis (``R`` (H, 2, 2), ``t`` (H, 2) [m]) that matches the most seen dots (the first of
    them on a tie) and its :func:`_matches` ``(ok, j)`` (K,), the rest as :func:`_matches`.

    Every hypothesis on every dot is about a million tree queries a view (0.3 s); counted a block of
    dots at a time, a hypothesis is dropped once the dots it has matched plus those still to count fall
    short of what the best so far matches on all of them (which it then cannot beat), so that most
    are counted on the first block only, and the pick is the same as counting them all."""
    H, K = len(R), len(seen_c)
    alive, got = np.arange(H), np.zeros(H, int)
    lower = 0
    for lo in range(0, K, block):
        k = slice(lo, lo + block)
        ok, _ = _matches(R[alive], t[alive], seen_c[k], seen_r[k], printed, Rad, rtol)
        got[alive] += ok.sum(1)
        left = max(K - lo - block, 0)
        lead = alive[int(np.argmax(got[alive]))]
        lower = max(lower, int(_matches(R[lead:lead + 1], t[lead:lead + 1], seen_c, seen_r, printed, Rad,
                                        rtol)[0].sum()))
        alive = alive[got[alive] + left >= lower]
    best = int(alive[np.argmax(got[alive])])
    ok, j = _matches(R[best:best + 1], t[best:best + 1], seen_c, seen_r, printed, Rad, rtol)
    return best, ok[0], j[0]


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
    R : (2, 2); t : (2,) [m] (``mat = R @ seen + t``); matched : (K,) index of the printed dot, -1 where
    none, :data:`OVERLAPPING` where it is one printed over another (left out of the fit)
    """
    C, Rad = mat.dots()
    K = len(seen_c)
    none = (np.eye(2), np.zeros(2), np.full(K, -1))
    if K < 3:
        return none
    tol, rtol = match_mm * 1e-3, radius_mm * 1e-3
    printed = _Printed(C, tol)
    tree = printed.tree
    # printed pairs by spacing (closer than the farthest seen pair)
    dmax = float(np.max(np.linalg.norm(seen_c[:, None] - seen_c[None], axis=2))) + tol
    pairs = tree.query_pairs(dmax, output_type="ndarray")
    if not len(pairs):
        return none
    pi, pj = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))].T  # in (i, j) order, as the ties' order below rests on it
    pi, pj = np.concatenate([pi, pj]), np.concatenate([pj, pi])  # both orders
    pd = np.linalg.norm(C[pi] - C[pj], axis=1)
    order = np.argsort(pd)
    pi, pj, pd = pi[order], pj[order], pd[order]
    si, sj = np.triu_indices(K, 1)
    sd = np.linalg.norm(seen_c[si] - seen_c[sj], axis=1)
    keep = np.argsort(sd)[:max_pairs]
    # each seen pair against every printed pair of its spacing (within tol), in the seen pairs' order
    a, b, d = si[keep], sj[keep], sd[keep]
    lo, hi = np.searchsorted(pd, d - tol), np.searchsorted(pd, d + tol)
    n = hi - lo
    seen = np.repeat(np.arange(len(d)), n)
    cand = np.repeat(lo - np.cumsum(n) + n, n) + np.arange(int(n.sum()))
    same = (np.abs(Rad[pi[cand]] - seen_r[a[seen]]) <= rtol) & (np.abs(Rad[pj[cand]] - seen_r[b[seen]]) <= rtol)
    seen, cand = seen[same], cand[same]
    if not len(cand):
        return none
    A, B = np.c_[a[seen], b[seen]], np.c_[pi[cand], pj[cand]]
    va = seen_c[A[:, 1]] - seen_c[A[:, 0]]
    vb = C[B[:, 1]] - C[B[:, 0]]
    th = np.arctan2(vb[:, 1], vb[:, 0]) - np.arctan2(va[:, 1], va[:, 0])
    cs, sn = np.cos(th), np.sin(th)
    mid_a = (seen_c[A[:, 0]] + seen_c[A[:, 1]]) / 2
    mid_b = (C[B[:, 0]] + C[B[:, 1]]) / 2
    t = mid_b - np.stack([cs * mid_a[:, 0] - sn * mid_a[:, 1], sn * mid_a[:, 0] + cs * mid_a[:, 1]], 1)
    # the hypothesis that brings the most seen dots onto a printed dot of their radius
    best, ok, j = _best_hypothesis(np.stack([np.c_[cs, -sn], np.c_[sn, cs]], 1), t, seen_c, seen_r, printed, Rad,
                                   rtol)
    R = rotation_2d(th[best])
    tt = t[best]
    overlapping = mat.overlapping()
    matched = _apart(np.where(ok, j, -1), overlapping)
    for _ in range(2):  # refit on the matches, match again
        m = matched >= 0
        if m.sum() < 3:
            break
        R, tt = _rigid_2d(seen_c[m], C[matched[m]])
        d, j = tree.query(seen_c @ R.T + tt, distance_upper_bound=tol)
        matched = _apart(np.where(np.isfinite(d) & (np.abs(Rad[np.minimum(j, len(C) - 1)] - seen_r) <= rtol), j, -1),
                         overlapping)
    return R, tt, matched


def locate_on_mat(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray | None, mat: DotMat, min_matched: int = 6,
                  match_mm: float = 4.0, min_share: float = 0.5) -> MatFix:
    """One view's camera pose on the mat (module docstring); ``alb``, ``rays``, ``plane`` as
    :func:`~tofmetry.reconstruct._mat_dots.seen_dots`.

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
    if m.sum() < max(min_matched, min_share * (len(c) - int(np.sum(matched == OVERLAPPING)))):
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
    them, and the motion refitted on them (twice); returns (R, t, matched (K,), -1: none,
    :data:`OVERLAPPING`: one printed over another, left out)."""
    C, Rad = mat.dots()
    overlapping = mat.overlapping()
    tree = cKDTree(C)
    matched = np.full(len(c), -1)
    for _ in range(2):
        if len(c) == 0:
            break
        d, j = tree.query(c @ R.T + t, distance_upper_bound=match_mm * 1e-3)
        ok = np.isfinite(d)
        ok[ok] &= np.abs(Rad[j[ok]] - r[ok]) <= radius_mm * 1e-3
        matched = _apart(np.where(ok, j, -1), overlapping)
        ok = matched >= 0
        if ok.sum() < 3:
            break
        R, t = _rigid_2d(c[ok], C[j[ok]])
    return R, t, matched
