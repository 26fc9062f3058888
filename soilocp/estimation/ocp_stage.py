"""The OCP stage: a soil estimate's K -> mu_T, S_T, S_E and TE at S_E (eqs. 7-10), as the
:class:`~soilocp.schemas.pipeline.OcpEstimate` record.  No numpy on this path: the OCP publisher, which runs
only this stage, loads none (tests/test_lean_processes.py)."""

from __future__ import annotations

from soilocp.schemas.pipeline import OcpEstimate, SoilEstimate

from soilocp.estimation.config import PipelineConfig
from soilocp.estimation.wheel_curve import WheelCurve, ocp_message  # noqa: F401  (the record this stage makes)
from soilocp.model.constants import ModelConstants
from soilocp.model.ocp_values import ocp_values


class OcpStage:
    """mu_T, S_T, S_E from K: eqs. 8, 7 (sign corrected), 10; TE (eq. 9) at S_E (:func:`ocp_values`)."""

    def __init__(self, config: PipelineConfig):
        self.constants: ModelConstants = config.constants
        # (K, its OCPs): K is held between informative samples, and the model's OCPs are a function of K alone
        self._last: tuple[float | None, tuple[float, float, float, float]] | None = None
        self.curve = WheelCurve(config, 1)

    def step(self, soil: SoilEstimate) -> OcpEstimate:
        """mu_T (eq. 8), S_T (eq. 7, sign corrected, docs/method.md §5), S_E (eq. 10) and TE at S_E
        (eq. 9) for the estimate's K (scalars; all None when K is None), or the wheel's learnt curve's
        (:class:`soilocp.estimation.wheel_curve.WheelCurve`), with the soil estimate's status, reason, slip
        (4,) and mu (4,) carried over."""
        k = soil.soil_strength
        if self._last is None or self._last[0] != k:
            self._last = (k, ocp_values(k, self.constants))
        return self.curve.record(0, soil, self._last[1])
