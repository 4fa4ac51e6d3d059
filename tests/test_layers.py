"""The import contracts of pyproject.toml ``[tool.importlinter]`` hold (docs/ARCHITECTURE.md,
"Layers"): ``lint-imports`` exits 0. About a second (it parses imports, imports nothing)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# the ``lint-imports`` console script, run by this interpreter (cwd first on sys.path, so the
# checkout under test is analysed, not another installed copy)
LINT_IMPORTS = "from importlinter.cli import lint_imports_command; lint_imports_command()"


def test_import_contracts_hold():
    pytest.importorskip("importlinter", reason="import-linter is in the dev extra")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    proc = subprocess.run([sys.executable, "-c", LINT_IMPORTS, "--no-cache"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


def _documented_modules(text: str) -> set[str]:
    """Module paths of docs/ARCHITECTURE.md's module tables: each section's header names its
    folder in backticks (the first one), each table row's first cell the modules in it."""
    found, base = set(), None
    for line in text.splitlines():
        if line.startswith("**") and "`" in line:
            base = line.split("`")[1]
        elif line.startswith("| `") and base is not None:
            cell = line.split("|")[1]
            found |= {base + name for name in cell.replace("`", "").replace(" ", "").split(",")}
    return found


def test_architecture_names_every_module():
    """Every module of igdrivsim/ and maze/ has its row in docs/ARCHITECTURE.md, and every row
    names a module that exists (a package's ``__init__.py`` may go without one)."""
    documented = _documented_modules((ROOT / "docs" / "ARCHITECTURE.md").read_text())
    modules = {p.relative_to(ROOT).as_posix() for pkg in ("igdrivsim", "maze")
               for p in (ROOT / pkg).rglob("*.py")}
    missing = sorted(m for m in modules if m not in documented and not m.endswith("__init__.py"))
    assert not missing, f"docs/ARCHITECTURE.md does not name: {missing}"
    stale = sorted(documented - modules)
    assert not stale, f"docs/ARCHITECTURE.md names modules that do not exist: {stale}"
