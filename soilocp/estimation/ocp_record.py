"""The OCP record as consumers get it: :mod:`soilocp.estimation.ocp_stage`'s record with the soil estimate's
reason code carried over (the record's ``reason_code``, schemas.pipeline.REASON_CODES).  No numpy, like the
OCP stage: the OCP publisher runs this stage and loads none (tests/test_lean_processes.py)."""

from __future__ import annotations

from typing import Sequence

from schemas.pipeline import OcpEstimate, SoilEstimate

from soilocp.estimation.ocp_stage import OcpStage, ocp_message


def with_reason_code(record: OcpEstimate, soil: SoilEstimate) -> OcpEstimate:
    """``record`` carrying ``soil``'s reason code (the record itself when it already does: no copy)."""
    if record.reason_code == soil.reason_code:
        return record
    return record.model_copy(update={"reason_code": soil.reason_code})


def ocp_record(soil: SoilEstimate, values: Sequence[float]) -> OcpEstimate:
    """:func:`soilocp.estimation.ocp_stage.ocp_message` with the soil estimate's reason code."""
    return with_reason_code(ocp_message(soil, values), soil)


class OcpRecordStage(OcpStage):
    """:class:`soilocp.estimation.ocp_stage.OcpStage` whose records carry the soil estimate's reason code."""

    def step(self, soil: SoilEstimate) -> OcpEstimate:
        """mu_T, S_T, S_E and TE at S_E for the estimate's K (:meth:`OcpStage.step`), with its reason code."""
        return with_reason_code(super().step(soil), soil)
