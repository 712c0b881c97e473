"""A declared turntable as a prior of the pairwise registration.

On a turntable at a constant step ``s`` (views in capture order, turning in either direction) the
object of view ``j`` is the object of view ``i`` turned by ``(j - i) s`` about the turntable's axis,
which is parallel to the support plane's normal. The geometry alone cannot tell some of these turns
from others: a thin slab seen from views 60 degrees apart matches its own back turned over by
180 degrees, and two such flips on one loop of views close it as well as the true turns (a plaque
on a 6-view turntable ended with every view 90 degrees off, the loop closed within 0.05 degrees).
The declared step removes those hypotheses: the yaw seeds of the search are the declared turns, and
a hypothesis whose rotation lies farther than ``turntable_tol_deg`` from them is not accepted.

The prior decides between hypotheses only; the poses are still fitted by the points (a manual
turntable's steps are off by a degree or two).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tofmetry._shared.geometry import rotation_angle_deg


def expected_turns_deg(i: int, j: int, step_deg: float) -> tuple[float, float]:
    """The turn [deg] from view ``i`` to view ``j`` on a turntable of step ``step_deg``, both senses."""
    a = float(np.mod((j - i) * step_deg, 360.0))
    return a, float(np.mod(-a, 360.0))


def _turn(axis: np.ndarray, deg: float) -> np.ndarray:
    """(3, 3) rotation by ``deg`` about the direction ``axis``."""
    return Rotation.from_rotvec(np.radians(deg) * axis / np.linalg.norm(axis)).as_matrix()


def turn_error_deg(transform: np.ndarray, turns_deg: tuple[float, ...], axis: np.ndarray | None) -> float:
    """Angle [deg] between the rotation of ``transform`` and the nearest declared turn.

    Parameters
    ----------
    transform : (4, 4) source camera -> target camera [m]
    turns_deg : the declared turns (:func:`expected_turns_deg`)
    axis : (3,) the turntable's axis in the target camera frame (the support plane's normal), or
        None: then only the magnitude of the rotation is compared
    """
    R = np.asarray(transform, np.float64)[:3, :3]
    if axis is None:
        ang = rotation_angle_deg(np.asarray(transform, np.float64))
        return float(min(abs(ang - min(t, 360.0 - t)) for t in turns_deg))
    errs = []
    for t in turns_deg:
        E = np.eye(4)
        E[:3, :3] = R @ _turn(np.asarray(axis, np.float64), t).T
        errs.append(rotation_angle_deg(E))
    return float(min(errs))


class TurntablePrior:
    """The declared turns of one pair of views and the test of a hypothesis against them.

    Parameters
    ----------
    i, j : the views' indices in capture order
    step_deg : the turntable's step [deg]
    tol_deg : a hypothesis farther than this from the declared turns is not accepted [deg]
    axis : (3,) support-plane normal of the target view (camera frame), or None
    """

    def __init__(self, i: int, j: int, step_deg: float, tol_deg: float, axis: np.ndarray | None) -> None:
        self.turns = expected_turns_deg(i, j, step_deg)
        self.tol = float(tol_deg)
        self.axis = None if axis is None else np.asarray(axis, np.float64)

    def error_deg(self, transform: np.ndarray) -> float:
        """:func:`turn_error_deg` of ``transform``."""
        return turn_error_deg(transform, self.turns, self.axis)

    def allows(self, transform: np.ndarray, widen: float = 1.0) -> bool:
        """Is ``transform`` within ``widen`` x the tolerance of a declared turn?"""
        return self.error_deg(transform) <= widen * self.tol

    def seeds_deg(self) -> tuple[float, ...]:
        """Yaw seeds of the search [deg]: the declared turns (once when both senses coincide)."""
        a, b = self.turns
        return (a,) if abs(a - b) < 1e-9 else (a, b)


def turn_about(centre: np.ndarray, axis: np.ndarray, deg: float) -> np.ndarray:
    """(4, 4) rotation by ``deg`` about the line through ``centre`` [m] along ``axis`` (camera frame)."""
    T = np.eye(4)
    T[:3, :3] = _turn(np.asarray(axis, np.float64), deg)
    T[:3, 3] = np.asarray(centre, np.float64) - T[:3, :3] @ centre
    return T


def signed_turn_deg(transform: np.ndarray, axis: np.ndarray) -> float:
    """The rotation of ``transform`` as a signed angle about ``axis`` [deg], in (-180, 180]."""
    R = np.asarray(transform, np.float64)[:3, :3]
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # 2 sin(a) x rotation axis
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arctan2(w @ axis / np.linalg.norm(axis) / 2.0, c)))


def _wrap(deg: float) -> float:
    return float((deg + 180.0) % 360.0 - 180.0)


def fit_turntable(transforms: list[np.ndarray], steps: list[int], step_deg: float, axis: np.ndarray) -> dict | None:
    """The turntable's axis and sense from registrations of view pairs on it.

    Parameters
    ----------
    transforms : (4, 4) each, source camera -> target camera [m] of accepted registrations
    steps : the number of turntable steps from source to target of each (``j - i``)
    step_deg : the declared step [deg]
    axis : (3,) the turntable's axis direction in the camera frame (the support plane's normal)

    Returns
    -------
    dict: centre (3,) a point of the axis [m], axis (3,) unit, sense (+1 / -1: the views turn by
    +step or -step about ``axis``), residual_deg (largest difference between a registration's turn
    and the declared one, in that sense), n; None without a registration that turns
    """
    n = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    votes, rows, rhs = 0.0, [], []
    for T, k in zip(transforms, steps):
        a = signed_turn_deg(T, n)
        e = _wrap(k * step_deg)
        if abs(e) < 1e-6:
            continue
        votes += 1.0 if abs(_wrap(a - e)) <= abs(_wrap(a + e)) else -1.0
        rows.append(np.eye(3) - np.asarray(T, np.float64)[:3, :3])
        rhs.append(np.asarray(T, np.float64)[:3, 3])
    if not rows:
        return None
    sense = 1.0 if votes >= 0 else -1.0
    centre = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
    res = max(abs(_wrap(signed_turn_deg(T, n) - sense * k * step_deg)) for T, k in zip(transforms, steps))
    return {"centre": centre, "axis": n, "sense": sense, "residual_deg": float(res), "n": len(rows)}


def turntable_poses(poses: np.ndarray, indices: list[int], step_deg: float, axis: np.ndarray,
                    tol_deg: float = 5.0) -> tuple[np.ndarray, dict]:
    """The views' poses as the declared turntable places them, about the axis fitted to ``poses``.

    Parameters
    ----------
    poses : (V, 4, 4) camera-to-world [m], world = the first view's camera (the pose graph's)
    indices : (V,) each view's place in capture order (its number of steps from the first, plus that one's)
    step_deg : the declared step [deg]
    axis : (3,) the turntable's axis direction, camera frame (the support plane's normal)
    tol_deg : views whose pose turns farther than this from the declared turn (a wrong pose graph)
        are left out of the axis fit, once the first fit over all views has given the sense

    Returns
    -------
    ((V, 4, 4) the turntable's poses, same world; dict: centre_m, sense, deviation_deg (largest angle
    between a view's two poses), n_fit (views the axis was fitted on)); ``poses`` unchanged when no
    view turns
    """
    P = np.asarray(poses, np.float64)
    to_view = [np.linalg.inv(P[v]) @ P[0] for v in range(1, len(P))]  # first camera -> camera v
    steps = [int(indices[v]) - int(indices[0]) for v in range(1, len(P))]
    fit = fit_turntable(to_view, steps, step_deg, axis)
    if fit is None:
        return P.copy(), {"deviation_deg": 0.0, "n_fit": 0}
    good = [abs(_wrap(signed_turn_deg(T, fit["axis"]) - fit["sense"] * k * step_deg)) <= tol_deg
            for T, k in zip(to_view, steps)]
    if any(good) and not all(good):
        refit = fit_turntable([T for T, g in zip(to_view, good) if g], [k for k, g in zip(steps, good) if g],
                              step_deg, axis)
        fit = refit if refit is not None else fit
    out = P.copy()
    for v in range(1, len(P)):
        out[v] = P[0] @ np.linalg.inv(turn_about(fit["centre"], fit["axis"], fit["sense"] * steps[v - 1] * step_deg))
    dev = max(rotation_angle_deg(np.linalg.inv(a) @ b) for a, b in zip(P, out))
    return out, {"centre_m": [round(float(x), 4) for x in fit["centre"]], "sense": int(fit["sense"]),
                 "deviation_deg": round(float(dev), 3), "n_fit": int(sum(good)) if any(good) else len(to_view)}
