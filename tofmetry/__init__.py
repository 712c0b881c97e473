"""tofmetry: turn a consumer time-of-flight RGB-D camera into a measuring instrument.

The public API (typed wrappers over :mod:`tofmetry.pipelines`, documented in :mod:`tofmetry.api`)::

    load_capture(path) -> Capture                            a capture folder, validated
    calibrate_intrinsics(images, board, square_mm) -> run    lens (pinhole + Brown)
    calibrate_depth(dataset, output=...) -> run              depth calibration (wall or board)
    correct(depth, calibration) -> depth                     one frame [mm]
    to_points(depth, calibration=None, intrinsics=...)       one frame -> (N, 3) points [m]
    reconstruct(scan, calibration, output=...) -> result     3D model of an object
    evaluate(model, reference, output=...) -> result         accuracy against a reference

``import tofmetry`` stays light: numpy, numba, OpenCV and the rest load on the first use of one
of these names (the same holds for ``import tofmetry.io`` and every other sub-package, which
import this module first).

``tofmetry.reconstruct`` and ``tofmetry.evaluate`` are also the sub-packages that hold those
algorithms: they stay ordinary modules (``from tofmetry.evaluate import EvaluationConfig``,
``import tofmetry.reconstruct as rec``) that can also be called, ``tofmetry.reconstruct(scan, ...)``
running the API function of the same name.
"""

import importlib as _importlib
import os as _os
import sys as _sys
import types as _types

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (type checkers read the name)

# numba's default TBB layer is unusable with the TBB some wheels bring (it warns and falls back);
# the OpenMP layer is always available with libgomp. Users may still override it.
_os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")

__version__ = "0.1.0"

__all__ = ["calibrate_depth", "calibrate_intrinsics", "correct", "evaluate", "load_capture", "reconstruct",
           "to_points"]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time the names load on first use
    from tofmetry.api import calibrate_depth, calibrate_intrinsics, correct, load_capture, to_points

# API functions that share their name with a sub-package: the sub-package is made callable
_CALLABLE_PACKAGES = ("evaluate", "reconstruct")


class _CallablePackage(_types.ModuleType):
    """A sub-package that is also the API function of its name (``tofmetry.reconstruct(scan, ...)``)."""

    def __call__(self, *args, **kwargs):
        """Run :func:`tofmetry.api.reconstruct` / :func:`tofmetry.api.evaluate` (see their docstrings)."""
        api = _importlib.import_module("tofmetry.api")
        return getattr(api, self.__name__.rpartition(".")[2])(*args, **kwargs)


class _Package(_types.ModuleType):
    """This package's module type: its callable sub-packages become callable when first imported."""

    def __setattr__(self, name: str, value) -> None:
        if name in _CALLABLE_PACKAGES and type(value) is _types.ModuleType:
            value.__class__ = _CallablePackage
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package


def __getattr__(name: str):
    """Load a public API name on first use (PEP 562)."""
    if name in _CALLABLE_PACKAGES:
        return _importlib.import_module(f"tofmetry.{name}")  # the import system sets it (callable) here
    if name in __all__:
        value = getattr(_importlib.import_module("tofmetry.api"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'tofmetry' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*(k for k in globals() if not k.startswith("_")), *__all__, "__version__"})
