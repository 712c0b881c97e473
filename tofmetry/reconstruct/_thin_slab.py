"""Are the two faces of a slab held together by more than its rim? A check on the views' relative
position along the object's thinnest axis.

Why: the two faces of a slab (a plaque, a tile, a panel, a relief, a shell fragment) are seen from
opposite sides by views that share only its rim. The rim is swept along the slab's thickness, so its
surface leaves the translation along the thickness free: where the views of one face sit, relative
to the views of the other, rests on the points at the rim's two corners, whose depths are mixed
over the pixel and whose normals straddle the corner. Measured on simulated plaques (20-36 mm thick,
2026-11-30): pairs across the rim, registered from the true pose, slid 2.6 and 3.7 mm along the
thickness, both thinning the slab; the joint fit of all views left one face 1.4-1.5 mm inside the
reference with only noise and pixel mixing, and 2.5-2.9 mm with the simulated sensor's errors,
while its restart came back (a stable solution) and its loops closed. The scale fitted to those
models was 0.9-1.3 % off, against a predicted 0.16-0.31 %.

What tells it: the model's extent along its thinnest principal axis, a small share of the next, and
views on both sides of that axis (each sees one face). No view sees both faces of a slab, so their
views are tied by the rim alone. How firmly is reported: for the pairs of views that share surface
at the final poses, the stiffness of their relative translation along the axis with the rotations
left free (the Schur complement of the point-to-plane normal matrix, normals by PCA as in
:func:`~tofmetry.reconstruct._regview.registration_conditioning`), as a share of that pair's
stiffest translation, along the strongest chain of pairs from one side to the other. Views that see
the rim alone are on neither side: they slide along it harmlessly.
"""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._regview import RegView, overlap_jacobian


def translation_stiffness(src: RegView, tgt: RegView, T: np.ndarray, radius_m: float,
                          min_matched: int = 50) -> np.ndarray | None:
    """(3, 3) stiffness of the relative translation of ``src`` and ``tgt`` (target frame, per matched
    point [1]), the rotations left free: the Schur complement ``S = H_tt - H_tr^T H_rr^-1 H_tr`` of
    the point-to-plane normal matrix at ``T`` (source -> target, (4, 4) [m]). None where fewer than
    ``min_matched`` object points match within ``radius_m``."""
    J = overlap_jacobian(src, tgt, T, radius_m, min_matched)[0]
    if J is None:
        return None
    H = J.T @ J / len(J)
    Hrr, Hrt, Htt = H[:3, :3], H[:3, 3:], H[3:, 3:]
    try:
        return Htt - Hrt.T @ np.linalg.solve(Hrr, Hrt)
    except np.linalg.LinAlgError:
        return Htt


def _ratio(S: np.ndarray, d: np.ndarray) -> float:
    """Stiffness of ``S`` along unit ``d`` (``1 / d' S^-1 d``) over its largest eigenvalue."""
    w = np.linalg.eigvalsh(S)
    if w[-1] <= 0:
        return 0.0
    try:
        k = 1.0 / float(d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        k = 0.0
    return max(k, 0.0) / w[-1]


def _side(reg: RegView, R: np.ndarray, d: np.ndarray, cos_min: float, share: float) -> int:
    """Which face along ``d`` the view sees: +1 where ``share`` of its object points have normals
    (toward the camera; rotated to the world by ``R``) within ``arccos(cos_min)`` of ``d``, -1 of
    ``-d`` (the larger share where both), 0 where neither."""
    n = reg.obj_normals if reg.obj_normals is not None else reg.icp_normals
    if n is None or len(n) == 0:
        return 0
    c = n @ (R.T @ d)
    pos, neg = float(np.mean(c >= cos_min)), float(np.mean(c <= -cos_min))
    if max(pos, neg) < share:
        return 0
    return 1 if pos >= neg else -1


def _tie(n: int, edges: list[tuple[float, int, int]], side: np.ndarray) -> float:
    """The weight of the strongest chain of ``edges`` (weight, i, j) between a view of side +1 and one
    of side -1 (``side``, (n,)): pairs joined from the stiffest down (Kruskal), the weight of the pair
    that first brings both sides into one group. inf without views on both sides, 0 where no chain
    joins them."""
    if not ((side > 0).any() and (side < 0).any()):
        return np.inf
    parent = list(range(n))
    sides = {k: {int(side[k])} for k in range(n)}

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for w, i, j in sorted(edges, reverse=True):
        ri, rj = find(i), find(j)
        if ri == rj:
            continue
        parent[ri] = rj
        sides[rj] |= sides.pop(ri)
        if {1, -1} <= sides[rj]:
            return w
    return 0.0


def split_along(regs: list[RegView], poses: np.ndarray, direction: np.ndarray, radius_m: float,
                min_matched: int = 50, facing_cos: float = 0.7071, facing_share: float = 0.3) -> dict | None:
    """The views that see surface facing either way along ``direction`` (a slab's two faces), and how
    firmly the two sides hold each other along it.

    Parameters
    ----------
    regs : the views' registration clouds (camera frames)
    poses : (V, 4, 4) camera -> world [m] of the same views
    direction : (3,) world frame (normalised here)
    radius_m : correspondence radius of the overlaps [m] (the last ICP stage's)
    facing_cos, facing_share : a view sees the face toward ``+direction`` (``-direction``) where this
        share of its object points have normals within ``arccos(facing_cos)`` of it. A view that sees
        only surface swept along it (a slab's rim, seen edge-on) is on neither side: it slides along
        its surface harmlessly

    Returns
    -------
    dict or None (fewer than two views): ``groups`` (the views of the ``-direction`` side, those of
    the ``+direction`` side; view indices), ``ratio`` (the tie between them: along the strongest
    chain of pairs from one side to the other, the weakest pair's stiffness along ``direction`` as a
    share of its own stiffest translation; 0 where no chain joins them, inf without views on both
    sides, null in ``poses.json``), ``pairs`` (number of pairs that share surface).
    """
    n = len(regs)
    if n < 2:
        return None
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    edges = []
    for i in range(n):
        for j in range(i + 1, n):
            s = translation_stiffness(regs[i], regs[j], np.linalg.inv(poses[j]) @ poses[i], radius_m, min_matched)
            if s is not None:
                R = poses[j][:3, :3]
                edges.append((_ratio(R @ s @ R.T, d), i, j))
    side = np.array([_side(r, P[:3, :3], d, facing_cos, facing_share) for r, P in zip(regs, poses)])
    return {"ratio": float(_tie(n, edges, side)), "groups": [np.flatnonzero(side < 0).tolist(),
                                                              np.flatnonzero(side > 0).tolist()],
            "pairs": len(edges)}


def thin_slab_check(points: np.ndarray, regs: list[RegView], poses: np.ndarray, radius_m: float,
                    max_thickness_share: float = 0.3) -> dict | None:
    """Is the object a slab whose two faces are seen by different views, tied only through its rim?

    Parameters
    ----------
    points : (N, 3) the model's points, world frame [m]
    regs, poses, radius_m : as :func:`split_along`
    max_thickness_share : the object is a slab where its extent along its thinnest principal axis
        is at most this share of the next (simulated plaques 0.12-0.19; over draws 39-40 of the family
        the next thinnest objects were domes 0.34-0.44, seen from one side of that axis only, and flat
        rocker arms 0.60)

    Returns
    -------
    None without points or views; else dict: ``extents_mm`` (3,) along the principal axes, thinnest
    first, ``axis`` (3,) the thinnest one (world), ``thickness_share``, ``split``
    (:func:`split_along` the axis: the two sides' views and their tie; None where the object is not
    thin, so that every pair of views is matched only for a thin one), ``slab`` (bool: thin, with
    views of both faces). No view sees both faces of a slab, so the views of its two faces are tied
    by the rim alone, whatever the tie reads (0.010-0.32 on four right plaques of draws 39-40, from
    the grazing face points and the corners; 0.95 on one 180 deg off): the tie is reported, not judged.
    """
    if len(points) < 3 or len(regs) < 2:
        return None
    c = points - points.mean(0)
    U = np.linalg.eigh(c.T @ c)[1]
    ext = np.ptp(c @ U, axis=0)
    share = float(ext[0] / max(ext[1], 1e-12))
    split = split_along(regs, poses, U[:, 0], radius_m) if share <= max_thickness_share else None
    slab = bool(split is not None and all(split["groups"]))
    return {"extents_mm": [round(float(x) * 1e3, 1) for x in ext], "axis": [round(float(x), 4) for x in U[:, 0]],
            "thickness_share": round(share, 3), "split": split, "slab": slab}


def slab_reason(check: dict, names: list[str]) -> str:
    """The verdict's reason for a :func:`thin_slab_check` that found a slab (``names``: the views')."""
    side = ["{" + ", ".join(names[k] for k in grp) + "}" for grp in check["split"]["groups"]]
    return (f"a slab {check['extents_mm'][0]:.0f} mm thick ({check['thickness_share']:.2f} of its width): the views of its "
            f"two faces, {side[0]} and {side[1]}, share only its rim, which leaves their distance along the thickness "
            "to the points at its corners: the thickness is not measured (simulated plaques came out 1.4-2.9 mm too "
            "thin, their loops closed); scan it lying flat on the support, so that each view sees the upper face and "
            "the plane together, or measure the thickness apart")
