"""The reference pages under docs/reference/ are generated from the code (the command line's click
definitions, the settings' and the messages' pydantic models, the Zenoh keys): the committed pages
must be what the generator gives today, so a new option, setting, field or key cannot be left out."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from soilocp.cli import docs_reference

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "docs" / "reference"


def test_committed_reference_pages_are_what_the_code_gives():
    problems = docs_reference.differences(REFERENCE)
    assert not problems, (
        "docs/reference/ is stale: run `" + docs_reference.REGENERATE + "` and commit the pages.\n\n"
        + "\n".join(problems))


def test_generator_writes_every_page_and_check_passes_on_them(tmp_path):
    out = tmp_path / "reference"
    gen = subprocess.run([sys.executable, "-m", "soilocp.cli.docs_reference", "--out", str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert gen.returncode == 0, gen.stderr
    assert sorted(p.name for p in out.iterdir()) == ["cli.md", "codes.md", "records.md", "settings.md", "topics.md"]
    check = subprocess.run([sys.executable, "-m", "soilocp.cli.docs_reference", "--out", str(out), "--check"],
                           cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stderr
    (out / "settings.md").write_text("stale\n")
    stale = subprocess.run([sys.executable, "-m", "soilocp.cli.docs_reference", "--out", str(out), "--check"],
                           cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert stale.returncode == 1
    assert docs_reference.REGENERATE in stale.stderr


def test_pages_cover_every_command_setting_field_and_key():
    from pydantic import BaseModel

    from soilocp.schemas.pipeline import OcpEstimate
    from soilocp.estimation.config import PipelineConfig
    from soilocp.cli.main import main

    cli = (REFERENCE / "cli.md").read_text()
    for name in main.commands:
        assert f"## soilocp {name}\n" in cli, name
    settings = (REFERENCE / "settings.md").read_text()

    def leaves(model, prefix=""):
        for name, field in model.model_fields.items():
            if isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel):
                yield from leaves(field.annotation, prefix + name + ".")
            else:
                yield prefix + name

    for key in leaves(PipelineConfig):
        assert f"| `{key}` |" in settings, key
    records = (REFERENCE / "records.md").read_text()
    for field in OcpEstimate.model_fields:
        assert f"| `{field}` |" in records, field
    assert "`soilocp/<vid>/ocp`" in (REFERENCE / "topics.md").read_text()
