"""The package's import graph keeps its shape: layers, and private modules stay private (import-linter).

Two contracts, checked on the source (nothing is imported):

* **layers**: a package imports only packages of lower layers; packages on one line are
  independent of each other;
* **private modules**: ``tofmetry.X._y`` is imported only from inside ``tofmetry.X``. The forbidden
  modules are every private module of every sub-package, listed from the tree at test time.

Known violations that other work removes are listed in ``KNOWN`` with the reason: the contracts
hold now, and each line goes when its import does (an entry that no longer matches is reported as
a warning in the output). Needs import-linter >= 2.13 (forbidden contracts whose source and
forbidden modules overlap; ``exclude_type_checking_imports``).
"""

from __future__ import annotations

import pkgutil
from pathlib import Path

import pytest

import_linter_cli = pytest.importorskip("importlinter.cli")

import tofmetry  # noqa: E402

# Top to bottom; "|" separates independent packages of one layer.
LAYERS = [
    "tofmetry.cli | tofmetry.api",
    "tofmetry.batch",
    "tofmetry.study",
    "tofmetry.record",
    "tofmetry.report | tofmetry.pipelines",
    "tofmetry.plan",
    "tofmetry.evaluate",
    "tofmetry.reconstruct",
    "tofmetry.devices",
    "tofmetry.calibrate | tofmetry.assess | tofmetry.simulate",
    "tofmetry.pointcloud",
    "tofmetry.io",
    "tofmetry.sensor",
    "tofmetry._shared",
    "tofmetry.errors",
]

# Imports that break a contract today and are being removed by other work (importer -> imported).
KNOWN = {
    "layers": [
    ],
    "private": [
        # the depth pipelines reach into calibrate's private modules; being promoted to public names
    ],
}


def private_modules() -> list[str]:
    """Every ``tofmetry.X._y`` (and below) with ``X`` a public sub-package."""
    out = []
    for m in pkgutil.walk_packages(tofmetry.__path__, "tofmetry."):
        parts = m.name.split(".")
        if len(parts) >= 3 and not parts[1].startswith("_") and any(
                p.startswith("_") and not p.startswith("__") for p in parts[2:]):
            out.append(m.name)
    return sorted(out)


def _lines(items: list[str]) -> str:
    return "".join(f"\n    {x}" for x in items)


def config() -> str:
    """The import-linter configuration (INI) of the two contracts."""
    subpackages = sorted(m.name for m in pkgutil.iter_modules(tofmetry.__path__))
    return f"""[importlinter]
root_package = tofmetry
exclude_type_checking_imports = true

[importlinter:contract:layers]
name = Layers: {' > '.join(x.replace('tofmetry.', '') for x in LAYERS)}
type = layers
layers ={_lines(LAYERS)}
ignore_imports ={_lines(KNOWN['layers'])}
unmatched_ignore_imports_alerting = warn

[importlinter:contract:private]
name = A package's private modules are imported only from inside that package
type = forbidden
source_modules ={_lines([f'tofmetry.{p}' for p in subpackages])}
forbidden_modules ={_lines(private_modules())}
allow_indirect_imports = true
ignore_imports ={_lines(KNOWN['private'])}
unmatched_ignore_imports_alerting = warn
"""


def test_every_package_is_on_a_layer():
    listed = {p.strip() for line in LAYERS for p in line.split("|")}
    found = {f"tofmetry.{m.name}" for m in pkgutil.iter_modules(tofmetry.__path__)}
    assert found - listed == set(), "add the new package to LAYERS"


def test_import_contracts(tmp_path: Path, capsys):
    cfg = tmp_path / "importlinter.ini"
    cfg.write_text(config())
    status = import_linter_cli.lint_imports(config_filename=str(cfg), no_cache=True, no_logo=True)
    out = capsys.readouterr().out
    assert status == 0, out
    assert "2 kept, 0 broken" in out, out
