"""``soilocp bench --soak DURATION``: hours of driving through the live pipeline, and what they leave behind.

The router and the five services (``Rig.standard``, as the bench's live rows: ephemeral loopback port,
explicit endpoints, no multicast scouting) carry one vehicle at ``--soak-rate`` Hz (100 by default) for
DURATION seconds.  The drive is a simulated one of ``LOOP_S`` seconds played over and over, its seq and
stamp continued across each seam (so the chain sees one long drive, with a change of terrain and speed at
each seam).  Measured:

* per process, resident memory (RSS) every few seconds: its growth from the end of the warm-up (the
  first tenth, at least 30 s) to the end;
* the sample -> OCP latency of every sample, and its p99 in the first and in the last tenth of the run
  (after the warm-up);
* drops (samples sent without an OCP after the drain), rejections;
* the observer's resets by reason (its health), the start's one expected.

The verdict uses the targets of a soak: RSS growth <= 5 MiB per process, last tenth's p99 within 20 % of
the first's, no drop, no reset other than the start.  A machine shared with other work moves the
latency figures (the report gives the load); the memory and the counts do not depend on it.
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any, Optional

from soilocp.services.bench.report import fmt, machine_info, write_report

SOAK_TARGETS = {"rss_growth_mib": 5.0, "p99_last_over_first": 1.2, "drops": 0}
LOOP_S = 120.0
RSS_PERIOD_S = 5.0


def looped_payloads(vid: str, rate: float, loop_s: float = LOOP_S):
    """``payload(k) -> (seq, bytes)`` for any step ``k``: the simulated drive of ``loop_s`` s, its seq and
    stamp continued across every repetition."""
    from soilocp.services.bench.stages import simulate_drive

    base = simulate_drive(vid, loop_s, rate=rate)
    n = len(base)
    period = n / rate  # the stamp span of one loop, so that the stamps keep their step across the seam
    cache: dict[int, list[tuple[int, bytes]]] = {}

    def payload(k: int) -> tuple[int, bytes]:
        rep, i = divmod(k, n)
        if rep not in cache:
            cache.clear()  # one loop's payloads at a time: memory flat however long the soak
            cache[rep] = [(s.seq + rep * n, s.model_copy(update={"seq": s.seq + rep * n,
                                                                 "stamp": s.stamp + rep * period})
                           .model_dump_json().encode()) for s in base]
        return cache[rep][i]

    return payload


def _quantile(xs: list[float], q: float) -> Optional[float]:
    if not xs:
        return None
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))]


def run_soak(duration: float, rate: float = 100.0, log=print) -> dict[str, Any]:
    """The soak (module doc); the report as a JSON-able dict."""
    import zenoh

    from soilocp.schemas import keys
    from soilocp.schemas.messages import ServiceHealth
    from soilocp.services.bench.live import Rig, _sleep_until, arrivals, open_client, proc_rss_mib

    vid = "soak"
    n_steps = int(round(duration * rate))
    warm_s = max(30.0, duration / 10.0) if duration >= 60 else duration / 10.0
    log(f"soak: simulating a {LOOP_S:.0f} s drive at {rate:.0f} Hz, played for {duration:.0f} s ({n_steps} samples)")
    payload = looped_payloads(vid, rate)
    report: dict[str, Any] = {"kind": "soak", "duration_s": duration, "rate_hz": rate, "machine": machine_info(),
                              "targets": SOAK_TARGETS, "warmup_s": warm_s,
                              "command": f"soilocp bench --soak {duration:g} --soak-rate {rate:g}"}
    rig = Rig.standard([vid])
    sent = [0.0] * n_steps  # send time of step k (perf_counter)
    got: dict[int, float] = {}
    seq_of = [0] * n_steps
    lock = threading.Lock()
    rss: dict[str, list[tuple[float, Optional[float]]]] = {}
    stop = threading.Event()

    try:
        rig.start()
        pids = {n: p for n, p in rig.pids().items() if n not in ("echo", "bench")}

        def _sample_rss() -> None:
            t0 = time.monotonic()
            while True:
                now = time.monotonic() - t0
                for n, p in pids.items():
                    rss.setdefault(n, []).append((now, proc_rss_mib(p)))
                if stop.wait(RSS_PERIOD_S):
                    return

        with open_client(rig.endpoint) as session:
            rig.wait_ready(session, 120.0)
            sub = session.declare_subscriber(keys.ocp(vid), arrivals(got, lock))
            pub = session.declare_publisher(keys.raw(vid), congestion_control=zenoh.CongestionControl.BLOCK)
            payload(0)  # the first loop's payloads before the clock starts
            time.sleep(0.3)
            th = threading.Thread(target=_sample_rss, name="soak-rss", daemon=True)
            th.start()
            t0 = time.perf_counter() + 0.05
            next_log = t0 + 60.0
            try:
                for k in range(n_steps):
                    seq, p = payload(k)
                    _sleep_until(t0 + k / rate)
                    seq_of[k] = seq
                    sent[k] = time.perf_counter()
                    pub.put(p)
                    if sent[k] >= next_log:
                        next_log += 60.0
                        with lock:
                            n_got = len(got)
                        log(f"soak: {sent[k] - t0:.0f} s, {k + 1} sent, {n_got} OCPs")
                    if rig.dead():
                        raise RuntimeError(f"soak: process(es) {rig.dead()} died; logs in {rig.log_dir}")
                deadline = time.monotonic() + 5.0
                while time.monotonic() < deadline:
                    with lock:
                        if seq_of[-1] in got:
                            break
                    time.sleep(0.05)
                time.sleep(0.5)
            finally:
                sub.undeclare()
                pub.undeclare()
            stop.set()
            th.join(RSS_PERIOD_S + 1)
            for n, p in pids.items():  # the last reading, after the drain
                rss.setdefault(n, []).append((time.perf_counter() - t0, proc_rss_mib(p)))
            health = {}
            for reply in session.get(keys.vehicle_status_all(vid), timeout=3.0):
                if reply.ok is not None:
                    h = ServiceHealth.model_validate_json(reply.ok.payload.to_bytes())
                    health[h.service] = h
    finally:
        stop.set()
        rig.stop()
    with lock:
        lat = [((sent[k] - t0), (got[seq_of[k]] - sent[k]) * 1e3) for k in range(n_steps) if seq_of[k] in got]
        drops = sum(1 for k in range(n_steps) if seq_of[k] not in got)
    after = [(t, v) for t, v in lat if t >= warm_s]
    span = duration - warm_s
    first = [v for t, v in after if t < warm_s + span / 10.0]
    last = [v for t, v in after if t >= duration - span / 10.0]
    report["latency"] = {"all_p50": _quantile([v for _t, v in after], 0.5),
                         "all_p99": _quantile([v for _t, v in after], 0.99),
                         "first_tenth_p99": _quantile(first, 0.99), "last_tenth_p99": _quantile(last, 0.99),
                         "first_tenth_n": len(first), "last_tenth_n": len(last)}
    fp, lp = report["latency"]["first_tenth_p99"], report["latency"]["last_tenth_p99"]
    report["latency"]["last_over_first"] = lp / fp if fp and lp else None
    report["sent"], report["drops"] = n_steps, drops
    report["rss"] = {}
    for n, series in rss.items():
        vals = [(t, v) for t, v in series if v is not None]
        at_warm = next((v for t, v in vals if t >= warm_s), vals[-1][1] if vals else None)
        end = vals[-1][1] if vals else None
        report["rss"][n] = {"start_mib": vals[0][1] if vals else None, "after_warmup_mib": at_warm, "end_mib": end,
                            "growth_mib": None if end is None or at_warm is None else end - at_warm,
                            "max_mib": max((v for _t, v in vals), default=None)}
    obs = health.get("observer")
    report["observer_resets"] = ({k[len("reset_"):]: v for k, v in obs.detail.items() if k.startswith("reset_")}
                                 if obs else None)
    report["health"] = {n: {"received": h.received, "published": h.published, "rejected": h.rejected,
                            "dropped": h.dropped, "errors": h.errors} for n, h in health.items()}
    report["machine"]["load_end"] = list(os.getloadavg())
    growth = [r["growth_mib"] for r in report["rss"].values() if r["growth_mib"] is not None]
    resets = report["observer_resets"] or {}
    report["verdict"] = {
        "rss_growth": bool(growth) and max(growth) <= SOAK_TARGETS["rss_growth_mib"],
        "p99_stable": report["latency"]["last_over_first"] is not None
        and report["latency"]["last_over_first"] <= SOAK_TARGETS["p99_last_over_first"],
        "no_drops": drops == 0,
        "no_unexplained_resets": set(resets) <= {"start"} and resets.get("start", 0) <= 1,
    }
    return report


def render_soak(report: dict[str, Any], console) -> None:
    from rich.table import Table

    m = report["machine"]
    console.print(f"{report['command']} — {m['nproc']} CPU(s), {m['cpu_model']}, load {fmt(m['load_start'][0])} -> "
                  f"{fmt(m.get('load_end', [float('nan')])[0])}; warm-up {report['warmup_s']:.0f} s")
    la = report["latency"]
    console.print(f"sample -> OCP latency after the warm-up, ms: p50 {fmt(la['all_p50'])}, p99 {fmt(la['all_p99'])}; "
                  f"p99 of the first tenth {fmt(la['first_tenth_p99'])} (n={la['first_tenth_n']}), of the last "
                  f"{fmt(la['last_tenth_p99'])} (n={la['last_tenth_n']}): x{fmt(la['last_over_first'])}")
    console.print(f"samples sent {report['sent']}, without an OCP {report['drops']}; observer resets by reason "
                  f"{report['observer_resets']}")
    t = Table(title="resident memory per process, MiB", title_justify="left")
    for c in ("process", "start", "after warm-up", "end", "max", "growth after warm-up"):
        t.add_column(c, justify="left" if c == "process" else "right")
    for n, r in report["rss"].items():
        t.add_row(n, fmt(r["start_mib"], ".1f"), fmt(r["after_warmup_mib"], ".1f"), fmt(r["end_mib"], ".1f"),
                  fmt(r["max_mib"], ".1f"), fmt(r["growth_mib"], "+.2f"))
    console.print(t)
    console.print("health: " + "; ".join(f"{n} " + " ".join(f"{k}={v}" for k, v in h.items())
                                          for n, h in report["health"].items()))
    console.print("soak targets: " + ", ".join(f"{k}={'met' if ok else 'NOT met'}" for k, ok in report["verdict"].items()))


def soak_command(duration: float, rate: float, json_out: Optional[str], console) -> dict[str, Any]:
    report = run_soak(duration, rate, log=lambda msg: console.print(msg, style="dim"))
    render_soak(report, console)
    if json_out:
        write_report(report, json_out, console)
    return report
