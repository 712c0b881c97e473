#!/usr/bin/env bash
# The main job: set up (if needed), then run the whole study on the virtual Kinect v2.
# Extra arguments are passed to `tofmetry study` (e.g. a DATA_DIR or --config). Works from any
# folder: relative paths (-o OUT, DATA_DIR) are taken from the caller's working directory.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup-env.sh"
exec "$ROOT/.venv/bin/tofmetry" study "$@"
