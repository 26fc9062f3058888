"""Each soil, torque-scale, usability and curve-learner setting is declared once, in the compiled core
(soilocp/_core/src/settings.rs and the settings_struct! blocks); the pydantic models are built from the
declarations, validate them by name, and the documentation reads the same declarations."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from pydantic import ValidationError

from soilocp import _core
from soilocp.estimation.curve_config import CurveConfig
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.torque_scale_config import TorqueScaleConfig
from soilocp.estimation.wheel_usability import UsabilityLimits

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("count_definitions", ROOT / "scripts/count_definitions.py")
count_definitions = importlib.util.module_from_spec(spec)
spec.loader.exec_module(count_definitions)

#: settings still written in more than one place, each with why (what remains of the work)
KNOWN = {
    # two switches of one name, each defined once: torque_scale.enabled and curve.enabled
    "enabled": "two settings",
    # calibrate-torque's own settings (soilocp.analysis.torque_constant), other settings of the same name
    **{n: "calibrate-torque" for n in ("window", "min_speed", "max_yaw_rate", "max_gap")},
}


@pytest.mark.parametrize("model, group", [(SoilConfig, "soil"), (TorqueScaleConfig, "torque_scale"),
                                          (UsabilityLimits, "usability"), (CurveConfig, "curve")])
def test_the_models_are_the_cores_declarations(model, group):
    for name, kind, default, bounds, unit, audience, doc in _core.settings_schema(group):
        f = model.model_fields[name]
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


def test_each_setting_is_defined_once_but_the_known_remainder():
    counts = count_definitions.setting_counts(None)
    extra = {n: c for group in counts.values() for n, c in group.items() if c != 1 and n not in KNOWN}
    assert extra == {}
    fixed = [n for n in KNOWN if max(counts[g].get(n, 0) for g in counts) <= 1]
    assert fixed == [], "these are defined once now: remove them from KNOWN"
