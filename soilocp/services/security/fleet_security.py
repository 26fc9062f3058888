"""The secure fleet's Zenoh settings: mutual TLS on the links that leave a vehicle, and the fleet
router's access control (Zenoh ``access_control``, subjects identified by the certificate's
common name).

Who may do what at the fleet router (``default_permission: deny``: anything not listed is
dropped, and a transport whose certificate names nobody below matches no policy at all):

* vehicle ``<id>`` (certificate CN = the vehicle id): publish, declare queryables and liveliness
  tokens, reply, only under ``soilocp/<id>/**``.  Towards it the router forwards only the
  interest of fleet tools (subscriptions, queries, liveliness queries): nothing another vehicle or
  a tool published, so one vehicle cannot read another's data through the fleet.
* fleet tools (dashboard, fleet CLI, recorder; CN from ``tools``): subscribe, query and take
  liveliness under ``soilocp/**`` and the soil map's ``soilmap/**``, and receive what that
  returns; never put, delete, reply, declare a queryable or a liveliness token.
* map services (CN = the map id, from ``maps``; docs/map.md): read like a tool (the vehicles' soil
  estimates), and publish, answer queries and hold their token only under ``soilmap/<id>/**``.
  A vehicle cannot write the map: it writes only its own estimates, and the map service checks
  that each estimate names the vehicle of the key it came on.

Key matching: Zenoh allows a message when a rule's key expression *includes* the message's key,
so the interest forwarded to a vehicle (``soilocp/*/ocp``) needs ``soilocp/**``, while what a
vehicle publishes must fall under its own ``soilocp/<id>/**``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any, Iterable, Optional

from soilocp.schemas import keys

#: Environment: the CA every peer's certificate must chain to, and this process's own certificate.
ENV_TLS_CA = "SOILOCP_TLS_CA"
ENV_TLS_CERT = "SOILOCP_TLS_CERT"
ENV_TLS_KEY = "SOILOCP_TLS_KEY"
#: Environment of the fleet router: the vehicle ids (= certificate CNs) it admits, comma-separated.
ENV_FLEET_VEHICLES = "SOILOCP_FLEET_VEHICLES"
ENV_FLEET_TOOLS = "SOILOCP_FLEET_TOOLS"
ENV_FLEET_MAPS = "SOILOCP_FLEET_MAPS"  # map ids (= certificate CNs) of the fleet's map services

ALL = "soilocp/**"
#: The fleet soil map's keys (soilocp.schemas.keys.MAP_ROOT): fleet tools read them, a map service writes its own.
MAPS = "soilmap/**"
_VEHICLE_IN = ["put", "delete", "declare_subscriber", "declare_queryable", "reply", "liveliness_token",
               "declare_liveliness_subscriber", "query", "liveliness_query"]
_VEHICLE_OUT = ["declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber"]
_TOOL_IN = ["declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber"]
_TOOL_OUT = ["put", "delete", "reply", "declare_queryable", "liveliness_token", "declare_subscriber"]
_MAP_IN = ["put", "delete", "declare_queryable", "reply", "liveliness_token"]


@dataclass(frozen=True)
class TlsFiles:
    """PEM files of one process: the CA to verify the other end with, and its own certificate."""

    ca: str
    cert: str
    key: str

    def check(self) -> "TlsFiles":
        for what, path in (("CA certificate", self.ca), ("certificate", self.cert), ("private key", self.key)):
            if not os.path.isfile(path):
                raise ValueError(f"TLS {what} {path!r}: no such file")
            if not os.access(path, os.R_OK):
                raise ValueError(f"TLS {what} {path!r}: not readable by this user (uid {os.getuid()})")
        return self


def tls_from_env(env: Optional[dict[str, str]] = None) -> Optional[TlsFiles]:
    """TlsFiles from SOILOCP_TLS_CA / _CERT / _KEY (all three or none; ValueError otherwise)."""
    env = dict(os.environ) if env is None else env
    values = {k: env.get(k, "").strip() for k in (ENV_TLS_CA, ENV_TLS_CERT, ENV_TLS_KEY)}
    if not any(values.values()):
        return None
    missing = [k for k, v in values.items() if not v]
    if missing:
        raise ValueError(f"TLS settings incomplete: {', '.join(missing)} not set (the CA, the certificate and "
                         "its key go together)")
    return TlsFiles(values[ENV_TLS_CA], values[ENV_TLS_CERT], values[ENV_TLS_KEY])


def apply_tls(conf, tls: TlsFiles, *, listener: bool) -> None:
    """Insert the TLS files into a ``zenoh.Config``.

    Every process presents its own certificate when it connects (mutual TLS: the fleet router
    admits nobody without one); a listener (the fleet router) also serves it and, with
    ``enable_mtls``, demands one from every client.  Plain ``tcp/`` endpoints of the same process are unaffected.
    """
    tls.check()
    base = "transport/link/tls"
    conf.insert_json5(f"{base}/root_ca_certificate", json.dumps(tls.ca))
    conf.insert_json5(f"{base}/connect_certificate", json.dumps(tls.cert))
    conf.insert_json5(f"{base}/connect_private_key", json.dumps(tls.key))
    # also on the connecting side: without it Zenoh does not send the client certificate at all
    conf.insert_json5(f"{base}/enable_mtls", "true")
    if listener:
        conf.insert_json5(f"{base}/listen_certificate", json.dumps(tls.cert))
        conf.insert_json5(f"{base}/listen_private_key", json.dumps(tls.key))


def _rule(rid: str, messages: list[str], flow: str, key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rid, "messages": messages, "flows": [flow], "permission": "allow", "key_exprs": key_exprs}


def fleet_access_control(vehicles: Iterable[str], tools: Iterable[str], maps: Iterable[str] = ()) -> dict[str, Any]:
    """The fleet router's ``access_control`` section for these vehicle ids, tool names and map ids."""
    vehicles = [keys.check_vehicle_id(v) for v in vehicles]
    tools = [keys.check_vehicle_id(t) for t in tools]
    maps = [keys.check_map_id(m) for m in maps]
    if not vehicles and not tools:
        raise ValueError("access control: no vehicle and no fleet tool named: every link would be refused")
    clash = sorted(set(vehicles) & set(tools))
    if clash:
        raise ValueError(f"access control: {clash} named both as vehicle and as fleet tool")
    clash = sorted(set(maps) & (set(vehicles) | set(tools)))
    if clash:
        raise ValueError(f"access control: {clash} named both as map service and as vehicle or fleet tool")
    rules, subjects, policies = [], [], []
    for vid in vehicles:
        own = f"soilocp/{vid}/**"
        rules += [_rule(f"{vid}-in", _VEHICLE_IN, "ingress", [own]), _rule(f"{vid}-out", _VEHICLE_OUT, "egress", [ALL])]
        subjects.append({"id": f"vehicle-{vid}", "cert_common_names": [vid]})
        policies.append({"id": f"vehicle-{vid}", "rules": [f"{vid}-in", f"{vid}-out"], "subjects": [f"vehicle-{vid}"]})
    if tools:
        rules += [_rule("tools-in", _TOOL_IN, "ingress", [ALL, MAPS]),
                  _rule("tools-out", _TOOL_OUT, "egress", [ALL, MAPS])]
        subjects.append({"id": "tools", "cert_common_names": list(tools)})
        policies.append({"id": "tools", "rules": ["tools-in", "tools-out"], "subjects": ["tools"]})
    for m in maps:
        own = f"{keys.MAP_ROOT}/{m}/**"
        rules += [_rule(f"map-{m}-read", _TOOL_IN, "ingress", [ALL]),
                  _rule(f"map-{m}-write", _MAP_IN, "ingress", [own]),
                  _rule(f"map-{m}-out", _TOOL_OUT + ["query"], "egress", [ALL, own])]
        subjects.append({"id": f"map-{m}", "cert_common_names": [m]})
        policies.append({"id": f"map-{m}", "rules": [f"map-{m}-read", f"map-{m}-write", f"map-{m}-out"],
                         "subjects": [f"map-{m}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def apply_access_control(conf, vehicles: Iterable[str], tools: Iterable[str], maps: Iterable[str] = ()) -> None:
    conf.insert_json5("access_control", json.dumps(fleet_access_control(vehicles, tools, maps)))


def check_client_tls(endpoints: Iterable[str], env: Optional[dict[str, str]] = None) -> Optional[TlsFiles]:
    """For a fleet tool before it connects: the TLS files are complete and readable, and present
    when an endpoint is ``tls/`` (ValueError naming what is missing)."""
    tls = tls_from_env(env)
    tls_eps = [ep for ep in endpoints if ep.startswith("tls/")]
    if tls_eps and tls is None:
        raise ValueError(f"endpoints {tls_eps} use TLS: set {ENV_TLS_CA}, {ENV_TLS_CERT} and {ENV_TLS_KEY} "
                         "(the fleet CA and this tool's certificate, e.g. dashboard.pem / dashboard.key)")
    return tls.check() if tls is not None else None


#: Publications leaving over a TLS link (a vehicle router's uplink, the fleet router's links to
#: vehicles and tools) are dropped rather than waited for when that link's queue is full.  The
#: pipeline publishes with congestion control BLOCK (nothing may be lost inside a vehicle), and a
#: router forwards a BLOCK message by waiting for room on every outgoing link: while the fleet
#: link is down, its queue fills within seconds and the vehicle router then stops forwarding
#: between the vehicle's own services too (measured: OCPs stale on the vehicle for the whole
#: lease, fleet recovery 2.5-7.5 s after the link returned).  The fleet only monitors, and reads
#: back what it missed with a query.
FLEET_LINK_QOS = [{
    "id": "fleet-links-never-block",
    "link_protocols": ["tls"],
    "messages": ["put", "delete"],
    "flows": ["egress"],
    "overwrite": {"congestion_control": "drop"},
}]


def apply_fleet_link_qos(conf) -> None:
    conf.insert_json5("qos/network", json.dumps(FLEET_LINK_QOS))
