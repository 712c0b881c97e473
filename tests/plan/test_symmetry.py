"""Whether an object's geometry fixes the views' turn about the vertical (tofmetry.plan._symmetry)."""

from __future__ import annotations

import numpy as np

from tofmetry.plan import TURN_FREE_BELOW, PlanObject, proxy_from_size, surface_samples, turn_about_vertical
from tofmetry.simulate.objects import grid_mesh


def _lathe(profile_r, profile_z, n_az: int = 96, bumps: float = 0.0) -> PlanObject:
    """A surface of revolution (radius profile over height) [m], optionally with ``bumps``: a
    relative radius change of 3 lobes round it."""
    az = np.linspace(0, 2 * np.pi, n_az, endpoint=False)
    r = np.asarray(profile_r)[:, None] * (1.0 + bumps * np.cos(3 * az))[None, :]
    P = np.stack([r * np.cos(az), r * np.sin(az), np.repeat(np.asarray(profile_z)[:, None], n_az, 1)], -1)
    v, f = grid_mesh(P)
    return PlanObject(v, f, "mesh")


def _vase(bumps: float = 0.0) -> PlanObject:
    z = np.linspace(0.005, 0.25, 40)
    return _lathe(0.08 + 0.02 * np.sin(z / 0.25 * np.pi * 1.5), z, bumps=bumps)


def test_a_surface_of_revolution_leaves_the_turn_free():
    """A vase-like lathe (radius 60-100 mm over 250 mm, 96 facets round): a turn about the vertical
    moves no point off the surface but for the facets' chord error, so its stiffness is a few
    thousandths of a shift's: free. Three lobes round it hold the turn by the slope of the surface
    along the turn (normals tilted by up to 3 x the lobes' relative depth), so the stiffness grows
    with their depth: lobes of 8 % of the radius barely (still free, as the family's lumpy pebbles),
    of 35 % clearly. A 300 x 200 mm box holds it as well."""
    vase = turn_about_vertical(*surface_samples(_vase()))
    assert vase["free"] and vase["ratio"] < 0.02, vase
    ratios = [turn_about_vertical(*surface_samples(_vase(bumps=b)))["ratio"] for b in (0.08, 0.15, 0.35)]
    assert vase["ratio"] < ratios[0] < ratios[1] < ratios[2], ratios
    assert ratios[0] < TURN_FREE_BELOW < ratios[2], ratios
    box = turn_about_vertical(*surface_samples(proxy_from_size(0.3, 0.2, 0.15)))
    assert not box["free"] and box["ratio"] > TURN_FREE_BELOW, box


def test_too_few_samples_are_not_judged():
    out = turn_about_vertical(np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1)))
    assert out["free"] is False and np.isnan(out["ratio"])


def test_the_plan_warns_on_a_surface_of_revolution_and_not_from_a_size(tmp_path):
    """``tofmetry plan --mesh`` of a lathe says that no set of views fixes the turn and what to do;
    a size alone is not judged (the rounded box stands for any shape of that size)."""
    from tofmetry.io.ply import write_ply
    from tofmetry.pipelines.plan import plan_acquisition

    vase = _vase()
    write_ply(tmp_path / "vase.ply", vase.vertices, faces=vase.triangles)
    run = plan_acquisition(mesh=tmp_path / "vase.ply")
    assert run.settings["turn_about_vertical"]["free"]
    assert any("surface of revolution" in w and "--turntable-step" in w for w in run.settings["warnings"])
    sized = plan_acquisition(size=(0.2, 0.2, 0.3))
    assert sized.settings["turn_about_vertical"]["free"] is None
    assert not any("surface of revolution" in w for w in sized.settings.get("warnings", []))
