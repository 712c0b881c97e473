"""``evaluate`` jobs in a batch: one glob, one job per model, the same figures as ``tofmetry evaluate``."""

from __future__ import annotations

import json

import numpy as np

from tofmetry.batch import batch_client, run_batch
from tofmetry.evaluate import EvaluationConfig
from tofmetry.io import write_ply
from tofmetry.pipelines.evaluate import evaluate_files
from tofmetry.simulate.objects import grid_mesh


def _sphere(radius_m: float, n_rings: int = 40, n_around: int = 80) -> tuple[np.ndarray, np.ndarray]:
    th = np.linspace(0.05, np.pi - 0.05, n_rings)[:, None]
    ph = np.linspace(0, 2 * np.pi, n_around, endpoint=False)[None, :]
    P = radius_m * np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th) * np.ones_like(ph)], -1)
    return grid_mesh(P + [0.0, 0.0, 0.2])


def test_evaluate_jobs_from_a_glob_match_the_command(tmp_path):
    ref_v, ref_f = _sphere(0.1)
    write_ply(tmp_path / "reference.ply", ref_v, faces=ref_f)
    # two "models": the reference's surface pushed out by 1 mm and by 2 mm (a known signed deviation)
    for k, off_m in ((1, 0.001), (2, 0.002)):
        v, f = _sphere(0.1 + off_m)
        write_ply(tmp_path / "models" / f"m{k}.ply", v, faces=f)
    (tmp_path / "batch.toml").write_text(
        '[[job]]\nkind = "evaluate"\nname = "eval"\n'
        'inputs = { model = "models/*.ply", reference = "reference.ply" }\n')
    out = tmp_path / "out"
    with batch_client(workers=2) as client:
        run = run_batch(tmp_path / "batch.toml", out, client=client)
    recs = {r["name"]: r for r in run.records}
    assert sorted(recs) == ["eval-m1.ply", "eval-m2.ply"], sorted(recs)   # the job name + the part the glob matched
    assert {r["status"] for r in recs.values()} == {"ok"}, {k: r.get("error") for k, r in recs.items()}
    doc = json.loads((out / "summary.json").read_text())
    assert doc["counts"]["ok"] == 2
    for k, off_mm in ((1, 1.0), (2, 2.0)):
        direct = evaluate_files(tmp_path / "models" / f"m{k}.ply", tmp_path / "reference.ply",
                                config=EvaluationConfig()).result.stats_trimmed
        got = json.loads((out / f"eval-m{k}.ply" / "metrics.json").read_text())["stats_trimmed"]
        # the batch job is the command: the same figures, up to the scatter of two runs of the same
        # evaluation. A sphere leaves the alignment's rotation free and Open3D's ICP is not
        # bit-reproducible (its threads' sums), so two runs settle at different turns and the facets of
        # the two meshes line up differently: by up to the chord sag of a 4.5-degree step on 100 mm,
        # 0.077 mm (measured: 1.0447-1.0478 mm over 6 runs of m1 alone; 0.999 vs 1.047 mm once in CI
        # under load, 2026-11-28)
        assert abs(got["mean_abs_mm"] - direct.mean_abs_mm) < 0.08, (got["mean_abs_mm"], direct.mean_abs_mm)
        # and the figures are the geometry's: a sphere 1 (2) mm larger deviates by about that much
        # (facets: the chord of a 4.5-degree ring step sags 0.08 mm below the sphere)
        assert abs(direct.mean_abs_mm - off_mm) < 0.15, direct.mean_abs_mm
