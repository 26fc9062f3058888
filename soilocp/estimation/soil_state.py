"""What one step of the soil-strength estimator takes and gives (:class:`SoilInputs`, :class:`SoilState`)
and the soil classes of a K belief (docs/method.md §4, §9, §11-13)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from soilocp import _core
from soilocp.estimation.soil_config import Status
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants


@dataclass(frozen=True)
class SoilState:
    """What an estimator reports after each step: K is a belief's median (the no-change belief's until
    the data take a terrain change, docs/method.md §9), soil_strength_std and log_k_std half the
    pooled belief's 16-84 % interval (in K and in ln K) with the systematic terms."""

    soil_strength: Optional[float]
    soil_strength_std: Optional[float]
    log_k_std: Optional[float]
    soil_class: Optional[str]
    soil_class_confidence: Optional[float]
    status: Status
    reason: str
    last_update_stamp: Optional[float]
    used: tuple[bool, bool, bool, bool]
    #: s since the last informative update when K is reported (0: this sample informed it); None: no K
    held_for_s: Optional[float] = None
    #: per wheel: why the longitudinal model does not describe it now (soilocp.estimation.wheel_usability), '' usable
    unusable: tuple[str, str, str, str] = ("", "", "", "")
    #: the reason's machine-readable code (soilocp.schemas.pipeline.REASON_CODES; "none": no reason)
    reason_code: str = "none"


_CLASS_BOUNDS: dict[tuple, tuple[list[str], np.ndarray]] = {}  # per soil table: classify runs every sample


def class_bounds(constants: ModelConstants) -> tuple[list[str], np.ndarray]:
    """Soil classes ordered by K and their boundaries in ln K (geometric means of neighbours).

    The weakest class starts at half its reference K: below that no class applies (the traction
    constants were fitted on the reference soils; a K far under the weakest is an extrapolation,
    typically a wrong torque scale), so that mass counts for no class.  Computed once per soil
    table (``classify`` runs on every sample)."""
    key = tuple(constants.soils.items())
    hit = _CLASS_BOUNDS.get(key)
    if hit is None:
        names = sorted(constants.soils, key=constants.soils.get)
        logs = np.log([constants.soils[n] for n in names])
        edges = np.concatenate([[logs[0] - math.log(2.0)], (logs[:-1] + logs[1:]) / 2.0, [np.inf]])
        edges.flags.writeable = False
        hit = _CLASS_BOUNDS[key] = (names, edges)
    return list(hit[0]), hit[1]


def _row(a) -> np.ndarray:
    """A 1-D float array, the argument itself where it is one (the core reads a view's base: slower)."""
    a = np.asarray(a, dtype=float)
    return a if a.ndim == 1 else a.reshape(-1)


def classify(soil_strength: float, log_k_std: float, constants: ModelConstants = DEFAULT_CONSTANTS) -> tuple[str, float]:
    """Most probable soil class for ln K ~ N(ln K, sigma^2), and its probability (:func:`classify_many`)."""
    names, conf = classify_many(np.array([math.log(soil_strength)]), np.array([log_k_std]), constants)
    return names[0], float(conf[0])


def classify_many(log_k: np.ndarray, log_k_std: np.ndarray,
                  constants: ModelConstants = DEFAULT_CONSTANTS, bounds=None) -> tuple[list[str], np.ndarray]:
    """For n beliefs ln K ~ N(log_k, log_k_std^2) (n,): the most probable soil class of each and its
    probability (the Gaussian's mass between the class boundaries of :func:`class_bounds`; the compiled
    core's soil/classes.rs, with the C library's erf, as math.erf).  ``bounds``: ``class_bounds(constants)``,
    when the caller holds them (else looked up by the soil table, on every call)."""
    names, edges = class_bounds(constants) if bounds is None else bounds
    i, conf = _core.soil_classes(_row(log_k), _row(log_k_std), edges)
    return [names[j] for j in i.tolist()], conf


@dataclass
class SoilInputs:
    """What the soil update takes for k vehicles, from the observer's outputs (:class:`soilocp.estimation.slip_gate.SlipGate`):
    arrays (k, 4) unless marked; one struct, passed whole (:meth:`soilocp.estimation.soil_strength.SoilBank.update`)."""

    slip: np.ndarray  # eq. 1 at each wheel's ground speed V - psi_dot y_i
    informative: np.ndarray
    observed: np.ndarray
    variance: np.ndarray
    slip_sigma: np.ndarray
    gate_slip: np.ndarray  # the low-pass slip the gate decides on (docs/method.md §9)
    gate_sigma: np.ndarray
    held: np.ndarray  # no new speed and torque reading of the wheel now (SoilConfig.fresh_age)
    ground_stale: np.ndarray  # (k,) the ground speed's last reading is older than SoilConfig.max_input_age
    identifiable: np.ndarray  # (k,) False without an independent ground speed (slip, eq. 1, needs it)
    speed: np.ndarray  # (k,) filtered ground speed, m/s: the distance over which the soil may change
    span: np.ndarray | None  # (k, 4) s a wheel's pair stands for: a refresh interval (0: the sample's own; None: none)
    slip_ends: np.ndarray | None  # (k, 4, 2) a refresh pair's slip at its interval's start and end (None: no pair)
    unusable: np.ndarray | None = None  # (k, 4) int: soilocp.estimation.wheel_usability's code (0: usable)

    def arrays(self, k: int) -> SoilInputs:
        """These inputs of k vehicles as the core reads them (float64 / bool arrays of their shapes: the soil
        core's ``SoilGridBank.step`` takes the struct whole); ValueError naming a malformed or non-finite
        slip, observed, variance or slip_sigma."""
        f64, flag = (lambda a: np.asarray(a, dtype=float)), (lambda a: np.asarray(a, dtype=bool))
        quads = {}
        for name in ("slip", "observed", "variance", "slip_sigma"):
            a = f64(getattr(self, name))
            if a.shape != (k, 4) or not np.isfinite(a).all():
                raise ValueError(f"{name} must be a finite array of shape ({k}, 4), got {a!r}")
            quads[name] = a
        return SoilInputs(
            informative=flag(self.informative), gate_slip=f64(self.gate_slip), gate_sigma=f64(self.gate_sigma),
            held=flag(self.held), ground_stale=flag(self.ground_stale).reshape(k),
            identifiable=flag(self.identifiable).reshape(k), speed=f64(self.speed).reshape(k),
            span=None if self.span is None else f64(self.span),
            slip_ends=None if self.slip_ends is None else f64(self.slip_ends), unusable=self.unusable, **quads)
