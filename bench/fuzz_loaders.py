"""Fuzz every reader with Hypothesis, 10,000 cases each (the CI runs a few dozen per reader).

Runs ``tests/io/test_fuzz_loaders.py`` with ``TOFMETRY_FUZZ_EXAMPLES`` cases per reader and writes
``bench/results/fuzz_loaders.json``: per reader, the cases run (a reader is called once or more per
case), the cases it refused with tofmetry's own error, and pass / fail. A failure means a reader
raised something else than a :class:`~tofmetry.errors.TofmetryError` naming the file (or crashed the
process): Hypothesis prints the smallest input that does it.

    .venv/bin/python -m bench.fuzz_loaders                 # 10,000 cases per reader (about an hour on 2 cores)
    .venv/bin/python -m bench.fuzz_loaders --cases 1000 -k "ply or e57"
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=10_000, help="Hypothesis cases per reader (default 10000).")
    ap.add_argument("-k", default=None, help="pytest -k expression selecting readers.")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "fuzz_loaders.json")
    a = ap.parse_args(argv)
    counts = Path(tempfile.mkdtemp()) / "counts.json"
    env = {**os.environ, "TOFMETRY_FUZZ_EXAMPLES": str(a.cases), "TOFMETRY_FUZZ_COUNTS": str(counts)}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/io/test_fuzz_loaders.py", "-rA"]
    if a.k:
        cmd += ["-k", a.k]
    t0 = time.time()
    r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.time() - t0
    outcome = {}
    for line in r.stdout.splitlines():
        for tag in ("PASSED", "FAILED", "ERROR"):
            if line.startswith(tag + " "):
                outcome[line.split("::", 1)[1].split(" ")[0]] = tag.lower()
    per = json.loads(counts.read_text()) if counts.is_file() else {}
    readers = {name: {"cases": c[0], "refused_with_tofmetry_error": c[1], "result": outcome.get(name, "?")}
               for name, c in per.items()}
    doc = {"cases_per_reader_requested": a.cases, "seconds": round(seconds, 1), "exit_code": r.returncode,
           "readers": readers, "tail": r.stdout[-4000:] + r.stderr[-2000:] if r.returncode else ""}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(doc, indent=1) + "\n")
    for name, d in readers.items():
        print(f"{name:45s} {d['cases']:>7} cases  {d['refused_with_tofmetry_error']:>7} refused  {d['result']}")
    print(f"{seconds:.0f} s, exit {r.returncode}; written {a.out}")
    return r.returncode


if __name__ == "__main__":
    sys.exit(main())
