"""Settings of the soil-strength estimator (docs/method.md §4, §9, §11-13) and its statuses: pydantic only,
no numpy (:mod:`soilocp.estimation.config`); what one step takes and gives is :mod:`soilocp.estimation.soil_state`.

Every numeric setting is declared once, in the compiled core (soilocp/_core/src/soil/params.rs: name,
default, bounds, unit, user or internal, description); :class:`SoilConfig` is built from those
declarations (:func:`soilocp.estimation.settings_model.model_from_core`), so that the validation, the
documentation and the numbers the core runs on cannot disagree.  Only the two choices the core takes as
arguments of their own (``method``, ``measurement``) are declared here.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from soilocp.estimation.settings_model import model_from_core
from soilocp.schemas.codes import STATUSES

#: the statuses the soil stage sets (soilocp/_core/src/codes.rs)
Status = Literal[tuple(name for name, (set_by, _) in STATUSES.items() if set_by == "soil")]  # type: ignore[valid-type]

SoilConfig = model_from_core(
    "SoilConfig", "soil", __name__, "Settings of the soil-strength estimator (docs/method.md §4, §9, §11-13, §16).",
    method=(Literal["bayes", "paper"], Field(
        "bayes", description="bayes (the grid Bayes filter) or paper (eqs. 36-37, sign fixed): paper only to "
        "reproduce the paper's update rule, which has no band, no hold and no soil change",
        json_schema_extra={"audience": "internal"})),
    measurement=(Literal["gross", "net"], Field(
        "gross", description="Compare gross (eq. 3) or net (eq. 6) traction: net only with the paper method (the "
        "gross traction is what the wheel's torque balance determines, the net also carries the observer's "
        "resistance split)", json_schema_extra={"audience": "internal"})),
)
