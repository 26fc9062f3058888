"""One import name: the code imports the services and the message contracts as ``soilocp.services`` and
``soilocp.schemas``.  The repository's top-level ``services/`` and ``schemas/`` are links to those folders,
so an ``import services`` would still work from a checkout, as a second copy of every module (two
``SensorSample`` classes, two registries) that the installed wheel does not have."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOP_LEVEL_IMPORT = re.compile(r"^\s*(from|import)\s+(services|schemas|soilocp_cli)\b", re.M)
MODULE_RUN = re.compile(r"-m[\"',\s]+(services|schemas|soilocp_cli)\b")


def test_no_code_imports_a_top_level_name():
    files = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    bad = []
    for f in files:
        p = ROOT / f
        if p.is_symlink() or not p.is_file():
            continue
        text = p.read_text()
        for m in (*TOP_LEVEL_IMPORT.finditer(text), *MODULE_RUN.finditer(text)):
            line = text.count("\n", 0, m.start()) + 1
            bad.append(f"{f}:{line}: {text.splitlines()[line - 1].strip()}")
    assert not bad, "import these as soilocp.services / soilocp.schemas / soilocp.cli:\n" + "\n".join(bad)


def test_top_level_folders_are_links_into_the_package():
    for name in ("services", "schemas"):
        link = ROOT / name
        assert link.is_symlink() and link.resolve() == (ROOT / "soilocp" / name).resolve(), name
