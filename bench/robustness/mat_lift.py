"""Where the dot mat's placements get their lift: the depth's error on the support and on the object, view by view.

``OMP_NUM_THREADS=1 PYTHONPATH=$PWD .venv/bin/python -m bench.robustness.mat_lift --seeds S1,S2,... -o DIR``

A diagnostic: each seed runs through the family (:func:`bench.robustness.family.run_case` with ``--mat --planned 0.9
--plan-distance``), the views are kept as the pipeline placed them on the mat (the calibrated depth, before the joint
fit and the support curve), and each is compared with the truth (the sheet is the world's plane z = 0; the object's
true depth is ray-cast from the true pose on the reference mesh). Per view, all in mm:

* ``support_dz``, ``support_dz_at_object``: the median depth error (measured Z minus true Z) of the support's points
  (within 10 mm of the view's support plane, off the object), over all of them and within 100 mm of the object's
  median depth;
* ``object_dz``: the same on the object's points;
* ``plane_height``: the support plane's height of the camera minus the true height; ``plane_at_foot``: how far the
  fitted plane lies from the true one below the object (positive: nearer the camera);
* ``placement_height``: the placed camera's height error in the mat's frame; ``placement_along``: how far the
  placement's error moves the object's centre along the view's direction (positive: away from the camera);
  ``surface_along``: that plus ``object_dz``, how far the view's surface of the object stands off along its view
  direction (negative: toward the camera, a model inflated where the placements stand).

Measured (2026-12-06, session 58) at 7622571 on four development runs whose placements stood unrefined (bunnies
982114271 and 454453909, fandisk 1626370171, rocker arm 1212029075) and two held (a vase, a rocker arm;
``bench/results/mat_lift_dev_rows.jsonl``), means over the views: the support's depth reads +0.72 to +1.24 mm
(all of it) but -1.21 to +3.43 mm at the object's depths, where the object reads -0.97 to +3.11 mm. The plane
through the whole support puts the camera +1.08 to +2.48 mm too high and lies 0.48-0.82 mm too far below the
object; cut with it, the dots carry the placements 1.14-2.00 mm toward the camera at the object (about 2.5 times the
plane's error there: ``1 / sin(e)``), so each view's surface stands -1.53 to -2.31 mm off along its view (+1.28 mm
on the rocker arm, whose object reads +3.1 mm far). On the held runs all of it is within 0.6 mm. The plane's
offset read at the object's depths instead (``registration.mat_plane_at_object``,
``bench/results/mat_lift_dev_plane_at_object_rows.jsonl``): the surfaces -1.11, +0.11, -0.34, -0.42 and +0.03 mm off.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path
from unittest import mock

import numpy as np
import open3d as o3d

from bench.robustness import family
from bench.robustness.mat_sight import world_to_mat
from tofmetry.io import read_json
from tofmetry.reconstruct import _pipeline

SUPPORT_BAND_M = 0.010
NEAR_OBJECT_M = 0.100


def _captured_run(seed: int, work: Path, config=None) -> tuple[dict, dict]:
    """The family row of ``seed`` (``config``: the reconstruction's, None: the default) and the views as the
    first mat placement saw them."""
    cap: dict = {}
    place = _pipeline.ReconstructionPipeline.place_on_mat

    def place_on_mat(self, views, segs, regs, intr, what):
        place(self, views, segs, regs, intr, what)
        if not cap:
            cap.update(intr=intr, names=[v.name for v in views],
                       views=[(v.points.copy(), v.index.copy()) for v in views],
                       segs=[(None if s.plane is None else np.array(s.plane), s.object_mask.copy()) for s in segs],
                       fixes={n: f.camera_to_mat.copy() for n, f in self.mat.fixes.items() if f.located})

    with mock.patch.object(_pipeline.ReconstructionPipeline, "place_on_mat", place_on_mat):
        row = family.run_case(seed, work, mat=True, planned=0.9, plan_distance=True, keep=True, config=config)
    return row, cap


def _median(x: np.ndarray) -> float | None:
    return round(float(np.median(x)), 3) if len(x) >= 50 else None


def view_lift(points, index, plane, obj, T, placed, to_mat, rays, scene) -> dict:
    """One view's figures (module docstring). ``points`` (N, 3) camera frame [m], ``index`` their pixels,
    ``plane`` the support plane (4,), ``obj`` (N,) the object's mask, ``T`` the true camera-to-world,
    ``placed`` the placement (camera to mat) or None, ``to_mat`` world to mat (4, 4), ``rays`` (H W, 2)
    normalised rays, ``scene`` Open3D raycasting scene of the reference mesh."""
    R, t = T[:3, :3], T[:3, 3]
    n_c = R.T @ np.array([0.0, 0.0, 1.0])
    xy = rays[index]
    z_true = -t[2] / (xy @ n_c[:2] + n_c[2])
    dz = 1e3 * (points[:, 2] - z_true)
    sup = (np.abs(points @ plane[:3] + plane[3]) < SUPPORT_BAND_M) & ~obj
    z_obj = float(np.median(points[obj, 2]))
    near = sup & (np.abs(points[:, 2] - z_obj) < NEAR_OBJECT_M)
    dirs = np.c_[xy[obj], np.ones(obj.sum())] @ R.T
    t_hit, _ = cast_from(scene, t, dirs)
    ok = np.isfinite(t_hit)
    obj_dz = 1e3 * (points[obj, 2][ok] - t_hit[ok])  # the ray's t along (x, y, 1) is Z
    centre_c = points[obj].mean(0)
    foot = centre_c - (centre_c @ plane[:3] + plane[3]) * plane[:3]
    out = {"support_dz": _median(dz[sup]), "support_dz_at_object": _median(dz[near]),
           "object_dz": _median(obj_dz[np.abs(obj_dz) < 20.0]),
           "plane_height": round(1e3 * (float(plane[3]) - float(t[2])), 3),
           "plane_at_foot": round(1e3 * float(foot @ n_c + t[2]), 3)}
    if placed is not None:
        to_world = np.linalg.inv(to_mat) @ placed
        X, Xp = R @ centre_c + t, to_world[:3, :3] @ centre_c + to_world[:3, 3]
        v = (X - t) / np.linalg.norm(X - t)
        out["placement_height"] = round(1e3 * float(placed[2, 3] - t[2]), 3)  # the turn about z keeps heights
        out["placement_along"] = round(1e3 * float((Xp - X) @ v), 3)
        if out["object_dz"] is not None:
            out["surface_along"] = round(out["placement_along"] + out["object_dz"], 3)
    return out


def cast_from(scene, t: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast ``scene`` from ``t`` (3,) along ``dirs`` (N, 3), world frame: each ray's hit distance in units of
    its direction's length (inf: no hit) and the hit triangle's normal (N, 3)."""
    hit = scene.cast_rays(o3d.core.Tensor(np.c_[np.repeat(t[None], len(dirs), 0), dirs].astype(np.float32)))
    return hit["t_hit"].numpy(), hit["primitive_normals"].numpy()


def scan_truth(scan: Path) -> tuple[dict, o3d.geometry.TriangleMesh, o3d.t.geometry.RaycastingScene]:
    """A family scan's truth (its folder ``scan``): each view's true camera-to-world (4, 4) by name, the
    reference mesh and an Open3D ray-casting scene of it."""
    truth = read_json(scan / "truth.json")
    mesh = o3d.io.read_triangle_mesh(str(scan / "reference.ply"))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return {v["name"]: np.array(v["camera_to_world"]) for v in truth["views"]}, mesh, scene


def run_lift(seed: int, config=None) -> dict:
    """One seed's run row figures and its views' lift figures (``config``: :func:`_captured_run`)."""
    work = Path(tempfile.mkdtemp(prefix="tof-mat-lift-"))
    try:
        row, cap = _captured_run(seed, work, config)
        true, _, scene = scan_truth(work / f"scan-{seed}")
        to_mat = np.eye(4)
        to_mat[:3, :3] = world_to_mat(row["mat"]["yaw_deg"])
        rays = np.asarray(cap["intr"].ray_table(True)).reshape(-1, 2)
        views = {}
        for name, (pts, idx), (plane, obj) in zip(cap["names"], cap["views"], cap["segs"]):
            if plane is not None and obj.any():
                views[name] = view_lift(pts, idx, plane, obj, true[name], cap["fixes"].get(name), to_mat, rays, scene)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    keys = sorted({k for v in views.values() for k in v})
    mean = {k: round(float(np.mean([v[k] for v in views.values() if v.get(k) is not None])), 3) for k in keys}
    return {"seed": seed, "object": row["object"]["name"], "distance_m": row["path"]["distance_m"],
            "elevation_deg": row["path"]["elevation_deg"],
            "unrefined": any("unrefined" in w for w in row.get("warnings", [])),
            "support_curve_levelled": (row.get("support_curve") or {}).get("levelled"),
            "support_curve_object_offset_mm": (row.get("support_curve") or {}).get("object_offset_mm"),
            "mean_signed_mm": row.get("mean_signed_mm"), "scale_error_pct": row.get("scale_error_pct"),
            "mean": mean, "views": views}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True, help="comma-separated seeds")
    ap.add_argument("-o", "--output", type=Path, default=Path("bench/results"))
    ap.add_argument("--set", action="append", default=[], metavar="STAGE.FIELD=JSON",
                    help="override one field of the reconstruction config (repeatable; bench.robustness.family's)")
    a = ap.parse_args(argv)
    a.output.mkdir(parents=True, exist_ok=True)
    config = family.config_with(a.set) if a.set else None
    for s in (int(x) for x in a.seeds.split(",")):
        r = run_lift(s, None if config is None else config.model_copy(deep=True))
        with open(a.output / "mat_lift_rows.jsonl", "a") as fh:
            fh.write(json.dumps(r) + "\n")
        print(f"{s:>10} {r['object']:<11} {'unrefined' if r['unrefined'] else 'held':<9} " + ", ".join(
            f"{k} {v:+.2f}" for k, v in r["mean"].items()) + f"; model {r['mean_signed_mm']} mm, scale {r['scale_error_pct']}",
            flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
