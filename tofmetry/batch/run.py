"""Run a manifest on Dask's distributed scheduler: a new LocalCluster, or an existing cluster.

Every job is one Dask task (chunked jobs submit their chunks from it), submitted with the
futures of the jobs whose outputs it reads, so Dask orders them. Placement, retries
(``retries=`` per task for unexpected errors; a task whose worker died is rescheduled by the
scheduler itself, up to ``distributed.scheduler.allowed-failures`` times) and load balancing are
Dask's. The client only collects one record per job, reports progress and writes the summary.
"""

from __future__ import annotations

import os
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from distributed import Client, LocalCluster, as_completed

from tofmetry.batch.chunk_jobs import is_chunked, run_chunked
from tofmetry.batch.jobs import failed, run_whole
from tofmetry.batch.manifest import JobSpec, load_manifest
from tofmetry.batch.summary import write_summary
from tofmetry.errors import InputError
from tofmetry.pipelines.paths import refuse_inside_inputs


@dataclass
class BatchRun:
    """Result of :func:`run_batch`.

    Attributes
    ----------
    records : one dict per job (``status`` ok / skipped / failed, ``seconds``, ``figures``, ``error``...)
    summary_json, summary_html : the summary files in the output folder
    dashboard : the Dask dashboard address ("" when the cluster has none)
    seconds : wall time of the batch [s]
    """

    records: list[dict]
    summary_json: Path
    summary_html: Path
    dashboard: str = ""
    seconds: float = 0.0
    workers: int = 0
    counts: dict = field(default_factory=dict)


@contextmanager
def batch_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Client]:
    """A client on the cluster at ``scheduler``, or on a new LocalCluster of ``workers`` processes
    with one thread each (a job that crashes its process takes no other job with it).

    Raises
    ------
    InputError
        ``workers`` below 1, or given together with ``scheduler`` (an existing cluster keeps its workers).
    """
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, found {workers}")
    if scheduler is not None:
        if workers is not None:
            raise InputError("--workers applies to the local cluster only; an existing cluster (--scheduler) keeps "
                             "its own workers")
        with Client(scheduler) as client:
            yield client
        return
    n = workers or max(1, (os.cpu_count() or 1))
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        yield client


def _order(jobs: list[JobSpec]) -> list[JobSpec]:
    """Jobs with every job after those it reads (manifest order otherwise); refuses a cycle."""
    by, done, out, busy = {j.name: j for j in jobs}, set(), [], set()

    def visit(j: JobSpec) -> None:
        if j.name in done:
            return
        if j.name in busy:
            raise InputError(f"manifest line {j.line}: job {j.name!r} reads its own output through a cycle of '@JOB' inputs")
        busy.add(j.name)
        for d in j.needs:
            visit(by[d])
        busy.discard(j.name)
        done.add(j.name)
        out.append(j)

    for j in jobs:
        visit(j)
    return out


def run_batch(manifest: str | os.PathLike, out: str | os.PathLike, *, scheduler: str | None = None,
              workers: int | None = None, client: Client | None = None,
              on_start: Callable[[str, int], None] | None = None,
              on_done: Callable[[dict], None] | None = None) -> BatchRun:
    """Run every job of ``manifest`` with outputs in ``out``; write ``out/summary.json`` and ``summary.html``.

    Parameters
    ----------
    manifest : TOML / YAML manifest (:mod:`tofmetry.batch.manifest`)
    out : output folder (created); job ``NAME`` writes ``out/NAME/``
    scheduler : address of a running Dask scheduler (e.g. ``tcp://host:8786``); None starts a LocalCluster
    workers : processes of the LocalCluster (default: one per core)
    client : an existing Client to use instead (``scheduler`` and ``workers`` are then ignored)
    on_start : called with the dashboard link and the number of jobs, once submitted
    on_done : called with each job's record as it finishes

    Returns
    -------
    BatchRun

    Raises
    ------
    InputError
        A bad manifest (naming the line), or an output folder inside an input.
    """
    import time

    t0 = time.perf_counter()
    out = Path(out).resolve()
    jobs = _order(load_manifest(manifest, out))
    for j in jobs:
        refuse_inside_inputs(out, *[p for p in j.inputs.values() if not Path(p).is_relative_to(out)])
    out.mkdir(parents=True, exist_ok=True)
    if client is not None:
        records, dash, n = _execute(client, jobs, out, on_start, on_done)
    else:
        with batch_client(scheduler, workers) as c:
            records, dash, n = _execute(c, jobs, out, on_start, on_done)
    seconds = time.perf_counter() - t0
    js, html = write_summary(out, records, seconds=seconds, workers=n, manifest=str(Path(manifest).resolve()))
    counts = {s: sum(r["status"] == s for r in records) for s in ("ok", "skipped", "failed")}
    return BatchRun(records, js, html, dash, seconds, n, counts)


def _execute(client: Client, jobs: list[JobSpec], out: Path, on_start, on_done) -> tuple[list[dict], str, int]:
    token = uuid.uuid4().hex[:8]
    futures, spec_of = {}, {}
    for j in jobs:
        spec = j.to_dict()
        deps = [futures[d] for d in j.needs]
        fn = run_chunked if is_chunked(spec) else run_whole
        args = (spec, str(out), token, *deps) if fn is run_chunked else (spec, str(out), *deps)
        f = client.submit(fn, *args, key=f"batch-{token}-{j.name}", retries=j.retries, pure=False)
        futures[j.name], spec_of[f.key] = f, spec
    dash = client.dashboard_link or ""
    n = len(client.scheduler_info(n_workers=-1).get("workers", {}))
    if on_start is not None:
        on_start(dash, len(jobs))
    records = {}
    for f in as_completed(list(futures.values())):
        spec = spec_of[f.key]
        try:
            rec = f.result()
        except Exception as exc:  # noqa: BLE001 - an unexpected error after Dask's retries: recorded, others go on
            rec = failed(spec, exc)
        records[spec["name"]] = rec
        if on_done is not None:
            on_done(rec)
    return [records[j.name] for j in jobs], dash, n
