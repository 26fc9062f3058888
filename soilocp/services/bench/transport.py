"""``python -m soilocp.services.bench.transport [--json OUT]``: Zenoh transport options on this machine.

The hops' transport is chosen with numbers.  Each variant is a ping-pong between
two OS processes (bench -> echo -> bench, the echo answering from its subscriber callback, the
payload the size of a pipeline message), at 100 Hz and 1 kHz, on an ephemeral loopback port,
multicast scouting off:

* ``client-router``: both clients of a router process (what the services do today: one
  ping-pong is two client -> router -> client hops);
* ``client-router-express``: the same with ``express`` publishers (no batching of small messages);
* ``peer-direct``: the echo a peer listening, the bench a peer connecting to it, no router:
  a link between two services of one compute unit;
* ``peer-direct-lowlatency``: the same with the low-latency unicast transport
  (``transport/unicast/lowlatency``, which needs QoS off on both sides);
* ``peer-direct-shm``: the same with shared memory enabled and the payload put from a shared
  memory buffer (zenoh's ``ShmProvider``), when this build of zenoh supports it.

One round trip crosses two hops of the variant; the median and p99 are given in ms.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import tempfile
import time
from pathlib import Path
from typing import Any

from soilocp.services.bench.echo import PING_KEY, PONG_KEY
from soilocp.services.bench.live import free_port, ping_pong
from soilocp.services.supervisor.processes import ProcessGroup

MODULE = "soilocp.services.bench.transport"

VARIANTS = ("client-router", "client-router-express", "peer-direct", "peer-direct-lowlatency", "peer-direct-shm")


def _config(mode: str, connect: list[str], listen: list[str], lowlatency: bool = False, shm: bool = False):
    import zenoh

    from soilocp.services.runtime.config import zenoh_config

    conf = zenoh_config(mode, connect, listen, connect_timeout_ms=10000) if mode != "router" else zenoh.Config()
    if mode == "router":
        conf.insert_json5("mode", '"router"')
        conf.insert_json5("listen/endpoints", json.dumps(listen))
        conf.insert_json5("scouting/multicast/enabled", "false")
    if lowlatency:
        conf.insert_json5("transport/unicast/lowlatency", "true")
        conf.insert_json5("transport/unicast/qos/enabled", "false")
    if shm:
        conf.insert_json5("transport/shared_memory/enabled", "true")
    return conf


def _serve(args) -> int:
    """The helper processes: a router, or the echo (client or listening peer)."""
    import zenoh

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.role == "router":
        conf = _config("router", [], [args.endpoint], args.lowlatency)
    elif args.mode == "peer":
        conf = _config("peer", [], [args.endpoint], args.lowlatency, args.shm)
    else:
        conf = _config("client", [args.endpoint], [], args.lowlatency)
    with zenoh.open(conf) as session:
        if args.role == "echo":
            pub = session.declare_publisher(PONG_KEY, congestion_control=zenoh.CongestionControl.BLOCK,
                                            express=args.express)
            sub = session.declare_subscriber(PING_KEY, lambda s: pub.put(s.payload))
            stop.wait()
            sub.undeclare()
            pub.undeclare()
        else:
            stop.wait()
    return 0


def measure(variant: str, rates=(100.0, 1000.0), duration: float = 3.0, payload_size: int = 1000) -> dict[str, Any]:
    """Ping-pong statistics of one variant at each rate (ms); ``error`` if it cannot run here."""
    import zenoh

    ep = f"tcp/127.0.0.1:{free_port()}"
    low, shm = variant.endswith("lowlatency"), variant.endswith("shm")
    express = variant.endswith("express")
    procs = ProcessGroup(Path(tempfile.mkdtemp(prefix="soilocp-transport-")), drop_env=("SOILOCP_",))
    try:
        if variant.startswith("client-router"):
            procs.start("router", ["--role", "router", "--endpoint", ep], module=MODULE)
            time.sleep(0.5)
            procs.start("echo", ["--role", "echo", "--mode", "client", "--endpoint", ep]
                        + (["--express"] if express else []), module=MODULE)
            conf = _config("client", [ep], [])
        else:
            procs.start("echo", ["--role", "echo", "--mode", "peer", "--endpoint", ep]
                        + (["--lowlatency"] if low else []) + (["--shm"] if shm else []), module=MODULE)
            time.sleep(0.5)
            conf = _config("peer", [ep], [], low, shm)
        provider = None
        with zenoh.open(conf) as session:
            if shm:
                provider = zenoh.shm.ShmProvider.default_backend(1 << 20)
            out = {}
            for r in rates:
                st = ping_pong(session, r, duration, payload_size, express=express, shm_provider=provider)
                if st["lost"] == st["sent"]:
                    raise RuntimeError(f"no pong at {r:.0f} Hz")
                out[f"{r:.0f}"] = st
        return {"variant": variant, "payload_bytes": payload_size, "rates": out}
    except Exception as exc:  # a variant this build cannot run is reported, not fatal
        return {"variant": variant, "error": f"{type(exc).__name__}: {exc}"}
    finally:
        procs.stop_all()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m soilocp.services.bench.transport")
    ap.add_argument("--role", choices=["router", "echo"], help=argparse.SUPPRESS)
    ap.add_argument("--mode", default="client", help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    ap.add_argument("--lowlatency", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--express", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--shm", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, default=3.0, help="seconds per rate and variant")
    ap.add_argument("--json", dest="json_out", help="also write the results as JSON here")
    args = ap.parse_args(argv)
    if args.role:
        return _serve(args)
    results = []
    print(f"Zenoh ping-pong between two processes, ms per round trip (2 hops); load {os.getloadavg()[0]:.1f}")
    print(f"{'variant':26s} {'rate':>6s} {'p50':>7s} {'p90':>7s} {'p99':>7s} {'lost':>5s}")
    for v in VARIANTS:
        res = measure(v, duration=args.duration)
        results.append(res)
        if "error" in res:
            print(f"{v:26s} error: {res['error']}")
            continue
        for rate, st in res["rates"].items():
            print(f"{v:26s} {rate:>6s} {st['p50']:7.3f} {st['p90']:7.3f} {st['p99']:7.3f} {st['lost']:5d}")
    if args.json_out:
        with open(args.json_out, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
