"""The ln K grid of the Bayes soil estimator (docs/method.md §9, §11) and the compiled bank of beliefs
on it (:class:`soilocp._core.SoilGridBank`, soilocp/_core/src/soil/): the grid's nodes, the slip-independent
factor of the traction curve on them, the scale profile's nodes, and the settings the per-sample update
reads, handed to the core once."""

from __future__ import annotations

import math

import numpy as np

from soilocp import _core
from soilocp.model.constants import ModelConstants
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.soil_state import class_bounds

#: m/s: the speed the terrain-change hazard assumes when a caller gives none (a typical rover's)
UNKNOWN_SPEED = 1.0
#: nodes of the common gross-traction scale c over +-4 of its 1-sigma (the band's scale profile, §9)
SCALE_NODES = 25
#: the SoilConfig fields the core's update reads (crate::soil::params::Params)
_CORE_FIELDS = ("slip_min", "slip_max", "slip_snr", "observable_max_gross_sigma", "q_log_k", "change_per_metre",
                "change_evidence", "stay_forgetting", "model_sigma", "outlier_prob", "temper", "temper_interval",
                "temper_max", "evidence_window", "gross_scale_sigma", "hold_after", "axle_mismatch_z",
                "axle_scale_sigma", "mismatch_min_evidence")


class LogKGrid:
    """The ln K grid: ``grid_points`` nodes from ln k_min to ln k_max, K at each, the node spacing and span."""

    def __init__(self, constants: ModelConstants, cfg: SoilConfig):
        if cfg.k_max <= cfg.k_min:
            raise ValueError(f"k_max ({cfg.k_max}) must exceed k_min ({cfg.k_min})")
        self.c, self.cfg, self.kind = constants, cfg, cfg.measurement
        self.theta = np.linspace(math.log(cfg.k_min), math.log(cfg.k_max), cfg.grid_points)
        self.k_grid = np.exp(self.theta)
        self.dtheta = self.theta[1] - self.theta[0]
        self.span = self.theta[-1] - self.theta[0]
        # half the weakest reference soil's K: the traction constants were fitted on soils from there up; a
        # belief mostly below it is an extrapolation that a wrong torque scale produces, not a soil
        self.k_floor = math.exp(class_bounds(constants)[1][0])

    def bank(self, n_vehicles: int) -> _core.SoilGridBank:
        """A compiled bank of ``n_vehicles`` uniform beliefs on this grid.  The grid's K, the curve's
        amplitude C1 (1 - e^{-C2 K}) (eq. 3) and the scale nodes are computed here, by numpy, once: the
        core then starts from the very numbers of the numpy estimator it replaced (numpy's exp and
        libm's differ in the last bit)."""
        c, cfg = self.c, self.cfg
        z = np.linspace(-4.0, 4.0, SCALE_NODES)
        params = {name: float(getattr(cfg, name)) for name in _CORE_FIELDS}
        params["unknown_speed"] = UNKNOWN_SPEED
        return _core.SoilGridBank(c.kernel, n_vehicles, self.kind, self.theta, self.k_grid,
                                  c.C1 * -np.expm1(-c.C2 * self.k_grid), z, -0.5 * z**2, self.k_floor, params)
