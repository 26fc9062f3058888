"""Words a settings file's validation error for the person who wrote the file.

pydantic's own text names the field but not what would have been right; a misspelt key in a vehicle
file or a pipeline config is the commonest mistake, so each problem here says where it is (the
dotted path), what was given, why it is refused, and for an unknown key the closest valid key
(:func:`difflib.get_close_matches`) and the list of valid keys at that level.  Lean: pydantic and the
standard library only (the OCP publisher loads its settings without numpy).
"""

from __future__ import annotations

import difflib
import types
import typing
from typing import Any, Optional

from pydantic import BaseModel, ValidationError

__all__ = ["describe_validation_error", "closest_key"]


def closest_key(key: str, valid: list[str]) -> Optional[str]:
    """The valid key nearest to ``key`` (difflib's ratio >= 0.6), or None when none is near."""
    hit = difflib.get_close_matches(key, valid, n=1, cutoff=0.6)
    return hit[0] if hit else None


def _submodel(annotation: Any) -> Optional[type[BaseModel]]:
    """The pydantic model inside a field's annotation (``Model``, ``Optional[Model]``, ``Model | None``)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(annotation):
            found = _submodel(arg)
            if found is not None:
                return found
    return None


def _model_at(model: type[BaseModel], path: tuple) -> Optional[type[BaseModel]]:
    """The model that holds the last key of ``path`` (None when the path leaves the models)."""
    current: Optional[type[BaseModel]] = model
    for part in path:
        if current is None or not isinstance(part, str) or part not in current.model_fields:
            return None
        current = _submodel(current.model_fields[part].annotation)
    return current


def _value(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def describe_validation_error(exc: ValidationError, source: str, model: type[BaseModel]) -> str:
    """One line per problem of ``exc`` (raised validating ``model`` from the file ``source``).

    Parameters
    ----------
    exc
        The validation error.
    source
        What was read, as the user knows it, e.g. ``"vehicle file 'robot.json'"``.
    model
        The model the file was validated against (its fields are the valid keys).

    Returns
    -------
    str
        ``source``, then for each problem: the dotted key, the value given and why it is refused; an
        unknown key also gets the closest valid key and the valid keys at its level.
    """
    lines = []
    for err in exc.errors(include_url=False):
        loc = tuple(err.get("loc", ()))
        where = ".".join(str(p) for p in loc) or "<file>"
        if err.get("type") == "extra_forbidden" and loc:
            key = str(loc[-1])
            owner = _model_at(model, loc[:-1])
            valid = sorted(owner.model_fields) if owner is not None else []
            near = closest_key(key, valid)
            hint = f"did you mean {near!r}? " if near else ""
            level = ".".join(str(p) for p in loc[:-1])
            keys_of = f"valid keys{' of ' + level if level else ''}: {', '.join(valid)}" if valid else ""
            lines.append(f"  {where}: unknown key (value {_value(err.get('input'))}); {hint}{keys_of}".rstrip("; "))
        else:
            lines.append(f"  {where}: {err.get('msg')} (got {_value(err.get('input'))})")
    n = len(lines)
    return f"{source}: {n} problem{'s' if n != 1 else ''}:\n" + "\n".join(lines)
