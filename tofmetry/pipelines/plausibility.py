"""Plausibility gates: a result far outside what the sensor can be fails loudly, never exits 0 quietly.

Every estimator of the pipeline layer passes its result through one of the checks below. A check
returns *findings* (one sentence each, naming the quantity, the value, the threshold and where the
threshold comes from); :func:`enforce` raises :class:`~tofmetry.errors.ImplausibleResultError` with
all of them unless the caller accepted implausible results (``--accept-implausible``), in which case
the findings are returned as a record ``{"accepted": True, "findings": [...]}`` that the run, the
calibration's provenance, ``fit.json`` and the study's report keep.

The thresholds come from the sensor profile and from the reference study's figures, never from the
data being judged:

====================================  =========================================================
gate                                  threshold
====================================  =========================================================
reprojection RMS (intrinsics)          :data:`MAX_REPROJECTION_RMS_PX` = 1 px: a sharp board's
                                       corners are found to about 0.1 px (the real Kinect v2
                                       recording: 0.095 px; OpenCV's sample images: 0.26 px)
focal length vs the sensor profile     within :data:`FOCAL_TOLERANCE` = 15 % of the profile's
                                       ``fx``/``fy`` when the image size is the profile's (Kinect
                                       v2 units: 364-378 px against the typical 365; the random
                                       sensor family: +-5 %, so 3x its span)
field of view, any camera              :data:`FOV_RANGE_DEG` = 20-150 deg horizontally (consumer
                                       RGB-D cameras: 58-120 deg)
pixel aspect                           ``|fx / fy - 1|`` <= :data:`MAX_ASPECT_DEVIATION` = 5 %
                                       (square pixels; the family: +-1 %)
principal point                        within the central half of the image
                                       (:data:`MAX_PRINCIPAL_OFFSET` = 25 % of the size per axis)
stated station distance vs measured    :func:`central_budget_mm`: 80 mm + 1 % of the distance
central depth (wall datasets)
depth correction, anywhere in the      :func:`correction_budget_mm`: the central budget + 50 mm
image and the fitted depths            of per-pixel deformation
capture vs the calibration's support   not every valid pixel outside it (``cloud``, ``correct``)
====================================  =========================================================

The error budget of a Kinect-v2-class sensor at the image centre, before calibration: its range
error (study §4.2.2: -15 .. +7 mm), warm-up drift (§3.2: about 5 mm; the family: up to 8 mm), a
mount offset nobody measured (study: about 2 cm; the family: up to 4 cm) and a scale error of the
modulation (the family: +-0.5 %), about 65 mm + 0.5 % of the distance, rounded up to
:data:`CENTRAL_BUDGET_MM` = 80 mm + :data:`SCALE_BUDGET` = 1 %. Away from the centre the
deformation adds up to a few cm (§4.2.3: "more than 1 cm on the corners"; the family: up to about
4 cm): :data:`DEFORMATION_BUDGET_MM` = 50 mm.
"""

from __future__ import annotations

import math

import numpy as np

from tofmetry.errors import DegenerateFitError, ImplausibleResultError
from tofmetry.sensor import CameraIntrinsics
from tofmetry.sensor.profiles import PROFILES

#: largest plausible RMS reprojection error of an intrinsic calibration [px]
MAX_REPROJECTION_RMS_PX = 1.0
#: largest relative deviation of fx, fy from the sensor profile's (same image size)
FOCAL_TOLERANCE = 0.15
#: plausible horizontal field of view of any camera [deg]
FOV_RANGE_DEG = (20.0, 150.0)
#: largest plausible |fx / fy - 1|
MAX_ASPECT_DEVIATION = 0.05
#: largest offset of the principal point from the image centre, as a share of the width / height
MAX_PRINCIPAL_OFFSET = 0.25
#: systematic depth error at the image centre before calibration, constant part [mm]
CENTRAL_BUDGET_MM = 80.0
#: systematic depth error at the image centre, part proportional to the distance
SCALE_BUDGET = 0.01
#: per-pixel deformation away from the centre [mm]
DEFORMATION_BUDGET_MM = 50.0

ACCEPT_HINT = "pass --accept-implausible to write the result anyway (the report then records it)"


def central_budget_mm(distance_mm: float) -> float:
    """Largest plausible systematic depth error at the image centre [mm] at ``distance_mm``."""
    return CENTRAL_BUDGET_MM + SCALE_BUDGET * abs(float(distance_mm))


def correction_budget_mm(distance_mm: float) -> float:
    """Largest plausible depth correction anywhere in the image [mm] at ``distance_mm``."""
    return central_budget_mm(distance_mm) + DEFORMATION_BUDGET_MM


def refuse_degenerate(err: DegenerateFitError, what: str) -> ImplausibleResultError:
    """The :class:`ImplausibleResultError` for a fit whose values describe no camera at all: its
    findings (the residual, then what is impossible) as :func:`enforce` words them, but nothing a
    user could accept, since no such camera can be written."""
    findings = check_reprojection(err.rms) + [f"the fitted {err.reason}"]
    return ImplausibleResultError(f"{what} is implausible: " + "; ".join(findings) + ". It cannot be written, even "
                                  "with --accept-implausible: check the board size and the images", findings)


def enforce(findings: list[str], what: str, accept: bool = False) -> dict:
    """Raise :class:`ImplausibleResultError` for ``findings`` unless ``accept``.

    Parameters
    ----------
    findings : sentences from the checks of this module (empty: plausible)
    what : the result judged, e.g. ``"intrinsic calibration of board-images"``
    accept : the user accepted implausible results (``--accept-implausible``)

    Returns
    -------
    dict ``{"checked": True, "accepted": bool, "findings": [...]}`` to store with the result.
    """
    if findings and not accept:
        raise ImplausibleResultError(f"{what} is implausible: " + "; ".join(findings) + f". {ACCEPT_HINT}",
                                     findings)
    return {"checked": True, "accepted": bool(findings), "findings": list(findings)}


def _profile_for(intr: CameraIntrinsics):
    for p in PROFILES.values():
        for cam in (p.depth, p.color):
            if cam is not None and (cam.width, cam.height) == (intr.width, intr.height):
                return p.name, cam
    return None, None


def check_reprojection(rms_px: float | None) -> list[str]:
    """Finding when an intrinsic fit's RMS reprojection error ``rms_px`` [px] exceeds
    :data:`MAX_REPROJECTION_RMS_PX` (None: not checked)."""
    if rms_px is not None and not (math.isfinite(rms_px) and rms_px <= MAX_REPROJECTION_RMS_PX):
        return [f"reprojection RMS {rms_px:.2f} px exceeds {MAX_REPROJECTION_RMS_PX:g} px (corners of a sharp board "
                "are found to about 0.1 px: a wrong --board size or square, or images of another board?)"]
    return []


def check_intrinsics(intr: CameraIntrinsics, rms_px: float | None = None, sensor: str | None = None) -> list[str]:
    """Findings on a fitted lens: reprojection RMS, focal length vs profile, field of view, aspect, centre.

    Parameters
    ----------
    intr : the fitted intrinsics [px]
    rms_px : RMS reprojection error of the fit [px], or None
    sensor : profile name to compare with (default: the profile whose depth or colour camera has
        the same image size, if any)
    """
    out = check_reprojection(rms_px)
    name, cam = (sensor, PROFILES[sensor].depth) if sensor in PROFILES else _profile_for(intr)
    if cam is not None and (cam.width, cam.height) == (intr.width, intr.height):
        for key in ("fx", "fy"):
            got, ref = getattr(intr, key), getattr(cam, key)
            if not abs(got / ref - 1.0) <= FOCAL_TOLERANCE:
                out.append(f"{key} = {got:.1f} px is {100 * (got / ref - 1):+.0f} % from the {name} profile's {ref:.1f} px "
                           f"(units differ by a few %; tolerance {100 * FOCAL_TOLERANCE:.0f} %)")
    fov = math.degrees(2 * math.atan(intr.width / (2 * intr.fx))) if intr.fx > 0 else float("nan")
    if not FOV_RANGE_DEG[0] <= fov <= FOV_RANGE_DEG[1]:
        out.append(f"horizontal field of view {fov:.1f} deg (fx {intr.fx:.1f} px over {intr.width} px) is outside "
                   f"{FOV_RANGE_DEG[0]:g}-{FOV_RANGE_DEG[1]:g} deg")
    if not abs(intr.fx / intr.fy - 1.0) <= MAX_ASPECT_DEVIATION:
        out.append(f"fx / fy = {intr.fx / intr.fy:.3f}: pixels are square to about 1 %, tolerance "
                   f"{100 * MAX_ASPECT_DEVIATION:.0f} %")
    for key, size in (("cx", intr.width), ("cy", intr.height)):
        off = getattr(intr, key) - (size - 1) / 2
        if not abs(off) <= MAX_PRINCIPAL_OFFSET * size:
            out.append(f"{key} = {getattr(intr, key):.1f} px is {off:+.0f} px from the image centre (more than "
                       f"{100 * MAX_PRINCIPAL_OFFSET:.0f} % of {size} px)")
    return out


def check_station(name: str, stated_mm: float, measured_mm: float) -> list[str]:
    """Finding when a wall station's stated distance (reference offset removed) disagrees with the
    central depth the sensor measured by more than :func:`central_budget_mm`."""
    if not math.isfinite(measured_mm):
        return [f"station {name!r}: no valid depth at the image centre to check its stated {stated_mm:.0f} mm against"]
    budget = central_budget_mm(stated_mm)
    if abs(measured_mm - stated_mm) > budget:
        return [f"station {name!r} is stated at {stated_mm:.0f} mm but the sensor measures {measured_mm:.0f} mm at the "
                f"image centre ({measured_mm - stated_mm:+.0f} mm; the sensor's error budget there is ±{budget:.0f} mm: "
                "a wrong distance in stations.csv, or a wrong folder?)"]
    return []


def check_correction(cal, step_px: int = 8, n_depths: int = 7) -> list[str]:
    """Finding when the calibration's correction exceeds :func:`correction_budget_mm` somewhere in
    the image over its fitted depths (sampled every ``step_px`` pixels at ``n_depths`` depths)."""
    lo, hi = cal.support_range_mm
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo > 0):
        return []
    h, w = cal.shape
    v, u = np.mgrid[0:h:step_px, 0:w:step_px]
    worst = None
    for d in np.linspace(lo, hi, n_depths):
        corr, _ = cal.correction_at(u, v, np.full(u.shape, d))
        c = np.abs(corr[np.isfinite(corr)])
        if c.size == 0:
            continue
        m = float(c.max())
        if m > correction_budget_mm(d) and (worst is None or m - correction_budget_mm(d) > worst[0] - worst[2]):
            worst = (m, d, correction_budget_mm(d))
    if worst is None:
        return []
    m, d, b = worst
    return [f"the depth correction reaches {m:.0f} mm at {d:.0f} mm, more than the sensor's error budget of {b:.0f} mm "
            "there (the reference distances or the dataset do not describe this sensor)"]


def check_support(outside: int, valid: int, lo_hi_mm: tuple[float, float], what: str) -> list[str]:
    """Finding when every valid pixel (``valid`` > 0) lies outside the calibration's support."""
    if valid > 0 and outside >= valid:
        return [f"all {valid} valid pixels of {what} lie outside the calibration's support (fitted depths "
                f"{lo_hi_mm[0]:.0f}-{lo_hi_mm[1]:.0f} mm): the calibration was not made for these depths"]
    return []
