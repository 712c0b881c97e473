"""The range error a flat support shows: a depth calibration's residual read from the scan itself.

A depth calibration from wall stations about 0.25 m apart cannot see a range error that wiggles
faster than twice that spacing (a ToF camera's harmonics): between its stations it leaves millimetres,
and a millimetre over a 100 mm deep object is a 1 % gain, which scales the model by about as much.
The support the object stands on (a table, a printed mat) is flat, and every view sees it over a
wide span of depths (0.5-1.5 m from a camera 0.3-0.5 m above it). Measured, it is not flat: each
point moved along its ray by the range error ``e(Z)`` at its depth. So the support shows ``e``.

Model (one smooth curve shared by every view, one plane per view): a point on view ``j``'s plane
satisfies ``1 / Z = a_j x + b_j y + c_j`` with ``(x, y)`` its normalised ray; measured at
``Z' = Z + e(Z)``,

    Z' ~= Z'^2 (a_j x + b_j y + c_j) - e(Z'),

linear in the planes' coefficients and in ``e``, a cubic B-spline in ``Z'`` (knots every
``step_mm``), weighted to millimetres. A gain (``e = b Z``: the inverse depth scaled) and a shift of
the inverse depth (``e = c Z^2``) map a plane onto a plane, and an offset (``e = a``) nearly so,
so the support cannot show the two first and shows the offset only through its ``1 / Z^2`` bend,
an extrapolation to the camera centre. The fit holds the curve orthogonal to ``Z - Z_mean`` and its
square over the span (which pins the two lost directions); the curve kept is its part orthogonal
to ``1``, ``Z`` and ``Z^2`` (uniformly in ``Z`` over the span), which does not depend on that choice:
its offset, gain and curvature stay the calibration's. (Held at zero in the fit, the offset's bend
leaked into the curve: 0.27 mm on an exact synthetic floor.) A smoothness prior on the spline's second
differences holds the curve where few points fall (the span's ends).

Its uncertainty comes from the views themselves: the curve is refitted with each view left out
(a jackknife), so a view's own errors (a per-pixel deformation it sees on the support, a patch of
dark print) count, which a formal covariance over 10^5 correlated points would not.

With ``anchors`` (each view's plane measured without the depth, e.g. from a printed pattern's
perspective, :mod:`tofmetry.reconstruct._mat_plane`) the parts a plane absorbs are measured too: each
anchored view's fitted plane, against its anchor over its support's depths, is what the fitted curve left
of the range error there, and those differences, each view weighted by its anchor's covariance, give the
curve's ``1``, ``Z`` and ``Z^2`` (:func:`._support_parts.anchored_part`); the curve is then whole (``anchored``). (A
joint fit with the anchors as priors on the planes was tried first: the linearisation's ``e^2 / Z`` in
directions the support hardly sees pulled the planes millimetres off, even with exact anchors.)

With ``lateral`` image terms the curve may change across the image, ``e(Z') + sum_k phi_k(x, y) h_k(Z')``
(``x^2``: the sides against the centre): the object stands in the image's middle while the support at its
depths is seen beside it, and a calibration's residual between its stations differs there. A plane takes up no
``x^2``, so the support shows each ``h_k`` whole.

Assumes the support is flat to well under the curve (a table or a floor: tenths of a millimetre
over the span) and the points on it were segmented (the object and its shadow left out).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline
from scipy.linalg import null_space

from tofmetry._shared.geometry import ray_factor
from tofmetry.calibrate._support_parts import anchor_samples, anchored_part, station_tie
from tofmetry.errors import EstimationError, InputError

#: cubic spline
_DEGREE = 3
#: image terms the curve may change by across the image (``lateral``): name -> phi(x, y) of the normalised ray
LATERAL_TERMS = {"x2": lambda x, y: x * x, "y2": lambda x, y: y * y, "r2": lambda x, y: x * x + y * y}
#: the lateral curves are in mm at this value of their term (x = 0.5: about the image's edge on a Kinect v2)
LATERAL_REF = 0.25
#: what the curve is a function of: the measured depth ``Z'``, or the measured ray length ``Z' rho``
#: (``rho = sqrt(1 + x^2 + y^2)``, the path whose phase a continuous-wave ToF camera measures)
CURVE_VARIABLES = ("z", "radial")


def curve_variable(z_mm, xy, variable: str) -> np.ndarray:
    """The curve's variable [mm] at measured depths ``z_mm`` (N,) [mm] and normalised rays ``xy`` (N, 2):
    ``Z'`` itself (``"z"``) or the ray length ``Z' sqrt(1 + x^2 + y^2)`` (``"radial"``)."""
    z = np.asarray(z_mm, np.float64).ravel()
    if variable == "z":
        return z
    if variable != "radial":
        raise InputError(f"flat support curve: variable must be one of {CURVE_VARIABLES}, found {variable!r}")
    return z * _rho(xy)


def _rho(xy) -> np.ndarray:
    """(N,) the ray length per unit of Z of normalised rays ``xy`` (N, 2), which a radial curve needs."""
    if xy is None:
        raise InputError("FlatSupportCurve: this curve is a function of the ray length (variable 'radial'); pass "
                         "the points' normalised rays xy (N, 2)")
    return ray_factor(np.asarray(xy, np.float64).reshape(-1, 2))


def _spline_rows(z_mm, knots: np.ndarray, span: tuple[float, float], nu: int = 0) -> np.ndarray:
    """(N, B) a cubic spline's basis functions (or their ``nu``-th derivative) at ``z_mm`` clipped to ``span``."""
    z = np.clip(np.asarray(z_mm, np.float64).ravel(), *span)
    if nu == 0:
        return BSpline.design_matrix(z, knots, _DEGREE).toarray()
    return BSpline(knots, np.eye(len(knots) - _DEGREE - 1), _DEGREE)(z, nu)


def _lateral_phi(terms: tuple, xy: np.ndarray) -> np.ndarray:
    """(N, T) the image terms ``terms`` at normalised rays ``xy`` (N, 2), over :data:`LATERAL_REF`."""
    return np.column_stack([LATERAL_TERMS[k](xy[:, 0], xy[:, 1]) / LATERAL_REF for k in terms]) \
        if terms else np.zeros((len(xy), 0))


@dataclass
class FlatSupportCurve:
    """A range-error curve read from a flat support (:func:`flat_support_curve`).

    Attributes
    ----------
    span_mm : (lo, hi) the measured depths Z' it was fitted over [mm]; beyond, it is held at its end values
    knots_mm : (K,) the spline's full knot vector [mm]
    coef_mm : (B,) the spline's coefficients [mm]
    coef_cov_mm2 : (B, B) their covariance from the views' jackknife [mm^2]
    n_views, n_points : views and support points that entered the fit (after the robust rejection)
    residual_mm : robust RMS of the support points about their planes and the curve [mm]
    flatness_before_mm : the same without the curve (the planes alone) [mm]
    step_mm : knot spacing [mm]
    level_mm : a constant taken off the curve (:meth:`levelled`) [mm]
    anchored : its offset, gain and curvature measured too, from planes known without the depth
        (``anchors``); otherwise its part orthogonal to ``1``, ``Z`` and ``Z^2`` only
    n_anchors : the anchored views that gave them
    tie_coef_mm : (B,) the part of ``coef_mm`` that ties the curve to the calibration's stations (its
        ``1``, ``Z`` and ``Z^2`` fitted so that the curve is nought there, :func:`._support_parts.station_tie`); None untied
    stations_mm : the stations within the span it was tied to [mm]
    lateral : the image terms ``phi_k(x, y)`` the curve changes by across the image (``"x2"``: ``x^2``,
        ``"y2"``: ``y^2``, ``"r2"``: ``x^2 + y^2``; :data:`LATERAL_TERMS`); empty: one curve for every pixel
    lateral_knots_mm : (K_l,) the lateral curves' knot vector [mm] (None without ``lateral``)
    lateral_coef_mm : (T, B_l) each term's spline ``h_k`` [mm at ``phi_k = LATERAL_REF``]: the range error
        at a pixel is ``e(Z) + sum_k phi_k / LATERAL_REF h_k(Z)``; ``coef_cov_mm2`` is then over ``coef_mm``
        and these, flattened, together
    variable : ``"z"``: the curve is a function of the measured depth ``Z'``; ``"radial"``: of the measured ray
        length ``Z' rho`` (:func:`curve_variable`; ``span_mm``, ``knots_mm`` and ``stations_mm`` are then ray
        lengths, the values still depth errors in Z [mm]). Evaluating a radial curve needs the points' rays
    """

    span_mm: tuple[float, float]
    knots_mm: np.ndarray
    coef_mm: np.ndarray
    coef_cov_mm2: np.ndarray
    n_views: int
    n_points: int
    residual_mm: float
    flatness_before_mm: float
    step_mm: float
    notes: list = field(default_factory=list)
    level_mm: float = 0.0
    anchored: bool = False
    n_anchors: int = 0
    tie_coef_mm: np.ndarray | None = None
    stations_mm: tuple = ()
    lateral: tuple = ()
    lateral_knots_mm: np.ndarray | None = None
    lateral_coef_mm: np.ndarray | None = None
    variable: str = "z"

    def _basis(self, z_mm: np.ndarray, nu: int = 0) -> np.ndarray:
        """(N, B) the basis functions (or their ``nu``-th derivative) at ``z_mm`` clipped to the span."""
        return _spline_rows(z_mm, self.knots_mm, self.span_mm, nu)

    def _rows(self, z_mm, xy, nu: int = 0) -> np.ndarray:
        """(N, B + T B_l) the rows over ``coef_mm`` and the lateral coefficients at depths ``z_mm`` [mm] and
        normalised rays ``xy`` (N, 2) (or their ``nu``-th derivative in Z', zero beyond the span)."""
        z = np.asarray(z_mm, np.float64).ravel()
        d = curve_variable(z, xy, self.variable)
        R = self._basis(d, nu)
        if self.lateral:
            if xy is None:
                raise InputError("FlatSupportCurve: this curve changes across the image (lateral "
                                 f"{list(self.lateral)}); pass the points' normalised rays xy (N, 2)")
            phi = _lateral_phi(self.lateral, np.asarray(xy, np.float64).reshape(-1, 2))
            Bl = _spline_rows(d, self.lateral_knots_mm, self.span_mm, nu)
            R = np.hstack([R] + [p[:, None] * Bl for p in phi.T])
        if nu:  # zero beyond the span; in the ray length d/dZ' = rho d/dd
            R = R * ((d >= self.span_mm[0]) & (d <= self.span_mm[1]))[:, None]
            if self.variable == "radial":
                R = R * (_rho(xy) ** nu)[:, None]
        return R

    @property
    def _coef(self) -> np.ndarray:
        """Every coefficient, ``coef_mm`` then the lateral ones (the order of ``coef_cov_mm2``)."""
        return self.coef_mm if not self.lateral else np.r_[self.coef_mm, np.ravel(self.lateral_coef_mm)]

    def error_mm(self, z_mm, xy=None) -> np.ndarray:
        """The range error ``e`` [mm] at measured depths ``z_mm`` [mm] (any shape; held constant beyond the span)
        and, with ``lateral``, normalised rays ``xy`` (..., 2): subtract it from the depth."""
        z = np.asarray(z_mm, np.float64)
        return (self._rows(z, xy) @ self._coef).reshape(z.shape) - self.level_mm

    def gain(self, z_mm, xy=None) -> tuple[np.ndarray, np.ndarray]:
        """The curve's slope ``de/dZ`` (dimensionless) at ``z_mm`` [mm] (and rays ``xy``) and its 1-sigma
        (jackknife); zero beyond the span."""
        D = self._rows(z_mm, xy, 1)
        s = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", D, self.coef_cov_mm2, D), 0.0))
        return D @ self._coef, s

    def mean_gain(self, z_mm, xy=None) -> tuple[float, float]:
        """The curve's mean slope over the depths ``z_mm`` [mm] (a model's points, their rays ``xy``: the gain
        its size sees from the curve) and its 1-sigma."""
        if np.size(z_mm) == 0:
            return 0.0, 0.0
        d = self._rows(z_mm, xy, 1).mean(0)
        return float(d @ self._coef), float(np.sqrt(max(d @ self.coef_cov_mm2 @ d, 0.0)))

    def mean_error(self, z_mm, xy=None) -> tuple[float, float]:
        """The curve's mean over the depths ``z_mm`` [mm] (a model's points, their rays ``xy``) and its
        1-sigma [mm]."""
        if np.size(z_mm) == 0:
            return 0.0, 0.0
        b = self._rows(z_mm, xy).mean(0)
        return float(b @ self._coef - self.level_mm), float(np.sqrt(max(b @ self.coef_cov_mm2 @ b, 0.0)))

    def tie_mean_mm(self, z_mm, xy=None) -> float:
        """The station tie's mean over the depths ``z_mm`` [mm] (their rays ``xy`` for a radial curve; 0 untied):
        what the tie adds to the curve's level there."""
        if self.tie_coef_mm is None or np.size(z_mm) == 0:
            return 0.0
        return float(self._basis(curve_variable(z_mm, xy, self.variable)).mean(0) @ self.tie_coef_mm)

    def levelled(self, z_mm, xy=None) -> "FlatSupportCurve":
        """The curve less its mean over the depths ``z_mm`` [mm] (an object's points, their rays ``xy``): it
        then changes their depths' slope (the gain their size sees) but not their mean, which the support
        cannot tell (its offset at any depth depends on the parts it cannot show). ``level_mm`` keeps what
        was taken."""
        z = np.asarray(z_mm, np.float64).ravel()
        if z.size == 0:
            return self
        out = dataclasses.replace(self, level_mm=0.0, notes=list(self.notes))
        out.level_mm = float(np.mean(out.error_mm(z, xy)))
        return out

    def to_dict(self, every_mm: float = 50.0) -> dict:
        lo, hi = self.span_mm
        z = np.arange(np.ceil(lo / every_mm) * every_mm, hi + 1e-9, every_mm)
        axis = np.zeros((len(z), 2))  # on the optical axis: the lateral terms are nought there
        Bz = self._rows(z, axis)
        s = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", Bz, self.coef_cov_mm2, Bz), 0.0))
        zz = np.linspace(lo, hi, 200)
        out = {"span_mm": [round(lo, 1), round(hi, 1)], "step_mm": self.step_mm, "n_views": self.n_views,
               "n_points": self.n_points, "residual_mm": round(self.residual_mm, 3),
               "flatness_before_mm": round(self.flatness_before_mm, 3),
               "curve_mm": {f"{v:.0f}": [round(float(e), 3), round(float(u), 3)]
                            for v, e, u in zip(z, self.error_mm(z, axis), s)},
               "max_abs_mm": round(float(np.max(np.abs(self.error_mm(zz, np.zeros((len(zz), 2)))))), 3)}
        if self.lateral:  # each term's h_k, at phi_k = LATERAL_REF [mm]
            Bl = _spline_rows(z, self.lateral_knots_mm, self.span_mm)
            out["lateral_mm"] = {k: {f"{v:.0f}": round(float(e), 3) for v, e in zip(z, Bl @ c)}
                                 for k, c in zip(self.lateral, self.lateral_coef_mm)}
            out["lateral_ref"] = LATERAL_REF
        return out | {
                "notes": list(self.notes), "level_mm": round(self.level_mm, 3), "anchored": self.anchored,
                "lateral": list(self.lateral), "variable": self.variable,
                "n_anchors": self.n_anchors, "stations_mm": [round(float(z), 1) for z in self.stations_mm],
                "model": "support flat: 1/Z = a x + b y + c per view, measured Z' = Z + "
                         + ("e(Z'), e a cubic spline " if self.variable == "z" else
                            "e(Z' rho), rho = sqrt(1 + x^2 + y^2) (the measured ray length), e a cubic spline ")
                         + (f"whole: its part orthogonal to 1, Z and Z^2 from the support, those from {self.n_anchors} "
                            "views' planes measured without the depth (the printed pattern's perspective)"
                            if self.anchored else
                            f"its 1, Z and Z^2 tied to nought at the calibration's {len(self.stations_mm)} stations "
                            "within the span" if self.tie_coef_mm is not None else
                            "kept orthogonal to 1, Z and Z^2 over the span (those parts stay the calibration's)")
                         + (f"; plus {' + '.join(f'{k} / {LATERAL_REF:g} h_{k}(Z)' for k in self.lateral)} across the "
                            "image, each h a cubic spline fitted whole" if self.lateral else "")
                         + "; 1-sigma from the views' jackknife"}


def _design(z: np.ndarray, xy: np.ndarray, knots: np.ndarray, span: tuple[float, float],
            lateral: tuple = (), lateral_knots: np.ndarray | None = None, variable: str = "z"):
    """Rows of one view: plane part (N, 3), curve part (N, B) and lateral part (N, T B_l) (the curves at
    the points' ``variable``, :func:`curve_variable`), right-hand side (N,), all in mm."""
    zm = z * 1e-3  # m
    P = (zm ** 2)[:, None] * np.column_stack([xy[:, 0], xy[:, 1], np.ones(len(z))]) * 1e3  # Z'^2 (x, y, 1) [mm m]
    d = curve_variable(z, xy, variable)
    B = -_spline_rows(d, knots, span)
    L = np.zeros((len(z), 0))
    if lateral:
        Bl = _spline_rows(d, lateral_knots, span)
        L = np.hstack([-p[:, None] * Bl for p in _lateral_phi(lateral, xy).T])
    return P, B, L, z


def _solve(blocks: list, nb: int, prior: np.ndarray, use: list[int]) -> tuple[np.ndarray, list]:
    """Least squares over the views in ``use``: the normal equations of every plane block eliminated
    (a Schur complement), so the cost does not grow with the views' count squared."""
    N = prior.copy()
    r = np.zeros(nb)
    elim = []
    for j in use:
        P, B, y, w = blocks[j]
        Pw, Bw = P * w[:, None], B * w[:, None]
        App, Apb, Abb = Pw.T @ P, Pw.T @ B, Bw.T @ B
        yp, yb = Pw.T @ y, Bw.T @ y
        inv = np.linalg.inv(App)
        N += Abb - Apb.T @ inv @ Apb
        r += yb - Apb.T @ inv @ yp
        elim.append((j, inv, Apb, yp))
    c = np.linalg.solve(N, r)
    planes = [(j, inv @ (yp - Apb @ c)) for j, inv, Apb, yp in elim]
    return c, planes


def flat_support_curve(z_mm: list[np.ndarray], xy: list[np.ndarray], step_mm: float = 60.0,
                       smooth_mm: float = 5.0, min_views: int = 3, min_points: int = 500,
                       min_span_steps: float = 3.0, clip_sigmas: float = 3.0,
                       max_points_per_view: int = 8000, seed: int = 0,
                       anchors: list | None = None, stations_mm: list[float] | None = None,
                       station_sigma_mm: float = 0.3, lateral: tuple = (), lateral_step_mm: float | None = None,
                       lateral_sigma_mm: float = 5.0, variable: str = "z") -> FlatSupportCurve:
    """Fit the range-error curve a flat support shows in several views of it.

    Parameters
    ----------
    z_mm : per view, (N_j,) measured depth Z' [mm] of points on the support (the object left out)
    xy : per view, (N_j, 2) their normalised rays ``(x, y)`` (the point is ``Z (x, y, 1)``)
    step_mm : knot spacing [mm]: the shortest wiggle the curve follows is about twice this
    smooth_mm : prior 1-sigma of the spline's second differences [mm] (a wiggle of amplitude ``A`` and
        period ``P`` has ``A (2 pi step / P)^2``: 5 mm passes 6 mm at 0.4 m)
    min_views : views with at least ``min_points`` support points needed
    min_span_steps : the support's depths must span at least this many knot steps
    clip_sigmas : points beyond this many robust sigmas of the fit are left out (dark print the amplitude
        correction missed, the object's foot, a cable)
    max_points_per_view : a view's points are subsampled to this many (drawn with ``seed``)
    anchors : optional, per view, None or ``(p, cov)``: the view's support plane measured without the
        depth (a printed pattern's perspective fit), ``p`` (3,) its ``(a, b, c)`` [1/m] and ``cov``
        (3, 3) their covariance. With at least ``min_views`` anchored views the curve's offset, gain
        and curvature come from them (:func:`._support_parts.anchored_part`) and the curve is whole (``anchored``)
    stations_mm : optional, the depths [mm] of the depth calibration's stations, where its own residual is
        about nought (it was fitted there; between them it wiggles, which the support shows). Without
        anchors, with at least two of them within the span, the curve's ``1``, ``Z`` and ``Z^2`` (``1`` and
        ``Z`` with two) are those that put it nearest nought there (:func:`._support_parts.station_tie`): its gain and
        curvature over an object's depths are then the whole range error's, not only its part the support
        shows. A part of the support's own error that is a parabola in Z (a smooth incidence bias) goes with them.
    station_sigma_mm : the calibration's residual at its stations (1 sigma) [mm], added to the curve's
        covariance through the tie
    lateral : image terms (keys of :data:`LATERAL_TERMS`, e.g. ``("x2",)``) the curve changes by across the
        image: ``e(Z') + sum_k phi_k(x, y) / LATERAL_REF h_k(Z')``, each ``h_k`` a cubic spline. A calibration's
        per-pixel deformation, interpolated in range between its stations, leaves a residual that differs
        between the image's centre (where the object is) and its sides (where the support is seen at the
        object's depths); a plane takes up no ``x^2`` or ``y^2``, so the support shows each ``h_k`` whole.
        ``y^2`` is told from ``e`` only by views at other heights (on a support, Z follows the image row)
    lateral_step_mm : the lateral curves' knot spacing [mm] (None: twice ``step_mm``)
    lateral_sigma_mm : prior 1-sigma of the lateral curves' values [mm] (holds them where the support's
        points do not tell them from ``e``); their second differences take ``smooth_mm``
    variable : ``"z"``: ``e`` a function of the measured depth ``Z'``; ``"radial"``: of the measured ray length
        ``Z' rho`` (:func:`curve_variable`), the path whose phase a continuous-wave ToF camera measures. A
        range error that wiggles in the ray length reads, at one ``Z'``, differently on the support's rows
        (below the object, ``rho`` up to 1.1) than on the object's (about the image's centre, ``rho`` near 1):
        a 60 mm shift of a wiggle's phase at 1 m. The knots, the span, the stations and the anchors' depths
        are then ray lengths; the planes stay in ``Z``

    Returns
    -------
    FlatSupportCurve

    Raises
    ------
    InputError on mismatched inputs; EstimationError when the support does not show the curve (too
    few views or points, too short a span), with the reason.
    """
    if len(z_mm) != len(xy):
        raise InputError(f"flat_support_curve: {len(z_mm)} depth arrays for {len(xy)} ray arrays")
    if variable not in CURVE_VARIABLES:
        raise InputError(f"flat_support_curve: variable must be one of {CURVE_VARIABLES}, found {variable!r}")
    views, held = [], []
    rng = np.random.default_rng(seed)
    if anchors is not None and len(anchors) != len(z_mm):
        raise InputError(f"flat_support_curve: {len(anchors)} anchors for {len(z_mm)} views")
    for j, (z, r) in enumerate(zip(z_mm, xy)):
        z, r = np.asarray(z, np.float64).ravel(), np.asarray(r, np.float64).reshape(-1, 2)
        if len(z) != len(r):
            raise InputError(f"flat_support_curve: view {j} has {len(z)} depths and {len(r)} rays")
        ok = np.isfinite(z) & (z > 0) & np.all(np.isfinite(r), axis=1)
        if ok.sum() >= min_points:
            pick = np.nonzero(ok)[0]
            if len(pick) > max_points_per_view:
                pick = np.sort(rng.choice(pick, max_points_per_view, replace=False))
            views.append((z[pick], r[pick]))
            held.append(None if anchors is None else anchors[j])
    if len(views) < min_views:
        raise EstimationError(f"the support shows no range curve: {len(views)} view(s) see at least {min_points} "
                              f"points of it, {min_views} needed")
    zall = np.concatenate([curve_variable(*v, variable) for v in views])
    lo, hi = (float(x) for x in np.percentile(zall, [0.5, 99.5]))
    if hi - lo < min_span_steps * step_mm:
        raise EstimationError(f"the support shows no range curve: its depths span {hi - lo:.0f} mm, "
                              f"{min_span_steps * step_mm:.0f} mm needed (knots every {step_mm:g} mm)")
    n_int = max(1, int(np.ceil((hi - lo) / step_mm)))
    knots = np.r_[[lo] * _DEGREE, np.linspace(lo, hi, n_int + 1), [hi] * _DEGREE]
    nb = len(knots) - _DEGREE - 1
    span = (lo, hi)
    # the curve's part in span{Z, Z^2} is the calibration's: the coefficients are held in the null space
    # of its projection, c = Q u
    zg = np.linspace(lo, hi, 400)
    Bg = BSpline.design_matrix(zg, knots, _DEGREE).toarray()
    u = (zg - zg.mean()) / (hi - lo)
    Q = null_space(np.vstack([u @ Bg, u ** 2 @ Bg]))
    Pg = np.column_stack([np.ones_like(u), u, u ** 2])
    to_coef = np.linalg.pinv(Bg) @ Pg  # (1, u, u^2) -> spline coefficients
    keep_part = np.eye(nb) - to_coef @ np.linalg.pinv(Pg) @ Bg  # c -> its part orthogonal to 1, Z, Z^2
    lat = tuple(lateral or ())
    bad = [k for k in lat if k not in LATERAL_TERMS]
    if bad:
        raise InputError(f"flat_support_curve: lateral terms {bad} unknown; expected some of {list(LATERAL_TERMS)}")
    lknots, nbl = None, 0
    if lat:
        n_l = max(1, int(np.ceil((hi - lo) / (lateral_step_mm or 2.0 * step_mm))))
        lknots = np.r_[[lo] * _DEGREE, np.linspace(lo, hi, n_l + 1), [hi] * _DEGREE]
        nbl = len(lknots) - _DEGREE - 1
    nl = len(lat) * nbl
    blocks = []
    for z, r in views:
        P, B, L, y = _design(z, r, knots, span, lat, lknots, variable)
        blocks.append((P, np.hstack([B @ Q, L]), y, np.ones(len(z))))
    DQ = np.diff(np.eye(nb), 2, axis=0) @ Q
    nq = Q.shape[1]
    Dl = np.kron(np.eye(len(lat)), np.diff(np.eye(nbl), 2, axis=0)) if lat else np.zeros((0, 0))

    def prior_of(sigma: float) -> np.ndarray:  # smoothness of e; smoothness and size of the lateral curves
        N = np.zeros((nq + nl, nq + nl))
        N[:nq, :nq] = (sigma / smooth_mm) ** 2 * DQ.T @ DQ
        if nl:
            N[nq:, nq:] = (sigma / smooth_mm) ** 2 * Dl.T @ Dl + (sigma / lateral_sigma_mm) ** 2 * np.eye(nl)
        return N

    def unpack(cq: np.ndarray) -> np.ndarray:  # solved coefficients -> the curve's kept part, lateral ones
        return np.r_[part @ Q @ cq[:nq], cq[nq:]]

    sigma = 1.0
    for _ in range(3):  # robust: refit without the points beyond clip_sigmas
        prior = prior_of(sigma)
        c, planes = _solve(blocks, nq + nl, prior, list(range(len(blocks))))
        res = np.concatenate([P @ p + B @ c - y for (_, p), (P, B, y, _) in zip(planes, blocks)])
        w_all = np.concatenate([b[3] for b in blocks])
        sigma = float(1.4826 * np.median(np.abs(res[w_all > 0]))) or 1.0
        keep = np.abs(res) < clip_sigmas * sigma
        k0 = 0
        for i, b in enumerate(blocks):
            n = len(b[2])
            blocks[i] = b[:3] + (keep[k0:k0 + n].astype(np.float64),)
            k0 += n
    prior = prior_of(sigma)
    c, planes = _solve(blocks, nq + nl, prior, list(range(len(blocks))))
    used = [b[3] > 0 for b in blocks]
    res = np.concatenate([(P @ p + B @ c - y)[m] for (_, p), (P, B, y, _), m in zip(planes, blocks, used)])
    flat = []
    for (P, _, y, _), m in zip(blocks, used):  # the planes alone
        p = np.linalg.lstsq(P[m], y[m], rcond=None)[0]
        flat.append((P[m] @ p - y[m]))
    V = len(blocks)
    anchored = [j for j in range(V) if held[j] is not None]
    whole = len(anchored) >= min_views
    part = np.eye(nb) if whole else keep_part  # anchored: the fitted curve whole, the planes' share added
    jack = np.array([unpack(_solve(blocks, nq + nl, prior, [i for i in range(V) if i != j])[0])
                     for j in range(V)])
    coef, lat_coef = unpack(c)[:nb], c[nq:]
    if whole:  # what the planes took up (the parts the support cannot show), from the anchors
        plane_of = dict(planes)
        samples = [anchor_samples(views[j][1][used[j]], plane_of[j], *held[j], radial=variable == "radial")
                   for j in anchored]

        def share(drop: int | None = None) -> np.ndarray:  # the planes' share, without anchor ``drop``
            return to_coef @ anchored_part([x for i, x in enumerate(samples) if i != drop], zg.mean(), hi - lo)

        full = share()
        coef = coef + full
        for j in range(V):  # a view without an anchor leaves the planes' share as it is
            jack[j, :nb] = jack[j, :nb] + (share(anchored.index(j)) if j in anchored else full)
    tie, zs = None, ()
    if not whole and stations_mm is not None:
        zs = tuple(float(z) for z in np.sort(np.asarray(stations_mm, np.float64).ravel()) if lo <= z <= hi)
        if len(zs) >= 2:
            M, G = station_tie(np.array(zs), _spline_rows(zs, knots, span), to_coef, zg.mean(), hi - lo)
            tie = M @ coef - coef
            coef, jack[:, :nb] = M @ coef, jack[:, :nb] @ M.T
        else:
            zs = ()
    cov = (V - 1) / V * (jack - jack.mean(0)).T @ (jack - jack.mean(0))
    if tie is not None:
        cov[:nb, :nb] = cov[:nb, :nb] + station_sigma_mm ** 2 * G @ G.T
    return FlatSupportCurve((lo, hi), knots, coef, cov, V, int(sum(m.sum() for m in used)),
                            float(1.4826 * np.median(np.abs(res))),
                            float(1.4826 * np.median(np.abs(np.concatenate(flat)))), float(step_mm),
                            anchored=whole, n_anchors=len(anchored) if whole else 0, tie_coef_mm=tie,
                            stations_mm=zs, lateral=lat, lateral_knots_mm=lknots,
                            lateral_coef_mm=lat_coef.reshape(len(lat), nbl) if lat else None, variable=variable)
