"""The traction observer's configuration, state layout and observability (paper eqs. 11-15 and 26-35).

The observer itself runs in the compiled core (soilocp/_core/src/observer/, behind
:class:`soilocp.estimation.observer_bank.ObserverBank`); its numpy / filterpy reference is the tests'
(tests/reference_observer.py).

State and observability (docs/method.md §7)
-----------------------------------------
The paper's state (eq. 26) is [mu_1..4, mu_xR_1..4, mu_yR_1..4, psi_dot, omega_1..4] with
measurements [V_x_dot, psi_dot, omega_1..4] (eq. 28).  It is not observable: each wheel equation
(eq. 13) sees only mu_i + mu_xR_i, the accelerometer (eq. 29) sees sum(mu_i Fz_i), and the yaw
equation (eq. 11) one more mix, so 17 states face 6 independent measurement directions and the
observability matrix has rank 10 (see :func:`soilocp.estimation.observer_bank.observability_rank`).

``structure="shared"`` makes the estimate determined: one longitudinal resistance coefficient mu_xR
shared by the four wheels (the wheels run on the same soil at similar slip), and one lateral
coefficient mu_yR.  Then the wheel equations give mu_i + mu_xR, the accelerometer gives
sum(mu_i Fz_i), hence mu_xR and every mu_i: full rank.  The default ``structure="slip"`` gives the
shared resistance eq. 4's form, a constant and a slope in each wheel's slip (mu_xR_i = a + b S_i),
which the wheels' different slips determine as well.  We also add the CoM speed V as a state,
driven by the same net traction (V_dot = sum(mu_i Fz_i)/m + g sin(pitch)) and measured by
ground_speed: that smooths the slip of eq. 1 with the physics instead of a low-pass filter; and a
slowly varying bias of that speed equation (accelerometer bias, g x pitch bias), which the ground
speed makes observable and which would otherwise turn into a slip bias.

``structure="none"`` drops motion-resistance compensation (mu_i absorbs mu_xR: the paper's
Figs. 11 and 13), ``structure="per_wheel"`` keeps the paper's full state (made well-posed only by
its prior; reported rank-deficient).

Corrections to the print
------------------------
* Eq. 29's V_x_dot is the accelerometer's specific force f_x (docs/method.md §3): sum(mu_i Fz_i)/m
  is a specific force, which is why it has no slope term.
* Eq. 35 mixes indices (P_k with M_k+1); we use the standard predict/update (filterpy's, in the
  tests' reference) with the Joseph-form covariance update, re-symmetrised and with variances clamped (as robot_localization
  does), and per-row innovation (Mahalanobis) gating.
* Eqs. 33-34: A(t) and B(t) are rebuilt each step from the current normal forces and torques and
  discretised by zero-order hold.  A is nilpotent (A @ A = 0: traction coefficients drive speeds,
  speeds drive nothing), so the ZOH of the augmented system is exactly F = I + A dt, G = b dt
  and the process noise Q_d = Q dt + (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3; the tests' reference computes
  the same by the matrix exponential (Van Loan) for checking.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from soilocp.estimation.observer_config import ObserverConfig, Structure  # noqa: F401 (re-exported)


@dataclass(frozen=True)
class StateLayout:
    """Index map of the observer state for a given structure, as the compiled core lays it out
    (soilocp/_core/src/observer/layout.rs, its one definition): the traction coefficients mu_1..4, the
    longitudinal resistance states (2 for ``slip``: constant and slope; 1 ``shared``; 4 ``per_wheel``;
    0 ``none``), the lateral ones (1, or 4 ``per_wheel``), the wheel speeds omega_1..4, the ground speed V,
    the yaw rate psi_dot and the speed equation's bias."""

    structure: Structure
    n_res: int  # longitudinal resistance states
    n_lat: int  # lateral resistance states
    mu: slice
    res: slice
    lat: slice
    omega: slice
    v: int
    psi: int
    bias: int  # bias of the speed equation (accelerometer bias + g x pitch bias), m/s^2
    n: int

    @staticmethod
    def of(structure: Structure) -> "StateLayout":
        """The layout of ``structure`` (slip, shared, per_wheel or none; another name is a ValueError)."""
        from soilocp import _core

        blocks = {name: (start, size) for name, start, size in _core.observer_layout(structure)}
        span = {name: slice(start, start + size) for name, (start, size) in blocks.items()}
        return StateLayout(structure, blocks["res"][1], blocks["lat"][1], span["mu"], span["res"], span["lat"],
                           span["omega"], blocks["v"][0], blocks["psi"][0], blocks["bias"][0], blocks["n"][1])

    def per_state(self, mu: float, res: float, res_slope: float, lat: float, omega: float, v: float, psi: float,
                  bias: float) -> np.ndarray:
        """(n,) one value per state, by kind (``res_slope`` for the second resistance state of the
        ``slip`` structure)."""
        out = np.zeros(self.n)
        out[self.mu] = mu
        out[self.res] = res
        if self.n_res == 2:
            out[self.res.start + 1] = res_slope
        out[self.lat] = lat
        out[self.omega] = omega
        out[self.v] = v
        out[self.psi] = psi
        out[self.bias] = bias
        return out


# measurement rows: f_x, yaw rate, omega_1..4, ground speed
N_MEAS = 7
