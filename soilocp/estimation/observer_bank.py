"""The traction observer: N vehicles' Kalman filters, stepped together, k of them at a time.

One implementation serves every caller: the single-vehicle stage (:mod:`soilocp.estimation.pipeline`, N = 1)
and the batched service (:mod:`soilocp.estimation.batch`, N = many).  The whole step runs in the compiled
core, ``soilocp._core.ObserverCore`` (soilocp/_core/src/observer/), one call per step for the k vehicles
stepped: the readings clock (``readings.rs``: which readings are new, docs/method.md §13), the per-side torque
split and the encoder lead (``wheel_inputs.rs``, §14), the ground-speed latency (``latency.rs``, §13), the
filter (the model below, predict, the gated update, re-anchoring, conditioning, resets, the divergence guard;
``bank.rs``) and the refresh pairs of slow streams (``intervals.rs``, §13), with every vehicle's state of each.
The core keeps the observer's clock (dt, dt^3 and the latency fit's exponentials, by libm).  This module
checks the call's inputs and returns the core's output blocks with their rows named by the core
(:class:`ObserverBlocks`), of which :func:`observer_message` makes the ObserverOutput message.  The tests
check it against filterpy's KalmanFilter and plain numpy references (tests/reference_observer.py), step by
step.

Model (paper eqs. 11-15, 26-35, corrected; the state layout is :class:`soilocp.estimation.observer.StateLayout`)
-------------------------------------------------------------------------------------------------
    omega_i_dot = (T_i - R_w (mu_i + mu_xR_i) Fz_i) / I_w      (eqs. 13-15; mu + mu_xR = gross)
    V_dot       = sum(mu_i Fz_i) / m + g sin(pitch) - bias       (longitudinal; REP-103 pitch)
    psi_ddot    = [d(Fx3 + Fx4) - c(Fx1 + Fx2) - M_zR] / I_z      (eqs. 11-12), Fx_i = mu_i Fz_i
    z = [f_x = sum(mu_i Fz_i)/m (eq. 29, docs/method.md §3), psi_dot, omega_1..4, V]

* Motion resistance (docs/method.md §11): eq. 4 is even in slip, so the ``slip`` structure models
  mu_xR_i = d_i (r0 b(S_i) + r1 |S_i|), with b the zero-slip bridge of :mod:`soilocp.model.traction` and
  d_i the wheel's travel direction (smoothed over ``travel_speed``).  The old form
  r0 sgn(S) + r1 S flipped the resistance on braking wheels and biased K 20-30 % low.
* ZOH (eq. 34): A is nilpotent (A @ A = 0), so F = I + A dt, G = b dt + A b dt^2/2 and
  Q_d = Q dt + (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3 exactly.
* Update (eq. 35 misprints its indices): standard Kalman update in Joseph form; a measurement row
  whose innovation exceeds ``gate_sigma`` is removed by zeroing its H row and innovation (its gain
  column is then exactly zero), and is taken again after ``gate_patience`` rejections in a row.
* Conditioning and bounds (docs/method.md §12: a net traction coefficient of 3 is not a soil):
  P is symmetrised, its variances clamped and its correlations kept inside (-1, 1); the traction
  and resistance states are projected into physical bounds (``ObserverConfig.mu_bound`` ...).
* Divergence: a non-finite or out-of-physics state resets that vehicle's filter with a counted
  reason (``resets_by_reason``); the next samples are processed normally.
* Skid-steer (``VehicleParams.drive == "per_side"``): the two wheels of a side share one motor, so
  the side's torque (logged as half on each wheel) is split between them by normal force, each
  keeping its own inertia torque, and each side's one speed measurement counts once (its two rows
  carry twice the variance).  Encoder speeds that are interval means (vehicle
  ``wheel_speed_reading``) are led by omega_dot tau / 2 (soilocp/_core/src/observer/wheel_inputs.rs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from soilocp.schemas.pipeline import BoolQuad, ObserverOutput, Quad

from soilocp._core import ObserverCore
from soilocp.estimation.core_attribute import core_attribute
from soilocp.estimation.observer import ObserverConfig, StateLayout
from soilocp.estimation.observer_config import Structure
from soilocp.estimation.settings_model import core_values
from soilocp.model.checks import check_count, check_index
from soilocp.model.constants import DEFAULT_CONSTANTS, STANDARD_GRAVITY
from soilocp.model.vehicle import VehicleParams

#: Normal force (N) below which a wheel is treated as lifted off: no traction information.
LIFT_OFF_FORCE = ObserverCore.lift_off_force

RESET_REASONS = tuple(ObserverCore.reset_reasons)


_FIELDS_K = ("stamp", "specific_force_x", "yaw_rate", "pitch", "ground_speed")
_FIELDS_K4 = ("wheel_speed", "wheel_torque", "normal_force")


@dataclass
class ObserverInputs:
    """One sensor sample per stepped vehicle, stacked: shapes (k,) or (k, 4)."""

    stamp: np.ndarray
    specific_force_x: np.ndarray
    yaw_rate: np.ndarray
    pitch: np.ndarray
    wheel_speed: np.ndarray
    wheel_torque: np.ndarray
    ground_speed: np.ndarray  # NaN: no independent ground-speed sensor (slip and K not identifiable)
    normal_force: np.ndarray  # as computed by the normal-force stage (the core clamps it to LIFT_OFF_FORCE)

    def check(self) -> int:
        """k, the number of vehicles, after checking every field's shape ((k,) or (k, 4)), dtype and
        finiteness (the ground speed may be NaN: absent); ValueError naming the field otherwise.  Fields
        that are not float arrays are converted.  (``ObserverBank.step`` leaves the check of float arrays
        to the core, which words its errors alike, and calls this for anything else.)"""
        st = self.stamp
        k = st.shape[0] if type(st) is np.ndarray and st.ndim == 1 else -1
        # happy path: float arrays of the right shapes, all finite but the ground speed's NaN, in
        # one test; anything else takes the field-by-field check below, which names the field
        flat = (st, self.specific_force_x, self.yaw_rate, self.pitch, self.ground_speed)
        quads = (self.wheel_speed, self.wheel_torque, self.normal_force)
        if k >= 0 and all(type(a) is np.ndarray and a.dtype == np.float64 and a.shape == (k,) for a in flat) \
                and all(type(a) is np.ndarray and a.dtype == np.float64 and a.shape == (k, 4) for a in quads):
            if np.isfinite(np.concatenate([*flat[:4], *quads], axis=None)).all() \
                    and not np.isinf(flat[4]).any():
                return k
        for name in _FIELDS_K:
            a = np.asarray(getattr(self, name), dtype=float)
            # a NaN ground speed means "no independent sensor" (the log's null); nothing else may be NaN
            ok = np.isfinite(a) | (np.isnan(a) if name == "ground_speed" else False)
            if a.shape != (k,) or not np.all(ok):
                raise ValueError(f"inputs.{name} must be a finite array of shape ({k},), got {a!r}")
            setattr(self, name, a)
        for name in _FIELDS_K4:
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (k, 4) or not np.all(np.isfinite(a)):
                raise ValueError(f"inputs.{name} must be a finite array of shape ({k}, 4), got {a!r}")
            setattr(self, name, a)
        return k


#: The rows of the core's four output blocks, named by the core (soilocp/_core/src/py/observer.rs), in its
#: order: floats (k, 4) and (k,), bools (k, 4) and (k,).  Each row is the ObserverOutput field of the same name
#: and kind (checked below), so a row the core adds reaches the message, or the import fails.
BLOCK_FIELDS = tuple(tuple(names) for names in ObserverCore.block_fields)
QUAD_FIELDS, FLAT_FIELDS, BOOL_QUAD_FIELDS, BOOL_FLAT_FIELDS = BLOCK_FIELDS
#: Every core row by name: (block, row)
ROWS = {name: (b, r) for b, names in enumerate(BLOCK_FIELDS) for r, name in enumerate(names)}
# ObserverOutput's fields that are no core row: the envelope, the two made from the step's last two arrays
# (rejections, reset codes) and those the stage adds (the torque scale, the sample's position)
_NOT_ROWS = {"schema_version", "vehicle_id", "seq", "stamp", "rejected_measurements", "reset_reason", "torque_scale",
             "torque_scale_std", "position", "geo"}


def _check_rows() -> None:
    # ImportError, not assert: a row that misses the message (or lands in the wrong kind) must not pass under -O
    fields = ObserverOutput.model_fields
    kinds = (Quad, float, BoolQuad, bool)
    wrong = [f"{name} ({kinds[b]}, message: {fields[name].annotation if name in fields else 'none'})"
             for name, (b, _) in ROWS.items() if name not in fields or fields[name].annotation != kinds[b]]
    unfed = sorted(set(fields) - set(ROWS) - _NOT_ROWS)
    twice = len(ROWS) != sum(map(len, BLOCK_FIELDS))
    if twice or wrong or unfed:
        raise ImportError(f"soilocp._core's observer rows and soilocp.schemas.pipeline.ObserverOutput disagree: rows without "
                          f"their message field {wrong}, message fields without a row {unfed}"
                          f"{', a row name in two blocks' if twice else ''}: rebuild the core (make setup), or follow "
                          f"its rows in the message")


_check_rows()


class ObserverBlocks(NamedTuple):
    """The observer's output for k vehicles as the core's step returns it: four blocks whose rows the core names
    (``BLOCK_FIELDS``), the rejections and the reset codes.  Each row reads by its name, a view of its block
    (``out.mu`` (k, 4), ``out.ground_speed`` (k,), ``out.reset_reason`` the codes' words); :func:`observer_message`
    makes the j-th vehicle's ObserverOutput of it and :func:`soilocp.estimation.slip_gate.pack_output` the
    gate's rows."""

    quads: np.ndarray  # (len(QUAD_FIELDS), k, 4) float
    flats: np.ndarray  # (len(FLAT_FIELDS), k) float
    bool_quads: np.ndarray  # (len(BOOL_QUAD_FIELDS), k, 4) bool
    bool_flats: np.ndarray  # (len(BOOL_FLAT_FIELDS), k) bool
    rejected: np.ndarray  # (k,) int: measurement rows dropped by the innovation gate this step
    codes: np.ndarray  # (k,) reset codes: 0 none, else RESET_REASONS[code - 1]

    @property
    def reset_reason(self) -> list[str]:
        """The reset reasons (k,), "" where there was none."""
        return [RESET_REASONS[c - 1] if c else "" for c in self.codes.tolist()]

    def __getattr__(self, name: str) -> np.ndarray:
        """The row ``name`` of its block (a view): its meaning is the ObserverOutput field of the same name."""
        try:
            block, row = ROWS[name]
        except KeyError:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute or observer row {name!r}") from None
        return self[block][row]


# a row named like a block or a tuple method would be hidden by it (ObserverBlocks.__getattr__ sees only the names
# the class lacks); ImportError, not assert, as above
_shadowed = sorted(name for name in ROWS if hasattr(ObserverBlocks, name))
if _shadowed:
    raise ImportError(f"soilocp._core's observer rows {_shadowed} shadow ObserverBlocks attributes of the same names")


def observer_message(vehicle_id: str, seq: int, stamp: float, out: ObserverBlocks, j: int,
                     torque_scale: float = 1.0, torque_scale_std: float | None = None, place=None) -> ObserverOutput:
    """The j-th vehicle of an observer step (eqs. 26-35: the posterior's traction, resistance and speeds, with the
    readings clock, latency and refresh pairs of docs/method.md §13) as the ObserverOutput message, every row as
    the field of its name, with the online torque scale the torques were multiplied by and its relative 1-sigma
    (None: the state is off); ``place``: the sample whose position and geo it passes on (None: none)."""
    quads, flats, bool_quads, bool_flats, rejected, codes = out
    # one tolist per block (a (len, 4) view for vehicle j) and tuples, which pydantic takes for the Quad
    # fields without a conversion
    rows = dict(zip(QUAD_FIELDS, map(tuple, quads[:, j].tolist())))
    rows.update(zip(FLAT_FIELDS, flats[:, j].tolist()))
    rows.update(zip(BOOL_QUAD_FIELDS, map(tuple, bool_quads[:, j].tolist())))
    rows.update(zip(BOOL_FLAT_FIELDS, bool_flats[:, j].tolist()))
    code = int(codes[j])
    rows.update(vehicle_id=vehicle_id, seq=seq, stamp=stamp, rejected_measurements=int(rejected[j]),
                reset_reason=RESET_REASONS[code - 1] if code else "", torque_scale=torque_scale,
                torque_scale_std=torque_scale_std)
    if place is not None:
        rows.update(position=place.position, geo=place.geo)
    # the model's validator on the fields (what ObserverOutput(**rows) runs, without the keyword call)
    return _validate_observer(rows)


_validate_observer = ObserverOutput.__pydantic_validator__.validate_python


class ObserverBank:
    """N traction observers stepped together (see the module doc).  ``step(idx, inputs)`` steps
    the vehicles ``idx`` (any subset, each at most once; None: all, in order); vehicles need not
    be in step.  Everything per sample runs in the compiled core (``soilocp._core.ObserverCore``,
    one call per step); this class checks the inputs and returns the core's blocks, named (:class:`ObserverBlocks`)."""

    def __init__(self, vehicle: VehicleParams, config: ObserverConfig | None, n_vehicles: int,
                 bridge_slip: float = DEFAULT_CONSTANTS.bridge_slip):
        """``bridge_slip``: the traction model's zero-slip bridge (:attr:`ModelConstants.bridge_slip`), which
        also bridges the constant part of eq. 4's motion resistance in the observer's model."""
        self.vehicle = vehicle
        self.cfg = cfg = config or ObserverConfig()
        self.n_vehicles = n = check_count(n_vehicles)
        self.layout = StateLayout.of(cfg.structure)
        v = vehicle
        self._core = ObserverCore(
            n, [v.mass, v.wheel_radius, v.wheel_inertia, v.yaw_inertia, v.a, v.b, v.c, v.d],
            [float(y) for y in v.wheel_y], core_values(cfg, "observer"), per_side=vehicle.drive == "per_side",
            interval_mean=vehicle.wheel_speed_reading == "interval_mean", bridge_slip=bridge_slip)

    # the core's state, as it holds it (each a copy)
    last_stamp = core_attribute(
        "last_stamp", "Each vehicle's last stamp (N,), NaN before its first sample: the core's clock (a copy).")
    x = core_attribute("x", "The states (N, n) (a copy).")
    P = core_attribute("P", "The covariances (N, n, n) (a copy).")
    rejections = core_attribute("rejections", "Consecutive gate rejections of each measurement row (N, 7) (a copy).")

    @property
    def resets_by_reason(self) -> dict[str, int]:
        """Resets so far, by reason (RESET_REASONS)."""
        return dict(zip(RESET_REASONS, self._core.resets))

    @property
    def anchored(self) -> int:
        """Wheel-speed states re-anchored to their reading at low speed (docs/method.md §17)."""
        return self._core.anchored

    def step(self, idx, inputs: ObserverInputs) -> ObserverBlocks:
        """One observer step (readings, predict / gated update (eq. 35, standard form), refresh pairs) for
        the vehicles ``idx`` (None: all), in one core call; ValueError naming a malformed input."""
        return ObserverBlocks(*self.run(self._core.step, None if idx is None else self.index(idx), inputs))

    def index(self, idx) -> np.ndarray:
        """``idx`` checked (ValueError: not distinct vehicle indices in range), as the core's int64 array."""
        ix = check_index(idx, self.n_vehicles)
        return ix if ix.dtype == np.int64 else ix.astype(np.int64)

    def run(self, call, ix: np.ndarray | None, inputs: ObserverInputs):
        """``call`` (the core's ``ObserverCore.step``, or a call that steps the observer inside it:
        ``ChainCore.step``) on the vehicles ``ix`` (:meth:`index`'s; None: all) and their inputs, which the
        core reads whole (float arrays; anything else is converted, or refused naming the field, by
        :meth:`ObserverInputs.check`).  Returns what ``call`` returns."""
        try:
            return call(ix, inputs)
        except TypeError:  # not float arrays: converted (or refused, naming the field) by the check, then again
            inputs.check()
            return call(ix, inputs)


def observability_rank(structure: Structure, vehicle: VehicleParams, fz=None, slips=None, tol: float = 1e-9) -> int:
    """Rank of the observability matrix [H_0; H_1 F_0; H_2 F_1 F_0; ...] of the discretised model, with the
    core's own A and H (``ObserverCore.model``, soilocp/_core/src/observer/model.rs) and F = I + A dt (eq. 34,
    exact: A is nilpotent).

    ``slips`` is a sequence of per-wheel slip vectors, one per step (cycled), for the ``slip``
    structure whose model varies with slip; by default a traction test's pattern.  With the
    paper's full state (``per_wheel``) the rank is below the state dimension (docs/method.md §7);
    ``slip``, ``shared`` and ``none`` are fully observable (``slip`` only while the wheels' slips
    vary, as in a traction test: at one constant slip pattern its two resistance coefficients
    merge into one).
    """
    layout = StateLayout.of(structure)
    core = ObserverBank(vehicle, ObserverConfig(structure=structure), 1)._core
    fz = np.full(4, vehicle.mass * STANDARD_GRAVITY / 4) if fz is None else np.asarray(fz, float)
    if slips is None:
        # a traction test: rear wheels (1, 4) sweep driving slip, front wheels (2, 3) brake
        slips = [(0.3, -0.1, -0.1, 0.3), (0.1, -0.05, -0.05, 0.1), (0.5, -0.2, -0.2, 0.5)]
    blocks, Phi = [], np.eye(layout.n)
    for k in range(layout.n):
        # the state whose wheels run at these slips (eq. 1) at 1 m/s straight ahead: the resistance map's prior
        s = np.asarray(slips[k % len(slips)], float)
        x = np.zeros(layout.n)
        x[layout.v] = 1.0
        x[layout.omega] = np.where(s >= 0, 1.0 / (1.0 - np.minimum(s, 0.99)), 1.0 + s) / vehicle.wheel_radius
        A, _, H = core.model(x.tolist(), fz.tolist(), [0.0] * 4, 0.0)
        blocks.append(H @ Phi)
        Phi = (np.eye(layout.n) + A * 0.01) @ Phi
    O = np.vstack(blocks)
    # scale rows so that the tolerance is relative
    O = O / np.maximum(np.linalg.norm(O, axis=1, keepdims=True), 1e-300)
    return int(np.linalg.matrix_rank(O, tol=tol))
