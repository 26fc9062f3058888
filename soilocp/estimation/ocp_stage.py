"""The OCP stage: a soil estimate's K -> mu_T, S_T, S_E and TE at S_E (eqs. 7-10), as the
:class:`~soilocp.schemas.pipeline.OcpEstimate` record.  No numpy on this path: the OCP publisher, which runs
only this stage, loads none (tests/test_lean_processes.py)."""

from __future__ import annotations

import math
from typing import Optional, Sequence

from soilocp.schemas.pipeline import OcpEstimate, SoilEstimate

from soilocp.estimation.config import PipelineConfig
from soilocp.model.constants import ModelConstants
from soilocp.model.ocp_values import ocp_values


def ocp_message(soil: SoilEstimate, values: Sequence[float], curve: str = "model", bands=(None, None),
                status: Optional[str] = None, reason: Optional[str] = None,
                reason_code: Optional[str] = None) -> OcpEstimate:
    """An OcpEstimate from a soil estimate and its K's (mu_T, S_T, S_E, TE at S_E) in the core's order
    (:data:`soilocp.model.ocp_values.OCP_NAMES`; NaN: none); ``curve`` says where they come from, ``bands`` is
    (mu_T's, S_T's) 1-sigma of a learnt curve, ``status``, ``reason`` and ``reason_code`` replace the soil
    estimate's (:class:`soilocp.estimation.wheel_curve.WheelCurve` decides them)."""
    have = soil.soil_strength is not None
    mu_t, s_t, s_e, te = (None if not have or math.isnan(v) else float(v) for v in values)
    return OcpEstimate(
        vehicle_id=soil.vehicle_id, seq=soil.seq, stamp=soil.stamp, soil_strength=soil.soil_strength,
        soil_strength_std=soil.soil_strength_std, soil_class=soil.soil_class,
        soil_class_confidence=soil.soil_class_confidence, status=status or soil.status,
        reason=soil.reason if reason is None else reason, reason_code=reason_code or soil.reason_code, mu=soil.mu,
        mu_determined=soil.mu_determined, slip=soil.slip, mu_T=mu_t, S_T=s_t, S_E=s_e, te_at_S_E=te,
        curve=curve, mu_T_std=bands[0], S_T_std=bands[1], held_for_s=soil.held_for_s, unusable=soil.unusable,
    )


class OcpStage:
    """mu_T, S_T, S_E from K: eqs. 8, 7 (sign corrected), 10; TE (eq. 9) at S_E (:func:`ocp_values`)."""

    def __init__(self, config: PipelineConfig):
        self.constants: ModelConstants = config.constants
        # (K, its OCPs): K is held between informative samples, and the model's OCPs are a function of K alone
        self._last: tuple[float | None, tuple[float, float, float, float]] | None = None
        from soilocp.estimation.wheel_curve import WheelCurve

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
