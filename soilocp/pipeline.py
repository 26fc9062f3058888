"""The estimation chain as stages: normal forces -> observer -> slip + soil strength -> OCPs.

Each stage is a small deterministic object with a ``step`` method that takes and returns the
message models of ``schemas.pipeline``.  The offline ``soilocp estimate`` composes them in one
process (:class:`VehiclePipeline`); the live services run one stage each and pass the same
messages over Zenoh.  Same code, same numbers.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from schemas.pipeline import NormalForces, ObserverOutput, OcpEstimate, SoilEstimate
from schemas.sensor import SensorSample

from .constants import DEFAULT_CONSTANTS, ModelConstants, load_constants
from .normal_force import NormalForceSolver
from .observer import ObserverConfig, TractionObserver
from .ocp import ocp_from_soil_strength
from .slip import DEFAULT_DEADBAND, DEFAULT_FLOOR, slip_ratio_unchecked
from .soil_strength import SoilConfig, make_soil_estimator, slip_uncertainty
from .traction import tractive_efficiency_scalar
from .vehicle import DEFAULT_VEHICLE, VehicleParams, load_vehicle

#: Normal force (N) below which a wheel is treated as lifted off: no traction information.
LIFT_OFF_FORCE = 1.0


class PipelineConfig(BaseModel):
    """Everything the estimation chain needs: vehicle, model constants, observer and soil settings."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    vehicle: VehicleParams = DEFAULT_VEHICLE
    constants: ModelConstants = DEFAULT_CONSTANTS
    observer: ObserverConfig = Field(default_factory=ObserverConfig)
    soil: SoilConfig = Field(default_factory=SoilConfig)
    slip_deadband: float = Field(DEFAULT_DEADBAND, ge=0, description="m/s below which slip is not informative (eq. 1)")
    slip_floor: float = Field(DEFAULT_FLOOR, gt=0, description="floor of eq. 1's denominator, m/s")


def load_pipeline_config(
    path: str | Path | None = None,
    *,
    vehicle: str | Path | None = None,
    constants: str | Path | None = None,
) -> PipelineConfig:
    """Read a pipeline config (JSON, shape of PipelineConfig; every key optional) and apply
    separate vehicle / constants files on top.  Errors name the file and the field."""
    data: dict = {}
    if path is not None:
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except FileNotFoundError as exc:
            raise ValueError(f"config file {str(p)!r} does not exist") from exc
        except json.JSONDecodeError as exc:
            raise ValueError(f"config file {str(p)!r} is not valid JSON: {exc}") from exc
        if not isinstance(data, dict):
            raise ValueError(f"config file {str(p)!r} must hold a JSON object")
    try:
        cfg = PipelineConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"config {str(path)!r}: {exc}") from exc
    update = {}
    if vehicle is not None:
        update["vehicle"] = load_vehicle(vehicle)
    if constants is not None:
        update["constants"] = load_constants(constants)
    return cfg.model_copy(update=update) if update else cfg


def _quad(a) -> tuple[float, float, float, float]:
    return tuple(np.asarray(a, dtype=float).tolist())  # type: ignore[return-value]


class NormalForceStage:
    """Normal forces from the measured specific force (eqs. 16-25, zero-warp, method-notes §2-3)."""

    def __init__(self, config: PipelineConfig):
        self.vehicle = config.vehicle
        self._solve = NormalForceSolver(config.vehicle)

    def step(self, sample: SensorSample) -> NormalForces:
        fz = self._solve(sample.specific_force)
        return NormalForces(
            vehicle_id=sample.vehicle_id,
            seq=sample.seq,
            stamp=sample.stamp,
            normal_force=_quad(fz),
            lift_off=bool(np.any(fz <= LIFT_OFF_FORCE)),
        )


class ObserverStage:
    """Per-wheel traction observer (eqs. 26-35 on filterpy; state chosen observable, §7)."""

    def __init__(self, config: PipelineConfig):
        self.observer = TractionObserver(config.vehicle, config.observer)

    def step(self, sample: SensorSample, forces: NormalForces) -> ObserverOutput:
        if forces.seq != sample.seq or forces.vehicle_id != sample.vehicle_id:
            raise ValueError(
                f"normal forces are for {forces.vehicle_id}#{forces.seq}, sample is {sample.vehicle_id}#{sample.seq}"
            )
        fz = np.maximum(np.asarray(forces.normal_force), LIFT_OFF_FORCE)
        est = self.observer.step(
            sample.stamp,
            sample.specific_force[0],
            sample.yaw_rate,
            sample.pitch,
            sample.wheel_speed,
            sample.wheel_torque,
            sample.ground_speed,
            fz,
        )
        return ObserverOutput(
            vehicle_id=sample.vehicle_id,
            seq=sample.seq,
            stamp=sample.stamp,
            mu=_quad(est.mu),
            mu_var=_quad(est.mu_var),
            resistance=_quad(est.resistance),
            gross=_quad(est.gross),
            gross_var=_quad(est.gross_var),
            wheel_speed=_quad(est.wheel_speed),
            ground_speed=est.ground_speed,
            yaw_rate=est.yaw_rate,
            normal_force=_quad(fz),
            rejected_measurements=est.rejected,
            reset=est.reset,
        )


class SoilStage:
    """Slip per wheel (eq. 1, from the filtered speeds) and soil strength K (eqs. 36-37, corrected)."""

    def __init__(self, config: PipelineConfig):
        self.cfg = config
        self.estimator = make_soil_estimator(config.constants, config.soil)
        v = config.vehicle
        self._wheel_y = np.asarray(v.wheel_y)
        self._slip_lp: Optional[np.ndarray] = None  # low-pass slip for the gate (SoilConfig.gate_smoothing)
        self._last_stamp: Optional[float] = None

    def step(self, obs: ObserverOutput) -> SoilEstimate:
        cfg = self.cfg
        # ground speed at each wheel of a differentially steered body: V - psi_dot * y_i
        v_wheel = obs.ground_speed - obs.yaw_rate * self._wheel_y
        s = slip_ratio_unchecked(np.asarray(obs.wheel_speed), v_wheel, cfg.vehicle.wheel_radius,
                                 cfg.slip_deadband, cfg.slip_floor)
        informative = s.informative & (np.asarray(obs.normal_force) > LIFT_OFF_FORCE) & (not obs.reset)
        if cfg.soil.measurement == "gross":
            observed, var = obs.gross, obs.gross_var
        else:
            observed, var = obs.mu, obs.mu_var
        speed = np.maximum(np.abs(v_wheel), np.abs(np.asarray(obs.wheel_speed)) * cfg.vehicle.wheel_radius)
        sigma = slip_uncertainty(speed, cfg.soil)
        # the gate looks at a low-pass slip: deciding on the raw slip would keep the samples whose
        # noise pushed |S| over the threshold and bias K (method-notes §9)
        tau = cfg.soil.gate_smoothing
        dt = 0.0 if self._last_stamp is None else obs.stamp - self._last_stamp
        if self._slip_lp is None or obs.reset or tau <= 0 or dt <= 0 or dt > 1.0:
            self._slip_lp, alpha = s.slip.copy(), 1.0
        else:
            alpha = -np.expm1(-dt / tau)
            self._slip_lp = self._slip_lp + alpha * (s.slip - self._slip_lp)
        self._last_stamp = obs.stamp
        gate_sigma = sigma * np.sqrt(alpha / (2.0 - alpha))  # stationary std of the low-passed white noise
        st = self.estimator.update(obs.stamp, s.slip, observed, var, informative, sigma, self._slip_lp, gate_sigma)
        return SoilEstimate(
            vehicle_id=obs.vehicle_id,
            seq=obs.seq,
            stamp=obs.stamp,
            slip=_quad(s.slip),
            informative=st.used,
            soil_strength=st.soil_strength,
            soil_strength_std=st.soil_strength_std,
            log_k_std=st.log_k_std,
            soil_class=st.soil_class,
            soil_class_confidence=st.soil_class_confidence,
            status=st.status,
            reason=st.reason,
            last_update_stamp=st.last_update_stamp,
            mu=obs.mu,
        )


class OcpStage:
    """mu_T, S_T, S_E from K: eqs. 8, 7 (sign corrected), 10; TE (eq. 9) at S_E."""

    def __init__(self, config: PipelineConfig):
        self.constants: ModelConstants = config.constants

    def step(self, soil: SoilEstimate) -> OcpEstimate:
        common = dict(
            vehicle_id=soil.vehicle_id,
            seq=soil.seq,
            stamp=soil.stamp,
            soil_strength=soil.soil_strength,
            soil_strength_std=soil.soil_strength_std,
            soil_class=soil.soil_class,
            soil_class_confidence=soil.soil_class_confidence,
            status=soil.status,
            reason=soil.reason,
            mu=soil.mu,
            slip=soil.slip,
        )
        if soil.soil_strength is None:
            return OcpEstimate(mu_T=None, S_T=None, S_E=None, te_at_S_E=None, **common)
        o = ocp_from_soil_strength(soil.soil_strength, self.constants)
        te: Optional[float] = None
        if 0 < o.S_E < 1 and o.S_E >= self.constants.bridge_slip:
            te = tractive_efficiency_scalar(o.S_E, o.soil_strength, self.constants)
        return OcpEstimate(mu_T=o.mu_T, S_T=o.S_T, S_E=o.S_E, te_at_S_E=te, **common)


class VehiclePipeline:
    """The four stages composed, for one vehicle: the offline path (``soilocp estimate``)."""

    def __init__(self, config: PipelineConfig | None = None):
        self.config = config or PipelineConfig()
        self.normal = NormalForceStage(self.config)
        self.observer = ObserverStage(self.config)
        self.soil = SoilStage(self.config)
        self.ocp = OcpStage(self.config)

    def process_all(self, sample: SensorSample) -> tuple[NormalForces, ObserverOutput, SoilEstimate, OcpEstimate]:
        nf = self.normal.step(sample)
        ob = self.observer.step(sample, nf)
        so = self.soil.step(ob)
        return nf, ob, so, self.ocp.step(so)

    def process(self, sample: SensorSample) -> OcpEstimate:
        return self.process_all(sample)[3]
