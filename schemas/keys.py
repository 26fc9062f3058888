"""Every Zenoh key expression of soilocp, in one place.

No other module builds a key by hand: services, tests, the dashboard and the fleet tools call the
functions below, so a key can change in one place and a vehicle id can never smuggle a ``/``,
``*``, ``$``, ``?``, ``#`` or ``@`` into a key (ids are checked against
:data:`schemas.sensor.VEHICLE_ID_PATTERN`).

Public keys (a contract for other programs, see ``docs/services.md``)::

    soilocp/<vid>/sensors/raw          SensorSample JSON, one sample per put (drivers, synthetic vehicle)
    soilocp/<vid>/ocp                  OcpEstimate JSON per sample (publication); queryable -> OcpReply
                                       (?last=N or ?since=STAMP add a history)
    soilocp/<vid>/rejected             Rejection JSON, one per rejected raw sample
    soilocp/<vid>/alive/<service>      liveliness token of each running service
    soilocp/<vid>/control/slip         SlipSetpoint JSON: wheel slip set-points of the controller service
                                       (on each OCP, and the safe fallback while the OCPs are stale)

Internal keys (between the services of one vehicle; stable, documented, but not a promise)::

    soilocp/<vid>/sensors/clean        SensorSample JSON that passed the gateway
    soilocp/<vid>/normal_forces        NormalForces JSON
    soilocp/<vid>/observer             ObserverOutput JSON
    soilocp/<vid>/soil                 SoilEstimate JSON
    soilocp/<vid>/status/<service>     ServiceHealth JSON: published periodically and on changes
                                       (e.g. the OCP publisher going stale) and answered by a queryable
"""

from __future__ import annotations

import re

from schemas.sensor import VEHICLE_ID_PATTERN

ROOT = "soilocp"

# Service names (key chunks, so they obey the same character rules) are declared with the pipeline,
# in services/stages/graph.py.

_VID_RE = re.compile(VEHICLE_ID_PATTERN)
_SERVICE_RE = re.compile(r"^[a-z][a-z0-9-]{0,31}$")


def check_vehicle_id(vehicle_id: object) -> str:
    """Return ``vehicle_id`` if it is a valid id ([A-Za-z0-9_-]{1,64}); ValueError otherwise.

    The id is a key chunk: anything else (``/``, wildcards, ``@``, ``$``, ``?``, blanks, empty)
    could address another vehicle's keys or the whole fleet.
    """
    if not isinstance(vehicle_id, str) or not _VID_RE.fullmatch(vehicle_id):
        raise ValueError(
            f"vehicle_id {vehicle_id!r} is invalid: it must match [A-Za-z0-9_-]{{1,64}} "
            "(it becomes part of Zenoh keys)"
        )
    return vehicle_id


def check_service(service: object) -> str:
    """Return ``service`` if it is a valid service key chunk; ValueError otherwise."""
    if not isinstance(service, str) or not _SERVICE_RE.fullmatch(service):
        raise ValueError(f"service name {service!r} is invalid: it must match [a-z][a-z0-9-]{{0,31}}")
    return service


def _vid(vehicle_id: str) -> str:
    # "*" is allowed only through the explicit fleet helpers below.
    return check_vehicle_id(vehicle_id)


# --- public -----------------------------------------------------------------------------------
def raw(vehicle_id: str) -> str:
    """Raw sensor input: ``soilocp/<vid>/sensors/raw``."""
    return f"{ROOT}/{_vid(vehicle_id)}/sensors/raw"


def ocp(vehicle_id: str) -> str:
    """OCP output (publication and queryable): ``soilocp/<vid>/ocp``."""
    return f"{ROOT}/{_vid(vehicle_id)}/ocp"


def control_slip(vehicle_id: str) -> str:
    """Wheel slip set-points of the controller service: ``soilocp/<vid>/control/slip``."""
    return f"{ROOT}/{_vid(vehicle_id)}/control/slip"


def rejected(vehicle_id: str) -> str:
    """Rejections of the gateway: ``soilocp/<vid>/rejected``."""
    return f"{ROOT}/{_vid(vehicle_id)}/rejected"


def alive(vehicle_id: str, service: str) -> str:
    """Liveliness token of one service: ``soilocp/<vid>/alive/<service>``."""
    return f"{ROOT}/{_vid(vehicle_id)}/alive/{check_service(service)}"


# --- internal ---------------------------------------------------------------------------------
def clean(vehicle_id: str) -> str:
    """Validated samples from the gateway: ``soilocp/<vid>/sensors/clean``."""
    return f"{ROOT}/{_vid(vehicle_id)}/sensors/clean"


def normal_forces(vehicle_id: str) -> str:
    """Normal forces per wheel: ``soilocp/<vid>/normal_forces``."""
    return f"{ROOT}/{_vid(vehicle_id)}/normal_forces"


def observer(vehicle_id: str) -> str:
    """Observer output: ``soilocp/<vid>/observer``."""
    return f"{ROOT}/{_vid(vehicle_id)}/observer"


def soil(vehicle_id: str) -> str:
    """Soil-strength estimate: ``soilocp/<vid>/soil``."""
    return f"{ROOT}/{_vid(vehicle_id)}/soil"


def status(vehicle_id: str, service: str) -> str:
    """Health/status of one service: ``soilocp/<vid>/status/<service>``."""
    return f"{ROOT}/{_vid(vehicle_id)}/status/{check_service(service)}"


# --- fleet-wide selectors (wildcards; for subscribers and gets only, never for puts) -----------
def any_vehicle_ocp() -> str:
    """Every vehicle's OCP: ``soilocp/*/ocp``."""
    return f"{ROOT}/*/ocp"


def vehicle_alive_all(vehicle_id: str) -> str:
    """Every liveliness token of one vehicle: ``soilocp/<vid>/alive/*``."""
    return f"{ROOT}/{_vid(vehicle_id)}/alive/*"


def any_vehicle_alive() -> str:
    """Every liveliness token of the fleet: ``soilocp/*/alive/*``."""
    return f"{ROOT}/*/alive/*"


def vehicle_status_all(vehicle_id: str) -> str:
    """Every status key of one vehicle: ``soilocp/<vid>/status/*``."""
    return f"{ROOT}/{_vid(vehicle_id)}/status/*"


def any_vehicle_status() -> str:
    """Every status key of the fleet: ``soilocp/*/status/*``."""
    return f"{ROOT}/*/status/*"


def any_vehicle_rejected() -> str:
    """Every vehicle's rejections: ``soilocp/*/rejected``."""
    return f"{ROOT}/*/rejected"


# --- parsing ----------------------------------------------------------------------------------
_PARSE_RE = re.compile(rf"^{ROOT}/([^/]+)/(.+)$")


def split_key(key: str) -> tuple[str, str]:
    """Split a concrete key into ``(vehicle_id, rest)``; ValueError if it is not a soilocp key.

    ``split_key("soilocp/rover1/alive/gateway") == ("rover1", "alive/gateway")``.
    """
    m = _PARSE_RE.match(str(key))
    if not m:
        raise ValueError(f"key {key!r} is not a soilocp key ({ROOT}/<vehicle_id>/...)")
    return check_vehicle_id(m.group(1)), m.group(2)


def service_of_alive_key(key: str) -> tuple[str, str]:
    """``(vehicle_id, service)`` of a liveliness key ``soilocp/<vid>/alive/<service>``."""
    vid, rest = split_key(key)
    head, _, service = rest.partition("/")
    if head != "alive" or not service:
        raise ValueError(f"key {key!r} is not a liveliness key ({ROOT}/<vid>/alive/<service>)")
    return vid, check_service(service)
