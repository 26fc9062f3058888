"""Settings of the wheel-curve learner (:mod:`soilocp.estimation.wheel_curve` says what it learns and how):
pydantic only, no numpy (:mod:`soilocp.estimation.config`).

The learner's settings and its bands' systematic errors are declared once, in the compiled core
(soilocp/_core/src/curve.rs); :class:`CurveConfig` is built from those declarations.  The switch, the OCP
records' tolerance for ok and a calibration's range, which the Python side applies, are declared here.
"""

from __future__ import annotations

from pydantic import Field

from soilocp.estimation.settings_model import model_from_core


CurveConfig = model_from_core(
    "CurveConfig", "curve", __name__, "Settings of the wheel's traction-curve learner (docs/method.md §19).",
    enabled=(bool, Field(
        True, description="Learn the curve of a wheel nobody checked where the drive shows it, and serve its OCPs, "
        "flagged (False: the OCPs always follow from K and the configured constants)",
        json_schema_extra={"audience": "user"})),
    ok_mu_t=(float, Field(
        0.1, gt=0, description="Half-width of mu_T's 2-sigma band, carried from K's band through a checked curve, "
        "beyond which an OCP record is not ok (uncertain, reason ocp_wide): the error in the maximum traction a "
        "controller that acts on ok records tolerates", json_schema_extra={"audience": "user"})),
    ok_s_t=(float, Field(
        0.05, gt=0, description="Half-width of S_T's 2-sigma band, carried from K's band through a checked curve, "
        "beyond which an OCP record is not ok (uncertain, reason ocp_wide): the error in the slip target a "
        "controller that acts on ok records tolerates", json_schema_extra={"audience": "user"})),
    k_range_margin=(float, Field(
        1.25, ge=1, description="A calibrated curve's OCPs are served as ok for K within its fitted soils' range "
        "widened by this factor either way; beyond, they are extrapolated and flagged. Raise it to trust a "
        "calibration further from the soils it was fitted on", json_schema_extra={"audience": "user"})),
)
