"""Echo process of the bench's Zenoh ping-pong baseline: every put on ``bench/ping`` comes back,
byte for byte, on ``bench/pong``, from the subscriber callback itself (nothing between the two
hops but Zenoh).  ``python -m soilocp.services.bench.echo --connect tcp/127.0.0.1:PORT``; stops on
SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

PING_KEY = "bench/ping"
PONG_KEY = "bench/pong"


def main(argv: list[str] | None = None) -> int:
    import zenoh

    from soilocp.services.runtime.config import zenoh_config

    ap = argparse.ArgumentParser(prog="python -m soilocp.services.bench.echo")
    ap.add_argument("--connect", required=True, help="router endpoint, e.g. tcp/127.0.0.1:7447")
    args = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    conf = zenoh_config("client", [args.connect], [], connect_timeout_ms=10000)
    with zenoh.open(conf) as session:
        # the same publisher settings as the pipeline services (reliable, block on congestion)
        pub = session.declare_publisher(PONG_KEY, congestion_control=zenoh.CongestionControl.BLOCK)

        def _echo(sample) -> None:
            pub.put(sample.payload)

        sub = session.declare_subscriber(PING_KEY, _echo)
        tok = session.liveliness().declare_token("bench/alive/echo")
        stop.wait()
        tok.undeclare()
        sub.undeclare()
        pub.undeclare()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
