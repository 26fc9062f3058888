"""The records' statuses and reason codes are defined once, in the compiled core (soilocp/_core/src/codes.rs):
the generated soilocp/schemas/codes.json (which soilocp.schemas.codes reads) is the core's tables, the schemas and
the soil stage take their names from it, and no other file of the package lists them."""

from __future__ import annotations

import ast
import re
import typing
from pathlib import Path

from soilocp import _core
from soilocp.cli.generate_codes import TARGET, render
from soilocp.estimation.soil_config import Status
from soilocp.schemas import codes
from soilocp.schemas.pipeline import REASON_CODES, EstimateStatus

PKG = Path(__file__).resolve().parents[1] / "soilocp"
STATUS_NAMES = {name for name, *_ in _core.status_codes()}
REASON_NAMES = {name for name, *_ in _core.reason_codes()}
#: the one definition, and the file generated from it
DEFINITIONS = {PKG / "_core/src/codes.rs", TARGET}
#: tables keyed by every code that add something per code without defining the codes (each checks at
#: import that its keys are the core's)
KEYED_BY_CODE = {
    PKG / "estimation/next_steps.py": "the next step a user can take per reason",
    PKG / "services/ros2/messages.py": "the ROS diagnostic level per status",
}


def test_the_generated_module_is_the_cores():
    """Fails when codes.rs changed without regenerating soilocp/schemas/codes.json."""
    assert TARGET.read_text() == render(), "run python -m soilocp.cli.generate_codes"


def test_schemas_and_the_soil_stage_take_the_cores_names():
    assert list(typing.get_args(EstimateStatus)) == [n for n, *_ in _core.status_codes()]
    assert list(REASON_CODES) == [n for n, *_ in _core.reason_codes()]
    assert REASON_CODES == {n: meaning for n, _, meaning in _core.reason_codes()}
    soil = [n for n, by, _ in _core.status_codes() if by == "soil"]
    assert list(typing.get_args(Status)) == soil == list(_core.SoilGridBank.status_names)
    assert list(_core.SoilGridBank.reason_names) == [n for n, by, _ in _core.reason_codes() if by == "soil"]
    assert set(codes.STATUSES) == STATUS_NAMES


def _listed_names(node: ast.AST) -> set[str]:
    """The string constants a tuple / list / set / dict-key literal or a Literal[...] lists."""
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        elts = node.elts
    elif isinstance(node, ast.Dict):
        elts = [k for k in node.keys if k is not None]
    else:
        return set()
    return {e.value for e in elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}


def _python_lists(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        names = _listed_names(node)
        for kind, known in (("statuses", STATUS_NAMES), ("reason codes", REASON_NAMES)):
            if len(names & known) >= 4:
                found.append((node.lineno, kind))
    return found


def _rust_lists(path: Path) -> list[tuple[int, str]]:
    found = []
    for i, line in enumerate(path.read_text().splitlines(), 1):
        quoted = set(re.findall(r'"([a-z_]+)"', line))
        if len(quoted & STATUS_NAMES) >= 3 or len(quoted & REASON_NAMES) >= 3:
            found.append((i, "names"))
    text = path.read_text()
    # one name per line (a const array): count the lines of one file that quote a code name alone
    alone = re.findall(r'^\s*"([a-z_]+)",\s*$', text, flags=re.M)
    if len(set(alone) & REASON_NAMES) >= 4 or len(set(alone) & STATUS_NAMES) >= 4:
        found.append((0, "a const array of code names"))
    return found


def test_no_other_file_defines_the_statuses_or_reasons():
    """Any literal collection of four or more status or reason names outside the core's tables and the keyed
    tables is a second definition; so is a Rust array of them."""
    offenders = []
    for path in sorted(PKG.rglob("*.py")):
        if path in DEFINITIONS or path in KEYED_BY_CODE:
            continue
        offenders += [f"{path.relative_to(PKG)}:{line} lists {kind}" for line, kind in _python_lists(path)]
    for path in sorted((PKG / "_core/src").rglob("*.rs")):
        if path in DEFINITIONS:
            continue
        offenders += [f"{path.relative_to(PKG)}:{line} lists {kind}" for line, kind in _rust_lists(path)]
    assert offenders == []


def test_the_check_finds_a_second_definition(tmp_path):
    """The scan above is not vacuous: a copy of the old hand-written Literal is found."""
    p = tmp_path / "x.py"
    p.write_text('Status = Literal["ok", "uncertain", "holding", "no_estimate"]\n'
                 'R = ("none", "not_yet", "withdrawn", "wide")\n')
    assert sorted(k for _, k in _python_lists(p)) == ["reason codes", "statuses"]
    r = tmp_path / "x.rs"
    r.write_text('pub const NAMES: [&str; 4] = [\n    "none",\n    "not_yet",\n    "wide",\n    "nis",\n];\n')
    assert _rust_lists(r)


def test_keyed_tables_cover_exactly_the_cores_codes():
    from soilocp.estimation.next_steps import NEXT_STEPS
    from soilocp.services.ros2.messages import ESTIMATE_LEVEL

    assert set(NEXT_STEPS) == REASON_NAMES and set(ESTIMATE_LEVEL) == STATUS_NAMES
