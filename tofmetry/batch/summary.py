"""The batch summary: ``OUT/summary.json`` and ``OUT/summary.html``.

One row per job (status, time, key figures, link to its report, the error of a failed job), and,
for the jobs that name a ``sensor``, the sensors side by side: warm-up drift, range error after
correction (validation), and the error the depth calibration predicted for itself.
"""

from __future__ import annotations

import html
import os
import time
from pathlib import Path

from tofmetry.io import atomic_write_bytes, atomic_write_json

#: fleet columns: (title, kind of job, figure, unit)
FLEET_COLUMNS = [
    ("warm-up drift", "assess", "total_drift_mm", "mm"),
    ("stabilisation", "assess", "stabilisation_time_s", "s"),
    ("range error after correction (max |central|)", "validate", "max_abs_dev_after_mm", "mm"),
    ("per-pixel RMS measured", "validate", "measured_rms_mm", "mm"),
    ("predicted per-pixel RMS", "calibrate-depth", "predicted_rms_mm", "mm"),
    ("predicted |central|", "calibrate-depth", "predicted_central_abs_mm", "mm"),
]


def fleet_table(records: list[dict]) -> list[dict]:
    """Per sensor (jobs with a ``sensor``), the figures of :data:`FLEET_COLUMNS` (None when absent)."""
    sensors: dict[str, dict] = {}
    for r in records:
        s = r.get("sensor")
        if not s:
            continue
        row = sensors.setdefault(s, {"sensor": s, **{c[2]: None for c in FLEET_COLUMNS}, "jobs": [], "failed": []})
        row["jobs"].append(r["name"])
        if r["status"] == "failed":
            row["failed"].append(r["name"])
        for _, kind, key, _ in FLEET_COLUMNS:
            v = (r.get("figures") or {}).get(key)
            if r["kind"] == kind and v is not None:
                row[key] = v
    return [sensors[k] for k in sorted(sensors)]


def _fmt(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
    return str(v)


def _job_rows(records: list[dict]) -> str:
    rows = []
    for r in records:
        st = r["status"]
        figs = ", ".join(f"{k} {_fmt(v)}" for k, v in (r.get("figures") or {}).items())
        if st == "failed":
            figs = f"<b>{html.escape(r.get('error_type', 'error'))}</b>: {html.escape(r.get('error', ''))}"
        else:
            figs = html.escape(figs)
        link = f'<a href="{html.escape(r["report"])}">{html.escape(r["report"])}</a>' if r.get("report") else ""
        secs = r.get("skipped_seconds") if st == "skipped" else r.get("seconds")
        rows.append(f'<tr class="{st}"><td>{html.escape(r["name"])}</td><td>{html.escape(r["kind"])}</td>'
                    f'<td>{html.escape(r.get("sensor") or "")}</td><td>{st}</td><td>{_fmt(secs)}</td>'
                    f"<td>{figs}</td><td>{link}</td></tr>")
    return "\n".join(rows)


def _fleet_rows(fleet: list[dict]) -> str:
    rows = []
    for f in fleet:
        cells = "".join(f"<td>{_fmt(f[key])}</td>" for _, _, key, _ in FLEET_COLUMNS)
        bad = html.escape(", ".join(f["failed"])) or ""
        rows.append(f"<tr><td>{html.escape(f['sensor'])}</td>{cells}<td>{bad}</td></tr>")
    return "\n".join(rows)


def render_summary_html(doc: dict) -> str:
    """The summary as a self-contained HTML page (no scripts)."""
    c = doc["counts"]
    head = "".join(f"<th>{html.escape(t)} [{u}]</th>" for t, _, _, u in FLEET_COLUMNS)
    fleet = (f"<h2>Sensors side by side</h2><table><tr><th>sensor</th>{head}<th>failed jobs</th></tr>"
             f"{_fleet_rows(doc['fleet'])}</table>") if doc["fleet"] else ""
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>tofmetry batch summary</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse;margin-bottom:2em}}
td,th{{border:1px solid #ccc;padding:4px 8px;text-align:left;vertical-align:top}}
tr.failed td{{background:#fde2e2}}tr.skipped td{{color:#666}}</style></head><body>
<h1>tofmetry batch</h1>
<p>{len(doc['jobs'])} jobs: {c['ok']} done, {c['skipped']} skipped (complete, inputs unchanged), {c['failed']} failed;
{_fmt(doc['seconds'])} s on {doc['workers']} worker(s); manifest {html.escape(doc['manifest'])}; {doc['finished_utc']}</p>
{fleet}
<h2>Jobs</h2>
<table><tr><th>job</th><th>kind</th><th>sensor</th><th>status</th><th>time [s]</th><th>key figures / error</th>
<th>report</th></tr>
{_job_rows(doc['jobs'])}
</table></body></html>
"""


def write_summary(out: str | os.PathLike, records: list[dict], *, seconds: float, workers: int,
                  manifest: str) -> tuple[Path, Path]:
    """Write ``summary.json`` and ``summary.html`` into ``out`` (atomically); returns their paths."""
    out = Path(out)
    jobs = [{k: v for k, v in r.items() if k not in ("input_hashes", "settings")} for r in records]
    doc = {"manifest": manifest, "seconds": seconds, "workers": workers,
           "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
           "counts": {s: sum(r["status"] == s for r in records) for s in ("ok", "skipped", "failed")},
           "jobs": jobs, "fleet": fleet_table(records)}
    return (atomic_write_json(out / "summary.json", doc),
            atomic_write_bytes(out / "summary.html", render_summary_html(doc).encode()))
