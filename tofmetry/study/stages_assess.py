"""Study stages of section 3 (sensor assessment) and the sensor summary.

They call :mod:`tofmetry.assess` and write through :mod:`tofmetry.pipelines.assess` — the same
functions as ``tofmetry assess ...``.
"""

from __future__ import annotations

from pathlib import Path

from tofmetry.assess import assess_materials, assess_noise, assess_outdoor, assess_warmup, regions_from_dict
from tofmetry.io import Capture, read_json
from tofmetry.pipelines.assess import write_assessment
from tofmetry.sensor import get_profile
from tofmetry.study.stage import Skip, StageOutcome, StudyContext


def _fig_list(paths) -> list[tuple[str, Path]]:
    return [(Path(p).stem.replace("_", " "), Path(p)) for p in paths]


def _record(ctx: StudyContext, key: str, res, **kwargs) -> tuple[dict, list[tuple[str, Path]]]:
    """Write an assessment result's JSON and PNG figures into ``OUT/<key>/``; returns (dict, figures)."""
    files = write_assessment(res, ctx.stage_dir(key), "result.json", **kwargs)
    return res.to_dict(), _fig_list(p for p in files["figures"] if str(p).endswith(".png"))


# --------------------------------------------------------------------------- sensor
def stage_sensor(ctx: StudyContext, out: StageOutcome) -> None:
    """Sensor summary: identity, typical parameters, what data is present."""
    sensors = set()
    present = {}
    for name in ("warmup", "noise", "materials", "outdoor", "checkerboard", "wall", "wall-validation", "scan"):
        p = ctx.data_dir / name
        present[name] = p.exists()
        for cj in (p / "capture.json", p / "capture" / "capture.json"):
            if cj.is_file():
                sensors.add(Capture(cj.parent).sensor)
    sensor = sorted(sensors)[0] if len(sensors) == 1 else ("kinect_v2" if not sensors else ", ".join(sorted(sensors)))
    prof = get_profile("kinect_v2") if sensor not in ("",) else None
    i = prof.depth
    hfov, vfov = i.fov_deg()
    out.data = {"sensor": sensor, "simulated": ctx.simulated, "inputs_present": present,
                "profile": {"depth": i.to_dict(), "fov_deg": [hfov, vfov], "range_mm": [prof.min_range_mm, prof.max_range_mm],
                            "fps": prof.fps, "color": prof.color.to_dict()}}
    out.paragraphs.append(
        ("Data: the virtual Kinect v2 (physically grounded ToF simulator; every error term of the study "
         "switched on), processed exactly as a user's recordings." if ctx.simulated else
         f"Data: recordings in {ctx.data_dir}.")
    )
    out.tables.append(("Sensor (typical published values, study Table 1; not per-device)", ["quantity", "value"], [
        ["sensor", sensor],
        ["depth / IR resolution", f"{i.width} x {i.height} px"],
        ["colour resolution", f"{prof.color.width} x {prof.color.height} px"],
        ["field of view", f"{hfov:.1f} x {vfov:.1f} deg"],
        ["operative range", f"{prof.min_range_mm / 1000:.1f} - {prof.max_range_mm / 1000:.1f} m"],
        ["frame rate", f"{prof.fps:.0f} fps"],
    ]))
    out.tables.append(("Inputs found", ["folder", "present"], [[k, "yes" if v else "no"] for k, v in present.items()]))


# --------------------------------------------------------------------------- assessment
def stage_warmup(ctx: StudyContext, out: StageOutcome) -> None:
    cap = Capture(ctx.capture_dir("warmup", "a wall capture with timestamps_s"))
    a = ctx.config.assess
    res = assess_warmup(cap, patch=a.patch_px, tolerance_mm=a.warmup_tolerance_mm)
    d, out.figures = _record(ctx, "warmup", res)
    st = d["stabilisation_time_min"]
    out.data = {k: d[k] for k in ("stabilisation_time_min", "stabilisation_range_s", "total_drift_mm", "drift_range_mm",
                                  "residual_drift_mm", "final_level_mm", "n_frames", "duration_s", "patch", "notes",
                                  "temperature")}
    rng = [None if x is None else x / 60.0 for x in d["stabilisation_range_s"]]
    rng_txt = " – ".join("not reached" if x is None else f"{x:.1f}" for x in rng) + " min"
    out.tables.append(("Warm-up (study §3.2: ~5 mm over 30 min, then ~1 mm)", ["quantity", "value"], [
        ["frames / duration", f"{d['n_frames']} / {d['duration_s'] / 60:.0f} min"],
        ["patch (highest IR)", f"{d['patch']['size']}x{d['patch']['size']} at u={d['patch']['u0']}, v={d['patch']['v0']}"],
        ["stabilisation time", "not reached" if st is None else f"{st:.1f} min"],
        [f"… at {1.1 * a.warmup_tolerance_mm:.2g} / {0.9 * a.warmup_tolerance_mm:.2g} mm tolerance", rng_txt],
        ["total drift", f"{d['total_drift_mm']:+.2f} mm"],
        ["residual drift after stabilisation", f"{d['residual_drift_mm']:.2f} mm"],
        *_temperature_rows(d["temperature"]),
    ]))
    out.paragraphs += d["notes"]


def _temperature_rows(temp: dict | None) -> list[list[str]]:
    """Table rows of the drift against the recorded temperature (none when the recording holds no temperature)."""
    if not temp:
        return []
    rows = []
    if temp.get("range_c"):
        rows.append([f"{temp['name']} temperature", f"{temp['range_c'][0]:.1f} – {temp['range_c'][1]:.1f} °C"])
    f = temp.get("fit")
    if f:
        lo, hi = f["slope_ci95_mm_per_c"]
        rows.append(["drift per degree (s.e. for correlated frames; 95 % interval)",
                     f"{f['slope_mm_per_c']:+.3f} ± {f['slope_se_mm_per_c']:.3f} mm/°C ({lo:+.3f} … {hi:+.3f})"])
    return rows


def stage_noise(ctx: StudyContext, out: StageOutcome) -> None:
    cap = Capture(ctx.capture_dir("noise", "a static capture of >= 100 frames"))
    a = ctx.config.assess
    res = assess_noise(cap, subsets=a.noise_subsets, row=a.noise_row)
    d, out.figures = _record(ctx, "noise", res)
    out.data = {"n_frames": d["n_frames"], "summaries": d["summaries"], "recommended_n": d["recommended_n"],
                "recommendation_reason": d["recommendation_reason"], "block_precision": d["block_precision"],
                "sigma_single_mm": d["sigma_single_mm"]}
    out.tables.append(("Std maps per number of frames n (study §3.2, Fig. 3)",
                       ["n", "median std [mm]", "spread [mm]", "corner [mm]", "centre [mm]", "corner/centre"],
                       [[s["n"], s["median_mm"], s["spread_mm"], s["corner_mm"], s["centre_mm"], s["corner_centre_ratio"]]
                        for s in d["summaries"]]))
    if d["block_precision"]:
        out.tables.append(("What averaging buys: std of the n-frame mean across disjoint blocks",
                           ["n", "blocks", "std of mean [mm]", "sigma/sqrt(n) [mm]"],
                           [[b["n"], b["n_blocks"], b["std_of_mean_mm"], b["expected_mm"]] for b in d["block_precision"]]))
    out.paragraphs.append(f"Recommended number of frames: {d['recommended_n']} ({d['recommendation_reason']}).")


def _regions_for(capdir: Path):
    for cand in (capdir / "regions.json", capdir.parent / "regions.json"):
        if cand.is_file():
            return cand
    return None


def stage_materials(ctx: StudyContext, out: StageOutcome) -> None:
    found = False
    for name, label in (("materials", "grey-level board"), ("materials-samples", "material samples")):
        if not (ctx.data_dir / name).exists():
            continue
        found = True
        capdir = ctx.capture_dir(name, label)
        cap = Capture(capdir)
        rj = _regions_for(capdir)
        if rj is not None:
            regions = regions_from_dict(read_json(rj, "regions file"), cap.shape, source=str(rj))
            res = assess_materials(cap, regions)
        else:
            res = assess_materials(cap, auto_grey_board=True)
        d, figs = _record(ctx, name, res)
        out.figures += [(f"{label}: {c}", p) for c, p in figs]
        out.data[name] = {"fit": d["fit"], "erratic": d["erratic"],
                          "regions": [{k: r[k] for k in ("name", "amplitude", "bias_mm", "spatial_std_mm", "erratic")}
                                      for r in d["regions"]]}
        out.tables.append((f"{label} (study §3.3.1, Fig. 4: black ≈ +12 mm vs white, amplitude 2000 vs 12000)",
                           ["region", "IR amplitude", "bias vs white plane [mm]", "spatial std [mm]", "erratic"],
                           [[r["name"], r["amplitude"], r["bias_mm"], r["spatial_std_mm"], "yes" if r["erratic"] else ""]
                            for r in d["regions"]]))
        f = d["fit"]
        out.paragraphs.append(
            f"{label}: bias = {f['slope_mm_per_ln']:.2f} (± {f['slope_se_mm_per_ln']:.2f}) mm × ln(A_white/A); "
            f"a surface 6× darker than white reads {f['bias_at_amplitude_ratio_6_mm']:+.1f} mm long."
            + (f" Erratic (reflective) samples: {', '.join(d['erratic'])}." if d["erratic"] else ""))
    if not found:
        raise Skip(f"no materials/ folder in {ctx.data_dir} (a capture of a grey-level or material board); stage skipped")


def stage_outdoor(ctx: StudyContext, out: StageOutcome) -> None:
    cap = Capture(ctx.capture_dir("outdoor", "a capture in strong ambient light"))
    res = assess_outdoor(cap)
    intr, _ = cap.intrinsics(ctx.intrinsics)
    d, out.figures = _record(ctx, "outdoor", res, intrinsics=intr)
    out.data = {k: d[k] for k in ("n_frames", "n_max_points", "valid_points_mean", "valid_fraction",
                                  "flying_points_mean", "flying_share_of_cloud", "detector")}
    out.tables.append(("Strong light (study §3.3.2: ~35 000 of 217 088 points ≈ 20 % valid; ~2 % flying)",
                       ["quantity", "value"], [
                           ["valid points (mean)", f"{d['valid_points_mean']:.0f} of {d['n_max_points']}"],
                           ["valid fraction", f"{100 * d['valid_fraction']:.1f} %"],
                           ["flying pixels, share of cloud", f"{100 * d['flying_share_of_cloud']:.2f} %"],
                       ]))
