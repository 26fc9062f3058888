"""Calibration of the torque channel: the constant k that turns a logged motor current (or a
torque of unknown scale) into wheel torque, from the vehicle's longitudinal force balance
(docs/method.md §15).

Summed over the wheels, eq. 13 gives T_i / R = F_GT,i + I_w omega_dot_i / R (gross traction
force at the rim plus the wheel's own inertia), and the body's longitudinal balance (eq. 29,
docs/method.md §3: only the specific force enters) gives m f_x = sum_i (F_GT,i - F_MR,i).
With the logged torque T_log,i = T_i / k:

    m f_x + (I_w / R) sum_i omega_dot_i  =  k sum_i T_log,i / R  -  F_MR          (eq. TC)

whatever the slip and the soil (:func:`soilocp.model.force_balance.longitudinal_balance`: the
compiled core's eq. TC, which the online torque scale runs too).  F_MR (motion resistance, plus
any accelerometer bias times m) is taken as one constant: the intercept of a straight-line fit.
The fit runs on window means (default 0.5 s): the balance is linear, so it holds for the means
exactly; the means bring a slow current stream and a 100 Hz IMU onto one clock and make the
windows nearly independent, so that the fit's standard errors mean something.  Only windows
where eq. TC holds are used:

* moving forward (speed >= ``min_speed``: F_MR has one sign, the wheels are not stuck in static
  friction) -- the speed is the ground speed if logged, else the wheels' rim speed;
* straight (|yaw rate| <= ``max_yaw_rate``: a skid-steer turn spends torque on scrubbing the
  wheels sideways, which no longitudinal term sees);
* not saturated (|T_log| below ``saturation``: a clipped current is not the torque);
* no gap in the stamps (the means would span a missing stretch).

The acceleration comes from the IMU (f_x as logged) or, with ``accel="ground_speed"``, from the
ground speed's change over the window plus the gravity reaction of the logged pitch (eq. 20).
k is determined only if the windows' torque varies independently of the resistance, i.e. the
robot accelerated and braked: cruising alone fixes only k sum T / R - F_MR.  The result says
``not_determined`` with the reason when the data cannot fix k (too few valid windows, a k whose
relative std exceeds ``max_rel_std``, or k <= 0).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np

from soilocp.estimation.settings_model import check_from_core, from_core
from soilocp.model.force_balance import longitudinal_balance
from soilocp.model.normal_force import gravity_from_attitude
from soilocp.model.vehicle import VehicleParams


@dataclass(frozen=True)
class TorqueSelection:
    """Which stretches of a log enter the fit (see the module doc).  The slow, turning and gap rules are the
    online torque scale's (its settings min_speed, max_yaw_rate, max_gap, declared in the core); the window is
    this fit's own: shorter than the online scale's, for more, nearly independent windows."""

    window: float = 0.5  #: s, length of the averaging windows
    min_speed: float = from_core("torque_scale", "min_speed")  #: m/s
    max_yaw_rate: float = from_core("torque_scale", "max_yaw_rate")  #: rad/s
    saturation: float | None = None  #: |logged torque| per wheel at or above this is clipped; None: none known
    max_gap: float = from_core("torque_scale", "max_gap")  #: s, a larger step between stamps ends the window
    min_windows: int = 10
    max_rel_std: float = 0.1  #: k_std / k above this: not determined
    #: m/s^2: the windows' mean f_x must spread (std) at least this much.  Motion resistance is
    #: not constant (eq. 4 grows with slip, i.e. with torque): over a narrow range of accelerations
    #: its variation is mistaken for torque, e.g. k read 29 % high at a simulated cruise whose
    #: f_x spread is 0.12 m/s^2 while the fit's own std said 0.7 %.
    min_accel_spread: float = 0.5
    accel: Literal["imu", "ground_speed"] = "imu"

    def __post_init__(self) -> None:
        check_from_core(self)
        for name in ("window", "max_rel_std", "min_accel_spread"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if self.saturation is not None and not (math.isfinite(self.saturation) and self.saturation > 0):
            raise ValueError(f"saturation must be a finite torque > 0 (or None), got {self.saturation!r}")
        if not (isinstance(self.min_windows, int) and self.min_windows >= 3):
            raise ValueError(f"min_windows must be an integer >= 3, got {self.min_windows!r}")
        if self.accel not in ("imu", "ground_speed"):
            raise ValueError(f"accel must be 'imu' or 'ground_speed', got {self.accel!r}")


@dataclass(frozen=True)
class TorqueConstantFit:
    """k (N m of wheel torque per unit of the logged torque column) +- its std, the intercept
    F_MR (N) +- std, the fit's residual (rms, N) and R^2, what was used and why the rest was not."""

    status: Literal["ok", "not_determined"]
    reason: str
    k: float | None
    k_std: float | None
    resistance: float | None
    resistance_std: float | None
    residual_rms: float | None
    r2: float | None
    accel_spread: float | None  # std of the used windows' mean f_x, m/s^2
    windows_used: int
    windows_total: int
    excluded: dict = field(default_factory=dict)  # reason -> windows
    accel: str = "imu"
    window_s: float = 0.5

    def as_dict(self) -> dict:
        return asdict(self)


def _columns(samples: Iterable) -> dict[str, np.ndarray]:
    """The log's fields as arrays; samples are SensorSample models or their JSON dicts."""
    rows = [s.model_dump() if hasattr(s, "model_dump") else dict(s) for s in samples]
    if not rows:
        raise ValueError("the log is empty: no sample to calibrate on")
    try:
        col = {
            "stamp": np.array([r["stamp"] for r in rows], float),
            "f_x": np.array([r["specific_force"][0] for r in rows], float),
            "pitch": np.array([r.get("pitch", 0.0) for r in rows], float),
            "yaw_rate": np.array([r["yaw_rate"] for r in rows], float),
            "wheel_speed": np.array([r["wheel_speed"] for r in rows], float),
            "torque": np.array([r["wheel_torque"] for r in rows], float),
            "ground_speed": np.array([np.nan if r.get("ground_speed") is None else r["ground_speed"] for r in rows],
                                     float),
        }
    except (KeyError, TypeError, IndexError) as exc:
        raise ValueError(f"a sample lacks a field the calibration needs ({exc!r}): stamp, specific_force, "
                         "yaw_rate, wheel_speed, wheel_torque (ground_speed optional)") from None
    if col["wheel_speed"].shape[1:] != (4,) or col["torque"].shape[1:] != (4,):
        raise ValueError("wheel_speed and wheel_torque must have 4 values per sample")
    if np.any(np.diff(col["stamp"]) < 0):
        raise ValueError("stamps go backwards: sort the log (or import it with soilocp import) first")
    return col


def _windows(stamp: np.ndarray, window: float, max_gap: float) -> list[tuple[int, int]]:
    """Index ranges [i0, i1) of consecutive windows of ``window`` s, cut at stamp gaps."""
    out, i0, n = [], 0, len(stamp)
    while i0 < n - 1:
        i1 = i0 + 1
        while i1 < n and stamp[i1] - stamp[i0] < window and stamp[i1] - stamp[i1 - 1] <= max_gap:
            i1 += 1
        if i1 < n and stamp[i1] - stamp[i1 - 1] <= max_gap:
            out.append((i0, i1 + 1))  # closed on the next sample: the window's change spans it
        i0 = i1
    return out


def fit_torque_constant(samples: Iterable, vehicle: VehicleParams,
                        selection: TorqueSelection | None = None) -> TorqueConstantFit:
    """Fit eq. TC (module doc) to a sensor log: k, F_MR, their std, the residual."""
    sel = selection or TorqueSelection()
    c = _columns(samples)
    R = vehicle.wheel_radius
    have_gs = np.isfinite(c["ground_speed"])
    if sel.accel == "ground_speed" and not have_gs.any():
        raise ValueError("accel='ground_speed' needs a ground speed in the log, and this one has none")
    speed = np.where(have_gs, c["ground_speed"], c["wheel_speed"].mean(axis=1) * R)
    sat = sel.saturation if sel.saturation is not None else math.inf
    excluded: dict[str, int] = {}
    X, Y, F = [], [], []
    wins = _windows(c["stamp"], sel.window, sel.max_gap)
    for i0, i1 in wins:
        s = slice(i0, i1)
        why = None
        if np.any(~np.isfinite(c["torque"][s])) or np.any(~np.isfinite(c["f_x"][s])):
            why = "non_finite"
        elif np.any(speed[s] < sel.min_speed):
            why = "slow_or_reversing"
        elif np.any(np.abs(c["yaw_rate"][s]) > sel.max_yaw_rate):
            why = "turning"
        elif np.any(np.abs(c["torque"][s]) >= sat):
            why = "saturated"
        elif sel.accel == "ground_speed" and not np.all(have_gs[s]):
            why = "no_ground_speed"
        if why:
            excluded[why] = excluded.get(why, 0) + 1
            continue
        dt = c["stamp"][i1 - 1] - c["stamp"][i0]
        # the mean over the window's intervals (trapezoid), the same span as the speed changes below
        w = np.diff(c["stamp"][s])
        mean = lambda a: float(np.sum(0.5 * (a[1:] + a[:-1]) * w) / dt)  # noqa: E731
        omega_dot = (c["wheel_speed"][i1 - 1] - c["wheel_speed"][i0]).sum() / dt
        if sel.accel == "imu":
            f_x = mean(c["f_x"][s])
        else:
            g_x = gravity_from_attitude(0.0, c["pitch"][s])[:, 0]
            f_x = (c["ground_speed"][i1 - 1] - c["ground_speed"][i0]) / dt + mean(g_x)
        x, y = longitudinal_balance(f_x, omega_dot, mean(c["torque"][s].sum(axis=1)), vehicle)
        X.append(float(x))
        Y.append(float(y))
        F.append(f_x)
    n = len(X)
    base = dict(windows_used=n, windows_total=len(wins), excluded=excluded, accel=sel.accel, window_s=sel.window)
    if n < sel.min_windows:
        return TorqueConstantFit("not_determined", f"only {n} window(s) of {sel.window:g} s where the force balance "
                                 f"holds (need {sel.min_windows}); excluded: {excluded or 'none'}",
                                 None, None, None, None, None, None, None, **base)
    X, Y = np.array(X), np.array(Y)
    A = np.column_stack([X, np.ones(n)])
    coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
    resid = Y - A @ coef
    dof = max(n - 2, 1)
    s2 = float(resid @ resid) / dof
    cov = s2 * np.linalg.pinv(A.T @ A)
    k, intercept = float(coef[0]), float(coef[1])
    k_std, b_std = float(math.sqrt(max(cov[0, 0], 0.0))), float(math.sqrt(max(cov[1, 1], 0.0)))
    ss_tot = float(np.sum((Y - Y.mean()) ** 2))
    r2 = 1.0 - float(resid @ resid) / ss_tot if ss_tot > 0 else None
    status, reason = "ok", ""
    spread = float(np.std(F))
    if spread < sel.min_accel_spread:
        status, reason = "not_determined", (
            f"the robot barely accelerated or braked in the usable windows (f_x std {spread:.2g} m/s^2 < "
            f"{sel.min_accel_spread:g}): the torque's variation cannot be told from the motion resistance's")
    elif not k > 0:
        status, reason = "not_determined", f"k = {k:.4g} <= 0: the logged torque does not drive the robot forward"
    elif k_std > sel.max_rel_std * k:
        status, reason = "not_determined", (
            f"k = {k:.4g} +- {k_std:.2g} ({k_std / k:.0%} > {sel.max_rel_std:.0%}): the logged torque varies too little "
            f"or too noisily against the acceleration to separate k from the resistance")
    return TorqueConstantFit(status, reason, k, k_std, -intercept, b_std, math.sqrt(s2), r2, spread, **base)


def scaled_torque_log(samples: Iterable, scale: float) -> list[dict]:
    """The samples as dicts with the torque column divided by ``scale`` (a "current" whose
    torque constant is ``scale``): the test fixture of the calibration, and a way to undo one."""
    out = []
    for s in samples:
        d = s.model_dump() if hasattr(s, "model_dump") else dict(s)
        d["wheel_torque"] = [q / scale for q in d["wheel_torque"]]
        out.append(d)
    return out


def summary_lines(fit: TorqueConstantFit, old_scale: float | None = None) -> list[str]:
    """Human-readable report of a fit (the CLI prints it)."""
    lines = [f"windows used {fit.windows_used} of {fit.windows_total} ({fit.window_s:g} s each, acceleration from "
             f"{fit.accel}); excluded: " + (", ".join(f"{k} {v}" for k, v in sorted(fit.excluded.items())) or "none")]
    if fit.k is not None:
        lines.append(f"k = {fit.k:.5g} +- {fit.k_std:.2g} N m per unit of the logged torque; motion resistance "
                     f"{fit.resistance:.4g} +- {fit.resistance_std:.2g} N; residual rms {fit.residual_rms:.3g} N; "
                     f"R^2 {fit.r2 if fit.r2 is not None else float('nan'):.3f}; f_x spread {fit.accel_spread:.2g} m/s^2")
    lines.append(f"status {fit.status}" + (f": {fit.reason}" if fit.reason else ""))
    if fit.status == "ok":
        lines.append("set it: multiply the map's effort_scale (or csv current_to_torque) by k"
                     + (f" -> {old_scale * fit.k:.5g}" if old_scale else "") + ", then re-import")
    return lines

