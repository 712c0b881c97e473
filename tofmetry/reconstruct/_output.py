"""Write a reconstruction: points.ply, mesh.ply (+ mesh_poisson.ply), poses.json.

A coloured model (the views had colour frames) carries RGB and a ``colored`` vertex property (1 =
a colour camera saw the point, 0 = no colour: RGB 0 there means *no colour*, not black) in each PLY,
and the share coloured under ``"color"`` in poses.json."""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry.io import atomic_dir, atomic_write_json, write_ply
from tofmetry.reconstruct._pipeline import ReconstructionResult


def poses_document(res: ReconstructionResult) -> dict:
    """The poses.json content: camera-to-world per view + registration diagnostics.

    ``world_from_first_camera`` (4x4, metres) carries points from the first camera's frame into the
    output's world frame (the support plane z = 0 by default): a transform known in the first
    camera's frame, ``T``, becomes ``T @ inv(world_from_first_camera)`` for the outputs."""
    world = res.diagnostics.get("world") or {}
    rel = res.diagnostics.get("reliability") or {}
    verdicts = rel.get("views") or {}
    return {
        "world": (world.get("frame") or "camera frame of the first view in name order (x right, y down, z forward)")
        + ", metres",
        "world_from_first_camera": world.get("from_first_camera"),
        "convention": "camera_to_world 4x4",
        "reliable": res.diagnostics.get("reliable", True),
        "reasons": rel.get("reasons", []),
        "warnings": rel.get("warnings", []),
        "scale": res.diagnostics.get("scale"),
        "consistency": res.diagnostics.get("consistency"),
        "views": [{"name": n, "camera_to_world": T.tolist(), **({"verdict": verdicts[n]} if n in verdicts else {})}
                  for n, T in zip(res.names, res.poses)],
        "views_left_out": res.diagnostics.get("left_out") or {},
        "edges": res.edges,
        "intrinsics": res.diagnostics.get("intrinsics"),
        "working_range_mm": res.diagnostics.get("working_range_mm"),
        "support_plane_world": None if res.support_plane is None else res.support_plane.tolist(),
        "color": res.diagnostics.get("color"),
        "diagnostics": res.diagnostics,
    }


def write_reconstruction(out: str | os.PathLike, res: ReconstructionResult, force: bool = False) -> Path:
    """Write the outputs into the folder ``out`` atomically (refuses to overwrite unless ``force``)."""
    col = res.colours or {}

    def colour_args(key: str) -> dict:
        c = col.get(key)
        return {} if c is None else {"colors": c.colors, "scalars": {"colored": c.colored.astype("float32")}}

    with atomic_dir(out, force=force) as tmp:
        write_ply(tmp / "points.ply", res.points, normals=res.normals, **colour_args("points"))
        write_ply(tmp / "mesh.ply", res.mesh_vertices, normals=res.mesh_normals, faces=res.mesh_triangles,
                  **colour_args("mesh"))
        if res.poisson is not None:
            write_ply(tmp / "mesh_poisson.ply", res.poisson[0], faces=res.poisson[1], **colour_args("poisson"))
        atomic_write_json(tmp / "poses.json", poses_document(res))
    return Path(out)
