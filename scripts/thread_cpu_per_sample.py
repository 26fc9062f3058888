"""CPU per sample of every process of the standard pipeline, split by thread, while one vehicle
drives it at a given rate (docs/performance.md, "The standard 1 kHz row, thread by thread").

    .venv/bin/python scripts/thread_cpu_per_sample.py [--rate 1000] [--duration 10] [--runs 1]

Each thread's CPU time (utime + stime from /proc/PID/task/TID/stat) over the drive, divided by the
samples sent (a thread that ends during the drive is not counted).  Zenoh's Rust threads carry their
own names (rx-N, tx-N, acc-N, app-N); every thread Python or zenoh-python starts keeps the process's
name, so those are told apart by thread id: ``py<TID>``, the busiest one being the service's worker.  The rig, the drive and the latency
figures are the bench's own (``soilocp.services.bench.live``).
"""

from __future__ import annotations

import argparse
import os


def _read(path: str) -> str:
    with open(path) as fh:
        return fh.read()


def _threads(pid: int) -> dict[str, tuple[str, int]]:
    """tid -> (name, CPU ticks), a thread named as its process being ``python``."""
    own = _read(f"/proc/{pid}/comm").strip()
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            comm = _read(f"/proc/{pid}/task/{tid}/comm").strip()
            fields = _read(f"/proc/{pid}/task/{tid}/stat").rsplit(")", 1)[1].split()
        except OSError:  # the thread ended between the listing and the read
            continue
        out[tid] = ("python" if comm == own else comm, int(fields[11]) + int(fields[12]))
    return out


def run_once(rate: float, duration: float) -> None:
    from soilocp.services.bench.live import Rig, drive, open_client
    from soilocp.services.bench.measure import clone_payloads, payloads
    from soilocp.services.bench.stages import simulate_drive

    drive_payloads = payloads(simulate_drive("bench", duration + 1.0, rate=rate))
    rig = Rig.standard(["cpu"])
    rig.start()
    try:
        with open_client(rig.endpoint) as session:
            rig.wait_ready(session, 90.0)
            pids = {n: p for n, p in rig.pids().items() if n not in ("echo", "bench")}
            before = {n: _threads(p) for n, p in pids.items()}
            res = drive(session, {"cpu": clone_payloads(drive_payloads, "bench", "cpu")}, rate, duration)
            after = {n: _threads(p) for n, p in pids.items()}
    finally:
        rig.stop()
    hz = os.sysconf("SC_CLK_TCK")
    per = 1e6 / hz / max(res["sent"], 1)
    print(f"{rate:.0f} Hz, {res['sent']} samples: p50 {res['p50']:.2f} ms, p99 {res['p99']:.2f} ms, "
          f"drops {res['drops']}; CPU µs per sample:")
    for name in pids:
        use: dict[str, int] = {}
        for tid, (comm, ticks) in after[name].items():
            key = f"py{tid}" if comm == "python" else comm
            use[key] = use.get(key, 0) + ticks - before[name].get(tid, (comm, 0))[1]
        parts = ", ".join(f"{k}={v * per:.0f}" for k, v in sorted(use.items(), key=lambda kv: -kv[1]) if v)
        print(f"  {name:14s} {sum(use.values()) * per:5.0f}  {parts}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=float, default=1000.0, help="samples per second of the one vehicle")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of driving per run")
    ap.add_argument("--runs", type=int, default=1)
    args = ap.parse_args()
    for _ in range(args.runs):
        run_once(args.rate, args.duration)


if __name__ == "__main__":
    main()
