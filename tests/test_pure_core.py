"""The physics library never imports Zenoh (architecture: a pure library, usable offline).

Every module of the ``soilocp`` package but the two floors above the library (the Zenoh services,
``soilocp.services``, and the command line, ``soilocp.cli``), its command modules included, is imported
in a fresh interpreter, which must end without ``zenoh`` or either floor in ``sys.modules``; and no file
under ``soilocp/`` imports zenoh at module level.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import soilocp

PACKAGE_DIR = Path(soilocp.__file__).resolve().parent
#: the floors above the library, which may use the transport
EXCLUDED: tuple[str, ...] = ("soilocp.services", "soilocp.cli")

PROBE = r"""
import importlib, json, pkgutil, sys
import soilocp
excluded = tuple(sys.argv[1:])
names = []
def walk(path, prefix):  # pkgutil.walk_packages would import the excluded packages to look inside them
    for info in pkgutil.iter_modules(path, prefix):
        if any(info.name == e or info.name.startswith(e + ".") for e in excluded):
            continue
        module = importlib.import_module(info.name)
        names.append(info.name)
        if info.ispkg:
            walk(module.__path__, info.name + ".")
walk(soilocp.__path__, "soilocp.")
print(json.dumps({"imported": names, "zenoh": sorted(m for m in sys.modules if m == "zenoh" or m.startswith("zenoh.")),
                  "upper": sorted(m for m in sys.modules if any(m == e or m.startswith(e + ".") for e in excluded))}))
"""


def test_importing_every_library_module_does_not_import_zenoh():
    p = subprocess.run(
        [sys.executable, "-c", PROBE, *EXCLUDED],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=PACKAGE_DIR.parent,
    )
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout.strip().splitlines()[-1])
    expected = {"soilocp.model.traction", "soilocp.model.ocp", "soilocp.model.slip", "soilocp.model.normal_force", "soilocp.analysis.calibration", "soilocp.analysis.curves"}
    assert expected <= set(out["imported"])
    assert "soilocp.commands.offline" in out["imported"]
    assert out["zenoh"] == [], f"zenoh imported by the pure library: {out['zenoh']}"
    assert out["upper"] == [], f"the library imports a floor above it: {out['upper']}"


def _module_level_zenoh_imports(path: Path) -> list[int]:
    """Line numbers of `import zenoh...` / `from zenoh... import` outside any function or class body."""
    tree = ast.parse(path.read_text(), filename=str(path))
    hits: list[int] = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue  # imported only when called
            if isinstance(child, ast.Import) and any(a.name.split(".")[0] == "zenoh" for a in child.names):
                hits.append(child.lineno)
            elif isinstance(child, ast.ImportFrom) and (child.module or "").split(".")[0] == "zenoh" and child.level == 0:
                hits.append(child.lineno)
            visit(child)  # if/try/with/class bodies run at import time

    visit(tree)
    return hits


def test_no_module_level_zenoh_import_under_soilocp():
    files = sorted(PACKAGE_DIR.rglob("*.py"))
    assert len(files) > 5
    offenders = {str(f.relative_to(PACKAGE_DIR.parent)): lines for f in files if (lines := _module_level_zenoh_imports(f))}
    assert offenders == {}, f"module-level zenoh imports: {offenders}"


def test_the_checker_detects_module_level_imports(tmp_path):
    # the scanner itself must be able to fail
    bad = tmp_path / "bad.py"
    bad.write_text("import os\nif True:\n    import zenoh\nfrom zenoh.foo import bar\ndef f():\n    import zenoh\n")
    assert _module_level_zenoh_imports(bad) == [3, 4]
