"""The torque scale learnt online: one common scale k of the wheel torques (motor constant x 1 /
mass), a slow state, from the longitudinal force balance whenever the robot accelerates or brakes
(docs/method.md §15).

Eq. TC (:func:`soilocp.model.force_balance.longitudinal_balance`, the function ``soilocp
calibrate-torque`` fits offline) holds for the means over a window: y = k x - F_MR with
x = sum T_log / R and y = m f_x + k^w I_w sum omega_dot / R (the inertia term's factor below).  Per vehicle the state is (k, F_MR), a
Kalman filter stepped once per window (``window`` s of samples, trapezoid means as the offline
fit's, cut at stamp gaps), where the balance holds with a slow F_MR (moving at >= ``min_speed``,
straight, every wheel's slip within ``max_slip``, finite):

* k: prior N(1, ``SoilConfig.gross_scale_sigma``), a random walk of ``scale_walk`` per sqrt(s);
* b: the motion resistance the model does not give (and an accelerometer bias times m), a random walk
  of ``resistance_walk`` N per sqrt(s), and a jump where the soil under the wheels changes: a window whose
  innovation is beyond ``resistance_jump`` of its sigmas returns b's (and c's) variance to its prior and informs them alone
  (a wrong k shifts the balance with the acceleration's sign, a jump of b does not, so a jump is taken only
  once windows of both signs have been fitted since b was last reset).  A jump's window is a mixed one (the
  axles cross the change one after the other): its b starts no contrast, and the adjoining window before it,
  which holds the change's first part, is taken back (docs/method.md §15, "A jump is a mixed window").
  The wheel-inertia term of the balance carries the payload's share of k, k^w, w = 1 - ``SoilConfig.gross_scale_sigma``^2 /
  ``TorqueScaleConfig.prior_sigma``^2 (docs/method.md §15, "The wheels' inertia under an unknown payload").  With ``model_resistance`` the
  resistance itself is modelled, not a state: eq. 4 at each sample's slips (eq. 1 from the readings),
  normal forces and the soil's K as the soil stage last reported it (the chain's ``feed``,
  :meth:`soilocp.estimation.estimator.Estimator.feed`, the K fed back; a median reference soil until then), :func:`soilocp.model.force_balance.modelled_resistance`,
  averaged over the window like the other terms.

Only a window whose mean acceleration (f_x less the gravity reaction of the pitch, eq. 20) reaches
``min_accel`` informs the state; any other informs nothing, so at constant speed k stays at its prior,
however long the drive.  The resistance in the balance is b + c |a|: c (prior ``resistance_slope_sigma``, reset
with b at a jump) is its growth with the window's |a|, eq. 4's resistance at the slips that accelerating and
braking alike take, even in a, so that windows at different |a| (a start ramp, a gentle swing) do not read
their resistances' difference as k (docs/method.md §15, "Gentle swings").  And k moves only once windows of
both signs (accelerating and braking) have been
fitted since F_MR was last reset (the prior or a jump): a force that does not flip sign with the
acceleration (a draft growing with the speed of a start from rest, the resistance at a sweep's slips)
shifts the windows of one sign alike, and only the contrast of the two tells it from k.  Until then a
shadow posterior lets those windows inform k, and becomes the state at the first window of the other sign.
The torques the observer sees are the logged ones times k's mean, and the soil
estimator's scale prior becomes k's relative posterior 1-sigma (:class:`soilocp.estimation.soil_strength.SoilBank`,
``scale_sigma``): K's band includes the scale's posterior.

The per-sample kernel (the window means, the Kalman update and its Schmidt form, eq. 1, eq. 4 summed, eq. 20
and eq. TC) is the compiled core's (``soilocp/_core/src/torque_scale/``, ``soilocp._core.TorqueScaleCore``),
one call per step for the vehicles stepped: the single-vehicle stage and the batched path run the same
kernel.  This module keeps the configuration and a thin bank over the core.
"""

from __future__ import annotations

import numpy as np

from soilocp import _core
from soilocp.model.constants import DEFAULT_CONSTANTS, STANDARD_GRAVITY, ModelConstants
from soilocp.estimation.settings_model import core_values
from soilocp.estimation.torque_scale_config import TorqueScaleConfig
from soilocp.model.slip import DEFAULT_FLOOR
from soilocp.model.vehicle import VehicleParams


class TorqueScaleBank:
    """N vehicles' torque scales (module doc), their state in the core, which the estimator's chain
    (``soilocp._core.ChainCore``) steps with the observer: one sample per vehicle in a step, the observer's inputs."""

    def __init__(self, vehicle: VehicleParams, cfg: TorqueScaleConfig, prior_sigma: float, n_vehicles: int,
                 constants: ModelConstants = DEFAULT_CONSTANTS, *, slip_floor: float = DEFAULT_FLOOR,
                 gravity: float = STANDARD_GRAVITY):
        """``slip_floor``: eq. 1's floor (the pipeline's ``slip_floor``, which the slip gate reads too);
        ``gravity``: m/s^2, the balance's slope term (the observer's ``gravity``)."""
        self.vehicle, self.cfg, self.prior_sigma, self.constants = vehicle, cfg, float(prior_sigma), constants
        # the state's own prior (wider where the mass is as uncertain as the motor constant); the soil estimator's
        # band keeps prior_sigma until a window informs k
        wider = cfg.enabled and cfg.prior_sigma is not None and prior_sigma > 0
        self.state_sigma = float(cfg.prior_sigma) if wider else self.prior_sigma
        self.active = cfg.enabled and self.prior_sigma > 0
        # the soil's K for eq. 4's resistance until the soil stage reports one (the chain's feed): the median reference
        # soil (the resistance of an unknown soil, within +-30 N of the truth on the reference soils)
        self.k_default = float(np.median(list(constants.soils.values())))
        self._n = n_vehicles
        # an inactive bank (disabled, or no prior) has no state: k = 1 +- prior_sigma always
        self._core = None if not self.active else _core.TorqueScaleCore(
            constants.kernel, n_vehicles, vehicle.mass, vehicle.wheel_inertia, vehicle.wheel_radius,
            core_values(cfg, "torque_scale"), state_sigma=self.state_sigma, prior_sigma=self.prior_sigma,
            k_default=self.k_default, slip_floor=float(slip_floor), gravity=float(gravity),
            model_resistance=bool(cfg.model_resistance))

    @property
    def theta(self) -> np.ndarray:
        """(k, F_MR) of every vehicle, (N, 2)."""
        if not self.active:
            return np.tile([1.0, 0.0], (self._n, 1))
        return self._core.theta

    @property
    def P(self) -> np.ndarray:  # noqa: N802 (the covariance's usual name)
        """Their covariances, (N, 2, 2)."""
        if not self.active:
            return np.tile(np.diag([self.state_sigma**2, self.cfg.resistance_sigma**2]), (self._n, 1, 1))
        return self._core.p

    def band_sigma(self, sd) -> np.ndarray:
        """k's 1-sigma for K's band: the windows' information about k (the state's posterior precision less its
        prior's, ``state_sigma``) combined with the torque constant's prior ``prior_sigma``
        (``soil.gross_scale_sigma``); with ``state_sigma`` = ``prior_sigma`` the state's posterior itself (the
        core's ``band_sigma``).  A wider state prior lets the balance move k as far as the data say (a payload
        the vehicle file does not know: 0.80), while a start ramp's one window, which hardly informs k, leaves
        K's band at the torque constant's prior instead of widening it to the state's."""
        sd = np.asarray(sd, dtype=float)
        if self.state_sigma == self.prior_sigma:
            return sd
        return self._core.band_sigma(sd.reshape(-1)).reshape(sd.shape)

    def scale(self, ix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """k's posterior mean and 1-sigma for the vehicles ``ix``."""
        ix = np.asarray(ix, dtype=np.int64)
        if not self.active:
            return np.ones(ix.size), np.sqrt(np.full(ix.size, self.state_sigma**2))
        return self._core.scale(ix)
