"""How much of a model's scale error the dot mat's placements carry, from stored family rows alone.

``PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.placement_scale ROWS.jsonl [ROWS.jsonl ...] [-o OUT.jsonl]``

A diagnostic on stored family rows (:mod:`bench.robustness.family` with ``--mat``; nothing is simulated or
reconstructed again). Each row's object and path are drawn again from its seed (:func:`family.draw_of_row`),
which gives the true camera poses; the object is ray-cast from them (exact depth, every second pixel, surfaces
seen within 80 deg of incidence), and each view's points are carried once by its true pose and once by its
stored placement (``mat_fixes[*].camera_to_mat``, after the one rigid alignment :func:`tofmetry.evaluate.pose_errors`
finds on the object's points; views the dots did not place are left out). The difference is what the placements'
pose errors alone do to the model. Its scale, with a surface offset fitted beside it (the evaluation's measure,
linearised: :func:`tofmetry.reconstruct._scale_budget._scale_rows`), is read two ways:

* ``fused_pct``: on points sampled evenly over the object's surface where the views see it, each moved by the
  mean of the view points within 3 mm that face the same way (what the fusion makes of the views, each surface
  once, as the evaluation samples the model);
* ``views_pct``: on the views' points together, each counted once (as the scale budget and the mat's scale hold
  count them: a surface that several views, or a near head-on view, sample densely weighs more);
* ``area_pct``: the same points, each weighted by the surface area it stands for (the squared distance to its
  12th neighbour), which stands for the fusion without fusing.

Per run also ``predicted_sigma_pct`` (the scale 1-sigma the placements' own covariances give, as the mat's scale
hold takes them: :func:`tofmetry.reconstruct._mat_scale.placement_covariance` with the calibration's predicted
central error as the height's sigma, on the area-weighted row), ``scale_error_pct`` (the model's, as the row
measured), ``unrefined`` (the placements stood unrefined, so they are the model's poses) and ``held_by_mat`` (the
fit's scale was weighed against the mat's).

Measured (2026-12-06, session 55) on the 140 runs of held-out draws 106-112 (113 separable on the fused surface;
``bench/results/placement_scale_fresh106_112_rows.jsonl``): the placements alone give the model RMS 0.132 %, p90
0.215 % of scale; their covariances predict a median 0.054 % (|error| / sigma median 1.07, p68 1.77, p90 3.31, RMS
2.25; 74 % within 2).
The views' points counted once read it 0.84 times (correlation 0.97; draw 108's plaques 0.66 and 0.52 times), weighted
by area 1.02 times (0.99). Where the placements stood unrefined (22 reliable runs) the models' scale follows theirs
(correlation +0.81; RMS 0.359 against 0.192 %); where the joint fit was held by the mat (69), hardly (+0.27).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from bench.robustness.family import MESH_DIR, over_stored_rows, stored_placements
from tofmetry._shared.geometry import skew
from tofmetry.reconstruct import RegistrationConfig
from tofmetry.reconstruct._mat_locate import MatFix
from tofmetry.reconstruct._mat_scale import placement_covariance
from tofmetry.reconstruct._scale_budget import _scale_rows

#: fused points take the mean move of the view points within this radius [m] that face the same way
FUSE_RADIUS_M = 0.003
#: surfaces seen within this incidence [deg] count (the views' normals are estimated beyond it)
MAX_INCIDENCE_DEG = 80.0


def seen_points(vertices: np.ndarray, triangles: np.ndarray, poses: np.ndarray, intr, step: int = 2):
    """Per pose (camera to world, (4, 4)) the object's visible points (N, 3) [m] and unit normals toward the
    camera (N, 3), camera frame (x right, y down, z forward), ray-cast through every ``step``-th pixel."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    u, v = np.meshgrid(np.arange(0, intr.width, step), np.arange(0, intr.height, step))
    d = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(u.shape)], -1).reshape(-1, 3)
    out = []
    for T in poses:
        R, t = T[:3, :3], T[:3, 3]
        rays = np.c_[np.repeat(t[None], len(d), 0), d @ R.T].astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))
        th = hit["t_hit"].numpy()
        ok = np.isfinite(th)
        P = d[ok] * th[ok, None]  # the ray's z is 1: t_hit is the depth Z
        N = hit["primitive_normals"].numpy()[ok].astype(np.float64) @ R
        N[np.einsum("ij,ij->i", N, P) > 0] *= -1
        cos_inc = -np.einsum("ij,ij->i", N, P) / np.linalg.norm(P, axis=1)
        keep = cos_inc > np.cos(np.radians(MAX_INCIDENCE_DEG))
        out.append((P[keep], N[keep]))
    return out


def surface_samples(vertices: np.ndarray, triangles: np.ndarray, n: int = 40_000):
    """``n`` points (n, 3) [m] drawn uniformly over the mesh's area (seeded: the same every call) and their
    triangles' unit normals (n, 3), oriented as the mesh's winding makes them."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    area = np.linalg.norm(cross, axis=1)
    rng = np.random.default_rng(0)
    t = rng.choice(len(triangles), n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    pts = a[t] + r1[:, None] * (b[t] - a[t]) + r2[:, None] * (c[t] - a[t])
    return pts, cross[t] / np.maximum(area[t], 1e-30)[:, None]


def area_scale_row(points: np.ndarray, normals: np.ndarray, k: int = 12) -> np.ndarray | None:
    """(N,) row ``r`` with ``r @ dn`` the relative scale of the normal moves ``dn`` (N,) [m] of ``points``
    (N, 3) with unit ``normals``, each point weighted by the surface area it stands for (the squared distance
    to its ``k``-th neighbour): the scale about the weighted centroid with a rigid motion and a normal offset
    fitted beside it. None where the two are not separable or the fit is singular."""
    d, _ = cKDTree(points).query(points, k=k + 1)
    w = d[:, -1] ** 2
    rows, _ = _scale_rows(points, normals, weights=w / w.mean())
    return None if rows is None else rows[0]


def predicted_sigma(points: np.ndarray, normals: np.ndarray, r: np.ndarray | None, view: np.ndarray, fixes: list[dict],
                    to_world: np.ndarray, height_sigma_m: float, tilt_sigma_deg: float) -> float:
    """The scale 1-sigma [%] the placements' own covariances give (as the mat's scale hold takes them:
    :func:`tofmetry.reconstruct._mat_scale.placement_covariance`, each view's left increment in the mat
    frame carried to the world by ``to_world`` (4, 4)), on the area-weighted row ``r`` (:func:`area_scale_row`,
    None: not separable) of the view points ``points`` (world), ``view`` (N,) their placed view's index into
    ``fixes`` (the rows' ``mat_fixes`` entries)."""
    if r is None:
        return float("nan")
    R, t = to_world[:3, :3], to_world[:3, 3]
    Ad = np.block([[R, np.zeros((3, 3))], [skew(t) @ R, R]])  # a left increment of the mat frame, in the world's
    var = 0.0
    for v, f in enumerate(fixes):
        k = view == v
        a = np.r_[np.cross(points[k], normals[k]).T @ r[k], normals[k].T @ r[k]]
        fix = MatFix(located=True, sigma_deg=f["sigma_deg"], sigma_mm=f["sigma_mm"],
                     tilt_sigma_deg=np.nan if f.get("tilt_sigma_deg") is None else f["tilt_sigma_deg"],
                     centre_xy=np.asarray(f.get("centre_xy") or [np.nan, np.nan], float))
        var += float(a @ Ad @ placement_covariance(fix, tilt_sigma_deg, height_sigma_m) @ Ad.T @ a)
    return 100.0 * float(np.sqrt(var))


def placement_scale(P_true: np.ndarray, N_true: np.ndarray, moves: np.ndarray, S: np.ndarray, SN: np.ndarray,
                    area_row: np.ndarray | None) -> tuple:
    """(fused, views, area) relative scale [%] of the moves ``moves`` (M, 3) [m] of the view points ``P_true``
    (M, 3) (world, unit normals ``N_true`` toward their cameras), read on the surface samples ``S``, ``SN``
    and on the view points themselves, counted once and weighted by area (``area_row``, :func:`area_scale_row`
    of those points; module docstring); NaN where scale and offset are not separable."""
    dn_views = np.einsum("ij,ij->i", N_true, moves)
    rows_v, _ = _scale_rows(P_true, N_true)
    views = float("nan") if rows_v is None else 100.0 * float(rows_v[0] @ dn_views)
    dist, idx = cKDTree(P_true).query(S, k=24, distance_upper_bound=FUSE_RADIUS_M)
    near = np.isfinite(dist)
    jj = np.where(near, idx, 0)
    cos = np.einsum("mkj,mj->mk", N_true[jj], SN)
    side = np.sign(np.median(cos[near]))  # the mesh's winding: its normals outward (+1) or inward (-1)
    same = near & (side * cos > 0.5)  # a thin wall's far face is not this one
    cnt = same.sum(1)
    good = cnt > 0
    mean_move = np.einsum("mk,mkj->mj", same.astype(np.float64), moves[jj]) / np.maximum(cnt, 1)[:, None]
    rows_f, _ = _scale_rows(S[good], SN[good])
    fused = float("nan") if rows_f is None else 100.0 * float(rows_f[0] @ np.einsum("ij,ij->i", SN[good], mean_move[good]))
    area = float("nan") if area_row is None else 100.0 * float(area_row @ dn_views)
    return fused, views, area


def run_row(row: dict, mesh_dir: Path | None = MESH_DIR) -> dict | None:
    """One stored family row (module docstring); None without placements (no mat, refused) or with fewer than
    two views the dots placed."""
    got = stored_placements(row, mesh_dir)
    if got is None:
        return None
    d, names, on, placed, true, pm = got
    fixes = row["mat_fixes"]
    views = seen_points(d.object.vertices, d.object.triangles, true[on], d.sensor.intrinsics)
    Pw, Nw, mv, vi = [], [], [], []
    for i, ((P, N), T, A) in enumerate(zip(views, true[on], placed)):
        B = pm.alignment @ A
        Pw.append(P @ T[:3, :3].T + T[:3, 3])
        Nw.append(N @ T[:3, :3].T)
        mv.append(P @ B[:3, :3].T + B[:3, 3] - Pw[-1])
        vi.append(np.full(len(P), i))
    S, SN = surface_samples(d.object.vertices, d.object.triangles)
    Pw, Nw = np.concatenate(Pw), np.concatenate(Nw)
    row_area = area_scale_row(Pw, Nw)
    fused, concat, area = placement_scale(Pw, Nw, np.concatenate(mv), S, SN, row_area)
    cal_mm = (row.get("calibration") or {}).get("predicted_central_mm") or RegistrationConfig().mat_prior_mm
    pred = predicted_sigma(Pw, Nw, row_area, np.concatenate(vi), [fixes[names[k]] for k in on], pm.alignment,
                           cal_mm * 1e-3, RegistrationConfig().mat_prior_deg)
    warnings = row.get("warnings") or []
    return {"seed": row["seed"], "object": row["object"]["name"], "views": len(on), "reliable": row.get("reliable"),
            "unrefined": any("unrefined" in w for w in warnings), "held_by_mat": row.get("mat_scale_hold") is not None,
            "fused_pct": round(fused, 4), "views_pct": round(concat, 4), "area_pct": round(area, 4),
            "predicted_sigma_pct": round(pred, 4), "scale_error_pct": row.get("scale_error_pct"),
            "hold_applied_pct": (row.get("mat_scale_hold") or {}).get("applied_pct"),
            "hold_fit_scale_pct": (row.get("mat_scale_hold") or {}).get("fit_scale_pct")}


def main(argv=None) -> int:
    over_stored_rows(argv, "python -m bench.robustness.placement_scale", __doc__.splitlines()[0], run_row,
                     lambda r: f"{r['seed']:>10} {r['object']:<11} placements: fused {r['fused_pct']:+.3f} %, views "
                               f"{r['views_pct']:+.3f} %, by area {r['area_pct']:+.3f} % (+/- {r['predicted_sigma_pct']:.3f} "
                               f"%); model {r['scale_error_pct']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
