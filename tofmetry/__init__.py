"""tofmetry: turn a consumer time-of-flight RGB-D camera into a measuring instrument."""

import os as _os

# numba's default TBB layer is unusable with the TBB some wheels bring (it warns and falls back);
# the OpenMP layer is always available with libgomp. Users may still override it.
_os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")

__version__ = "0.1.0"
