"""The support curve in the measured ray length (tofmetry.reconstruct._support_curve.correct_by_support, ``variable``).

Six views of a floor from cameras at several heights and pitches, a box standing in the image's middle; every
pixel's depth is off by a range wiggle of its ray length ``Z sqrt(1 + x^2 + y^2)``, as a continuous-wave ToF
camera's is. The floor at the box's depths is seen on rows below it, on rays 2-10 % longer: a curve in Z reads
the wiggle there at another phase; one in the ray length gives the box's own gain.
"""

from __future__ import annotations

import numpy as np

from tests.reconstruct.floor_scenes import INTR, POSES, floor_and_box, wiggle_mm
from tests.reconstruct.test_support_lateral import object_gain_truth
from tofmetry.reconstruct._support_curve import correct_by_support


def ray_wiggle_mm(z, xy):
    return wiggle_mm(z * np.sqrt(1.0 + xy[:, 0] ** 2 + xy[:, 1] ** 2))


def corrected(variable: str) -> tuple[dict, np.ndarray]:
    rng = np.random.default_rng(6)
    pairs = []
    for h, p in POSES:
        box_z = 0.95 * h / np.sin(np.radians(p))  # the floor's depth on the optical axis
        pairs.append(floor_and_box(h, p, 0.1, (-0.08, 0.08), box_z, 0.35, error_mm=ray_wiggle_mm, noise_mm=0.5,
                                   rng=rng, name=f"{p:02d}"))
    views, segs = [v for v, _ in pairs], [s for _, s in pairs]
    z_obj = np.concatenate([v.points[s.object_mask, 2] for v, s in pairs]) * 1e3
    rep = correct_by_support(views, segs, INTR, 0.015, 12.0, 0.01, 60.0, 5.0, variable=variable)
    return rep, z_obj


def test_the_ray_length_gives_the_objects_gain_where_the_wiggle_is_in_it():
    in_z, z_obj = corrected("z")
    radial, _ = corrected("radial")
    assert in_z["applied"] and radial["applied"] and radial["variable"] == "radial" and in_z["variable"] == "z"
    # the box's rays are within 0.7 % of the axis: its gain is the axis' wiggle's slope (several per cent)
    err_z = abs(in_z["object_gain_pct"] - 100 * object_gain_truth(in_z, z_obj))
    err_r = abs(radial["object_gain_pct"] - 100 * object_gain_truth(radial, z_obj))
    # read in Z, the floor's longer rays shift the 470 mm wiggle's phase by 20-100 mm at the box's depths: its
    # slope there is off by tenths of a per cent; in the ray length what the spline's smoothing leaves (hundredths)
    assert err_r < 0.1 and err_r < 0.5 * err_z, (err_r, err_z)
    assert err_r < 3 * radial["object_gain_sigma_pct"] + 0.05
