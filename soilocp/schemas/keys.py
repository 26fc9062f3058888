"""Every Zenoh key expression of soilocp, in one place.

No other module builds a key by hand: services, tests, the dashboard and the fleet tools call the
functions below, so a key can change in one place and a vehicle id can never smuggle a ``/``,
``*``, ``$``, ``?``, ``#`` or ``@`` into a key (ids are checked against
:data:`VEHICLE_ID_PATTERN`, defined here so that the key functions need no pydantic: the router and
the fleet tools' ACLs use them).

Public keys (a contract for other programs, see ``docs/services.md``)::

    soilocp/<vid>/sensors/raw          SensorSample JSON, one sample per put (drivers, synthetic vehicle)
    soilocp/<vid>/ocp                  OcpEstimate JSON per sample (publication); queryable -> OcpReply
                                       (?last=N or ?since=STAMP add a history)
    soilocp/<vid>/rejected             Rejection JSON, one per rejected raw sample (a flood: 50/s, the rest counted)
    soilocp/<vid>/alive/<service>      liveliness token of each running service
    soilocp/<vid>/control/slip         SlipSetpoint JSON: wheel slip set-points of the controller service
    soilocp/<vid>/control/drive        DriveSetpoint JSON: speed and slip set-points of a calibration drive
                                       (on each OCP, and the safe fallback while the OCPs are stale)
    soilocp/<vid>/supervisor           SupervisorStatus JSON: the processes ``soilocp run`` runs for the
                                       vehicle and their restarts (at each restart; queryable)

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
from typing import Callable

#: A vehicle id: a key chunk, and the ``vehicle_id`` field of every message (soilocp.schemas.sensor).
VEHICLE_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"

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


def _vehicle_key(tail: str, what: str) -> Callable[[str], str]:
    """A builder ``f(vehicle_id) -> "soilocp/<vid>/<tail>"``, the id checked."""

    def build(vehicle_id: str) -> str:
        return f"{ROOT}/{_vid(vehicle_id)}/{tail}"

    build.__doc__ = f"{what}: ``{ROOT}/<vid>/{tail}``."
    return build


def _service_key(tail: str, what: str) -> Callable[[str, str], str]:
    """A builder ``f(vehicle_id, service) -> "soilocp/<vid>/<tail>/<service>"``, both checked."""

    def build(vehicle_id: str, service: str) -> str:
        return f"{ROOT}/{_vid(vehicle_id)}/{tail}/{check_service(service)}"

    build.__doc__ = f"{what}: ``{ROOT}/<vid>/{tail}/<service>``."
    return build


def _fleet_selector(tail: str, what: str) -> Callable[[], str]:
    """A wildcard selector over every vehicle: ``soilocp/*/<tail>`` (for subscribers and gets only,
    never for puts)."""

    def build() -> str:
        return f"{ROOT}/*/{tail}"

    build.__doc__ = f"{what}: ``{ROOT}/*/{tail}``."
    return build


# --- public -----------------------------------------------------------------------------------
raw = _vehicle_key("sensors/raw", "Raw sensor input")
ocp = _vehicle_key("ocp", "OCP output (publication and queryable)")
control_slip = _vehicle_key("control/slip", "Wheel slip set-points of the controller service")
control_drive = _vehicle_key("control/drive", "Speed and slip set-points of a calibration drive (soilocp calibrate-drive)")
rejected = _vehicle_key("rejected", "Rejections of the gateway")
alive = _service_key("alive", "Liveliness token of one service")
supervisor = _vehicle_key("supervisor", "The supervisor of soilocp run: its processes and their restarts")

# --- internal ---------------------------------------------------------------------------------
clean = _vehicle_key("sensors/clean", "Validated samples from the gateway")
normal_forces = _vehicle_key("normal_forces", "Normal forces per wheel")
observer = _vehicle_key("observer", "Observer output")
soil = _vehicle_key("soil", "Soil-strength estimate")
status = _service_key("status", "Health/status of one service")

# --- selectors (wildcards; for subscribers and gets only, never for puts) ---------------------
vehicle_alive_all = _vehicle_key("alive/*", "Every liveliness token of one vehicle")
vehicle_status_all = _vehicle_key("status/*", "Every status key of one vehicle")
any_vehicle_ocp = _fleet_selector("ocp", "Every vehicle's OCP")
any_vehicle_raw = _fleet_selector("sensors/raw", "Every vehicle's raw sensor input")
any_vehicle_alive = _fleet_selector("alive/*", "Every liveliness token of the fleet")
any_vehicle_status = _fleet_selector("status/*", "Every status key of the fleet")
any_vehicle_rejected = _fleet_selector("rejected", "Every vehicle's rejections")
any_vehicle_supervisor = _fleet_selector("supervisor", "Every vehicle's supervisor status")


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


# --- the fleet soil map (docs/map.md): its own root, so soilocp/*/... never matches it --------
MAP_ROOT = "soilmap"
_MAP_ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


def check_map_id(map_id: object) -> str:
    """Return ``map_id`` if it is a valid map id ([A-Za-z0-9_-]{1,64}); ValueError otherwise."""
    if not isinstance(map_id, str) or not _MAP_ID_RE.fullmatch(map_id):
        raise ValueError(f"map id {map_id!r} is invalid: it must match [A-Za-z0-9_-]{{1,64}} (it becomes a key chunk)")
    return map_id


def map_key(map_id: str, tail: str) -> str:
    """``soilmap/<map_id>/<tail>``, tail one of cells, query, rejected, status, alive."""
    if tail not in ("cells", "query", "rejected", "status", "alive"):
        raise ValueError(f"map key tail {tail!r} is not one of cells, query, rejected, status, alive")
    return f"{MAP_ROOT}/{check_map_id(map_id)}/{tail}"


any_vehicle_soil = _fleet_selector("soil", "Every vehicle's soil estimate (the map service's input)")

