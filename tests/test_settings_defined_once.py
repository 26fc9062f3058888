"""Each soil, torque-scale, usability, curve-learner and observer setting is declared once, in the compiled core
(soilocp/_core/src/settings.rs and the settings_struct! blocks); the pydantic models are built from the
declarations, validate them by name, and the documentation reads the same declarations."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from pydantic import ValidationError

from soilocp import _core
from soilocp.estimation.curve_config import CurveConfig
from soilocp.estimation.observer_config import ObserverConfig
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.torque_scale_config import TorqueScaleConfig
from soilocp.estimation.wheel_usability import UsabilityLimits

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("count_definitions", ROOT / "scripts/count_definitions.py")
count_definitions = importlib.util.module_from_spec(spec)
spec.loader.exec_module(count_definitions)

#: settings still written in more than one place, each with why (what remains of the work): none
KNOWN: dict[str, str] = {}


@pytest.mark.parametrize("model, group", [(SoilConfig, "soil"), (TorqueScaleConfig, "torque_scale"),
                                          (UsabilityLimits, "usability"), (CurveConfig, "curve"),
                                          (ObserverConfig, "observer")])
def test_the_models_are_the_cores_declarations(model, group):
    for name, kind, default, bounds, unit, audience, doc, choices in _core.settings_schema(group):
        f = model.model_fields[name]
        if kind == "choice":
            assert f.default == choices[int(default)] and f.annotation.__args__ == tuple(choices), name
        else:
            assert f.default == default and f.annotation is {"float": float, "int": int}[kind], name
        assert f.json_schema_extra["audience"] == audience and doc in f.description, name
        for op, v in bounds:
            assert any(getattr(m, op, None) == v for m in f.metadata), (name, op)


def test_a_bad_value_names_the_setting_in_python_and_in_the_core():
    with pytest.raises(ValidationError, match="temper"):
        SoilConfig(temper=2.0)
    with pytest.raises(ValidationError, match="hold_aftr"):
        SoilConfig(hold_aftr=1.0)
    # the core checks the same bounds (a config that skipped pydantic's validation)
    from soilocp.estimation.soil_grid import LogKGrid
    from soilocp.model.constants import DEFAULT_CONSTANTS

    with pytest.raises(ValueError, match="soil settings: temper = 2 must be <= 1"):
        LogKGrid(DEFAULT_CONSTANTS, SoilConfig.model_construct(temper=2.0)).bank(1)


def test_a_choice_is_a_literal_named_in_python_and_checked_in_the_core():
    with pytest.raises(ValidationError, match="structure"):
        ObserverConfig(structure="paper")
    with pytest.raises(ValueError, match='observer settings: structure = "paper" must be one of slip, shared'):
        _core.ObserverCore(1, [1.0] * 8, [0.0] * 4, {"structure": "paper"}, per_side=False, interval_mean=False,
                           bridge_slip=0.005)


def test_each_setting_is_defined_once_but_the_known_remainder():
    counts = count_definitions.setting_counts(None)
    extra = {n: c for group in counts.values() for n, c in group.items() if c != 1 and n not in KNOWN}
    assert extra == {}
    fixed = [n for n in KNOWN if max(counts[g].get(n, 0) for g in counts) <= 1]
    assert fixed == [], "these are defined once now: remove them from KNOWN"
