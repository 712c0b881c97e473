"""Ctrl-C waits for an import under way (tofmetry.cli._interrupt): an extension interrupted in its
initialisation is broken for good (``ImportError: initialization failed``, or a crash)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

# a module whose import runs Python code for ~1.5 s (as an extension's initialisation calls back into Python)
SLOW_MODULE = textwrap.dedent("""
    import time
    t0 = time.perf_counter()
    n = 0
    while time.perf_counter() - t0 < 1.5:
        n += 1
    done = True
""")

SCRIPT = textwrap.dedent("""
    import sys, time
    from tofmetry.cli import _interrupt
    _interrupt.install()
    print("go", flush=True)
    try:
        if sys.argv[1] == "import":
            import slow_module
        elif sys.argv[1] == "join":  # as SciPy's parallel k-d tree query waits for its threads
            import threading
            t = threading.Thread(target=time.sleep, args=(1.5,), daemon=True)
            t.start()
            t.join()
        time.sleep(5)  # the command goes on working
    except KeyboardInterrupt:
        done = "slow_module" in sys.modules if sys.argv[1] == "import" else not t.is_alive() if sys.argv[1] == "join" else False
        print("interrupted", done, flush=True)
        sys.exit(130)
    print("not interrupted", flush=True)
""")


def _communicate(p: subprocess.Popen, timeout: float) -> tuple[str, str]:
    """The output of ``p``; a process still running after ``timeout`` [s] (a lost interrupt) is
    killed, so that no process outlives the test, and the test fails with what it printed."""
    try:
        return p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        out, err = p.communicate()
        pytest.fail(f"still running {timeout} s after Ctrl-C; stdout {out[-500:]!r}, stderr {err[-2000:]!r}")


def _run(tmp_path, what: str, signals: int):
    (tmp_path / "slow_module.py").write_text(SLOW_MODULE)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    p = subprocess.Popen([sys.executable, "-c", SCRIPT, what], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert p.stdout.readline().strip() == "go"
    time.sleep(0.5)
    t0 = time.perf_counter()
    for _ in range(signals):
        p.send_signal(signal.SIGINT)
        time.sleep(0.05)
    out, err = _communicate(p, 60)
    return p.returncode, out.strip(), time.perf_counter() - t0, err


@pytest.mark.parametrize("what", ["import", "join", "sleep"])
def test_ctrl_c_waits_for_the_import_under_way(tmp_path, what):
    rc, out, waited, err = _run(tmp_path, what, 1)
    assert rc == 130, err
    if what in ("import", "join"):  # the module was imported whole / the thread finished, then it stopped
        assert out == "interrupted True", (out, err)
        assert waited > 0.5, waited
    else:  # outside an import it stops at once
        assert out == "interrupted False", (out, err)
        assert waited < 2.0, waited


def test_a_second_ctrl_c_stops_at_once(tmp_path):
    rc, out, waited, err = _run(tmp_path, "import", 2)
    assert rc == 130 and out == "interrupted False", (out, err)


KDTREE_LOOP = textwrap.dedent("""
    import sys
    import numpy as np
    from scipy.spatial import cKDTree
    from tofmetry.cli import _interrupt
    _interrupt.install()
    rng = np.random.default_rng(0)
    tree = cKDTree(rng.random((100000, 3)))
    print("go", flush=True)
    try:
        while True:
            d, i = tree.query(rng.random((20000, 3)), workers=-1)
    except KeyboardInterrupt:
        sys.exit(130)
""")


@pytest.mark.slow
def test_interrupted_parallel_kdtree_queries_never_crash(tmp_path):
    """Back-to-back ``cKDTree.query(workers=-1)`` interrupted at random: without the handler 10 of
    100 runs died of a segmentation fault (the query threads wrote into freed arrays); with it, every
    run must exit 130, stopped between two queries."""
    rng = np.random.default_rng(7)
    codes = []
    for _ in range(20):
        p = subprocess.Popen([sys.executable, "-c", KDTREE_LOOP], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        assert p.stdout.readline().strip() == "go"
        time.sleep(float(rng.uniform(0.05, 0.5)))
        p.send_signal(signal.SIGINT)
        _, err = _communicate(p, 60)
        codes.append((p.returncode, err[-500:]))
    assert all(c == 130 for c, _ in codes), codes


# Python swallows an exception raised in a weakref callback ("Exception ignored"); the callback
# here runs 98 % of the time, as the WeakSet callback that forgets a finished k-d tree query thread
# did when CI's loop of queries ran on for good after its Ctrl-C.
CALLBACK_LOOP = textwrap.dedent("""
    import sys, time, weakref
    from tofmetry.cli import _interrupt
    _interrupt.install()
    class Thing:
        pass
    def forget(_):
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.05:
            pass
    print("go", flush=True)
    try:
        while True:
            thing = Thing()
            ref = weakref.ref(thing, forget)
            del thing
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(130)
""")


def test_ctrl_c_in_a_weakref_callback_is_not_lost(tmp_path):
    """A Ctrl-C that lands in a callback stops the code that was running when it was called."""
    for _ in range(3):
        p = subprocess.Popen([sys.executable, "-c", CALLBACK_LOOP], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        assert p.stdout.readline().strip() == "go"
        time.sleep(0.3)
        p.send_signal(signal.SIGINT)
        out, err = _communicate(p, 20)
        assert (p.returncode, out.strip()) == (130, "interrupted"), err
        assert "Exception ignored" not in err, err
