"""The ln K grid of the Bayes soil estimator (docs/method.md §9, §11) and the compiled bank of beliefs
on it (:class:`soilocp._core.SoilGridBank`, soilocp/_core/src/soil/): the grid's nodes, the slip-independent
factor of the traction curve on them, the scale profile's nodes, and the soil settings, handed to the core
once."""

from __future__ import annotations

import math

import numpy as np

from soilocp import _core
from soilocp.model.constants import ModelConstants
from soilocp.estimation.settings_model import core_values
from soilocp.estimation.soil_config import SoilConfig
from soilocp.estimation.soil_state import class_bounds

#: nodes of the common gross-traction scale c over +-4 of its 1-sigma (the band's scale profile, §9)
SCALE_NODES = 25


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
        return _core.SoilGridBank(c.kernel, n_vehicles, self.kind, self.theta, self.k_grid,
                                  c.C1 * -np.expm1(-c.C2 * self.k_grid), z, -0.5 * z**2, self.k_floor,
                                  core_values(cfg, "soil"))
