"""The slip gate: from the observer's output, each wheel's slip (eq. 1 with the floor and deadband of
docs/method.md §6, §10, in its direction of travel, §17), the traction it is compared with, their
uncertainties, the low-pass slip the soil gate decides on (``gate_smoothing``: gating on the raw, noisy
slip keeps the samples whose noise pushed |S| up and biases K, §9), a slow stream's refresh pairs, and
the wheels the longitudinal model describes now (:mod:`soilocp.estimation.wheel_usability`'s codes),
for N vehicles.

The gate runs in the compiled core (``soilocp._core.SlipGateBank``, soilocp/_core/src/soil/gate.rs, one
call per step); this module packs the observer's output into the one array the core reads and keeps
the settings.  The soil stage runs the gate and the soil update in one core call (the chain's
``update``, :class:`soilocp.estimation.estimator.Estimator`); :meth:`SlipGate.step` alone serves the
paper method and the tests.
"""

from __future__ import annotations

from itertools import chain
from operator import attrgetter

import numpy as np

from soilocp.schemas.pipeline import ObserverOutput

from soilocp import _core
from soilocp.estimation.observer_bank import (BOOL_FLAT_FIELDS, BOOL_QUAD_FIELDS, FLAT_FIELDS, LIFT_OFF_FORCE, QUAD_FIELDS,
                                             ObserverBlocks)
from soilocp.estimation.soil_state import SoilInputs
from soilocp.estimation.settings_model import core_values
from soilocp.estimation.wheel_usability import UsabilityLimits

__all__ = ["GATE_FIELDS", "SlipGate", "pack_message", "pack_output"]

#: The observer rows the gate reads, in the order of a packed row, named by the core (soilocp/_core/src/soil/gate.rs):
#: per-wheel rows (four numbers each), then per-vehicle ones (bools as 0 / 1)
GATE_QUADS = tuple(getattr(_core.SlipGateBank, "quad_fields", ()))
GATE_SCALARS = tuple(getattr(_core.SlipGateBank, "scalar_fields", ()))
GATE_FIELDS = GATE_QUADS + GATE_SCALARS
# each column's row in the observer's blocks, floats then bools (pack_output); every observer row is the
# ObserverOutput field of its name (observer_bank checks it), so pack_message reads the same names.
# ImportError, not assert: a mis-packed row must not pass silently under python -O
_quad_rows, _flat_rows = QUAD_FIELDS + BOOL_QUAD_FIELDS, FLAT_FIELDS + BOOL_FLAT_FIELDS
if not (set(GATE_QUADS) <= set(_quad_rows) and set(GATE_SCALARS) <= set(_flat_rows)
        and min(len(GATE_QUADS), len(GATE_SCALARS)) >= 2
        and getattr(_core.SlipGateBank, "columns", 0) == 4 * len(GATE_QUADS) + len(GATE_SCALARS)):
    raise ImportError(f"soilocp._core's gate columns {GATE_QUADS} / {GATE_SCALARS} are not observer rows of their kind "
                      f"({_quad_rows} / {_flat_rows}), or fewer than two of a kind: rebuild the core (make setup)")
_QUAD_ROWS = np.array([_quad_rows.index(f) for f in GATE_QUADS])
_FLAT_ROWS = np.array([_flat_rows.index(f) for f in GATE_SCALARS])
# pack_message's two reads of a message: its quads' tuples, then its scalars (attrgetter of two names or more
# returns a tuple; the core names 19 and 6)
_quads_of, _scalars_of = attrgetter(*GATE_QUADS), attrgetter(*GATE_SCALARS)


def pack_output(ob: ObserverBlocks) -> np.ndarray:
    """The observer's output for k vehicles as the gate's packed rows (k, ``SlipGateBank.columns``), read from
    its blocks."""
    quads = np.concatenate((ob.quads, ob.bool_quads))[_QUAD_ROWS]  # (columns' quads, k, 4), bools as 0 / 1
    flats = np.concatenate((ob.flats, ob.bool_flats))[_FLAT_ROWS]
    k = flats.shape[1]
    return np.concatenate((quads.transpose(1, 0, 2).reshape(k, -1), flats.T), axis=1)


def pack_message(obs: ObserverOutput) -> tuple:
    """One ObserverOutput message as the gate's packed row: a flat tuple of ``SlipGateBank.columns`` numbers,
    which the core reads as it is (a numpy array of these mixed floats and bools costs 3x the tuple)."""
    return (*chain(*_quads_of(obs)), *_scalars_of(obs))


class SlipGate:
    """The slip gate of N vehicles (module doc): ``soilocp._core.SlipGateBank`` with the pipeline's settings."""

    def __init__(self, config, n_vehicles: int, limits: UsabilityLimits = UsabilityLimits()):
        v, soil = config.vehicle, config.soil
        wheel_y = tuple(float(y) for y in np.asarray(v.wheel_y, dtype=float).reshape(4))
        params = dict(
            wheel_radius=v.wheel_radius,
            half_track=0.5 * (v.c + v.d),
            static_load=v.mass * config.observer.gravity / 4.0,
            # skid-steer: the two wheels of a side carry one torque measurement, so each counts half
            shared=2.0 if v.drive == "per_side" else 1.0,
            lift_off_force=LIFT_OFF_FORCE,
            slip_deadband=config.slip_deadband, slip_floor=config.slip_floor,
            **core_values(soil, "soil"), **core_values(limits, "usability"),
        )
        self.core = _core.SlipGateBank(int(n_vehicles), wheel_y, soil.measurement == "gross",
                                       {k: float(x) for k, x in params.items()})

    def step(self, ix: np.ndarray, stamp: np.ndarray, ob: ObserverBlocks | np.ndarray | tuple) -> SoilInputs:
        """ix (k,) vehicle indices, stamp (k,) s, and the observer's output for them (or its packed rows:
        :func:`pack_output`'s array, or :func:`pack_message`'s tuple for one vehicle)."""
        rows = pack_output(ob) if isinstance(ob, ObserverBlocks) else ob  # the blocks are a tuple too: tested for first
        return SoilInputs(*self.core.step(np.asarray(ix, dtype=np.int64), np.asarray(stamp, dtype=float), rows))
