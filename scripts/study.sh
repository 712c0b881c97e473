#!/usr/bin/env bash
# The main job: set up (if needed), then run the whole study on the virtual Kinect v2.
# Extra arguments are passed to `tofmetry study` (e.g. a DATA_DIR or --config).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup-env.sh"
cd "$ROOT"
exec .venv/bin/tofmetry study "$@"
