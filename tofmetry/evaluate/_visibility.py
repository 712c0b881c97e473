"""Which reference surface could the cameras see? (observed-surface completeness)

Completeness counts the reference surface the model reproduces. Surface no view could see
(outside every view's image or working range, facing away, seen at a grazing angle, or hidden
behind another part of the object) cannot be reconstructed by any method, so
:func:`observed_mask` flags the reference samples seen by at least one camera; the
evaluation reports completeness over those as well as over the whole reference. No truth is
used: the cameras are the *registered* poses of the reconstruction (poses.json), carried
into the reference frame by the model -> reference alignment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor import CameraIntrinsics


@dataclass
class CameraViews:
    """Cameras of a reconstruction, in the model frame.

    Attributes
    ----------
    poses : (V, 4, 4) float64 camera-to-model [m]
    intrinsics : CameraIntrinsics of the depth camera
    min_mm, max_mm : working range used by the reconstruction (depth Z) [mm]
    names : view names (for diagnostics)
    support_plane : (4,) model-frame support plane (unit normal up, offset [m]) or None
    """

    poses: np.ndarray
    intrinsics: CameraIntrinsics
    min_mm: float = 500.0
    max_mm: float = 4500.0
    names: tuple = ()
    support_plane: np.ndarray | None = None

    @classmethod
    def from_document(cls, doc: dict, source: str = "poses.json") -> CameraViews:
        """Build from the content of a reconstruction's poses.json.

        Raises
        ------
        InputError when the document has no views or no intrinsics.
        """
        if not isinstance(doc, dict) or not doc.get("views"):
            raise InputError(f"{source}: expected a reconstruction poses.json with a 'views' list")
        try:
            poses = np.array([v["camera_to_world"] for v in doc["views"]], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{source}: every view needs a 4x4 'camera_to_world'") from None
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.isfinite(poses).all():
            raise InputError(f"{source}: camera_to_world must be finite 4x4 matrices, found shape {poses.shape}")
        intr_d = doc.get("intrinsics") or (doc.get("diagnostics") or {}).get("intrinsics")
        if intr_d is None:
            raise InputError(f"{source}: no 'intrinsics' (written by tofmetry reconstruct since the observed-surface "
                             "completeness was added); re-run reconstruct")
        intr = CameraIntrinsics.from_dict(intr_d)
        rng = doc.get("working_range_mm") or [500.0, 4500.0]
        sp = doc.get("support_plane_world")
        sp = None if sp is None else np.asarray(sp, np.float64).reshape(4)
        return cls(poses, intr, float(rng[0]), float(rng[1]), tuple(v.get("name", str(k)) for k, v in enumerate(doc["views"])),
                   sp)


def _raycaster(mesh: tuple[np.ndarray, np.ndarray] | None):
    """An Open3D RaycastingScene of ``mesh`` (vertices (V, 3) [m], faces (M, 3)); None without one."""
    if mesh is None:
        return None
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(mesh[0], np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(mesh[1], np.uint32)))
    return scene


def _ray_box(intr: CameraIntrinsics) -> tuple[float, float, float, float]:
    """The normalised ray coordinates' bounds (x_lo, x_hi, y_lo, y_hi) over the image."""
    rays = intr.ray_table(True)
    return (float(np.nanmin(rays[..., 0])), float(np.nanmax(rays[..., 0])),
            float(np.nanmin(rays[..., 1])), float(np.nanmax(rays[..., 1])))


def _seen_by(pts: np.ndarray, nrm: np.ndarray, C: np.ndarray, cameras: CameraViews, box: tuple, scene,
             cos_max: float, occlusion_tol_m: float, image_margin_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The samples one camera (camera-to-reference ``C`` (4, 4)) sees (:func:`observed_mask`'s
    rules; ``box``: :func:`_ray_box`): their indices (K,) and the cosines (K,) of their incidence angles."""
    intr = cameras.intrinsics
    xlo, xhi, ylo, yhi = box
    H, W = intr.shape
    R, c = C[:3, :3], C[:3, 3]
    pc = (pts - c) @ R  # reference -> camera frame
    z = pc[:, 2]
    ok = (z * 1e3 >= cameras.min_mm) & (z * 1e3 <= cameras.max_mm)
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = pc[:, 0] / z, pc[:, 1] / z
    ok &= (x >= xlo) & (x <= xhi) & (y >= ylo) & (y <= yhi)
    idx = np.flatnonzero(ok)
    if len(idx):
        uv = intr.project(pc[idx])
        m = ((uv[:, 0] >= -0.5 + image_margin_px) & (uv[:, 0] <= W - 0.5 - image_margin_px)
             & (uv[:, 1] >= -0.5 + image_margin_px) & (uv[:, 1] <= H - 0.5 - image_margin_px))
        idx = idx[m]
    if not len(idx):
        return idx, np.zeros(0)
    to_cam = c - pts[idx]
    dist = np.linalg.norm(to_cam, axis=1)
    cos_i = np.einsum("ij,ij->i", nrm[idx], to_cam) / np.maximum(dist, 1e-12)
    m = cos_i >= cos_max
    idx, dist, to_cam, cos_i = idx[m], dist[m], to_cam[m], cos_i[m]
    if len(idx) and scene is not None:
        import open3d as o3d

        d = -to_cam / dist[:, None]
        r = np.concatenate([np.broadcast_to(c, (len(idx), 3)), d], axis=1).astype(np.float32)
        t_hit = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(r)))["t_hit"].numpy().astype(np.float64)
        front = t_hit >= dist - occlusion_tol_m
        idx, cos_i = idx[front], cos_i[front]
    return idx, cos_i


def observed_mask(points: np.ndarray, normals: np.ndarray, cameras: CameraViews,
                  world_from_model: np.ndarray | None = None, mesh: tuple[np.ndarray, np.ndarray] | None = None,
                  max_incidence_deg: float = 80.0, occlusion_tol_m: float = 0.003,
                  image_margin_px: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Reference samples visible from at least one camera.

    A sample is seen by a camera when it lies in front of it within the working range (Z),
    projects inside the image (``image_margin_px`` from the border), faces the camera at an
    incidence angle below ``max_incidence_deg`` (the reconstruction drops grazing pixels at
    80 deg) and, when ``mesh`` is given, the ray from the camera centre hits the mesh no
    nearer than ``occlusion_tol_m`` before the sample (Open3D RaycastingScene).

    Parameters
    ----------
    points, normals : (N, 3) reference samples [m] and their unit outward normals
    cameras : CameraViews (camera-to-model poses)
    world_from_model : (4, 4) model -> reference transform (the alignment); identity if None
    mesh : (vertices (V, 3) [m], faces (M, 3)) of the reference, for the occlusion test

    Returns
    -------
    seen : (N,) bool, seen by at least one camera
    count : (N,) int, number of cameras seeing each sample
    """
    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    T = np.eye(4) if world_from_model is None else np.asarray(world_from_model, np.float64)
    cos_max = np.cos(np.radians(max_incidence_deg))
    scene = _raycaster(mesh)
    box = _ray_box(cameras.intrinsics)
    count = np.zeros(len(pts), np.int64)
    for P in cameras.poses:
        idx, _ = _seen_by(pts, nrm, T @ P, cameras, box, scene, cos_max, occlusion_tol_m, image_margin_px)
        count[idx] += 1
    return count > 0, count


def view_cosines(points: np.ndarray, normals: np.ndarray, cameras: CameraViews,
                 mesh: tuple[np.ndarray, np.ndarray] | None = None, max_incidence_deg: float = 85.0,
                 occlusion_tol_m: float = 0.003, image_margin_px: float = 2.0) -> np.ndarray:
    """How squarely each camera sees each sample: the cosine of the incidence angle.

    The rules of :func:`observed_mask` (image, working range, occlusion by ``mesh``), per camera
    and without a count, so that one pass serves several incidence limits.

    Parameters
    ----------
    points, normals : (N, 3) samples [m] and their unit outward normals, in the cameras' frame
    cameras : CameraViews (C cameras)
    max_incidence_deg : samples seen at a larger incidence count as not seen

    Returns
    -------
    (C, N) float: cos(incidence) where camera k sees sample j, NaN where it does not
    """
    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    cos_max = np.cos(np.radians(max_incidence_deg))
    scene = _raycaster(mesh)
    box = _ray_box(cameras.intrinsics)
    out = np.full((len(cameras.poses), len(pts)), np.nan)
    for k, P in enumerate(cameras.poses):
        idx, cos_i = _seen_by(pts, nrm, np.asarray(P, np.float64), cameras, box, scene, cos_max, occlusion_tol_m,
                              image_margin_px)
        out[k, idx] = cos_i
    return out
