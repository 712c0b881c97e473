"""Does the joint fit come back? The global adjustment restarted from the far side of its solution.

Why: the global adjustment (:func:`~tofmetry.reconstruct._adjust.global_adjust`) starts at the
pose-graph poses ``G`` and ends at ``J``. When it moves a view far (more than the pose accuracy a
run must hold), either the pose graph was off and the points put the view right, or the points
leave a direction free (a surface of revolution, a slab, a bar) and the fit slid along it. The move
alone cannot tell the two apart: over the family draws of 2026-11-25 the joint fit moved a view by
0.51-1.68 deg on seven runs whose final poses were within 0.16-0.41 deg of the truth (domes, a box,
a rocker arm, bunnies: the pose graph had been off), and on two vases 0.67 and 1.03 deg off
(slid about their axis).

What tells a slide from a fix is whether ``J`` is an attractor: started again from ``G`` reflected
through ``J`` (every view moved as far again, the same way, ``S = J G^-1 J``), a fit whose points
determine the poses returns to ``J``; one that slid along a free direction stays away (or walks on).
On those nine runs the restarts of the seven right ones ended 0.0003-0.23 deg from ``J``; the two
vases 0.91 and 1.18 deg away. What it does not tell is whether a determined ``J`` is right: the
registration of a plaque (a slab whose faces meet only at its rim) thins it the same way in every
pair, a stable wrong solution, and its restarts came back to within 0.03-0.25 deg while the poses were
0.4-1.1 deg / 4 mm off. So the verdict (:func:`tofmetry.reconstruct._verdict.assess`) flags a restart
that does not come back, and keeps flagging a move beyond the pose gate that does.

Moves are left increments in the world frame (as in the adjustment): ``M_v = J_v G_v^-1``. A move
below the pose gate is amplified to reach it (``min_deg``), so that the restart tests the fit over
the distance the verdict vouches for.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from tofmetry._shared.geometry import rotation_angle_deg, transform_points


def reflected_start(solution: np.ndarray, start: np.ndarray, min_deg: float = 0.0) -> np.ndarray:
    """The start ``G`` reflected through the solution ``J``: ``M_v J_v`` with ``M_v = J_v G_v^-1``,
    the moves scaled up (rotation vector and translation alike) so that the largest rotation is at
    least ``min_deg``.

    Parameters
    ----------
    solution, start : (V, 4, 4) camera-to-world poses [m]
    min_deg : smallest largest move of the reflected start [deg]; 0: plain reflection

    Returns
    -------
    (V, 4, 4) camera-to-world [m]
    """
    J, G = np.asarray(solution, np.float64), np.asarray(start, np.float64)
    M = np.einsum("vij,vjk->vik", J, np.linalg.inv(G))
    largest = max(rotation_angle_deg(m) for m in M)
    a = max(1.0, min_deg / largest) if largest > 1e-9 else 1.0
    out = np.empty_like(J)
    for v, (m, j) in enumerate(zip(M, J)):
        step = np.eye(4)
        step[:3, :3] = Rotation.from_rotvec(a * Rotation.from_matrix(m[:3, :3]).as_rotvec()).as_matrix()
        step[:3, 3] = a * m[:3, 3]
        out[v] = step @ j
    return out


def restart_probe(solution: np.ndarray, start: np.ndarray, rerun: Callable[[np.ndarray], np.ndarray],
                  object_points: np.ndarray, min_deg: float) -> dict:
    """Restart the adjustment from :func:`reflected_start` and measure how far it ends from ``solution``.

    Parameters
    ----------
    solution : (V, 4, 4) the adjustment's poses ``J`` [m]
    start : (V, 4, 4) the poses it started from ``G`` (the pose graph's) [m]
    rerun : the same adjustment from other initial poses: (V, 4, 4) -> (V, 4, 4) final poses
    object_points : (N, 3) world points of the object at ``solution`` [m] (a few thousand suffice):
        the displacement is measured on them, as the verdict's pose gate is
    min_deg : the reflected start moves the views at least this far [deg] (the pose gate)

    Returns
    -------
    dict: ``deg`` (largest rotation between the restart's poses and ``solution`` [deg]), ``mm``
    (largest displacement of an object point [mm]), ``view`` (index of the view with ``deg``),
    ``start_deg`` (largest rotation of the reflected start from ``solution`` [deg]), ``per_view_deg``
    """
    J = np.asarray(solution, np.float64)
    S = reflected_start(J, start, min_deg)
    out = _apart(J, np.asarray(rerun(S), np.float64), object_points)
    out["start_deg"] = round(float(max(rotation_angle_deg(S[v] @ np.linalg.inv(J[v])) for v in range(len(J)))), 4)
    return out


def _apart(J: np.ndarray, R2: np.ndarray, object_points: np.ndarray) -> dict:
    """How far the poses ``R2`` end from ``J`` (V, 4, 4): the largest rotation [deg] (``deg``, its
    ``view``, ``per_view_deg``) and the largest displacement of an object point [mm] (``mm``)."""
    pts = np.asarray(object_points, np.float64)
    deg, mm = [], []
    for v in range(len(J)):
        E = R2[v] @ np.linalg.inv(J[v])  # world-frame difference (left increment)
        deg.append(rotation_angle_deg(E))
        mm.append(float(np.linalg.norm(transform_points(pts, E) - pts, axis=1).max()) * 1e3 if len(pts) else 0.0)
    k = int(np.argmax(deg))
    return {"deg": round(float(deg[k]), 4), "mm": round(float(max(mm)), 3), "view": k,
            "per_view_deg": [round(float(x), 4) for x in deg]}


def tied_probe(solution: np.ndarray, starts: list, rerun: Callable[[np.ndarray], np.ndarray],
               object_points: np.ndarray) -> list[dict]:
    """The joint fit started from the pose graph of each choice of pairwise hypotheses the selection
    found tied with its own (:meth:`~tofmetry.reconstruct.PoseGraphBuilder.tied_poses`): how far from
    ``solution`` does it end?

    A nearly symmetric object lets several choices of the pairs' hypotheses close every loop with
    the same matched share ("registration ambiguous"). The pairs cannot tell them apart; the points of
    all views, matched jointly, may: where the fit from every tied choice ends at the same poses, the
    points decide between them, and the ambiguity is the pairs', not the model's.

    Parameters
    ----------
    solution : (V, 4, 4) the joint fit's poses from the chosen pose graph [m]
    starts : (V, 4, 4) pose-graph poses of each tied choice, in the same frame
    rerun, object_points : as :func:`restart_probe`

    Returns
    -------
    per start: ``deg``, ``mm``, ``view``, ``per_view_deg`` (as :func:`restart_probe`)
    """
    J = np.asarray(solution, np.float64)
    return [_apart(J, np.asarray(rerun(np.asarray(S, np.float64)), np.float64), object_points) for S in starts]


def came_back(restart: dict | None, pose_gate_deg: float, pose_gate_mm: float, share: float = 1.0) -> bool:
    """Whether a :func:`restart_probe` result (or a :func:`pair_walks` entry) ended within ``share``
    of the pose gate of the solution (rotation [deg] and displacement at the object [mm]); False
    without one or when it failed. ``share``: ``registration.restart_share`` (:class:`~tofmetry.reconstruct.ReconstructionConfig`)."""
    return (restart is not None and "failed" not in restart and restart["deg"] <= share * pose_gate_deg
            and restart["mm"] <= share * pose_gate_mm)


def pair_walks(solution: np.ndarray, pairs, refine: Callable[[int, int, np.ndarray], np.ndarray],
               source_points) -> list[dict]:
    """Each pair's own registration started at the joint fit: how far does it walk away?

    A restart that comes back shows that the points of all views determine the joint fit ``J``; it
    does not show whether the pairs, each on its own, agree with it. Here the pair's ICP (as the
    registration refines a pair from an initial pose) starts at the relative pose ``J`` gives the
    pair. A pair whose registration had stopped elsewhere on a cost that is flat or has two basins
    stays at ``J`` (the pose graph was off, the joint fit put it right); a pair whose data pull it
    away (a bias the pairs share, such as the thinning of a slab matched face to face) walks back.

    Parameters
    ----------
    solution : (V, 4, 4) camera-to-world of the joint fit [m]
    pairs : (i, j) view indices (source i registered onto target j)
    refine : (i, j, init) -> (4, 4) the pair's ICP from ``init`` (source camera -> target camera)
    source_points : per view, (N, 3) its object points in its own camera frame [m]

    Returns
    -------
    per pair: ``source``, ``target``, ``deg`` (rotation of the walk [deg]), ``mm`` (largest
    displacement of the source's object points by the walk [mm])
    """
    J = np.asarray(solution, np.float64)
    out = []
    for i, j in pairs:
        init = np.linalg.inv(J[j]) @ J[i]
        T = np.asarray(refine(i, j, init), np.float64)
        pts = np.asarray(source_points[i], np.float64)
        a, b = transform_points(pts, init), transform_points(pts, T)
        mm = float(np.linalg.norm(a - b, axis=1).max()) * 1e3 if len(pts) else 0.0
        out.append({"source": int(i), "target": int(j), "deg": round(rotation_angle_deg(np.linalg.inv(init) @ T), 4),
                    "mm": round(mm, 3)})
    return out


def settles_loops(consistency: dict, restart: dict | None, judged_move_deg: float, pose_gate_deg: float,
                  pose_gate_mm: float, share: float) -> bool:
    """Whether the joint fit, not the pairwise loops, can be trusted to place the views where a loop
    of the pose graph does not close.

    A loop that does not close says that the pairwise registrations disagree; the pose graph spreads
    the disagreement, and the joint fit of all views' points starts from there. When that fit is
    determined (its restart came back within ``share`` of the pose gate) and moved no view beyond the
    gate (``judged_move_deg``, the verdict's judged move), the points of all views settle the poses
    the pairs could not, and the loops' closure describes the pairs, not the model. Only loops whose
    rotation closes within the gate per edge (``consistency["thresholds"]["deg"]``) count: they fail
    on the cameras' displacement, which the lever arm of a ring of cameras about the object magnifies
    (a closure of 3.3 deg is 47 mm at the cameras of a dome scanned from 0.9 m, 2.8 mm at the object).
    Measured on the family (draws 41-55, 292 runs): loops were the only reasons on three runs, all
    within the gate (a pebble, a bar and a dome, 0.16-0.22 deg); every truly wrong run they flagged
    was flagged by another reason too.

    Parameters
    ----------
    consistency : :func:`~tofmetry.reconstruct.consistency_gate` output
    restart : the joint fit's :func:`restart_probe` result, or None (no restart: not settled)
    judged_move_deg : the largest move of a view by the joint fit, as the verdict judges it [deg]
    pose_gate_deg, pose_gate_mm, share : the pose gate and ``registration.restart_share``

    Returns
    -------
    bool
    """
    if not came_back(restart, pose_gate_deg, pose_gate_mm, share) or judged_move_deg > pose_gate_deg:
        return False
    lim = (consistency.get("thresholds") or {}).get("deg", np.inf)
    per_edge = [lp.get("per_edge_deg", np.inf) for lp in consistency.get("loops") or []]
    if consistency.get("cycle_per_edge_deg") is not None:
        per_edge.append(consistency["cycle_per_edge_deg"])
    return all(x <= lim for x in per_edge)
