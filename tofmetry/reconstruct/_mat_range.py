"""The mat's own range error, read from the size of its dots (and, where asked, taken out of the placements).

A view is placed on the mat by its support plane (the depth: the camera's height and tilt) and by
its dots (their rays cut with that plane, matched to the printed layout). If the depth reads the
mat's plane a distance ``delta`` too far along the rays, every cut lies too far by the same factor
``1 + delta / D`` about the camera (``D`` the distance to the dots): the dots come out
``delta / D`` too large (:attr:`~tofmetry.reconstruct._mat_locate.MatFix.pattern_scale`), and the
rigid match to the layout, which cannot take a scale, puts the camera ``delta`` too far back along
its line of sight to the dots. The object's points go with the camera: ``delta`` toward it.

Where the object's depth shares the mat's range error the two cancel (its points are read
``delta`` too far as well). The mat does not share all of it: it is seen at 60-75 deg of incidence
and at low amplitude, where the calibration's incidence and amplitude terms are least sure. What
is left moves every view's points along its own line of sight, together: a thin plaque's faces
moved 0.7-0.9 mm apart or together on the family's held-out draw 108, its scale -0.71 and +0.49 %.
The placements' errors against the truth there, along each camera's line of sight to the dots,
+0.2 to +1.3 mm (mean +0.78) and -0.8 to -1.35 mm (mean -1.1), while the dots read +0.127 % and
-0.122 % large from about 0.75 m: +0.95 and -0.92 mm.

:func:`range_offset` fits one ``delta`` to every view's dots (``pattern_scale_v = delta / D_v``,
weighted by their sigmas, widened by their scatter), and :func:`moved_along_sight` takes it out of
a placement: the camera moved ``delta`` toward the dots' centroid on the sheet. One value for all
views: the dots of a single view give its ``delta`` to 0.2-1.5 mm only. It is taken out only where
it is significant (beyond :data:`SIGNIFICANT_Z` of its sigma): measured on 22 development runs of
the family (draws 107 and 108's seeds), taken out wherever it was found it moved the placements
of the two plaques 1.38 -> 0.71 and 1.60 -> 0.77 mm off at the object, but an igea seen from
1.44 m, whose dots gave -1.56 +- 0.55 mm (-0.77 +- 0.71 mm on depth with noise alone), 0.96 ->
2.08 mm; the four runs beyond 3 sigma were the two plaques, an igea (1.41 -> 0.73 mm) and a bunny
(0.89 -> 0.96 mm).

**Not used by default** (``registration.mat_range_from_dots``, off): on the held-out draw 109 eight
of 20 runs were beyond 3 sigma, and taking it out left them worse placed (1.33 -> 1.71 mm at the
object, mean of the eight; the models' mean |d| 0.27 -> 0.31 mm, |scale| 0.13 -> 0.11 %). Every
negative value (six, -0.47 to -1.29 mm) made the placements worse (a bunny 0.33 -> 1.23 mm), both
positive ones better (2.08 -> 1.70, 2.58 -> 2.42 mm); on the development runs likewise but for one
plaque. So the dots' size reads the mat's range error with a negative bias of some tenths of a
millimetre that this module does not know yet (on depth with noise alone two igeas seen from
1.44-1.47 m read -0.40 +- 0.57 and -0.77 +- 0.71 mm, the plaques at 0.73 m +-0.1 mm). Measured
against the truth on the 200 runs of held-out draws 100-109 (``bench/robustness/mat_sight``, session
54): the placements stand +0.31 mm too far back along their lines of sight on average (sd 0.35 mm),
the dots read -0.45 +- 0.54 mm off that (about -0.46 mm more per metre of distance), 2.3 times the
sigma they claim; and the models' scale does not follow the placements' error along sight
(correlation -0.02): where the joint fit refines them, the scale left is the object's own. The value
is measured and reported on every mat scan (``diagnostics.mat_range_offset``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tofmetry.reconstruct._mat_locate import MatFix

#: the mat's range error is taken out of the placements only beyond this many of its sigmas
SIGNIFICANT_Z = 3.0


def _sight(fix: MatFix) -> tuple[np.ndarray, float]:
    """(unit vector from the dots' centroid on the sheet to the camera (3,), their distance [m])."""
    c = np.r_[fix.centre_xy, 0.0] if np.all(np.isfinite(fix.centre_xy)) else np.zeros(3)
    d = fix.camera_to_mat[:3, 3] - c
    D = float(np.linalg.norm(d))
    return d / max(D, 1e-9), D


def widened_fit(values: np.ndarray, sigmas: np.ndarray, regressor: np.ndarray) -> tuple[float, float, float]:
    """One factor ``a`` with ``values ~ a * regressor``, least squares weighted by ``1 / sigmas^2``.

    Parameters
    ----------
    values, sigmas, regressor : (n,) the measured values, their 1-sigmas (> 0), what ``a`` multiplies
        (all ones: the weighted mean), n >= 2

    Returns
    -------
    (a, its 1-sigma widened by sqrt(chi2 / (n - 1)) where the scatter exceeds the sigmas, chi2 / (n - 1))
    """
    w = 1.0 / np.asarray(sigmas, float) ** 2
    x, e = np.asarray(regressor, float), np.asarray(values, float)
    info = float(np.sum(w * x ** 2))
    a = float(np.sum(w * x * e) / info)
    chi2_dof = float(np.sum(w * (e - a * x) ** 2)) / (len(e) - 1)
    return a, float(np.sqrt(1.0 / info) * max(1.0, np.sqrt(chi2_dof))), chi2_dof


def range_offset(fixes: list[MatFix], min_dots: int = 6) -> dict | None:
    """The mat's range error ``delta`` [mm] common to the views, from their dots' sizes (module
    docstring); None where fewer than two views were placed by at least ``min_dots`` matched dots.

    Parameters
    ----------
    fixes : every view's :class:`MatFix`
    min_dots : a view's dots count only where at least this many were matched

    Returns
    -------
    dict: ``delta_mm`` (positive: the depth reads the mat too far, the placements stand too far from
    it), ``sigma_mm`` (1-sigma, widened by the views' scatter where it exceeds their sigmas),
    ``chi2_per_view``, ``views``, ``significant`` (beyond :data:`SIGNIFICANT_Z` sigmas: to be
    taken out of the placements)
    """
    use = [f for f in fixes if f.located and "dots" in f.how and f.n_matched >= min_dots
           and np.isfinite(f.pattern_scale) and np.isfinite(f.pattern_scale_sigma) and f.pattern_scale_sigma > 0]
    if len(use) < 2:
        return None
    inv_d = np.array([1.0 / max(_sight(f)[1], 1e-3) for f in use])  # pattern_scale = delta * inv_d
    delta, sigma, chi2_dof = widened_fit(np.array([f.pattern_scale for f in use]),
                                         np.array([f.pattern_scale_sigma for f in use]), inv_d)
    return {"delta_mm": round(1e3 * delta, 4), "sigma_mm": round(1e3 * sigma, 4),
            "chi2_per_view": round(chi2_dof, 3), "views": len(use),
            "significant": bool(abs(delta) > SIGNIFICANT_Z * sigma),
            "rule": "pattern_scale_v = delta / D_v (D_v the camera's distance to its dots), least squares "
                    "weighted by the dots' sigmas; where beyond 3 of its sigmas, each placement moved delta toward its dots"}


def moved_along_sight(fix: MatFix, delta_mm: float) -> MatFix:
    """``fix`` with its camera moved ``delta_mm`` [mm] toward its dots' centroid on the sheet (along
    its line of sight to them; the orientation kept): the placement :func:`range_offset`'s
    ``delta`` made too far, brought back. A view not placed is returned as it is."""
    if not fix.located or not np.isfinite(delta_mm):
        return fix
    u, _ = _sight(fix)
    T = fix.camera_to_mat.copy()
    T[:3, 3] = T[:3, 3] - 1e-3 * delta_mm * u
    return replace(fix, camera_to_mat=T)
