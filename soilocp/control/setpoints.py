"""Slip set-points: fixed, or an OCP (S_T, S_E) from the product's own live estimate.

:class:`OcpSetPoint` reads the :class:`soilocp.schemas.pipeline.OcpEstimate` the estimation chain
produced (never the simulator's truth) and falls back to a documented safe set-point whenever
the estimate cannot be acted on:

* no estimate yet, or ``S_T`` / ``S_E`` is null (K unknown: status ``no_estimate``);
* status ``stale`` (the live OCP publisher lost its input) or the estimate is older than
  ``stale_timeout_s`` (sample time, the estimate's stamp against the controller's clock);
* any status other than ``ok``, ``uncertain`` (K known to +-20 %: S_T moves by ~0.02 over
  that range, eq. 7) or ``holding`` (the last K, kept while the slip is uninformative).

The safe fallbacks, from the model constants, not tuned per soil:

* traction: S_T of the weakest reference soil (sand, K = 50 -> 0.26 with the paper's
  constants).  eq. 7 grows with K, so this slip is at or below the traction peak on every
  reference soil: on the stable, rising side of eq. 6, where more slip never loses pull;
* efficiency: S_E of the same weakest soil (eq. 10 falls with K, so 0.12 is the largest S_E
  of the reference soils: it never starves a weak soil of the slip it needs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional

from soilocp.schemas.pipeline import OcpEstimate

from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.ocp import ocp_from_soil_strength

#: Estimate statuses a set-point may be taken from (see the module docstring).
USABLE_STATUSES = frozenset({"ok", "uncertain", "holding"})

Source = Literal["fixed", "estimate", "fallback", "none"]


@dataclass(frozen=True)
class SetPoint:
    value: Optional[float]  #: slip set-point (None: no slip control)
    source: Source
    reason: str = ""
    soil_strength: Optional[float] = None  #: the K the set-point came from (estimate only)


class FixedSetPoint:
    """A constant slip set-point (rule of thumb 0.15, ABS-like 0.20)."""

    def __init__(self, value: float):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and 0.0 < value < 1.0):
            raise ValueError(f"fixed slip set-point must be in (0, 1), got {value!r}")
        self.value = float(value)

    def __call__(self, stamp: float, estimate: Optional[OcpEstimate]) -> SetPoint:
        return SetPoint(self.value, "fixed")


def fallback_slip(which: str, constants: ModelConstants = DEFAULT_CONSTANTS) -> float:
    """The safe set-point of :class:`OcpSetPoint` for ``which`` in (``S_T``, ``S_E``): the OCP of
    the weakest reference soil of ``constants`` (eq. 7 / eq. 10; see the module docstring)."""
    if which not in ("S_T", "S_E"):
        raise ValueError(f"which must be 'S_T' or 'S_E', got {which!r}")
    weakest = min(constants.soils.values())
    return float(getattr(ocp_from_soil_strength(weakest, constants), which))


class OcpSetPoint:
    """Set-point = the estimate's ``S_T`` or ``S_E``, or the safe fallback (module docstring)."""

    def __init__(self, which: str, *, stale_timeout_s: float = 0.5, constants: ModelConstants = DEFAULT_CONSTANTS,
                 fallback: Optional[float] = None, min_slip: float = 0.02):
        self.which = which
        self.fallback = fallback_slip(which, constants) if fallback is None else float(fallback)
        if not (math.isfinite(stale_timeout_s) and stale_timeout_s > 0):
            raise ValueError(f"stale_timeout_s must be > 0, got {stale_timeout_s!r}")
        if not 0.0 < self.fallback < 1.0:
            raise ValueError(f"fallback slip must be in (0, 1), got {self.fallback!r}")
        self.stale_timeout_s = float(stale_timeout_s)
        # S_E is 0 above K = alpha (eq. 10): a zero slip limit would stop the rover; keep a floor
        self.min_slip = float(min_slip)

    def __call__(self, stamp: float, estimate: Optional[OcpEstimate]) -> SetPoint:
        if estimate is None:
            return SetPoint(self.fallback, "fallback", "no estimate yet")
        if estimate.status not in USABLE_STATUSES:
            return SetPoint(self.fallback, "fallback", f"estimate status {estimate.status}: {estimate.reason}"[:200])
        age = stamp - estimate.stamp
        if age > self.stale_timeout_s:
            return SetPoint(self.fallback, "fallback",
                            f"estimate {age:.3f} s old (> stale_timeout_s {self.stale_timeout_s} s)")
        value = getattr(estimate, self.which)
        if value is None or not math.isfinite(value):
            return SetPoint(self.fallback, "fallback", f"{self.which} unknown (K not observable)")
        return SetPoint(min(max(value, self.min_slip), 0.95), "estimate", "", estimate.soil_strength)
