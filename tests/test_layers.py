"""The layer rules of docs/design.md §1, checked by import-linter on the real import graph.

``bodyschema`` (pure) imports nothing of ours, ``simulators`` only ``bodyschema``, the running service
none of the offline tooling (``emulators``, ``sim2real``, ``bench``, ``cli``), every package only those
below it, and no two sibling modules import each other; the contracts live in pyproject.toml
``[tool.importlinter]``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: ``lint-imports`` of this interpreter's environment, without its cache (the graph is read afresh).
LINT = [
    sys.executable,
    "-c",
    "import sys; from importlinter.cli import lint_imports_command as c; sys.exit(c())",
    "--no-cache",
]


def _lint(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*LINT, *args], cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_every_layer_contract_is_kept():
    res = _lint()
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Contracts: 5 kept, 0 broken." in res.stdout
    out = " ".join(res.stdout.split())  # long contract names wrap
    for name in (
        "bodyschema is pure: it imports nothing of ours KEPT",
        "simulators import only bodyschema KEPT",
        "the running service imports no offline tooling KEPT",
        "layers: cli above bench above the tools above service above simulators above bodyschema KEPT",
        "no import cycles between sibling modules KEPT",
    ):
        assert name in out


def test_a_broken_contract_fails_the_check(tmp_path):
    """The checker can fail: a contract the code breaks (the service does use the science) is reported."""
    cfg = tmp_path / "broken.toml"
    cfg.write_text(
        '[tool.importlinter]\nroot_packages = ["bodyschema", "service"]\n\n'
        "[[tool.importlinter.contracts]]\n"
        'name = "service without bodyschema"\ntype = "forbidden"\n'
        'source_modules = ["service.worker"]\nforbidden_modules = ["bodyschema"]\n'
    )
    res = _lint("--config", str(cfg))
    assert res.returncode == 1
    assert "service without bodyschema BROKEN" in res.stdout
    assert "service.worker -> bodyschema." in res.stdout


def test_an_import_cycle_fails_the_check(tmp_path):
    """The cycle contract can fail: two sibling modules that import each other are reported."""
    pkg = tmp_path / "cyc"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from cyc import b\n")
    (pkg / "b.py").write_text("from cyc import a\n")
    cfg = tmp_path / "cycle.toml"
    cfg.write_text(
        '[tool.importlinter]\nroot_packages = ["cyc"]\n\n'
        "[[tool.importlinter.contracts]]\n"
        'name = "no cycles"\ntype = "acyclic_siblings"\nancestors = ["cyc"]\n'
    )
    res = subprocess.run(
        [*LINT, "--config", str(cfg)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
    )
    assert res.returncode == 1, res.stdout + res.stderr
    assert "no cycles BROKEN" in res.stdout
