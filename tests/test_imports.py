"""Every module imports on its own, first (no circular-import traps depending on import order)."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = r"""
import importlib, pkgutil, sys
import tofmetry
names = sorted(m.name for m in pkgutil.walk_packages(tofmetry.__path__, "tofmetry."))
bad = []
for name in names:
    for k in [k for k in sys.modules if k == "tofmetry" or k.startswith("tofmetry.")]:
        del sys.modules[k]
    try:
        importlib.import_module(name)
    except Exception as exc:  # noqa: BLE001
        bad.append(f"{name}: {type(exc).__name__}: {exc}")
print(len(names))
print("\n".join(bad))
sys.exit(1 if bad else 0)
"""


def test_every_module_imports_first():
    r = subprocess.run([sys.executable, "-W", "error::DeprecationWarning:tofmetry", "-c", SCRIPT],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert int(r.stdout.split()[0]) > 50
