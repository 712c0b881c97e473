"""``evaluate --plan``: the plan's prediction for the views as taken beside the completeness achieved."""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError
from tofmetry.evaluate import CameraViews
from tofmetry.pipelines.plan_check import plan_check
from tofmetry.plan import proxy_from_size, reconstructed_share, ring, seen_cosines, surface_samples
from tofmetry.sensor import KINECT_V2


def _rigid(rx_deg: float, shift) -> np.ndarray:
    a = np.radians(rx_deg)
    T = np.eye(4)
    T[1:3, 1:3] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = shift
    return T


def test_plan_check_counts_what_the_views_saw_in_any_frame():
    """A box seen from a ring at 30 deg; the 'model' holds exactly the surface samples some view
    sees within 70 deg. The reference lies in another frame (turned 90 deg about x, shifted), the
    cameras and the support plane in the model's ground frame. The achieved completeness must be
    the share of those samples (up to the samples of the seen area's border that fall within 5 mm
    of a seen one: less than 3 points), the prediction the plan's own for those views, and the
    plan's figure for the views it asked for is carried along."""
    box = proxy_from_size(0.3, 0.2, 0.15)
    views = ring(6, 1.0, 30.0, box.centre_m)
    C = seen_cosines(box, views, KINECT_V2.depth)
    pts, _ = surface_samples(box)
    with np.errstate(invalid="ignore"):
        sure = (C >= np.cos(np.radians(70.0))).any(0)
    A = _rigid(90.0, [0.4, -0.2, 1.1])  # model (ground) frame -> reference frame
    ref = (box.vertices @ A[:3, :3].T + A[:3, 3], box.triangles)
    model_pts = pts[sure] @ A[:3, :3].T + A[:3, 3]
    cams = CameraViews(np.stack(views), KINECT_V2.depth, 500.0, 2500.0, support_plane=np.array([0.0, 0.0, 1.0, 0.0]))
    doc = {"proposal": {"name": "ring 6 @ 30 deg", "prediction": {"n_views": 6, "completeness": 0.9,
                                                                   "completeness_range": [0.88, 0.93]}}}
    out = plan_check(doc, ref, model_pts, cams, A)
    assert sure.mean() <= out["achieved"] < sure.mean() + 0.03
    np.testing.assert_allclose(out["views_taken"]["predicted"], reconstructed_share(C).mean(), atol=1e-4)
    assert out["views_taken"]["elevation_deg"][0] > 29.0 and out["views_taken"]["elevation_deg"][1] < 31.0
    assert out["planned"]["completeness"] == 0.9 and out["planned"]["which"] == "proposal"
    assert abs(out["error_pts"] - 100 * (out["views_taken"]["predicted"] - out["achieved"])) < 0.01


def test_cli_evaluate_with_a_plan(tmp_path):
    """``tofmetry evaluate --poses --plan``: prints the plan's line and writes plan_check.json;
    without ``--poses`` it stops with an input error that says what is missing, before any work."""
    import json

    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io.ply import write_ply

    box = proxy_from_size(0.3, 0.2, 0.15)
    views = ring(6, 1.0, 30.0, box.centre_m)
    pts, _ = surface_samples(box)
    write_ply(tmp_path / "ref.ply", box.vertices, faces=box.triangles)
    write_ply(tmp_path / "model.ply", pts)
    (tmp_path / "poses.json").write_text(json.dumps({
        "views": [{"name": f"{k:02d}", "camera_to_world": T.tolist()} for k, T in enumerate(views)],
        "intrinsics": KINECT_V2.depth.to_dict(), "working_range_mm": [500.0, 2500.0],
        "support_plane_world": [0.0, 0.0, 1.0, 0.0]}))
    (tmp_path / "plan.json").write_text(json.dumps({"proposal": {"name": "ring 6 @ 30 deg", "prediction": {
        "n_views": 6, "completeness": 0.9, "completeness_range": [0.88, 0.93]}}}))
    args = ["evaluate", str(tmp_path / "model.ply"), "--reference", str(tmp_path / "ref.ply"), "--no-icp",
            "--plan", str(tmp_path / "plan.json")]
    r = CliRunner().invoke(app, args + ["-o", str(tmp_path / "ev"), "--poses", str(tmp_path / "poses.json")])
    assert r.exit_code == 0, r.output
    check = json.loads((tmp_path / "ev" / "plan_check.json").read_text())
    assert check["achieved"] > 0.99 and "plan: predicted" in r.output  # the model is the whole surface
    r = CliRunner().invoke(app, args + ["-o", str(tmp_path / "ev2")])
    assert isinstance(r.exception, InputError) and "--poses" in str(r.exception)
    assert not (tmp_path / "ev2").exists()


def _turn(deg: float, shift) -> np.ndarray:
    a = np.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = shift
    return T


def _plan_doc(poses, extent):
    return {"object": {"source": "size", "extent_m": list(extent)},
            "proposal": {"name": f"ring {len(poses)}", "camera_to_world": [T.tolist() for T in poses],
                         "prediction": {"n_views": len(poses), "completeness": 0.95,
                                        "completeness_range": [0.93, 0.96]}}}


def test_plan_followed_sets_the_views_taken_beside_the_planned_ones():
    """No reference: a box 0.3 x 0.2 x 0.15 m planned with a ring of 12 at 30 deg. The model lies in
    its ground frame turned 37 deg about the vertical and 40 mm off the origin, as a reconstruction
    places it. Taken as planned (the ring carried into that frame), the prediction on the plan's
    size is the plan's own to 0.5 points; the box is found whichever way it is turned (its longer
    side along x or, when the plan's depth is the longer, along y). Half the ring (6 views over
    150 deg) leaves a 210 deg gap and is predicted well short."""
    from tofmetry.pipelines.plan_check import plan_followed

    box = proxy_from_size(0.3, 0.2, 0.15)
    planned = ring(12, 1.0, 30.0, box.centre_m)
    M = _turn(37.0, [0.04, -0.03, 0.0])  # plan frame -> the model's ground frame
    pts, _ = surface_samples(box)
    model = pts @ M[:3, :3].T + M[:3, 3]
    taken = [M @ T for T in planned]
    out = plan_followed(_plan_doc(planned, (0.3, 0.2, 0.15)), model, taken, KINECT_V2.depth)
    assert abs(out["short_pts"]) < 0.5, out["summary"]
    assert out["taken"]["layout"]["n_views"] == 12 and abs(out["taken"]["layout"]["azimuth_gap_deg"] - 30.0) < 0.5
    assert abs(out["taken"]["layout"]["elevation_deg"][0] - 30.0) < 0.5
    assert out["planned"]["completeness"] == 0.95 and "as the plan or better" in out["summary"]
    # the same box planned with its longer side as its depth (along y): the ring turned with it
    out2 = plan_followed(_plan_doc([_turn(90.0, [0, 0, 0]) @ T for T in planned], (0.2, 0.3, 0.15)),
                         model, taken, KINECT_V2.depth)
    assert abs(out2["short_pts"]) < 0.5, out2["summary"]
    half = plan_followed(_plan_doc(planned, (0.3, 0.2, 0.15)), model, taken[:6], KINECT_V2.depth)
    assert half["short_pts"] > 5.0 and abs(half["taken"]["layout"]["azimuth_gap_deg"] - 210.0) < 0.5
    assert "points short of the plan" in half["summary"]
    assert not out["turn_free_warned"] and "turn about the vertical" not in out["summary"]
    warned = {**_plan_doc(planned, (0.3, 0.2, 0.15)), "settings": {"turn_about_vertical": {"ratio": 0.01, "free": True}}}
    w = plan_followed(warned, model, taken, KINECT_V2.depth)  # the plan's warning is repeated after the scan
    assert w["turn_free_warned"] and "leaves the views' turn about the vertical free" in w["summary"]


def test_plan_followed_needs_a_size_and_views():
    from tofmetry.pipelines.plan_check import plan_followed

    box = proxy_from_size(0.3, 0.2, 0.15)
    views = ring(8, 1.0, 30.0, box.centre_m)
    pts, _ = surface_samples(box)
    doc = _plan_doc(views, (0.3, 0.2, 0.15))
    for broken, what in (({**doc, "object": {}}, "object size"), ({**doc, "proposal": {"name": "x"}}, "no views")):
        try:
            plan_followed(broken, pts, views, KINECT_V2.depth)
        except InputError as exc:
            assert what in str(exc)
        else:
            raise AssertionError(f"no error for {what}")
