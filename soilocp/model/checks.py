"""Argument checks shared by the physics functions.

Every public physics function rejects bad input with a ValueError that names the argument, the
offending value and the reason, instead of letting a NaN propagate silently.
"""

from __future__ import annotations

import numpy as np


def _describe(value) -> str:
    arr = np.asarray(value)
    if arr.ndim == 0:
        return repr(arr.item()) if arr.dtype.kind in "biuf" else repr(value)
    bad = arr.ravel()[:4]
    return f"array of shape {arr.shape} (first values {bad.tolist()})"


def as_float_array(name: str, value, *, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """Convert to a float ndarray, rejecting non-numeric input, NaN/inf and (optionally) wrong shapes."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {value!r}") from exc
    if shape is not None:
        if arr.ndim != len(shape) or any(s not in (-1, n) for s, n in zip(shape, arr.shape)):
            want = "x".join("N" if s == -1 else str(s) for s in shape) or "scalar"
            raise ValueError(f"{name} must have shape ({want}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {_describe(value)}")
    return arr


def positive(name: str, value, *, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A finite, strictly positive array (e.g. soil strength K, masses, lengths)."""
    arr = as_float_array(name, value, shape=shape)
    if np.any(arr <= 0):
        raise ValueError(f"{name} must be > 0, got {_describe(value)}")
    return arr


def finite_scalar(name: str, value) -> float:
    arr = as_float_array(name, value)
    if arr.ndim != 0:
        raise ValueError(f"{name} must be a scalar, got shape {arr.shape}")
    return float(arr)


def positive_scalar(name: str, value) -> float:
    v = finite_scalar(name, value)
    if v <= 0:
        raise ValueError(f"{name} must be > 0, got {v!r}")
    return v


def check_count(n: object) -> int:
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
        raise ValueError(f"n_vehicles {n!r} is invalid: must be an integer >= 1")
    return int(n)


def check_index(idx, n: int) -> np.ndarray:
    """``idx`` as a 1-D integer array of distinct vehicle indices in [0, n); ValueError otherwise."""
    if type(idx) is np.ndarray and idx.shape == (1,) and idx.dtype == np.int64 and 0 <= idx[0] < n:
        return idx  # one vehicle's step: the common call, checked without a reduction
    ix = np.asarray(idx)
    if ix.ndim != 1 or ix.size == 0 or not np.issubdtype(ix.dtype, np.integer):
        raise ValueError(f"idx {idx!r} is invalid: need a non-empty 1-D array of vehicle indices")
    if ix.min() < 0 or ix.max() >= n:
        raise ValueError(f"idx {idx!r} is invalid: indices must be in [0, {n - 1}]")
    if ix.size > 1 and len(set(ix.tolist())) != ix.size:
        raise ValueError(f"idx {idx!r} is invalid: a vehicle can be stepped only once per call")
    return ix
