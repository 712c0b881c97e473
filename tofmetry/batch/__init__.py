"""Batch processing on Dask: many sensors, many objects, long recordings.

* :mod:`.manifest` — the TOML / YAML manifest of jobs (pydantic, errors naming the line, globs)
* :mod:`.run` — :func:`run_batch`: the jobs on a LocalCluster or an existing Dask cluster
* :mod:`.jobs` — one job through the same pipeline functions as the CLI; :mod:`.chunk_jobs` and
  :mod:`.chunked` — long recordings in chunks of frames
* :mod:`.stats` — per-pixel moments merged exactly across chunks (parallel variance)
* :mod:`.outputs` — staging folder, completion marker, content hashes (skip on rerun)
* :mod:`.summary` — ``summary.json`` and ``summary.html``
"""

from tofmetry.batch.manifest import JobSpec, load_manifest
from tofmetry.batch.run import BatchRun, batch_client, run_batch

__all__ = ["BatchRun", "JobSpec", "batch_client", "load_manifest", "run_batch"]
