"""The OCPs of one K as plain floats: the core's eqs. 7-10 with no numpy on the path, for the OCP
publisher (:mod:`soilocp.model.ocp` has the array form, the per-equation functions and their
corrections)."""

from __future__ import annotations

import math
from typing import Optional

from soilocp import _core
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants

#: the OCPs of the core (``ocp_bank``, ``ocp_one``, ``ChainCore.step``), in their order
OCP_NAMES = ("mu_T", "S_T", "S_E", "te_at_S_E")


def ocp_values(soil_strength: Optional[float],
               constants: ModelConstants = DEFAULT_CONSTANTS) -> tuple[float, float, float, float]:
    """(mu_T, S_T, S_E, TE at S_E) of one K: eq. 8, eq. 7 (sign corrected, docs/method.md §1), eq. 10
    (clamped at 0, §5) and eq. 9 at S_E (NaN unless 0 < S_E < 1): the core's ``ocp::ocp``, as
    :func:`soilocp.model.ocp.ocp_arrays` runs it for a bank.  All NaN for None (no estimate);
    ValueError naming a K the model cannot evaluate."""
    return _core.ocp_one(math.nan if soil_strength is None else float(soil_strength), constants.kernel)
