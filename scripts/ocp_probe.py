#!/usr/bin/env python3
"""Watch vehicles' OCP output and liveliness from one place in the network; JSON lines out.

    ocp_probe.py --connect tcp/10.99.1.2:7447 --vehicle rover1 [--vehicle rover2] \
                 [--period 0.1] [--duration 60] [--out FILE]

Opens a Zenoh client session (waits for the router; for a ``tls/`` endpoint with the certificate
named by SOILOCP_TLS_CA / SOILOCP_TLS_CERT / SOILOCP_TLS_KEY), then records, each line one JSON object
with ``t`` (wall clock, s since the epoch):

* ``{"kind": "sample", "vid", "seq", "stamp", "status"}`` for every OCP publication received on
  ``soilocp/<vid>/ocp``, or ``{"kind": "corrupt", "vid", "error"}`` if the payload is not a
  valid :class:`soilocp.schemas.pipeline.OcpEstimate`;
* ``{"kind": "query", "vid", "replies", "stale", "age_s", "seq"}`` for a get on the OCP
  queryable every ``--period`` seconds (``replies`` 0: nobody answered: the publisher is not
  reachable from here);
* ``{"kind": "alive", "key", "present"}`` for each liveliness change of ``soilocp/<vid>/alive/*``
  (present tokens at start included);
* ``{"kind": "ready"}`` once the session is open and everything is declared;
* at exit, ``{"kind": "status", "vid", "service", "state", "received", "published", "rejected",
  "dropped", "errors"}`` per service answering ``soilocp/<vid>/status/*``.

Stops after ``--duration`` seconds or on SIGTERM/SIGINT. Used by the deployment tests across
network namespaces and containers; also handy on a real fleet ("is rover2 live from here?").
Zenoh callbacks only append to a deque; the main thread writes the lines.
"""

from __future__ import annotations

import argparse
import collections
import json
import signal
import sys
import threading
import time


def _config(connect: list[str]):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps(connect))
    conf.insert_json5("connect/timeout_ms", "-1")  # wait for the router rather than fail
    conf.insert_json5("scouting/multicast/enabled", "false")
    # a secure fleet router (tls/ endpoint) admits only certified tools: SOILOCP_TLS_CA/_CERT/_KEY
    from soilocp.services.security.fleet_security import apply_tls, check_client_tls

    tls = check_client_tls(connect)
    if tls is not None:
        apply_tls(conf, tls, listener=False)
    return conf


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", action="append", required=True, help="router endpoint (repeatable)")
    parser.add_argument("--vehicle", action="append", required=True, help="vehicle id (repeatable)")
    parser.add_argument("--period", type=float, default=0.1, help="seconds between OCP queries")
    parser.add_argument("--query-timeout", type=float, default=0.5, help="seconds to wait for a query's reply")
    parser.add_argument("--duration", type=float, default=3600.0, help="stop after this many seconds")
    parser.add_argument("--out", help="output file (default stdout)")
    args = parser.parse_args(argv)
    if args.period <= 0:
        parser.error(f"--period {args.period!r}: must be > 0 s")
    if args.query_timeout <= 0:
        parser.error(f"--query-timeout {args.query_timeout!r}: must be > 0 s")

    import zenoh
    from pydantic import ValidationError

    from soilocp.schemas import keys
    from soilocp.schemas.messages import OcpReply, ServiceHealth
    from soilocp.schemas.pipeline import OcpEstimate

    vids = [keys.check_vehicle_id(v) for v in args.vehicle]
    out = open(args.out, "w", encoding="utf-8", buffering=1) if args.out else sys.stdout
    events: collections.deque = collections.deque()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())

    def emit(rec: dict) -> None:
        events.append(rec)

    def flush() -> None:
        while events:
            out.write(json.dumps(events.popleft()) + "\n")
        out.flush()

    def on_sample(vid: str):
        def _cb(sample) -> None:
            t = time.time()
            raw = sample.payload.to_bytes()
            try:
                est = OcpEstimate.model_validate_json(raw)
            except (ValidationError, ValueError) as exc:
                emit({"t": t, "kind": "corrupt", "vid": vid, "error": str(exc)[:200]})
                return
            emit({"t": t, "kind": "sample", "vid": vid, "seq": est.seq, "stamp": est.stamp, "status": est.status})
        return _cb

    def on_alive(sample) -> None:
        emit({"t": time.time(), "kind": "alive", "key": str(sample.key_expr),
              "present": sample.kind == zenoh.SampleKind.PUT})

    deadline = time.time() + args.duration
    try:
        conf = _config(args.connect)
    except ValueError as exc:  # TLS settings incomplete or unreadable
        parser.error(str(exc))
    with zenoh.open(conf) as session:
        subs = [session.declare_subscriber(keys.ocp(v), on_sample(v)) for v in vids]
        subs += [session.liveliness().declare_subscriber(keys.vehicle_alive_all(v), on_alive, history=True)
                 for v in vids]
        emit({"t": time.time(), "kind": "ready"})
        while not stop.is_set() and time.time() < deadline:
            t0 = time.time()
            for v in vids:
                rec = {"t": t0, "kind": "query", "vid": v, "replies": 0, "stale": None, "age_s": None, "seq": None}
                for reply in session.get(keys.ocp(v), timeout=args.query_timeout):
                    if reply.ok is None:
                        continue
                    try:
                        rep = OcpReply.model_validate_json(reply.ok.payload.to_bytes())
                    except (ValidationError, ValueError) as exc:
                        rec["error"] = str(exc)[:200]
                        continue
                    rec["replies"] += 1
                    rec.update(stale=rep.stale, age_s=rep.age_s, seq=rep.latest.seq if rep.latest else None)
                rec["t_reply"] = time.time()
                emit(rec)
            flush()
            stop.wait(max(0.0, args.period - (time.time() - t0)))
        # status of every service: QueryTarget.ALL (best matching asks only one) and no
        # consolidation (a service that replies on the selector's key would hide the others)
        for v in vids:
            for reply in session.get(keys.vehicle_status_all(v), target=zenoh.QueryTarget.ALL,
                                     consolidation=zenoh.ConsolidationMode.NONE,
                                     timeout=args.query_timeout * 2):
                if reply.ok is None:
                    continue
                try:
                    h = ServiceHealth.model_validate_json(reply.ok.payload.to_bytes())
                except (ValidationError, ValueError):
                    continue
                emit({"t": time.time(), "kind": "status", "vid": v, "service": h.service, "state": h.state,
                      "received": h.received, "published": h.published, "rejected": h.rejected,
                      "dropped": h.dropped, "errors": h.errors})
        for sub in subs:
            sub.undeclare()
    flush()
    if out is not sys.stdout:
        out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
