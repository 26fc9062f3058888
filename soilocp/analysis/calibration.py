"""Calibration of the improved Brixius model from testbed data (paper §2.2).

The paper fits C1..C6 of eqs. 3-6 and a soil strength K per soil to drawbar-pull measurements
taken on a single-wheel testbed at slips 0.1 .. 0.6 ("a nonlinear regression technique"), and then
draws the S_E line of eq. 10 through the tractive-efficiency peaks of eq. 9.  This module does the
same with :func:`scipy.optimize.least_squares` and writes a :class:`~soilocp.model.constants.ModelConstants`
that every other part of the system loads with :func:`~soilocp.model.constants.load_constants`.

Data: :mod:`soilocp.analysis.testbed` (the CSV columns, synthetic testbeds).

Identifiability (read this before trusting a number):

* **Scale degeneracy.**  For any lambda > 0 the substitution K -> lambda K (every soil),
  C2 -> C2 / lambda, C5 -> lambda C5, C6 -> sqrt(lambda) C6 leaves eqs. 3, 4 and 6 unchanged,
  hence also S_T (eq. 7), mu_T (eq. 8) and - with alpha, beta scaled by lambda - S_E (eq. 10).
  The data fix the curves, not the unit of K.  We remove the degeneracy by fixing the K of at least
  one soil: the *anchor* (default: sand at its reference K = 50, or the first soil of the data that
  has a reference K), plus any soils whose K the caller fixes.  All other K are relative to it.
* **C4 cancels in the net traction** (eq. 6 = eq. 3 - eq. 4: the +C4 of gross traction and of motion
  resistance cancel).  Drawbar data alone cannot see C4; it is fitted only when the data carry gross
  traction, otherwise kept at the initial value and reported as fixed.
* C1 and C2 are separable only through soils of different K: the fit needs at least two soils,
  and at least three distinct slips per soil (each soil's curve has three shape numbers).

S_E (eq. 10): the peaks of eq. 9 come from the *fitted* model, so docs/method.md §5 applies: with a
negative C5 the drawbar coefficient is positive at zero slip, "TE" exceeds 1 near S = 0 and there
is no interior peak on weak soils.  A soil counts only if eq. 9 has an interior maximum with
0 < TE <= 1 and positive gross traction.  If any calibrated soil has no such peak (or there are
fewer than two soils of different K) the initial alpha, beta are kept and the result says so.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from soilocp.model.checks import positive_scalar
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants
from soilocp.model.traction import gross_traction, net_traction, tractive_efficiency
from soilocp.analysis.testbed import TestbedData


#: Brixius constants in the order they are reported.
CONSTANT_NAMES: tuple[str, ...] = ("C1", "C2", "C3", "C4", "C5", "C6")
#: Search bounds.  C1, C2, C3, C6 must be > 0 (ModelConstants' own bounds).  The upper bounds
#: are generous physical limits that stop the fit from running along a flat ridge: with noisy
#: drawbar-only data from few soils, C1 (1 - exp(-C2 K)) ~ C1 C2 K leaves C1 -> inf, C2 -> 0 nearly
#: free.  C1 + C4 is the saturated gross traction coefficient, which no tyre on soil brings near 3.
PARAMETER_BOUNDS: dict[str, tuple[float, float]] = {
    "C1": (1e-6, 3.0),
    "C2": (1e-7, 1.0),
    "C3": (1e-3, 100.0),
    "C4": (-1.0, 1.0),
    "C5": (-1e3, 1e3),
    "C6": (1e-6, 100.0),
    "K": (1e-2, 1e5),
}
#: Condition number (of the column-scaled Jacobian) above which the fit is reported ill-posed.
ILL_CONDITIONED = 1e8


# -------------------------------------------------------------------------------- the results
@dataclass(frozen=True)
class ParameterEstimate:
    name: str  #: "C1".."C6" or "K[soil]"
    value: float
    std_error: float | None  #: from the Jacobian; None when the parameter was not fitted
    status: str  #: "fitted", "anchor" (fixed K that sets the scale), "fixed" (given K / unseen C4)


@dataclass(frozen=True)
class EfficiencyFit:
    """The S_E line (eq. 10) through the eq. 9 peaks of the fitted model, or the kept defaults."""

    alpha: float
    beta: float
    fitted: bool
    peaks: dict[str, float | None]  #: soil -> slip of the interior TE peak, None if there is none
    reasons: dict[str, str]  #: soil -> why it has no usable peak
    message: str


@dataclass(frozen=True)
class CalibrationResult:
    constants: ModelConstants
    parameters: list[ParameterEstimate]
    efficiency: EfficiencyFit
    rms: float  #: root-mean-square residual (coefficient units)
    n_points: int  #: residuals used (rows, twice if gross traction is given)
    n_free: int
    condition: float  #: condition number of the column-scaled Jacobian
    anchors: dict[str, float]  #: the fixed K values that set the scale
    notes: list[str] = field(default_factory=list)

    def parameter(self, name: str) -> ParameterEstimate:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)


# -------------------------------------------------------------------------------- S_E (eq. 9)
def efficiency_peak(soil_strength: float, constants: ModelConstants) -> tuple[float | None, str]:
    """Slip of the interior maximum of eq. 9 (tractive efficiency) for one K, by numerical argmax.

    Returns (S_peak, "") or (None, reason).  A peak counts only if it lies strictly inside the
    grid (not at the small-slip end, where docs/method.md §5's TE > 1 artefact sits), its TE is in
    (0, 1] and gross traction is positive up to it: otherwise eq. 9 is outside its validity.
    """
    k = positive_scalar("soil_strength", soil_strength)
    lo = max(2.0 * constants.bridge_slip, 1e-3)
    s = np.linspace(lo, 0.99, 1961)
    te = tractive_efficiency(s, k, constants)
    g = gross_traction(s, k, constants)
    i = int(np.argmax(te))
    if i == 0:
        return None, f"TE is largest at the smallest slip ({te[0]:.3g} at S={lo:g}): no interior peak"
    if i == len(s) - 1:
        return None, "TE still rises at S = 0.99: no interior peak"
    if np.any(g[: i + 1] <= 0):
        return None, "gross traction <= 0 below the peak: eq. 9 is not an efficiency there"
    res = minimize_scalar(
        lambda x: -float(tractive_efficiency(x, k, constants)),
        bounds=(float(s[i - 1]), float(s[i + 1])),
        method="bounded",
        options={"xatol": 1e-7},
    )
    s_peak, te_peak = float(res.x), -float(res.fun)
    if not (0 < te_peak <= 1):
        return None, f"peak TE = {te_peak:.3g} is outside (0, 1]: eq. 9 is not valid for this fit"
    return s_peak, ""


def fit_efficiency_line(soils: Mapping[str, float], constants: ModelConstants) -> EfficiencyFit:
    """Fit S_E = (K - alpha) / beta (eq. 10) through the eq. 9 peaks of ``constants`` at ``soils``.

    Least-squares line through (K, S_peak) of the soils (peaks from :func:`efficiency_peak`).
    Every soil must have a valid interior peak, and there must be two soils of different K:
    otherwise ``constants``' own alpha, beta are kept and ``fitted`` is False, with the reason in
    ``message`` (a line through some soils would be extrapolated where eq. 9 is invalid).
    """
    peaks: dict[str, float | None] = {}
    reasons: dict[str, str] = {}
    for name, k in soils.items():
        peaks[name], why = efficiency_peak(k, constants)
        if why:
            reasons[name] = why
    good = [(soils[n], sp) for n, sp in peaks.items() if sp is not None]
    missing = [n for n, sp in peaks.items() if sp is None]
    keep = f"kept alpha={constants.alpha:g}, beta={constants.beta:g}"
    if missing:
        # a line through the other soils would be extrapolated exactly where eq. 9 is invalid
        msg = (
            f"S_E line not fitted: no interior eq. 9 peak with 0 < TE <= 1 for {', '.join(missing)} "
            f"(docs/method.md §5); {keep}"
        )
        return EfficiencyFit(constants.alpha, constants.beta, False, peaks, reasons, msg)
    if len({k for k, _ in good}) < 2:
        msg = f"S_E line not fitted: needs eq. 9 peaks of at least two soils of different K; {keep}"
        return EfficiencyFit(constants.alpha, constants.beta, False, peaks, reasons, msg)
    ks, ss = np.array(good).T
    slope, intercept = np.polyfit(ks, ss, 1)
    if not np.isfinite(slope) or abs(slope) < 1e-12:
        msg = "S_E line not fitted: the peaks do not depend on K; kept alpha, beta"
        return EfficiencyFit(constants.alpha, constants.beta, False, peaks, reasons, msg)
    beta = 1.0 / slope
    alpha = -intercept / slope
    msg = f"S_E line fitted through {len(good)} eq. 9 peaks (valid only where eq. 9 is, docs/method.md §5)"
    return EfficiencyFit(float(alpha), float(beta), True, peaks, reasons, msg)


# ---------------------------------------------------------------------------- C1..C6 and K
def _initial_k(data: TestbedData, soil: str, constants: ModelConstants) -> float:
    """Start value for a free K: the best K on a log grid with the initial constants."""
    sel = np.array([x == soil for x in data.soil])
    grid = np.logspace(0.3, 4.0, 300)
    s = data.slip[sel][None, :]
    pred = net_traction(s, grid[:, None], constants)
    cost = np.sum((pred - data.mu[sel][None, :]) ** 2, axis=1)
    return float(grid[int(np.argmin(cost))])


def fit_constants(
    data: TestbedData,
    *,
    anchor: tuple[str, float] | None = None,
    fixed_k: Mapping[str, float] | None = None,
    initial: ModelConstants = DEFAULT_CONSTANTS,
    fit_efficiency: bool = True,
) -> CalibrationResult:
    """Fit C1..C6 and K per soil to testbed data by nonlinear least squares (paper §2.2).

    Residuals: eq. 6 (net drawbar coefficient) minus the measured mu at every row, plus eq. 3
    (gross traction) minus the measured gross coefficient when the data have it.

    The scale degeneracy (module docstring) is removed by fixing K of the ``anchor`` soil
    (name, K) - default: ``sand`` at ``initial.soils['sand']`` if sand is in the data, else the
    first soil of the data that ``initial.soils`` names - and of every soil in ``fixed_k``.  C4 is
    fitted only with gross-traction data.  ``initial`` gives the start values, C4 when it is not
    fitted, bridge_slip, and alpha, beta when the S_E line cannot be fitted.

    Standard errors: sqrt(diag(s^2 (J^T J)^+)) with s^2 = sum(residual^2) / (n - p), J the
    Jacobian at the solution (central differences).  Then the S_E line (eq. 10) is fitted through
    the eq. 9 peaks of the fitted model (:func:`fit_efficiency_line`).
    """
    soils = data.soils
    fixed: dict[str, float] = {}
    anchor_name: str | None = None
    for name, k in (fixed_k or {}).items():
        fixed[name] = positive_scalar(f"fixed_k[{name!r}]", k)
    if anchor is not None:
        name, k = anchor
        fixed[name] = positive_scalar(f"anchor K of {name!r}", k)
        anchor_name = name
    elif not fixed:
        candidates = (["sand"] if "sand" in soils else []) + [s for s in soils if s in initial.soils]
        if not candidates:
            raise ValueError(
                f"anchor: no soil of the data ({soils}) has a reference K in the initial constants "
                f"({sorted(initial.soils)}); give one, e.g. anchor=({soils[0]!r}, 50.0)"
            )
        anchor_name = candidates[0]
        fixed[anchor_name] = initial.soils[anchor_name]
    unknown = [n for n in fixed if n not in soils]
    if unknown:
        raise ValueError(f"anchor/fixed_k: soil(s) {unknown} are not in the data (soils: {soils})")
    if len(soils) < 2:
        raise ValueError(
            f"data: calibration needs at least two soils, got {soils}: with one soil C1 and C2 "
            "(eq. 3's amplitude C1 (1 - exp(-C2 K))) are not separately identifiable"
        )
    for name in soils:
        n_slips = len({float(s) for s, lab in zip(data.slip, data.soil) if lab == name})
        if n_slips < 3:
            raise ValueError(f"data: soil {name!r} has {n_slips} distinct slip value(s), need at least 3")

    has_gross = data.gross is not None
    c_free = [n for n in CONSTANT_NAMES if n != "C4" or has_gross]
    k_free = [n for n in soils if n not in fixed]
    names = c_free + [f"K[{n}]" for n in k_free]

    x0 = [getattr(initial, n) for n in c_free] + [_initial_k(data, n, initial) for n in k_free]
    bounds = [PARAMETER_BOUNDS[n] for n in c_free] + [PARAMETER_BOUNDS["K"]] * len(k_free)
    lower, upper = (np.array(b, dtype=float) for b in zip(*bounds))
    # start strictly inside the box
    margin = 1e-6 * (upper - lower)
    x0 = np.clip(np.array(x0, dtype=float), lower + margin, upper - margin)
    row_soil = np.array([soils.index(s) for s in data.soil])
    y = data.mu if not has_gross else np.concatenate([data.mu, data.gross])
    n_res = len(y)
    if n_res <= len(names):
        raise ValueError(f"data: {n_res} residuals cannot fit {len(names)} free parameters")

    def unpack(x: np.ndarray) -> tuple[ModelConstants, np.ndarray]:
        upd = dict(zip(c_free, (float(v) for v in x[: len(c_free)])))
        c = initial.model_copy(update=upd)
        kmap = dict(fixed) | dict(zip(k_free, x[len(c_free) :]))
        return c, np.array([kmap[n] for n in soils], dtype=float)[row_soil]

    def residuals(x: np.ndarray) -> np.ndarray:
        c, k = unpack(x)
        r = net_traction(data.slip, k, c)
        if has_gross:
            r = np.concatenate([r, gross_traction(data.slip, k, c)])
        return r - y

    sol = least_squares(
        residuals,
        x0,
        jac="3-point",
        bounds=(lower, upper),
        x_scale="jac",
        xtol=1e-10,
        ftol=1e-12,
        gtol=1e-10,
        max_nfev=2000,
    )
    if not sol.success:
        raise ValueError(
            f"calibration did not converge ({sol.message}); the data may not determine the "
            f"parameters - add soils, slips or gross traction"
        )
    x = sol.x
    at_bound = [n for n, v, lo, hi in zip(names, x, lower, upper) if min(v - lo, hi - v) <= 1e-6 * (hi - lo)]
    J = sol.jac
    dof = n_res - len(names)
    s2 = float(2.0 * sol.cost / dof)
    cov = s2 * np.linalg.pinv(J.T @ J)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    sv = np.linalg.svd(J / norms, compute_uv=False)
    condition = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")

    fitted = dict(zip(names, x))
    errors = dict(zip(names, se))
    params: list[ParameterEstimate] = []
    for n in CONSTANT_NAMES:
        if n in fitted:
            status = "at bound" if n in at_bound else "fitted"
            params.append(ParameterEstimate(n, float(fitted[n]), float(errors[n]), status))
        else:
            params.append(ParameterEstimate(n, float(getattr(initial, n)), None, "fixed"))
    soil_k: dict[str, float] = {}
    for n in soils:
        key = f"K[{n}]"
        if key in fitted:
            soil_k[n] = float(fitted[key])
            status = "at bound" if key in at_bound else "fitted"
            params.append(ParameterEstimate(key, soil_k[n], float(errors[key]), status))
        else:
            soil_k[n] = fixed[n]
            status = "anchor" if n == anchor_name else "fixed"
            params.append(ParameterEstimate(key, fixed[n], None, status))

    update = {n: p.value for n, p in zip(CONSTANT_NAMES, params)}
    c_fit = initial.model_copy(update=update)
    if fit_efficiency:
        eff = fit_efficiency_line(soil_k, c_fit)
    else:
        eff = EfficiencyFit(initial.alpha, initial.beta, False, {}, {}, "S_E line not fitted (not requested)")
    merged = dict(initial.soils) | soil_k
    constants = ModelConstants.model_validate(
        initial.model_dump() | update | {"alpha": eff.alpha, "beta": eff.beta, "soils": merged}
    )

    notes = [
        "K is defined only up to a common scale (K -> lambda K, C2 -> C2/lambda, C5 -> lambda C5, "
        "C6 -> sqrt(lambda) C6 leaves eq. 6 unchanged); fixed K that set it: "
        + ", ".join(f"{n}={k:g}" for n, k in fixed.items()),
    ]
    if not has_gross:
        notes.append(f"C4 cancels in the net traction (eq. 6): not fitted, kept at {initial.C4:g}")
    kept = sorted(set(initial.soils) - set(soils))
    if kept:
        notes.append(f"soils not in the data kept from the initial constants: {', '.join(kept)}")
    if at_bound:
        notes.append(
            f"{', '.join(at_bound)} ended at the search bound {[PARAMETER_BOUNDS.get(n, PARAMETER_BOUNDS['K']) for n in at_bound]}: "
            "the data do not determine them (typically C1 vs C2 from drawbar pull of few soils); "
            "their values and standard errors are not estimates - add gross traction (wheel torque) or more soils"
        )
    if condition > ILL_CONDITIONED:
        notes.append(f"the fit is ill-conditioned (condition number {condition:.3g}): standard errors are unreliable")
    notes.append(eff.message)
    return CalibrationResult(
        constants=constants,
        parameters=params,
        efficiency=eff,
        rms=float(np.sqrt(2.0 * sol.cost / n_res)),
        n_points=n_res,
        n_free=len(names),
        condition=condition,
        anchors=fixed,
        notes=notes,
    )
