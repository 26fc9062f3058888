"""A bare zenoh-python relay: the true floor of one pipeline process, for ``soilocp bench --floor``.

One process, one Zenoh session, nothing of ours on the message path: a subscriber whose callback
republishes at once, on the Zenoh thread that delivered the sample (no queue, no worker thread,
no parsing, no validation, no health, no logging).  Its output has the size of the real row's
output: a recorded message of that row, the input's seq spliced in (the bench matches its
latencies by seq), or the input bytes themselves where the row forwards a sample (the gateway).
What such a process costs per message is what any Python process over Zenoh costs; the live rows
of the bench are reported as ratios to a pipeline of them (:mod:`soilocp.services.bench.floor`).

It imports only the standard library and ``zenoh``; the keys come on the command line, built by
the caller from ``soilocp.services.stages.graph`` (``{vid}`` in a key is each vehicle id)::

    python -m soilocp.services.bench.bare --sub 'soilocp/{vid}/sensors/clean' --sub 'soilocp/{vid}/normal_forces' \\
        --forward 'soilocp/{vid}/normal_forces' --pub 'soilocp/{vid}/observer' --template FILE \\
        --token 'soilocp/{vid}/alive/observer'

Settings from the environment as every service (``SOILOCP_VEHICLE_ID``, ``SOILOCP_CONNECT``,
``SOILOCP_MODE``, ``SOILOCP_LISTEN``, ``SOILOCP_EXPRESS``, ``SOILOCP_BATCHING``), applied with the
same Zenoh options (explicit endpoints, multicast scouting off, batching, express), so that the
transport is the one the services have.  SIGTERM / SIGINT close the session and exit; so does the
parent's death when ``SOILOCP_EXIT_WITH_PARENT=1``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import sys
import threading
from pathlib import Path
from typing import Optional

_SEQ = re.compile(rb'"seq":\s*(\d+)')


def splice_template(template: bytes):
    """``out(seq_digits) -> bytes``: ``template`` with its seq replaced (one concatenation a message)."""
    m = _SEQ.search(template)
    if m is None:
        raise ValueError("template has no \"seq\": its seq cannot be replaced")
    head, tail = template[:m.start(1)], template[m.end(1):]
    return lambda digits: head + digits + tail


def _config(vid_env: dict[str, str]):
    import zenoh

    mode = vid_env.get("SOILOCP_MODE", "client")
    connect = [e for e in vid_env.get("SOILOCP_CONNECT", "tcp/127.0.0.1:7447").split(",") if e]
    listen = [e for e in vid_env.get("SOILOCP_LISTEN", "").split(",") if e] if mode == "peer" else []
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(connect))
    conf.insert_json5("listen/endpoints", json.dumps(listen))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if vid_env.get("SOILOCP_BATCHING", "true").lower() in ("0", "false", "no"):
        conf.insert_json5("transport/link/tx/queue/batching/enabled", "false")
    if mode == "client":
        conf.insert_json5("connect/timeout_ms", "-1")  # wait for the router
    conf.insert_json5("connect/retry", "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}")
    return conf


def run(subs: list[str], forward: Optional[list[str]], pub: Optional[str], template: Optional[bytes],
        tokens: list[str], env: dict[str, str], stop: threading.Event) -> int:
    """Relay until ``stop`` is set; the keys' ``{vid}`` is each id of ``SOILOCP_VEHICLE_ID``."""
    import zenoh

    vids = [v for v in env.get("SOILOCP_VEHICLE_ID", "rover1").split(",") if v]
    express = env.get("SOILOCP_EXPRESS", "false").lower() in ("1", "true", "yes")
    out = splice_template(template) if template is not None else None
    forward_keys = set(forward if forward is not None else subs)
    with zenoh.open(_config(env)) as session:
        keep = []
        for vid in vids:
            if pub is not None:
                p = session.declare_publisher(pub.format(vid=vid), congestion_control=zenoh.CongestionControl.BLOCK,
                                              express=express)
                keep.append(p)
            for key in subs:
                if pub is None or key not in forward_keys:
                    cb = _ignore
                elif out is None:
                    cb = _forwarder(p)
                else:
                    cb = _splicer(p, out)
                keep.append(session.declare_subscriber(key.format(vid=vid), cb))
        for vid in vids:  # last: once visible, the inputs are subscribed (as the services do)
            for tok in tokens:
                keep.append(session.liveliness().declare_token(tok.format(vid=vid)))
        parent = os.getppid()
        watch = env.get("SOILOCP_EXIT_WITH_PARENT") == "1"
        while not stop.wait(0.5):
            if watch and os.getppid() != parent:
                break
        for e in reversed(keep):
            try:
                e.undeclare()
            except Exception:  # gone with the session
                pass
    return 0


def _ignore(_sample) -> None:
    pass


def _forwarder(p):
    def cb(sample) -> None:
        p.put(sample.payload.to_bytes())

    return cb


def _splicer(p, out):
    search = _SEQ.search

    def cb(sample) -> None:
        m = search(sample.payload.to_bytes())
        if m is not None:
            p.put(out(m.group(1)))

    return cb


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m soilocp.services.bench.bare", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sub", action="append", required=True, help="input key ({vid}: each vehicle id); repeat")
    ap.add_argument("--forward", action="append", help="the input(s) that trigger a put (default: every --sub)")
    ap.add_argument("--pub", help="output key ({vid}); none: a sink")
    ap.add_argument("--template", help="file holding the output message (its seq replaced); none: the input bytes")
    ap.add_argument("--token", action="append", default=[], help="liveliness token key ({vid}); repeat")
    a = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    try:
        template = Path(a.template).read_bytes().strip() if a.template else None
        code = run(a.sub, a.forward, a.pub, template, a.token, dict(os.environ), stop)
    except (OSError, ValueError) as exc:
        print(f"python -m soilocp.services.bench.bare: error: {exc}", file=sys.stderr, flush=True)
        return 2
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # no interpreter finalisation after the session is closed (as the services)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
