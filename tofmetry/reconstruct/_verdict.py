"""Reliability verdicts of a reconstruction: every edge, every view and the run, each with its reason.

A model must never be handed out silently wrong. The registration knows a good deal about its
own state, and :func:`assess` turns it into verdicts:

* **edges** (pairs of views): ``verified`` (accepted, kept, and on a loop of the view graph that
  closes), ``unverified`` (accepted and kept, but no loop goes through it: nothing checks it),
  ``yaw free`` (its overlap is nearly a surface of revolution: the rotation about the vertical is
  not determined by the geometry, :func:`~tofmetry.reconstruct.registration_conditioning`) unless
  the IR amplitude's albedo pattern decides it (``verified by IR``,
  :func:`~tofmetry.reconstruct._photometric.ir_yaw_sweep`) or a loop in which it is the only free
  edge closes within the pose gate (``verified by its loop``: a wrong yaw there would show in the
  closure; two free edges on a loop can cancel, as every edge of a vase does),
  ``pruned``, ``dropped`` (contradicts the other views' loops), ``rejected`` (failed the pairwise
  gates; the figures and the gates are in the reason);
* **views**: ``verified`` (on a closed loop), ``unverified`` (linked by unverified edges only) or
  ``left out`` (no accepted registration links it to the others; the model is built without it);
* **the run**: reliable, or unreliable with the reasons. A run is unreliable when the pose-graph
  consistency gate fails (:func:`~tofmetry.reconstruct.consistency_gate`), when a kept edge is yaw
  free, when the loops close only once their error is spread and that error is larger than the
  pose accuracy asked for, when the global adjustment failed, when it moved a view from its
  pose-graph pose by more than ``pose_gate_deg`` (the pairs and the joint fit disagree beyond the
  accuracy asked for), or when, restarted from the far side of its solution
  (:mod:`~tofmetry.reconstruct._adjust_restart`; moves beyond half the gate), it did not come back to
  within ``restart_share`` of the pose gate (the points leave a direction free and the fit slides along it),
  or when more than ``max_left_out`` of the views are left out (the pipeline adds three more: a declared
  turntable's axis the views rejected, a slab whose two faces' views are tied only through its rim,
  :mod:`~tofmetry.reconstruct._thin_slab`, and a turntable's views that the joint fit could not hold to one
  turn axis, :func:`~tofmetry.reconstruct._adjust_circle.off_axis_reason`). A few views
  left out, an unobservable depth gain, unverified views, a pair registered again from the pose
  its loop implies (:mod:`~tofmetry.reconstruct._loop_implied`), a depth calibration that doubts its
  own prediction and one that predicts its own error between stations, where the object lies
  (:func:`~tofmetry.reconstruct._calibration_support.local_prediction`), above
  ``max_calibration_mm`` are warnings: the model is then incomplete or less checked, not wrong. (A calibration's doubt was a reason until a family of 20 random
  draws showed it flagging three runs whose poses were within 0.16 deg / 1.4 mm, while the runs
  it should have caught were caught by their own loops. Its predicted error above
  ``max_calibration_mm`` was a reason until draws 30-34 of the family (104 runs): each of the 6
  wrong runs it flagged was flagged by another reason too, and it was the only reason on 4 right ones. Views on
  no loop were tried as a reason too: on 20 draws it caught no wrong run the other reasons missed
  and flagged a right one.)

The pose accuracy a loop can vouch for: after the pose graph spreads a loop's closure error over
its ``m`` edges, a view half-way round the loop can still be off by about half the closure; the
run is flagged when half the closure of a loop, at the object, exceeds (``pose_gate_deg``,
``pose_gate_mm``).
"""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct._adjust_restart import came_back, settles_loops
from tofmetry.reconstruct._calibration_support import (
    calibration_central_mm,
    station_spacing_mm,
)
from tofmetry.reconstruct._loops import bridges
from tofmetry.reconstruct._pattern_search import METHOD as PATTERN_METHOD
from tofmetry.reconstruct._regview import leaves_yaw_free

#: the share of the pose gate within which the joint fits from every tied choice of pairwise hypotheses
#: must end (of each other's solution) for the points to decide between them
TIED_SHARE = 0.5


def assess(names: list[str], edges: list[dict], consistency: dict, left_out: dict | None = None,
           adjustment: dict | None = None, calibration_prediction: dict | None = None,
           max_calibration_mm: float = 1.5, pose_gate_deg: float = 0.5, pose_gate_mm: float = 3.0,
           yaw_free_ratio: float = 0.15, max_left_out: float = 0.25, gain_alarm_factor: float = 1.5,
           turntable_accuracy_deg: float | None = None, turntable_placed: bool = False,
           restart_share: float = 1.0) -> dict:
    """Verdicts of the edges (added to each edge dict as ``verdict`` and ``reason``), the views and the run.

    Parameters
    ----------
    names : names of the registered views (the graph's nodes, in order)
    edges : edge dicts of :meth:`PoseGraphBuilder.optimize` (and of the views left out)
    consistency : :func:`consistency_gate` output (loops with ``closure_object_mm`` when known)
    left_out : view name -> reason, for views left out of the model
    adjustment : :meth:`AdjustResult.to_dict` or ``{"failed": reason}`` or None
    calibration_prediction : the depth calibration's ``prediction`` (None: raw depth)
    max_calibration_mm : a calibration predicting a larger central error between its stations is
        a warning [mm]
    pose_gate_deg, pose_gate_mm : the pose accuracy asked for (rotation [deg], displacement of the
        object [mm]); see the module docstring
    yaw_free_ratio : an edge whose yaw stiffness ratio (``conditioning["yaw_ratio"]``) is below this is yaw free
    max_left_out : a larger share of the views left out makes the run unreliable (a few are a warning)
    turntable_accuracy_deg : how accurately a declared turntable turns [deg]: edges that its step alone
        gives (method ``turntable-step``, no registration passed the gates) are that accurate; a reason
        when it exceeds ``pose_gate_deg``, a warning otherwise
    turntable_placed : the declared turntable placed the views (the joint fit started from its poses
        and held them within ``turntable_accuracy_deg``): when that accuracy is within
        ``pose_gate_deg``, what the pairwise graph's loops, ambiguity or free yaws say about the pose
        graph's poses no longer bears on the poses, and is a warning (the joint fit's move and
        restart still judge them)
    restart_share : the joint fit's restart, and a moved view's pairs registered again from it, must end
        within this share of the pose gate (:func:`_judge_move`)
    gain_alarm_factor : a depth gain the adjustment refused as implausible makes the run unreliable when it
        exceeds this many times the bound it broke (the calibration's allowance); below, it is a warning.
        Set on 8 family runs with a refused gain: asking 1.04-1.4 times the bound, 5 runs were within the
        pose gate; a bunny asking 1.6 times was 0.65 deg / 5.7 mm off (at 2, it was a miss)

    Returns
    -------
    dict: reliable, reasons (why unreliable), warnings, views {name: {verdict, reason}},
    loop_pose_bound {deg, mm} (half the largest loop closure), yaw_free_edges
    """
    left_out = dict(left_out or {})
    idx = {nm: k for k, nm in enumerate(names)}
    kept = [e for e in edges if e.get("kept") and e["source"] in idx and e["target"] in idx]
    pairs = [(idx[e["source"]], idx[e["target"]]) for e in kept]
    br = bridges(len(names), pairs)
    reasons = list(consistency.get("reasons", []))
    graph = list(reasons)  # what the pairwise graph says about the pose graph's poses
    warnings = []
    yaw_free = []
    stepped = []  # edges the declared turntable's step gives
    loops = consistency.get("loops") or []
    free = {frozenset((e["source"], e["target"])) for e in kept
            if leaves_yaw_free(e.get("conditioning"), yaw_free_ratio) and not (e.get("ir_yaw") or {}).get("decided")}
    for e in edges:
        if "verdict" in e and e["verdict"] == "left out with its view":
            continue
        if not e.get("accepted"):
            e["verdict"], e["reason"] = ("dropped" if "dropped" in e.get("method", "") else "rejected",
                                         e.get("reason") or e.get("method", ""))
            continue
        if not e.get("kept"):
            e["verdict"], e["reason"] = "pruned", "pruned by the pose-graph optimisation (disagrees with the others)"
            continue
        k = kept.index(e)
        if e.get("method") == "turntable-step":
            e["verdict"] = "turntable step"
            e["reason"] = ("no registration of these views passed the gates; the declared turntable step links them, "
                           f"as accurately as the turntable turns (+/- {turntable_accuracy_deg:g} deg)")
            stepped.append(f"{e['source']}->{e['target']}")
            continue
        if e.get("method", "").startswith(PATTERN_METHOD):
            e["verdict"] = "verified by IR" if k not in br else "unverified"
            e["reason"] = (f"the IR albedo pattern placed it (correlation {e.get('ir_corr', float('nan')):.2f} over "
                           "the whole turn about the vertical): the geometry's own hypotheses left the pattern "
                           "unmatched (a pose turned by the object's symmetry)"
                           + ("" if k not in br else "; no loop goes through this edge"))
            continue
        yr = (e.get("conditioning") or {}).get("yaw_ratio")
        free_e = leaves_yaw_free(e.get("conditioning"), yaw_free_ratio)
        iy = e.get("ir_yaw") or {}
        if free_e and iy.get("decided"):
            e["verdict"] = "verified by IR" if k not in br else "unverified"
            e["reason"] = (f"the geometry leaves the yaw free (stiffness ratio {yr:.2f}); the IR albedo pattern fixes it "
                           f"(correlation {iy['correlation']:.2f}, {iy['margin']:.2f} above any other yaw)"
                           + ("" if k not in br else "; no loop goes through this edge"))
        elif free_e and (lp := _loop_pinning_yaw(e, loops, free, pose_gate_deg,
                                                                              pose_gate_mm)):
            e["verdict"] = "verified by its loop"
            e["reason"] = (f"the geometry leaves the yaw free (stiffness ratio {yr:.2f}), but the loop closed by "
                           f"{lp['edge'][0]}->{lp['edge'][1]} ({lp['n_edges']} edges, this one the only free one) "
                           f"closes to {lp['closure_deg']:.2f} deg / {lp.get('closure_object_mm', lp['closure_mm']):.1f} "
                           "mm at the object: a wrong yaw here would show there, so it holds within the pose gate")
        elif free_e:
            e["verdict"] = "yaw free"
            e["reason"] = (f"the overlap is nearly a surface of revolution: its stiffness about the vertical is {yr:.2f} "
                           f"of the tilts' (< {yaw_free_ratio}); the rotation between these views is not determined "
                           "by the geometry" + (" nor by the IR amplitude (no pattern decides it)" if iy else ""))
            yaw_free.append(f"{e['source']}->{e['target']}")
        elif k in br:
            e["verdict"], e["reason"] = "unverified", "no loop of the view graph goes through this edge"
        else:
            e["verdict"], e["reason"] = "verified", "on a closed loop of the view graph"
    if yaw_free:
        graph.append(f"edge(s) {', '.join(yaw_free)}: the views overlap on a nearly rotation-symmetric part only; their "
                       "rotation about the vertical is not determined by the geometry (add views that see a distinctive "
                       "feature, or texture/markers)")
        reasons.append(graph[-1])
    if stepped:
        msg = (f"edge(s) {', '.join(stepped)}: no registration passed the gates; the declared turntable step links the "
               f"views, as accurately as the turntable turns (+/- {turntable_accuracy_deg:g} deg")
        if turntable_accuracy_deg is None or turntable_accuracy_deg > pose_gate_deg:
            reasons.append(msg + f", beyond the pose gate of {pose_gate_deg:g} deg)")
        else:
            warnings.append(msg + ")")
    # views
    views = {}
    on_loop = {v for k, (a, b) in enumerate(pairs) if k not in br for v in (a, b)}
    for k, nm in enumerate(names):
        if k in on_loop:
            views[nm] = {"verdict": "verified", "reason": "on a closed loop of the view graph"}
        else:
            views[nm] = {"verdict": "unverified", "reason": "linked to the others by unverified edges only"}
    for nm, why in left_out.items():
        views[nm] = {"verdict": "left out", "reason": why}
    unver = [nm for nm, v in views.items() if v["verdict"] == "unverified"]
    n_all = len(names) + len(left_out)
    if left_out and len(left_out) > max_left_out * n_all:
        reasons.append(f"{len(left_out)} of {n_all} views left out of the model (no registration links them to the "
                       f"others; more than {100 * max_left_out:.0f} %): the registration failed for most of the scan "
                       "(too little overlap between successive views, or a shape the views cannot be matched on)")
    elif left_out:
        warnings.append(f"view(s) {', '.join(left_out)} left out of the model (no registration links them to the "
                        "others): the model is incomplete there")
    if unver:
        warnings.append(f"view(s) {', '.join(unver)} are on no closed loop: their poses are not checked")
    # loops: what a spread closure leaves on the views
    b_deg = max((lp["closure_deg"] for lp in loops), default=0.0) / 2
    b_mm = max((lp.get("closure_object_mm", lp["closure_mm"]) for lp in loops), default=0.0) / 2
    sel = consistency.get("selection") or {}
    loop_msgs = list(consistency.get("loop_reasons") or [])
    if sel.get("spread") and (b_deg > pose_gate_deg or b_mm > pose_gate_mm):
        loop_msgs.append(f"the loops close only to {2 * b_deg:.2f} deg / {2 * b_mm:.1f} mm at the object; spread over "
                         f"their edges this leaves up to ~{b_deg:.2f} deg / {b_mm:.1f} mm on a view (limit "
                         f"{pose_gate_deg:g} deg / {pose_gate_mm:g} mm): the views disagree (depth-calibration residual?)")
        graph.append(loop_msgs[-1])
        reasons.append(graph[-1])
    if turntable_placed and turntable_accuracy_deg is not None and turntable_accuracy_deg <= pose_gate_deg:
        reasons = [r for r in reasons if r not in graph]
        warnings.extend("the declared turntable places the views (within its accuracy, +/- "
                        f"{turntable_accuracy_deg:g} deg), not the pairwise graph, which says: {r}" for r in graph)
    for li in sel.get("loop_implied") or []:
        warnings.append(f"edge {li['edge']} registered again from the pose its loop implies (closed by {li['implied_by']}): "
                        f"its points fit that pose better ({100 * li['fitness']:.0f} % matched against "
                        f"{100 * li['replaced_fitness']:.0f} % for the pairwise search's pose)")
    if sel.get("decided_by_ir"):
        warnings.append("the geometry alone left the registration ambiguous (the object looks alike from different "
                        f"sides: {sel['decided_by_ir']['n_tied']} choices closed every loop); the IR albedo pattern "
                        "decided between them")
    if sel.get("closing_pair_walks"):
        warnings.append(f"edge {sel['closing_pair_walks']} (the scan's last view and its first) is the only link between "
                        "two parts of the scan and no loop verifies it; with it the cameras walk once around the object "
                        "in scan order, so it is taken as the successive pair it is")
    if sel.get("decided_by_path"):
        d = sel["decided_by_path"]
        warnings.append("the pairwise hypotheses that scored best stepped the cameras back or leapt (at "
                        f"{', '.join(d['steps_before'])}); the choice that walks them around the object in scan order "
                        f"was taken ({d['fitness_given_up']:.3f} less summed fitness)")
    if adjustment is not None and "failed" in adjustment:
        reasons.append(f"the global adjustment failed ({adjustment['failed']}); the pose-graph poses are not refined")
    implausible = adjustment is not None and (adjustment.get("gain_note") or "").startswith("implausible")
    g_ask, g_max = ((adjustment or {}).get("gain_refused", np.nan), (adjustment or {}).get("gain_max_abs", np.nan))
    if implausible and np.isfinite(g_ask) and np.isfinite(g_max) and abs(g_ask) <= gain_alarm_factor * g_max:
        warnings.append(f"depth gain {adjustment['gain_note']}: up to {gain_alarm_factor:g} times what the calibration "
                        "predicts it can leave, within how far that prediction can be low; the poses are judged by "
                        "the views' loops")
    elif implausible:
        reasons.append(f"depth gain {adjustment['gain_note']}: the views disagree with the depth calibration by more "
                       "than it allows (wrong poses on a smooth or symmetric object, or a wrong calibration)")
    if adjustment is not None and (adjustment.get("gain_note") or "").startswith("not observable"):
        warnings.append(f"depth gain {adjustment['gain_note']}")
    _judge_move(adjustment or {}, names, pose_gate_deg, pose_gate_mm, reasons, warnings,
                "the declared turntable" if turntable_placed else "the pairwise registrations",
                max(pose_gate_deg, 2.0 * turntable_accuracy_deg) if turntable_placed and turntable_accuracy_deg else
                pose_gate_deg, restart_share)
    amb = sel.get("ambiguous_reason")
    tied = (adjustment or {}).get("tied") or []
    if (amb in reasons and len(tied) == len(sel.get("ambiguous_with") or [])
            and all(came_back(t, pose_gate_deg, pose_gate_mm, TIED_SHARE) for t in tied)):
        reasons.remove(amb)
        far = max(tied, key=lambda t: (t["deg"] / pose_gate_deg, t["mm"] / pose_gate_mm))
        warnings.append(f"{amb}; but the joint fit of all views, started from each of them, ends within "
                        f"{far['deg']:.2f} deg / {far['mm']:.1f} mm of its solution (limit {TIED_SHARE * pose_gate_deg:g} "
                        f"deg / {TIED_SHARE * pose_gate_mm:g} mm): the points of all views decide")
    moves = _move_judged(adjustment)[0] if (adjustment or {}).get("moved_deg") else {}
    loop_msgs = [r for r in loop_msgs if r in reasons]
    if loop_msgs and settles_loops(consistency, (adjustment or {}).get("restart"), max(moves.values(), default=0.0),
                                   pose_gate_deg, pose_gate_mm, restart_share):
        reasons = [r for r in reasons if r not in loop_msgs]
        warnings.extend("the joint fit of all views places them (its restart came back, and it moved no view beyond "
                        "the pose gate), not the pairwise loops, which say: " + r for r in loop_msgs)
    warns = (calibration_prediction or {}).get("warnings") or []
    pc = calibration_central_mm(calibration_prediction)
    local = (calibration_prediction or {}).get("local") or {}
    where = (f" where the object lies ({local['span_mm'][0]:.0f}-{local['span_mm'][1]:.0f} mm, stations "
             + ", ".join(f"{c:.0f}" for c in local["stations_mm"]) + " mm)") if local else ""
    if pc is not None and pc > max_calibration_mm:  # a prediction, not evidence: the views' own checks judge the poses
        warnings.append(f"the depth calibration predicts its own error between stations{where} at {pc:.1f} mm (above "
                        f"{max_calibration_mm:g} mm): the views' depths can disagree by that much and the poses absorb "
                        "it; the poses are judged by the views' own loops and the joint fit's restart; recalibrate with "
                        "stations closer together (its warning: " + ("; ".join(warns) or "none") + ")")
    elif warns:  # a doubt about the prediction, not evidence of wrong poses: the views' own loops judge those
        warnings.append("the depth calibration warns that its prediction cannot be trusted"
                        + (f" (its predicted central error, {pc:.1f} mm, may be too low)" if pc is not None else "")
                        + ": " + "; ".join(warns) + "; the predicted scale uncertainty may be too low, the poses "
                        "are judged by the views' own loops")
    if calibration_prediction is None:
        warnings.append("raw depth (no depth calibration): the model's scale and shape carry the sensor's range error")
    return {"reliable": not reasons, "reasons": reasons, "warnings": warnings, "views": views,
            "loop_pose_bound": {"deg": round(b_deg, 4), "mm": round(b_mm, 3)}, "yaw_free_edges": yaw_free}


def _judge_move(adjustment: dict, names: list[str], pose_gate_deg: float, pose_gate_mm: float, reasons: list[str],
                warnings: list[str], placed_by: str = "the pairwise registrations", move_gate_deg: float | None = None,
                share: float = 1.0) -> None:
    """The joint fit's move from where ``placed_by`` put the views (the pose graph, or a declared
    turntable), and its restart from the far side
    (:mod:`tofmetry.reconstruct._adjust_restart`) when there is one.

    * A restart that ends more than ``share`` of the pose gate from the solution is a reason, whatever
      the move: the points do not pin the joint fit down (it slides along a direction they leave free,
      or sits in a wrong basin); one that ends between half the gate and that is a warning. ``share``
      was 0.5 until 2026-11-29: over the 144 family runs of draws 30-36, the restarts and pair walks
      that ended between half and the whole gate were on 12 right runs and 3 truly wrong ones, each
      of which another reason flagged as well. A flag now needs a check that shows the poses spread
      by more than the gate itself. On the held-out draw 37 that cleared two right runs and let one
      wrong run through (a fandisk 0.47 deg / 3.2 mm off, its restart 0.34 deg / 1.4 mm away).
    * A move beyond ``pose_gate_deg`` is a reason even when the restart came back: the restart shows
      that the points determine the joint fit locally, not that they are consistent with the truth.
      Measured on the family (2026-11-27): clearing such moves freed seven right runs (domes, a box, a
      rocker arm, bunnies, a fandisk: the pose graph had been off) but let three wrong runs through: an
      igea 0.58 deg off and two plaques, 1.11 deg / 4.1 mm and 0.38 deg / 4.2 mm off, whose registration
      thins the slab consistently in every pair (a stable wrong solution: restarts came back to 0.25 and
      0.03 deg). The reason then says that the
      fit is determined, so that the disagreement lies between the pairs and the joint fit.
    * Such a move is cleared (a warning) when the moved view's pairs, registered again from the
      joint fit (:func:`~tofmetry.reconstruct._adjust_restart.pair_walks`), stay within ``share`` of
      the pose gate of it: then the pairs' own data accept the joint fit and the pose graph had been off.
      Measured on six such runs of the family (2026-11-28): the plaque 0.33 deg / 3.1 mm off walked
      0.94 and 1.26 deg back (kept flagged); of five right runs one pebble stayed (0.10, 0.15 deg,
      cleared), the others walked 0.38-0.69 deg (kept flagged: the pairs prefer their own poses).
    * A failed restart is a reason when the move is beyond the gate, a warning below it.
    * From a declared turntable's poses the joint fit is expected to move the views by up to about
      the turntable's accuracy: the move is then judged against ``move_gate_deg`` (twice that
      accuracy, at least the pose gate); the restart still against the pose gate.
    """
    moved = adjustment.get("moved_deg") or {}
    if not moved:
        return
    rs = adjustment.get("restart")
    judged, held = _move_judged(adjustment)
    worst = max(judged, key=judged.get)
    gate = pose_gate_deg if move_gate_deg is None else move_gate_deg
    beyond = judged[worst] > gate
    tilt_part = "" if not held else (
        f" ({judged[worst]:.2f} deg of it about the vertical; the rest, its tilt, is what the views' support planes "
        f"asked for, within {held['spread_deg']:.2f} deg of one plane at the end)")
    move = f"the global adjustment moved view {worst} by {moved[worst]:.2f} deg{tilt_part} from where {placed_by} put it"
    if held and not beyond and max(moved.values()) > gate:
        w = max(moved, key=moved.get)
        warnings.append(f"the global adjustment moved view {w} by {moved[w]:.2f} deg from where {placed_by} put it, "
                        f"{judged[w]:.2f} deg of it about the vertical: the rest tilted the views onto one support "
                        f"plane (within {held['spread_deg']:.2f} deg at the end): the pose graph's tilts had been off")
    if rs and came_back(rs, pose_gate_deg, pose_gate_mm, share) and not came_back(rs, pose_gate_deg, pose_gate_mm, 0.5):
        warnings.append(f"restarted {rs['start_deg']:.2f} deg away on the far side, the joint fit ended {rs['deg']:.2f} "
                        f"deg / {rs['mm']:.1f} mm at the object from its solution, within the pose gate but beyond half "
                        "of it: the points determine the poses only to about that (on draw 37 of the family one such "
                        "run was 0.47 deg / 3.2 mm off)")
    if rs and "failed" in rs:
        (reasons if beyond else warnings).append(f"{move}, and its restart from the far side failed ({rs['failed']}): "
                                                 "the joint fit is not checked")
    elif rs and not came_back(rs, pose_gate_deg, pose_gate_mm, share):
        v = names[rs["view"]] if 0 <= rs["view"] < len(names) else rs["view"]
        reasons.append(f"{move}; restarted {rs['start_deg']:.2f} deg away on the far side, it ended {rs['deg']:.2f} deg "
                       f"/ {rs['mm']:.1f} mm at the object from its solution (view {v}; limit {share * pose_gate_deg:g} deg "
                       f"/ {share * pose_gate_mm:g} mm): the points do not pin the joint fit down (they leave a direction "
                       "free and the fit slides along it, a smooth or symmetric object, or the views sit in a wrong "
                       "basin); add views that see a distinctive feature, or texture")
    elif beyond and rs:
        back = (f"{move} (limit {gate:g} deg); restarted {rs['start_deg']:.2f} deg away on the far side, "
                f"the joint fit came back to within {rs['deg']:.2f} deg / {rs['mm']:.1f} mm: the points determine it")
        walks = rs.get("pairs") or []
        worst = max(walks, key=lambda w: (w["deg"] / pose_gate_deg, w["mm"] / pose_gate_mm), default=None)
        if worst is not None and all(came_back(w, pose_gate_deg, pose_gate_mm, share) for w in walks):
            warnings.append(f"{back}; the registrations of its {len(walks)} pair(s), started again at the joint fit, "
                            f"stay there (at most {worst['deg']:.2f} deg / {worst['mm']:.1f} mm away; limit "
                            f"{share * pose_gate_deg:g} deg / {share * pose_gate_mm:g} mm): the pose graph had been off")
        else:
            pw = "" if worst is None else (
                f"; started again at the joint fit, the registration of pair {names[worst['source']]}->"
                f"{names[worst['target']]} walks {worst['deg']:.2f} deg / {worst['mm']:.1f} mm away (limit "
                f"{share * pose_gate_deg:g} deg / {share * pose_gate_mm:g} mm)")
            reasons.append(f"{back}{pw}, so the pairwise registrations and the joint fit of all views disagree, and a "
                           "consistent bias can hold both off (a thin object whose faces meet only at its rim)")
    elif beyond:
        reasons.append(f"{move} (limit {gate:g} deg): the pairs and the joint fit of all views "
                       "disagree by more than the poses must hold, so one of them is off (a smooth or symmetric "
                       "object sliding, or a depth-calibration residual)")


def _move_judged(adjustment: dict) -> tuple[dict, dict | None]:
    """The views' moves the verdict judges: their whole rotation, or, where the support planes held
    the views (:mod:`~tofmetry.reconstruct._adjust_support`) and end on one plane (every view's within
    twice the term's allowance, none off the plane), only the part about the vertical, the tilt part
    being measured by the planes themselves. Returns ``(moves by view name [deg], the planes' end
    state or None)``."""
    moved = adjustment.get("moved_deg") or {}
    turn = adjustment.get("moved_turn_deg")
    sp = adjustment.get("support_plane") or {}
    end = sp.get("end") or {}
    if (turn and sp.get("used") and not end.get("off_plane") and end.get("n_views", 0) == len(moved)
            and end.get("spread_deg", np.inf) <= 2 * sp.get("sigma_deg", 0.0)):
        return turn, end
    return moved, None


def _loop_pinning_yaw(edge: dict, loops: list[dict], free: set, pose_gate_deg: float,
                      pose_gate_mm: float) -> dict | None:
    """A loop through ``edge`` in which it is the only yaw-free edge and whose closure, halved as
    the pose graph spreads it, stays within the pose gate (rotation, and displacement at the object):
    the loop then determines the yaw the geometry of the pair leaves free. None when there is none."""
    key = frozenset((edge["source"], edge["target"]))
    for lp in loops:
        members = {frozenset(m) for m in lp.get("members") or []}
        if key not in members or len(members & free) != 1:
            continue
        if (lp["closure_deg"] / 2 <= pose_gate_deg
                and lp.get("closure_object_mm", lp["closure_mm"]) / 2 <= pose_gate_mm):
            return lp
    return None


def scale_report(adjustment: dict | None, calibration_prediction: dict | None, z_ref_mm: float,
                 budget=None, k_sigma_mm: float | None = None, floor_pct: float = 0.0) -> dict:
    """The model's predicted scale and surface-offset uncertainty from the depth chain.

    A range offset ``e`` left by the calibration moves every point along its ray: the surfaces
    move by ``e`` toward their cameras (a normal offset of the model, which makes an object seen
    from all round ``2 e`` thinner or thicker) and the lateral size scales by ``e / z``. A gain ``g``
    left over the object's depth stretches each view along its line of sight; fused from all round
    it scales the model by about ``g / 2``. So ``sigma_scale = sqrt((e / z)^2 + (sigma_g / 2)^2)``
    with ``e`` the calibration's predicted central error (quadratic mean over its blocked folds)
    and ``sigma_g`` the self-calibrated gain's standard error when it was estimated, otherwise
    the gain a calibration with that error can leave between stations, ``e / (spacing / 2)``.
    Not included: the lens calibration's focal error (it scales the lateral size as well).

    A self-calibrated gain trades with the amplitude-bias coefficient ``k`` (both act through the
    depth of points seen at different incidences): with ``k_sigma_mm`` [mm per ln unit], its
    uncertainty, and the gain's regression on ``dk`` from the adjustment
    (``amplitude_bias.gain_per_mm_per_ln``), ``sigma_g`` gains ``|slope| k_sigma_mm`` in quadrature.

    ``budget``: optional callable ``(offset_sigma_m, gain_sigma) -> dict`` of
    :func:`~tofmetry.reconstruct._scale_budget.scale_budget`: the same errors, and the amplitude
    bias's uncertainty, propagated on the model's own geometry (poses held). The prediction is
    the larger of the two (``rule_scale_sigma_pct``, ``budget_scale_sigma_pct``): the budget sees
    which surfaces face the cameras, which on elongated or flat parts makes the scale far more
    sensitive than the rule says; the rule's ``g / 2`` stands for the views re-registering, which
    the budget does not model. Neither counts the registration's own errors or the fusion's. On
    2026-11-25's family (README), before the gain inherited ``k``'s uncertainty both undershot
    the measured scale error (1.55 sigma at the median); with it the measured error was 0.41 sigma
    at the median, 5 of 5 reliable runs within 1.645 sigma.

    Where the gain was not estimated but the joint fit estimated its range curve
    (``adjustment.range_curve``), the curve's RMS over the object's depths (:func:`curve_residual_mm`)
    is the views' own measure of the range error the calibration left there; when it exceeds ``e``,
    the gain a calibration can leave is taken from it instead (``curve_residual_mm``). Measured on the
    35 reliable runs of family draws 30-34 with a scale: two ended 2.7 and 2.8 sigma off (an igea
    -0.60 % against 0.21 %, its curve 1.43 mm RMS where the calibration predicted 0.36 mm); recomputed
    with the curve, 1 run beyond 2 sigma, |error| / sigma p68 0.31 (0.40 before), p90 0.78 (1.32).

    ``floor_pct`` [%], the modelling chain's own scale error (registration, fusion, meshing; a
    configured figure, :attr:`RegistrationConfig.scale_floor_pct`), is added in quadrature to the
    prediction (``chain_floor_pct``).

    Returns
    -------
    dict: depth_gain, gain_estimated, gain_sigma, predicted_scale_sigma_pct,
    predicted_offset_sigma_mm, station_spacing_mm, source
    """
    adj = adjustment or {}
    g = float(adj.get("depth_gain", 0.0) or 0.0)
    est = bool(adj.get("gain_estimated", False))
    out = {"depth_gain": g, "gain_estimated": est, "gain_note": adj.get("gain_note"), "z_ref_mm": float(z_ref_mm)}
    if calibration_prediction is None:
        return out | {"predicted_scale_sigma_pct": None, "predicted_offset_sigma_mm": None,
                      "source": "raw depth: no calibration, no prediction"}
    e = calibration_central_mm(calibration_prediction)
    spacing = station_spacing_mm(calibration_prediction)
    if e is None:
        return out | {"predicted_scale_sigma_pct": None, "predicted_offset_sigma_mm": None,
                      "source": "the calibration carries no predicted error"}
    e_gain, e_curve = e, curve_residual_mm(adj)
    if not est and e_curve is not None and e_curve > e:  # the views show more residual than predicted
        e_gain = e_curve
        out["curve_residual_mm"] = e_curve
    sg = float(adj.get("gain_sigma_data", np.nan)) if est else e_gain / (spacing / 2)
    slope = (adj.get("amplitude_bias") or {}).get("gain_per_mm_per_ln")
    sg_k = abs(float(slope)) * k_sigma_mm if est and slope is not None and k_sigma_mm is not None else 0.0
    if sg_k > 0:
        out["gain_sigma_from_k"] = sg_k
        sg = float(np.hypot(sg, sg_k))
    s = float(np.hypot(e / z_ref_mm, sg / 2))
    src = "calibration's predicted central error" + (" and the self-calibrated gain's standard error"
                                                     if est else " (gain not estimated)")
    if e_gain > e:
        src += (f"; the gain it can leave taken from the joint fit's range curve, {e_gain:.2f} mm RMS over the "
                f"object's depths (more than the calibration's predicted {e:.2f} mm)")
    if sg_k > 0:
        src += f" (with k known to +-{k_sigma_mm:.2f} mm per ln unit)"
    out |= {"gain_sigma": sg, "predicted_scale_sigma_pct": 100 * s, "rule_scale_sigma_pct": 100 * s,
            "predicted_offset_sigma_mm": float(e), "station_spacing_mm": spacing, "source": src}
    b = budget(e * 1e-3, sg) if budget is not None and np.isfinite(sg) else None
    if b is not None:
        out["budget"] = b
        out["budget_scale_sigma_pct"] = 100 * float(b["sigma"]) if np.isfinite(b.get("sigma", np.nan)) else None
        if out["budget_scale_sigma_pct"] is not None and out["budget_scale_sigma_pct"] > 100 * s:
            out["predicted_scale_sigma_pct"] = out["budget_scale_sigma_pct"]
            out["source"] = src + ", propagated on the model's geometry" + (
                "" if "amplitude" not in b else " with the amplitude bias's uncertainty") + (
                "" if "sigma_poses_held" not in b else ", and the poses' own uncertainty")
    if floor_pct > 0:
        out["chain_floor_pct"] = float(floor_pct)
        out["predicted_scale_sigma_pct"] = float(np.hypot(out["predicted_scale_sigma_pct"], floor_pct))
        out["source"] += f"; the modelling chain's own {floor_pct:g} % in quadrature"
    return out


def curve_residual_mm(adjustment: dict | None) -> float | None:
    """RMS [mm] of the joint fit's estimated range curve at its five reported depths
    (``adjustment.range_curve.dz_mm``, zero at ``z_ref``): the range error the views show the
    calibration left over the object's depths; None when the curve was not estimated."""
    rc = (adjustment or {}).get("range_curve") or {}
    dz = rc.get("dz_mm")
    if not rc.get("estimated") or not dz:
        return None
    return float(np.sqrt(np.mean(np.square(np.asarray(dz, float)))))
