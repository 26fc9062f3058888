"""The statuses and reason codes of a soil / OCP record: name -> (who sets it, its meaning), in code
order.  The compiled core defines them (soilocp/_core/src/codes.rs); ``python -m
soilocp.cli.generate_codes`` writes its tables to codes.json beside this module (not edited by hand:
tests/test_codes.py fails when the file and the core differ), read here because the message contracts
load in processes that do not load the compiled core (the gateway).  Who sets it: "soil" (the soil
stage), "publisher" (the live publisher), "ocp" (the OCP stage)."""

from __future__ import annotations

import json
from pathlib import Path

_TABLES = json.loads((Path(__file__).parent / "codes.json").read_text())

STATUSES: dict[str, tuple[str, str]] = {name: (by, meaning) for name, by, meaning in _TABLES["statuses"]}
REASONS: dict[str, tuple[str, str]] = {name: (by, meaning) for name, by, meaning in _TABLES["reasons"]}
