"""Acquisition planning (study §6.3): predicted completeness and accuracy of a set of views around an
object, and the proposal of views (rings, zenithal views, stripes) that reach a target.

:func:`predict` judges a set of views; :func:`propose` picks one among :func:`candidates`; the object
is a mesh, a proxy of a rough size (:func:`proxy_from_size`) or of a first view
(:func:`proxy_from_points`). ``tofmetry plan`` is :mod:`tofmetry.pipelines.plan`.
"""

from tofmetry.plan._plan import (
    PREDICTION_ERROR_PTS,
    PlanObject,
    Prediction,
    Proposal,
    aim_for,
    candidates,
    complete,
    predict,
    propose,
    proxy_from_mesh,
    proxy_from_points,
    proxy_from_size,
    reconstructed_share,
    ring,
    seen_cosines,
    seen_masks,
    stripes,
    surface_samples,
)
from tofmetry.plan._symmetry import TURN_FREE_BELOW, turn_about_vertical

__all__ = ["PREDICTION_ERROR_PTS", "PlanObject", "Prediction", "Proposal", "aim_for", "candidates", "complete", "predict", "propose", "proxy_from_mesh",
           "proxy_from_points", "proxy_from_size", "reconstructed_share", "ring", "seen_cosines", "seen_masks", "stripes",
           "surface_samples", "TURN_FREE_BELOW", "turn_about_vertical"]
