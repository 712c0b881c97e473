"""Streaming of a capture's frames: decoding and encoding in threads, the kernel in between.

:func:`stream_frames` reads frame ``i + k`` and writes frame ``i - k`` while the caller's
``process`` works on frame ``i``. PNG decoding and encoding (OpenCV) and the numba kernels
release the GIL, so on a machine with several cores they overlap. At most ``ahead`` frames are
being read and ``ahead`` being written at any time (bounded queues): the memory used does not
grow with the number of frames.

While frames stream, the numba kernels called by ``process`` run on the calling thread alone
(``kernel_threads=1``): the decoding and encoding threads already keep the cores busy, and an
OpenMP team spin-waits between two frames on the cores the codecs need. Measured on 2 cores, 300
frames of ``tofmetry correct``: 7.7 s of CPU with the kernels' two threads, 4.4 s with one.
"""

from __future__ import annotations

import os
from collections import deque
from contextlib import contextmanager
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Iterator, TypeVar

import numba

F = TypeVar("F")
R = TypeVar("R")


def default_workers() -> int:
    """Decoding/encoding threads: one per core, at least 2 (one reads while one writes)."""
    return max(2, os.cpu_count() or 1)


@contextmanager
def kernel_threads(n: int | None) -> Iterator[None]:
    """Run the numba kernels called from this thread on ``n`` threads inside the block (None: unchanged)."""
    if n is None:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)


def stream_frames(n_frames: int, read: Callable[[int], F], process: Callable[[int, F], R],
                  write: Callable[[int, R], None] | None = None, *, workers: int | None = None,
                  ahead: int | None = None, advance: Callable[[], None] | None = None,
                  numba_threads: int | None = 1) -> None:
    """Run ``write(i, process(i, read(i)))`` for ``i = 0 .. n_frames - 1``, reads and writes in threads.

    Parameters
    ----------
    n_frames : number of frames
    read : ``read(i) -> frame``, called in a worker thread (e.g. ``Capture.depth``)
    process : ``process(i, frame) -> result``, called in the calling thread, in frame order; its
        result must not be modified afterwards (the writer may still hold it)
    write : optional ``write(i, result)``, called in a worker thread, any order
    workers : worker threads (default :func:`default_workers`)
    ahead : frames read ahead and writes pending at most (default ``2 * workers``)
    advance : optional progress callable, called once per processed frame (calling thread)
    numba_threads : threads of the numba kernels that ``process`` calls, during the stream
        (default 1, see the module docstring; None leaves numba's setting)

    Raises
    ------
    The first exception of ``read``, ``process`` or ``write``; pending work is cancelled and the
    running reads/writes are waited for before it propagates.
    """
    workers = workers or default_workers()
    ahead = max(1, ahead or 2 * workers)
    with kernel_threads(numba_threads):
        _stream(n_frames, read, process, write, workers, ahead, advance)


def _stream(n_frames, read, process, write, workers, ahead, advance) -> None:
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="tofmetry-frames")
    reads: deque[Future] = deque()
    writes: deque[Future] = deque()
    try:
        submitted = 0
        while submitted < min(n_frames, ahead):
            reads.append(pool.submit(read, submitted))
            submitted += 1
        for i in range(n_frames):
            frame = reads.popleft().result()
            if submitted < n_frames:
                reads.append(pool.submit(read, submitted))
                submitted += 1
            result = process(i, frame)
            del frame
            if write is not None:
                writes.append(pool.submit(write, i, result))
                while writes and (len(writes) > ahead or writes[0].done()):
                    writes.popleft().result()  # bounded, and a failed write stops the run early
            if advance is not None:
                advance()
        while writes:
            writes.popleft().result()
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
