"""Pydantic settings models built from the compiled core's declarations (``soilocp._core.settings_schema``,
soilocp/_core/src/settings.rs): each setting's name, default, bounds, unit and description are written once,
in the core, and the model validates them (an error names the setting), documents them and carries
whether a setting is for users or an internal constant of the method (``json_schema_extra["audience"]``)."""

from __future__ import annotations

import dataclasses
import math
import operator
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



def from_core(group: str, name: str) -> Any:
    """A dataclass field that is the core's setting ``name`` of group ``group``: its default is the core's (a
    tool that applies the same rule reads it, it does not define it again); :func:`check_from_core` checks a
    value against the core's bounds."""
    default = next(d for n, _, d, *_ in _core.settings_schema(group) if n == name)
    return dataclasses.field(default=default, metadata={"core": group})


_OPS = {"gt": (operator.gt, ">"), "ge": (operator.ge, ">="), "lt": (operator.lt, "<"), "le": (operator.le, "<=")}


def check_from_core(obj: Any) -> None:
    """The fields of dataclass ``obj`` made by :func:`from_core`, checked against the core's declaration (a
    finite number, whole for an int, within the bounds): ValueError naming the setting."""
    for f in dataclasses.fields(obj):
        group = f.metadata.get("core")
        if group is None:
            continue
        v = getattr(obj, f.name)
        (kind, bounds), = [(k, b) for n, k, _, b, *_ in _core.settings_schema(group) if n == f.name]
        ok = (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
              and (kind != "int" or float(v).is_integer()) and all(_OPS[op][0](v, b) for op, b in bounds))
        if not ok:
            need = " and ".join(f"{_OPS[op][1]} {b:g}" for op, b in bounds)
            raise ValueError(f"{f.name} must be a finite {'integer' if kind == 'int' else 'number'} {need}, got {v!r}")
