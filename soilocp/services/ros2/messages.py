"""soilocp's records as ROS 2 messages: the estimate as ``soilocp_msgs/msg/SoilEstimate``, status
and health as ``diagnostic_msgs/msg/DiagnosticArray`` (one DiagnosticStatus per service and one
for the estimate, with levels the way robot_localization and diagnostic_updater use them)."""

from __future__ import annotations

import math
from typing import Any, Iterable, Optional

import numpy as np

from soilocp.schemas.messages import ServiceHealth
from soilocp.schemas.pipeline import OcpEstimate
from soilocp.services.ros2.rmw_zenoh import DIAGNOSTICS_TYPE, ESTIMATE_TYPE, typestore

#: diagnostic_msgs/msg/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3

#: estimate status -> level: an estimate the controller may use is OK; one it should treat with
#: care (wide band, held, not determined, model does not fit) is WARN; a stopped input is STALE
ESTIMATE_LEVEL = {"ok": OK, "uncertain": WARN, "holding": WARN, "no_estimate": WARN, "not_observable": WARN,
                  "model_mismatch": WARN, "stale": STALE}
#: service state -> level
SERVICE_LEVEL = {"starting": OK, "running": OK, "stopping": WARN, "failing": ERROR, "stale": STALE}


def _time(stamp: float):
    T = typestore().types["builtin_interfaces/msg/Time"]
    ns = int(round(stamp * 1e9)) if stamp > 0 else 0
    return T(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _header(stamp: float, frame_id: str):
    return typestore().types["std_msgs/msg/Header"](stamp=_time(stamp), frame_id=frame_id)


def _nan(v: Optional[float]) -> float:
    return math.nan if v is None else float(v)


def soil_estimate(rec: OcpEstimate, frame_id: str = "base_link"):
    """The SoilEstimate message of one OCP record (None -> NaN, or "" for the class)."""
    T = typestore().types[ESTIMATE_TYPE]
    return T(
        header=_header(rec.stamp, frame_id), vehicle_id=rec.vehicle_id, seq=rec.seq, status=rec.status,
        reason=rec.reason, soil_strength=_nan(rec.soil_strength), soil_strength_std=_nan(rec.soil_strength_std),
        soil_class=rec.soil_class or "", soil_class_confidence=_nan(rec.soil_class_confidence),
        mu_t=_nan(rec.mu_T), s_t=_nan(rec.S_T), s_e=_nan(rec.S_E), te_at_s_e=_nan(rec.te_at_S_E),
        mu=np.asarray(rec.mu, dtype=np.float64), mu_determined=np.asarray(rec.mu_determined, dtype=bool),
        slip=np.asarray(rec.slip, dtype=np.float64))


def _kv(key: str, value: Any):
    return typestore().types["diagnostic_msgs/msg/KeyValue"](key=key, value="" if value is None else str(value))


def _status(level: int, name: str, message: str, hardware_id: str, values: Iterable[tuple[str, Any]]):
    return typestore().types["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level, name=name, message=message,
        hardware_id=hardware_id, values=[_kv(k, v) for k, v in values])


def estimate_status(vehicle_id: str, rec: Optional[OcpEstimate], age_s: Optional[float], stale_timeout_s: float):
    """The estimate's DiagnosticStatus: level from its status (STALE once no record came for the
    stale timeout, or none ever came), message ``status: reason``, values K, OCPs, seq, age."""
    name = f"soilocp/{vehicle_id}/estimate"
    if rec is None:
        return _status(STALE, name, "no estimate received yet", vehicle_id, [])
    stale = age_s is not None and age_s > stale_timeout_s
    level = STALE if stale else ESTIMATE_LEVEL[rec.status]
    status = "stale" if stale else rec.status
    msg = status + (f": {rec.reason}" if rec.reason else "") + (f" (no record for {age_s:.1f} s)" if stale else "")
    return _status(level, name, msg, vehicle_id, [
        ("seq", rec.seq), ("stamp", f"{rec.stamp:.6f}"), ("age_s", None if age_s is None else f"{age_s:.3f}"),
        ("soil_strength", rec.soil_strength), ("soil_strength_std", rec.soil_strength_std),
        ("soil_class", rec.soil_class), ("mu_T", rec.mu_T), ("S_T", rec.S_T), ("S_E", rec.S_E)])


def service_status(h: ServiceHealth, age_s: float, stale_after_s: float):
    """One service's DiagnosticStatus: level from its state (ERROR when failing, STALE when its
    reports stopped), its counters as values."""
    stale = age_s > stale_after_s
    level = STALE if stale else SERVICE_LEVEL.get(h.state, WARN)
    msg = ("no health report for %.1f s" % age_s) if stale else h.state
    vals = [("state", h.state), ("received", h.received), ("published", h.published), ("rejected", h.rejected),
            ("dropped", h.dropped), ("errors", h.errors), ("failure_rate", f"{h.failure_rate:.3f}"),
            ("queue_depth", h.queue_depth), ("last_seq", h.last_seq), ("pid", h.pid), ("host", h.host),
            *sorted(h.detail.items())]  # e.g. the ROS 2 reader's messages, drops and skips by reason
    return _status(level, f"soilocp/{h.vehicle_id}/{h.service}", msg, h.vehicle_id, vals)


def diagnostic_array(stamp_wall: float, statuses: list):
    return typestore().types[DIAGNOSTICS_TYPE](header=_header(stamp_wall, ""), status=statuses)
