"""Ctrl-C that waits for an import, a numba compilation or a thread start / join under way to
finish before it stops the command.

Python raises ``KeyboardInterrupt`` between two bytecodes, wherever they are. Three places are
unsafe, measured on this project's commands:

- inside the initialisation of a compiled extension it breaks the extension for good: SIGINT
  during ``import open3d`` gives ``ImportError: initialization failed`` (exit 1 with a traceback)
  in 16 of 40 tries (the commands import the library, Open3D and numba's kernels lazily);
- SciPy's parallel k-d tree queries (``workers=-1``) start threads that write into arrays the
  caller owns, then join them. Interrupted while a thread is started or joined, the caller frees
  the arrays under the running workers: a loop of queries interrupted at random died of a
  segmentation fault in 3 of 40 tries, and ``reconstruct`` interrupted 2.5-5 s after its start in
  4 of 210 (once in CI);
- the same crash, in the interpreter's finalisation, when native state is left mid-way (see
  :func:`exit_interrupted`).

:func:`install` replaces Python's SIGINT handler by one that raises ``KeyboardInterrupt`` at once,
except while the main thread is inside such code. Then it marks the frame that called into it
(the first frame outside) and turns tracing on for that frame alone: the interrupt is raised at
the first line that frame runs after the call returned (or in its caller, when it returns). No
polling: a loop of back-to-back queries is stopped between two queries. A second Ctrl-C while one
is deferred stops at once.

An interrupt raised inside a weakref callback or a ``__del__`` never reaches the command: Python
prints "Exception ignored" and goes on (a loop of k-d tree queries ran on for good in CI, its
Ctrl-C lost in the ``WeakSet`` callback that forgets a finished query thread). :func:`install`
also wraps ``sys.unraisablehook``: such a lost interrupt is deferred, as above, to the frame that
was running when the callback was called.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from types import FrameType

#: Code whose interruption leaves a broken module behind: the import machinery, numba's compiler.
_PROTECTED = ("<frozen importlib._bootstrap", "importlib/_bootstrap", "numba/core/")
#: ``threading.Thread`` methods that start or wait for a thread (SciPy's k-d tree calls them from C).
_THREAD_WAITS = ("start", "join", "_wait_for_tstate_lock")


def _is_protected(frame: FrameType) -> bool:
    name = frame.f_code.co_filename.replace("\\", "/")
    if any(p in name for p in _PROTECTED):
        return True
    return name.endswith("/threading.py") and frame.f_code.co_name in _THREAD_WAITS


def outermost_protected(frame: FrameType | None) -> FrameType | None:
    """The outermost frame, from ``frame`` up its callers, that runs the import machinery, numba's
    compiler, or starts or joins a thread; None when none does."""
    found = None
    while frame is not None:
        if _is_protected(frame):
            found = frame
        frame = frame.f_back
    return found


def _no_new_frames(frame: FrameType, event: str, arg) -> None:
    """Global trace function while an interrupt is deferred: frames it did not mark are not traced."""
    return None


class _DeferredInterrupt:
    """The SIGINT handler (module docstring)."""

    def __init__(self) -> None:
        self.pending = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        outer = outermost_protected(frame)
        if self.pending or outer is None or outer.f_back is None:
            self._stop()
        self.pending = True
        self._mark(outer.f_back)

    def defer(self, frame: FrameType) -> None:
        """Raise ``KeyboardInterrupt`` at the next line that ``frame`` runs (after the protected
        code it may be inside, as :meth:`__call__`): an interrupt that a callback swallowed."""
        outer = outermost_protected(frame)
        target = frame if outer is None else outer.f_back
        if target is None:  # nothing outside the protected code to stop in: Python's own handler
            signal.default_int_handler(signal.SIGINT, frame)
        self.pending = True
        self._mark(target)

    def _mark(self, frame: FrameType) -> None:
        frame.f_trace = self._on_event
        frame.f_trace_lines = True
        sys.settrace(_no_new_frames)

    def _on_event(self, frame: FrameType, event: str, arg):
        if not self.pending:
            return None
        if event == "line":
            self._stop()
        if event == "return" and frame.f_back is not None:
            self._mark(frame.f_back)
        return self._on_event

    def _stop(self) -> None:
        self.pending = False
        sys.settrace(None)
        raise KeyboardInterrupt


def install() -> None:
    """Make SIGINT wait for imports, numba compilations and thread starts / joins to finish (main
    thread only; a no-op where SIGINT is ignored, e.g. in a background job, or under a tracer such
    as a debugger or coverage)."""
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN or sys.gettrace() is not None:
        return
    handler = _DeferredInterrupt()
    signal.signal(signal.SIGINT, handler)
    sys.unraisablehook = _UnraisableInterrupt(handler, sys.unraisablehook)


class _UnraisableInterrupt:
    """``sys.unraisablehook`` that defers a ``KeyboardInterrupt`` lost in a callback (module
    docstring) to the frame that called into the callback; everything else goes to ``previous``."""

    def __init__(self, handler: _DeferredInterrupt, previous) -> None:
        self.handler = handler
        self.previous = previous

    def __call__(self, unraisable) -> None:
        caller = sys._getframe(0).f_back  # the callback has returned: the code it interrupted
        if (unraisable.exc_type is not KeyboardInterrupt or caller is None
                or threading.current_thread() is not threading.main_thread()):
            self.previous(unraisable)
            return
        self.handler.defer(caller)


def exit_interrupted(code: int = 130) -> None:
    """Flush the standard streams and end the process with ``code`` at once (``os._exit``).

    After an interrupt during the preparation of views, ``reconstruct`` once died of a
    segmentation fault with no Python frame, in the interpreter's finalisation, after its outputs
    had been cleaned and "interrupted" printed. The clean-up that matters (hidden staging folders)
    has run while the exception unwound; the command has nothing left to finalise."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
