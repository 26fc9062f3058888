"""Settings of the online torque scale (:mod:`soilocp.estimation.torque_scale` says what it learns and
how): pydantic only, no numpy (:mod:`soilocp.estimation.config`).

The numeric settings are declared once, in the compiled core (soilocp/_core/src/torque_scale/params.rs);
:class:`TorqueScaleConfig` is built from those declarations.  The switches and the optional prior, which
the core takes as arguments of their own, are declared here.
"""

from __future__ import annotations

from typing import Optional

from pydantic import Field

from soilocp.estimation.settings_model import model_from_core

TorqueScaleConfig = model_from_core(
    "TorqueScaleConfig", "torque_scale", __name__, "Settings of the online torque scale (module doc).",
    enabled=(bool, Field(
        True, description="Learn the torque scale online (False: k = 1 +- soil.gross_scale_sigma always). Turn it "
        "off only where the torque constant and the mass are calibrated", json_schema_extra={"audience": "user"})),
    model_resistance=(bool, Field(
        False, description="Subtract eq. 4's motion resistance at the soil stage's K and slips from the balance, "
        "leaving F_MR the unmodelled rest; False: F_MR is the whole motion resistance, a random walk. Off by default: "
        "its slips and K are themselves estimates. The K is fed back in the offline and batched paths only: the live "
        "observer service runs before the soil service and models the resistance at the median reference soil and "
        "the readings' slips", json_schema_extra={"audience": "user"})),
    prior_sigma=(Optional[float], Field(
        0.10, gt=0, description="Prior 1-sigma of k (motor constant x 1 / mass) for the online state (None: "
        "soil.gross_scale_sigma, the torque constant's alone): a payload the vehicle file does not know is a scale "
        "error too. Raise it when the payload varies; K's band combines the windows' information with "
        "soil.gross_scale_sigma", json_schema_extra={"audience": "user"})),
)
