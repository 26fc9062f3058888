"""Many vehicles at once: the observer, soil-strength and OCP stages on stacked numpy arrays.

The single-vehicle path (:mod:`soilocp.pipeline`) runs one filterpy ``KalmanFilter`` and one grid
Bayes estimator per vehicle; each step costs about a millisecond of Python overhead on 12x12
matrices, so one process serves about 1000 samples/s at best.  Here the same model runs for N
vehicles as (N, n, n) arrays, one numpy call per operation for the whole fleet:

* observer (:class:`BatchObserver`): the model of :mod:`soilocp.observer` — eqs. 11-15 and 29
  for A(t), b(t), H(t) (eq. 33) rebuilt each step from the current normal forces and torques;
  ZOH by the exact series (A nilpotent: F = I + A dt, G = b dt + A b dt^2/2, Q_d = Q dt +
  (A Q + Q A^T) dt^2/2 + A Q A^T dt^3/3, eq. 34); the standard predict / Joseph-form update in
  place of the misprinted eq. 35 (method-notes), per-row innovation gating with patience,
  symmetrisation and variance clamping.  A gated row is removed from the update by zeroing its
  H row and innovation (its Kalman gain column is then exactly zero), which is the update
  filterpy makes on the kept rows only.
* soil strength (:class:`BatchSoil`): the grid Bayes filter over ln K of
  :class:`soilocp.soil_strength.BayesSoilEstimator` (eqs. 3 / 6 likelihood in place of the
  paper's eqs. 36-37, method-notes §4 and §9), its diffusion + change-hazard prediction, and its
  hold / expiry logic (the very same ``_HoldLogic`` object per vehicle);
* slip (eq. 1 with the floor and deadband of method-notes §6, §10), the low-pass slip the soil
  gate decides on (``SoilConfig.gate_smoothing``, method-notes §9), and the OCPs: eq. 7 (sign
  corrected, method-notes §1), eq. 8, eq. 10 and eq. 9 at S_E, as :class:`soilocp.pipeline.OcpStage`.

Every step takes the indices of the vehicles that have a sample now (any subset, each at most
once): vehicles are independent and need not be in step.  ``tests/test_batch.py`` checks that
the batched outputs equal the single-vehicle pipeline's to ~1e-9 on real simulated drives.
Only the default ``bayes`` soil method and the ``series`` discretisation are batched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from .constants import ModelConstants
from .observer import N_MEAS, ObserverConfig, StateLayout, TractionObserver, continuous_process_noise
from .pipeline import LIFT_OFF_FORCE, PipelineConfig
from .soil_strength import LogKGrid, SoilConfig, SoilState, _gate, _HoldLogic, classify
from .traction import curve_unchecked
from .vehicle import VehicleParams


def _check_count(n: object) -> int:
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
        raise ValueError(f"n_vehicles {n!r} is invalid: must be an integer >= 1")
    return int(n)


def _check_index(idx, n: int) -> np.ndarray:
    ix = np.asarray(idx)
    if ix.ndim != 1 or ix.size == 0 or not np.issubdtype(ix.dtype, np.integer):
        raise ValueError(f"idx {idx!r} is invalid: need a non-empty 1-D array of vehicle indices")
    if ix.min() < 0 or ix.max() >= n:
        raise ValueError(f"idx {idx!r} is invalid: indices must be in [0, {n - 1}]")
    if ix.size > 1 and len(set(ix.tolist())) != ix.size:
        raise ValueError(f"idx {idx!r} is invalid: a vehicle can be stepped only once per call")
    return ix


@dataclass
class BatchInputs:
    """One sensor sample per stepped vehicle, stacked: shapes (k,) or (k, 4)."""

    stamp: np.ndarray
    specific_force_x: np.ndarray
    yaw_rate: np.ndarray
    pitch: np.ndarray
    wheel_speed: np.ndarray
    wheel_torque: np.ndarray
    ground_speed: np.ndarray
    normal_force: np.ndarray  # as computed by the normal-force stage (clamped here)

    def check(self) -> int:
        k = np.shape(self.stamp)[0] if np.ndim(self.stamp) == 1 else -1
        for name in ("stamp", "specific_force_x", "yaw_rate", "pitch", "ground_speed"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (k,) or not np.all(np.isfinite(a)):
                raise ValueError(f"inputs.{name} must be a finite array of shape ({k},), got shape {a.shape}")
            setattr(self, name, a)
        for name in ("wheel_speed", "wheel_torque", "normal_force"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (k, 4) or not np.all(np.isfinite(a)):
                raise ValueError(f"inputs.{name} must be a finite array of shape ({k}, 4), got shape {a.shape}")
            setattr(self, name, a)
        return k


@dataclass
class ObserverBatchOutput:
    """What :class:`soilocp.observer.ObserverEstimate` holds, for k vehicles."""

    mu: np.ndarray
    mu_var: np.ndarray
    resistance: np.ndarray
    gross: np.ndarray
    gross_var: np.ndarray
    wheel_speed: np.ndarray
    ground_speed: np.ndarray
    yaw_rate: np.ndarray
    rejected: np.ndarray
    reset: np.ndarray
    normal_force: np.ndarray


class BatchObserver:
    """N traction observers (``soilocp.observer.TractionObserver``) stepped together."""

    def __init__(self, vehicle: VehicleParams, config: ObserverConfig | None, n_vehicles: int):
        self.vehicle = vehicle
        self.cfg = cfg = config or ObserverConfig()
        if cfg.discretization != "series":
            raise ValueError(f"discretization {cfg.discretization!r}: the batched observer implements 'series' only")
        self.n_vehicles = n = _check_count(n_vehicles)
        self.layout = L = StateLayout.of(cfg.structure)
        nx = L.n
        self._Qc = continuous_process_noise(L, cfg)
        self._r = np.array([cfg.r_specific_force**2, cfg.r_yaw_rate**2, *([cfg.r_wheel_speed**2] * 4),
                            cfg.r_ground_speed**2])
        self._I = np.eye(nx)
        self.x = np.zeros((n, nx))
        self.P = np.zeros((n, nx, nx))
        self.last_stamp = np.full(n, np.nan)
        self.rejections = np.zeros((n, N_MEAS), dtype=int)
        # the initial covariance of the single-vehicle observer, taken from it (one definition)
        one = TractionObserver(vehicle, cfg)
        one._initialise(np.zeros(4), 0.0, 0.0)
        self._P0 = np.array(one.kf.P, dtype=float)
        self._wheel_y = np.asarray(vehicle.wheel_y, dtype=float)
        om = np.arange(nx)[L.omega]
        self._om = om
        self._mu = np.arange(nx)[L.mu]
        v = vehicle
        self._yaw_arm = np.array([-v.c, -v.c, v.d, v.d])
        self._lat_arm = np.array([v.a, v.b, v.b, v.a])
        H0 = np.zeros((N_MEAS, nx))
        H0[1, L.psi] = 1.0
        H0[2:6, L.omega] = np.eye(4)
        H0[6, L.v] = 1.0
        self._H0 = H0

    def state_slip(self, x: np.ndarray) -> np.ndarray:
        """Per-wheel slip (eq. 1, floor 0.05 m/s) of states x (k, n): the regressor of the
        observer's ``slip`` structure (``TractionObserver._state_slip``)."""
        L = self.layout
        rim = x[:, L.omega] * self.vehicle.wheel_radius
        ground = x[:, L.v][:, None] - x[:, L.psi][:, None] * self._wheel_y
        return (rim - ground) / np.maximum(np.maximum(np.abs(rim), np.abs(ground)), 0.05)

    def resistance_matrices(self, slip: Optional[np.ndarray], k: int) -> np.ndarray:
        """(k, 4, n_res) maps from resistance states to each wheel's mu_xR (``StateLayout.resistance_matrix``,
        called on the stacked slips so that the definition stays the observer's)."""
        L = self.layout
        if L.n_res == 2:
            s = np.zeros((k, 4)) if slip is None else slip
            return L.resistance_matrix(s.reshape(-1)).reshape(k, 4, 2)
        return np.broadcast_to(L.resistance_matrix(), (k, 4, L.n_res))

    def model(self, fz: np.ndarray, torque: np.ndarray, pitch: np.ndarray, M: np.ndarray):
        """A (k,n,n), b (k,n), H (k,7,n) of eq. 33 for k vehicles (``observer.continuous_model``);
        M (k, 4, n_res) are the resistance maps."""
        L, v, g = self.layout, self.vehicle, self.cfg.gravity
        k = fz.shape[0]
        nx = L.n
        A = np.zeros((k, nx, nx))
        b = np.zeros((k, nx))
        wheel_gain = -v.wheel_radius * fz / v.wheel_inertia  # eqs. 13-15
        A[:, self._om, self._mu] = wheel_gain
        if L.n_res:
            A[:, L.omega, L.res] = wheel_gain[:, :, None] * M
        b[:, L.omega] = torque / v.wheel_inertia
        A[:, L.v, L.mu] = fz / v.mass
        if hasattr(L, "bias"):  # the speed equation's bias state (accelerometer / pitch bias)
            A[:, L.v, L.bias] = -1.0
        b[:, L.v] = g * np.sin(pitch)
        A[:, L.psi, L.mu] = self._yaw_arm * fz / v.yaw_inertia  # eqs. 11-12
        lat = self._lat_arm * fz
        if L.n_lat == 1:
            A[:, L.psi, L.lat] = (-lat.sum(axis=1) / v.yaw_inertia)[:, None]
        else:
            A[:, L.psi, L.lat] = -lat / v.yaw_inertia
        H = np.repeat(self._H0[None], k, axis=0)
        H[:, 0, L.mu] = fz / v.mass  # eq. 29: f_x = sum(mu_i Fz_i) / m
        return A, b, H

    def step(self, idx, inputs: BatchInputs) -> ObserverBatchOutput:
        """One predict / gated update for the vehicles ``idx`` (eq. 35, standard form)."""
        ix = _check_index(idx, self.n_vehicles)
        k = inputs.check()
        if k != ix.size:
            raise ValueError(f"inputs hold {k} samples for {ix.size} vehicle indices")
        cfg, L = self.cfg, self.layout
        fz = np.maximum(inputs.normal_force, LIFT_OFF_FORCE)
        stamp = inputs.stamp
        last = self.last_stamp[ix]
        slip = None
        if L.n_res == 2:  # the 'slip' structure: the model's regressor from the prior state
            slip = self.state_slip(self.x[ix])
            slip[np.isnan(last)] = 0.0
        A, b, H = self.model(fz, inputs.wheel_torque, inputs.pitch, self.resistance_matrices(slip, k))
        with np.errstate(invalid="ignore"):
            dt = stamp - last
            # dt == 0 (a repeated stamp) is no reset: F = I, G = 0, Qd = 0 and only the update runs
            reset = np.isnan(last) | ~(dt >= 0) | (dt > cfg.max_gap)
        x = self.x[ix]
        P = self.P[ix]
        rejected = np.zeros(k, dtype=int)
        if reset.any():
            x0 = np.zeros((int(reset.sum()), L.n))
            x0[:, L.omega] = inputs.wheel_speed[reset]
            x0[:, L.v] = inputs.ground_speed[reset]
            x0[:, L.psi] = inputs.yaw_rate[reset]
            x[reset] = x0
            P[reset] = self._P0
            self.rejections[ix[reset]] = 0
        run = ~reset
        if run.any():
            xr, Pr, Ar, br, Hr = x[run], P[run], A[run], b[run], H[run]
            d = dt[run]
            d3 = d[:, None, None]
            # ZOH (eq. 34), exact by the series because A @ A = 0
            F = self._I + Ar * d3
            G = br * d[:, None] + np.einsum("kij,kj->ki", Ar, br) * (d * d / 2.0)[:, None]
            AQ = Ar @ self._Qc
            Qd = self._Qc * d3 + (AQ + AQ.transpose(0, 2, 1)) * (d3 * d3 / 2.0) + \
                AQ @ Ar.transpose(0, 2, 1) * (d3**3 / 3.0)
            xr = np.einsum("kij,kj->ki", F, xr) + G
            Pr = F @ Pr @ F.transpose(0, 2, 1) + Qd
            z = np.column_stack([inputs.specific_force_x[run], inputs.yaw_rate[run], inputs.wheel_speed[run],
                                 inputs.ground_speed[run]])
            innov = z - np.einsum("kij,kj->ki", Hr, xr)
            s = np.einsum("kij,kij->ki", Hr @ Pr, Hr) + self._r  # diag(H P H^T) + diag(R)
            keep = innov**2 <= (cfg.gate_sigma**2) * s
            counts = self.rejections[ix[run]]
            keep |= counts >= cfg.gate_patience  # re-acquire a row rejected again and again
            self.rejections[ix[run]] = np.where(keep, 0, counts + 1)
            rejected[run] = np.count_nonzero(~keep, axis=1)
            upd = keep.any(axis=1)
            if upd.any():
                kp = keep[upd]
                Hm = Hr[upd] * kp[:, :, None]  # a gated row contributes nothing: zero H row ...
                y = innov[upd] * kp  # ... and zero innovation; its R entry is a harmless 1
                Rm = np.zeros((int(upd.sum()), N_MEAS, N_MEAS))
                diag = np.arange(N_MEAS)
                Rm[:, diag, diag] = np.where(kp, self._r, 1.0)
                Pu = Pr[upd]
                PHT = Pu @ Hm.transpose(0, 2, 1)
                S = Hm @ PHT + Rm
                K = PHT @ np.linalg.inv(S)
                xr[upd] = xr[upd] + np.einsum("kij,kj->ki", K, y)
                IKH = self._I - K @ Hm
                KR = K * Rm[:, diag, diag][:, None, :]  # K @ R with R diagonal
                Pr[upd] = IKH @ Pu @ IKH.transpose(0, 2, 1) + KR @ K.transpose(0, 2, 1)  # Joseph form
            # keep P symmetric positive definite over long runs (TractionObserver._condition)
            Pr = (Pr + Pr.transpose(0, 2, 1)) / 2.0
            nx = L.n
            dg = np.arange(nx)
            Pr[:, dg, dg] = np.clip(Pr[:, dg, dg], cfg.variance_floor, cfg.variance_ceiling)
            x[run], P[run] = xr, Pr
        self.x[ix], self.P[ix] = x, P
        self.last_stamp[ix] = stamp
        mu = x[:, L.mu]
        M = self.resistance_matrices(self.state_slip(x) if L.n_res == 2 else None, k)
        res = np.einsum("kir,kr->ki", M, x[:, L.res]) if L.n_res else np.zeros((k, 4))
        # gross_i = mu_i + (M x_res)_i: its variance from the joint covariance
        J = np.zeros((k, 4, L.n))
        J[:, :, L.mu] = np.eye(4)
        if L.n_res:
            J[:, :, L.res] = M
        dg = np.arange(L.n)
        return ObserverBatchOutput(
            mu=mu.copy(),
            mu_var=P[:, dg, dg][:, L.mu],
            resistance=res,
            gross=mu + res,
            gross_var=np.einsum("kil,kil->ki", J @ P, J),
            wheel_speed=x[:, L.omega].copy(),
            ground_speed=x[:, L.v].copy(),
            yaw_rate=x[:, L.psi].copy(),
            rejected=rejected,
            reset=reset,
            normal_force=fz,
        )


class BatchSoil:
    """N grid Bayes soil estimators (``soil_strength.BayesSoilEstimator``) stepped together."""

    def __init__(self, constants: ModelConstants, config: SoilConfig | None, n_vehicles: int):
        self.c = constants
        self.cfg = cfg = config or SoilConfig()
        if cfg.method != "bayes":
            raise ValueError(f"soil method {cfg.method!r}: the batched estimator implements 'bayes' only")
        self.n_vehicles = n = _check_count(n_vehicles)
        # the same grid, curve, prediction and summaries as the single-vehicle estimator
        self.grid = LogKGrid(constants, cfg)
        self.theta, self.k_grid = self.grid.theta, self.grid.k_grid
        self.p = np.full((n, cfg.grid_points), 1.0 / cfg.grid_points)
        self._names = self.grid.names
        self._onehot = (self.grid.class_idx[:, None] == np.arange(len(self._names))[None, :]).astype(float)
        self._holds = [_HoldLogic(cfg) for _ in range(n)]
        self.last_stamp = np.full(n, np.nan)

    def update(self, idx, stamp, slip, observed, variance, informative, slip_sigma, gate_slip=None,
               gate_sigma=None) -> list[SoilState]:
        """Fuse one sample per vehicle in ``idx``: arrays (k,) / (k, 4) as BayesSoilEstimator.update
        (``gate_slip`` / ``gate_sigma``: the smoothed slip and its 1-sigma the gate decides on)."""
        cfg = self.cfg
        ix = _check_index(idx, self.n_vehicles)
        k = ix.size
        stamp = np.asarray(stamp, dtype=float)
        slip, obs, var, s_sig = (np.asarray(a, dtype=float) for a in (slip, observed, variance, slip_sigma))
        for name, a in (("slip", slip), ("observed", obs), ("variance", var), ("slip_sigma", s_sig)):
            if a.shape != (k, 4):
                raise ValueError(f"{name} must have shape ({k}, 4), got {a.shape}")
        g_slip = slip if gate_slip is None else np.asarray(gate_slip, dtype=float)
        g_sig = s_sig if gate_sigma is None else np.asarray(gate_sigma, dtype=float)
        use = _gate(g_slip, np.asarray(informative, dtype=bool), cfg, g_sig) & (np.sign(g_slip) == np.sign(slip))
        p = self.p[ix]
        last = self.last_stamp[ix]
        with np.errstate(invalid="ignore"):
            dt = stamp - last
            pred = ~np.isnan(last) & (dt > 0)
        if pred.any():
            p[pred] = self.grid.predict(p[pred], dt[pred])
        self.last_stamp[ix] = stamp
        info = np.zeros(k, dtype=bool)
        upd = use.any(axis=1)
        if upd.any():
            u = use[upd]
            # the likelihood of the used wheels only, (m, G); the unused get a factor of exactly 1
            h, dh_ds = self.grid.curve(slip[upd][u][:, None])
            sig2 = var[upd][u][:, None] + cfg.model_sigma**2 + (dh_ds * s_sig[upd][u][:, None]) ** 2
            r2 = (obs[upd][u][:, None] - h) ** 2 / sig2
            like_used = (1 - cfg.outlier_prob) * np.exp(-0.5 * r2) / np.sqrt(sig2) + cfg.outlier_prob
            like = np.ones(u.shape + (self.theta.size,))
            like[u] = like_used
            loglike = np.log(np.prod(like, axis=1)) * cfg.temper
            post = p[upd] * np.exp(loglike - loglike.max(axis=1, keepdims=True))
            total = post.sum(axis=1)
            ok = (total > 0) & np.isfinite(total)
            rows = np.flatnonzero(upd)[ok]
            p[rows] = post[ok] / total[ok][:, None]
            info[rows] = True
        self.p[ix] = p
        # robust summaries of each belief: median and half the 16-84 % interval (in ln K and K)
        cdf = np.cumsum(p, axis=1) - 0.5 * p
        masses = p @ self._onehot
        best = masses.argmax(axis=1)
        best_mass = masses[np.arange(k), best].tolist()
        best = best.tolist()
        # per vehicle, plain Python floats from here on (the hold logic is the estimator's own)
        out = []
        for j, (ixj, st, inf, used) in enumerate(zip(ix.tolist(), stamp.tolist(), info.tolist(), use.tolist())):
            hold = self._holds[ixj]
            if inf:
                hold.last_update = st
            k_med, k_std, log_std = self.grid.summary(cdf[j])
            status, reason, (rk, rs, rl) = hold.status(st, k_med, k_std, log_std)
            cls = conf = None
            if rk is not None:
                if not inf:
                    cls, conf = classify(rk, rl, self.c)
                else:
                    cls, conf = self._names[best[j]], best_mass[j]
            out.append(SoilState(rk, rs, rl, cls, conf, status, reason, hold.last_update, tuple(used)))
        return out


def ocp_batch(soil_strength: np.ndarray, constants: ModelConstants) -> dict[str, np.ndarray]:
    """mu_T (eq. 8), S_T (eq. 7, sign corrected), S_E (eq. 10) and TE (eq. 9) at S_E for an array
    of K > 0, as ``ocp.ocp_from_soil_strength`` + ``pipeline.OcpStage`` (te NaN where undefined)."""
    c = constants
    k = np.asarray(soil_strength, dtype=float)
    if np.any(~(k > 0)) or not np.all(np.isfinite(c.C5 / k)):
        raise ValueError(f"soil_strength must be positive Ks the model can evaluate, got {k!r}")
    amp = c.C1 * -np.expm1(-c.C2 * k)
    st = np.maximum(np.log(c.C3 * np.sqrt(k) * amp / c.C6) / c.C3, 0.0)  # eq. 7 corrected
    s_eval = np.maximum(st, c.bridge_slip)  # a peak at the origin: the bridge's end point
    mu_t = amp * (1.0 - np.exp(-c.C3 * s_eval)) - (c.C5 / k + c.C6 * s_eval / np.sqrt(k))  # eqs. 6 / 8
    se = np.maximum((k - c.alpha) / c.beta, 0.0)  # eq. 10
    te = np.full_like(k, np.nan)
    m = (se > 0) & (se < 1)
    if m.any():
        net = curve_unchecked("net", se[m], k[m], c)[0]
        gross = curve_unchecked("gross", se[m], k[m], c)[0]
        te[m] = net / gross * (1.0 - se[m])  # eq. 9
    return {"mu_T": mu_t, "S_T": st, "S_E": se, "te_at_S_E": te}


@dataclass
class BatchStep:
    """Everything one batched step produced for the stepped vehicles (in ``idx`` order)."""

    idx: np.ndarray
    stamp: np.ndarray
    observer: ObserverBatchOutput
    slip: np.ndarray
    soil: list[SoilState]
    mu_T: list[Optional[float]]
    S_T: list[Optional[float]]
    S_E: list[Optional[float]]
    te_at_S_E: list[Optional[float]]

    def ocp_fields(self, j: int) -> dict:
        """The fields of ``schemas.pipeline.OcpEstimate`` (minus ids) of the j-th stepped vehicle,
        as ``pipeline.OcpStage`` fills them."""
        st = self.soil[j]
        return dict(
            stamp=float(self.stamp[j]),
            soil_strength=st.soil_strength,
            soil_strength_std=st.soil_strength_std,
            soil_class=st.soil_class,
            soil_class_confidence=st.soil_class_confidence,
            status=st.status,
            reason=st.reason,
            mu=tuple(float(v) for v in self.observer.mu[j]),
            slip=tuple(float(v) for v in self.slip[j]),
            mu_T=self.mu_T[j],
            S_T=self.S_T[j],
            S_E=self.S_E[j],
            te_at_S_E=self.te_at_S_E[j],
        )


class BatchPipeline:
    """Observer -> slip + soil strength -> OCPs for N vehicles (normal forces come from outside,
    as in the services: the normal-force stage is cheap and per sample)."""

    def __init__(self, config: PipelineConfig | None, n_vehicles: int):
        self.config = cfg = config or PipelineConfig()
        self.n_vehicles = _check_count(n_vehicles)
        self.observer = BatchObserver(cfg.vehicle, cfg.observer, self.n_vehicles)
        self.soil = BatchSoil(cfg.constants, cfg.soil, self.n_vehicles)
        self._wheel_y = np.asarray(cfg.vehicle.wheel_y, dtype=float)
        # SoilStage's low-pass slip for the gate (SoilConfig.gate_smoothing), per vehicle
        self._slip_lp = np.zeros((self.n_vehicles, 4))
        self._lp_stamp = np.full(self.n_vehicles, np.nan)

    @staticmethod
    def inputs_from_samples(samples: Sequence, normal_forces: Sequence) -> BatchInputs:
        """Stack ``SensorSample``s and their normal forces (each a 4-sequence) into BatchInputs."""
        if len(samples) != len(normal_forces):
            raise ValueError(f"{len(samples)} samples but {len(normal_forces)} normal-force quads")
        return BatchInputs(
            stamp=np.array([s.stamp for s in samples], dtype=float),
            specific_force_x=np.array([s.specific_force[0] for s in samples], dtype=float),
            yaw_rate=np.array([s.yaw_rate for s in samples], dtype=float),
            pitch=np.array([s.pitch for s in samples], dtype=float),
            wheel_speed=np.array([s.wheel_speed for s in samples], dtype=float).reshape(-1, 4),
            wheel_torque=np.array([s.wheel_torque for s in samples], dtype=float).reshape(-1, 4),
            ground_speed=np.array([s.ground_speed for s in samples], dtype=float),
            normal_force=np.array([np.asarray(f, dtype=float) for f in normal_forces]).reshape(-1, 4),
        )

    def step(self, idx, inputs: BatchInputs) -> BatchStep:
        cfg = self.config
        ix = _check_index(idx, self.n_vehicles)
        ob = self.observer.step(ix, inputs)
        # slip, eq. 1, at each wheel's ground speed V - psi_dot y_i (SoilStage)
        v_wheel = ob.ground_speed[:, None] - ob.yaw_rate[:, None] * self._wheel_y
        r = cfg.vehicle.wheel_radius
        rim = ob.wheel_speed * r
        scale = np.maximum(np.abs(rim), np.abs(v_wheel))
        slip = (rim - v_wheel) / np.maximum(scale, cfg.slip_floor)
        informative = (scale >= cfg.slip_deadband) & (ob.normal_force > LIFT_OFF_FORCE) & ~ob.reset[:, None]
        if cfg.soil.measurement == "gross":
            observed, var = ob.gross, ob.gross_var
        else:
            observed, var = ob.mu, ob.mu_var
        speed = np.maximum(np.abs(v_wheel), np.abs(ob.wheel_speed) * r)
        s_sig = np.hypot(cfg.soil.slip_sigma, cfg.soil.speed_sigma / np.maximum(speed, 1e-3))  # slip_uncertainty
        # the gate looks at a low-pass slip (SoilStage, method-notes §9): restart it on a reset,
        # a first sample, a gap > 1 s or a non-increasing stamp
        tau = cfg.soil.gate_smoothing
        last = self._lp_stamp[ix]
        with np.errstate(invalid="ignore"):
            dt = np.where(np.isnan(last), 0.0, inputs.stamp - last)
        restart = np.isnan(last) | ob.reset | (tau <= 0) | (dt <= 0) | (dt > 1.0)
        alpha = np.ones(ix.size)
        if tau > 0:
            alpha = np.where(restart, 1.0, -np.expm1(-np.where(restart, 0.0, dt) / tau))
        lp = np.where(restart[:, None], slip, self._slip_lp[ix] + alpha[:, None] * (slip - self._slip_lp[ix]))
        self._slip_lp[ix] = lp
        self._lp_stamp[ix] = inputs.stamp
        g_sig = s_sig * np.sqrt(alpha / (2.0 - alpha))[:, None]  # stationary std of low-passed white noise
        # (with tau = 0 every step restarts: lp = slip, g_sig = s_sig, the gate on the raw slip)
        soil = self.soil.update(ix, inputs.stamp, slip, observed, var, informative, s_sig, lp, g_sig)
        ks = np.array([s.soil_strength if s.soil_strength is not None else np.nan for s in soil])
        have = ~np.isnan(ks)
        n = ix.size
        mu_t: list[Optional[float]] = [None] * n
        s_t: list[Optional[float]] = [None] * n
        s_e: list[Optional[float]] = [None] * n
        te: list[Optional[float]] = [None] * n
        if have.any():
            o = ocp_batch(ks[have], cfg.constants)
            for j, jj in enumerate(np.flatnonzero(have)):
                mu_t[jj], s_t[jj], s_e[jj] = float(o["mu_T"][j]), float(o["S_T"][j]), float(o["S_E"][j])
                t = float(o["te_at_S_E"][j])
                te[jj] = None if math.isnan(t) else t
        return BatchStep(ix, inputs.stamp, ob, slip, soil, mu_t, s_t, s_e, te)
