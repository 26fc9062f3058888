"""Pydantic settings models built from the compiled core's declarations (``soilocp._core.settings_schema``,
soilocp/_core/src/settings.rs): each setting's name, default, bounds, unit and description are written once,
in the core, and the model validates them (an error names the setting), documents them and carries
whether a setting is for users or an internal constant of the method (``json_schema_extra["audience"]``)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model

from soilocp import _core

_TYPES = {"float": float, "int": int}


def describe(doc: str, unit: str) -> str:
    """A setting's description with its unit."""
    return f"{doc} Unit: {unit}." if unit else doc


def core_fields(group: str) -> dict[str, tuple[type, Any]]:
    """The fields of the core's settings group ``group``, in the core's order: name -> (type, FieldInfo).  A
    choice is a ``Literal`` of its names (its default: the core's index into them)."""
    fields: dict[str, tuple[type, Any]] = {}
    for name, kind, default, bounds, unit, audience, doc, choices in _core.settings_schema(group):
        if kind == "choice":
            typ, value = Literal[tuple(choices)], choices[int(default)]
        else:
            typ = _TYPES[kind]
            value = typ(default)
        fields[name] = (typ, Field(value, description=describe(doc, unit), **dict(bounds),
                                   json_schema_extra={"audience": audience, "unit": unit}))
    return fields


def model_from_core(name: str, group: str, module: str, doc: str, **own: tuple[type, Any]) -> type[BaseModel]:
    """A frozen model (unknown keys refused) named ``name``, of module ``module`` (where it is pickled from),
    with the fields ``own`` first, then the core's settings group ``group``."""
    return create_model(name, __config__=ConfigDict(frozen=True, extra="forbid"), __doc__=doc, __module__=module,
                        **own, **core_fields(group))


def core_values(config: BaseModel, group: str) -> dict[str, float | str]:
    """The core's settings of group ``group`` from a validated ``config``, as the core takes them (a number as a
    float, a choice as its name)."""
    return {name: getattr(config, name) if kind == "choice" else float(getattr(config, name))
            for name, kind, *_ in _core.settings_schema(group)}

