"""The live rows' measurement, which ``soilocp bench``, its ``--floor`` and the tools around it share: the
targets, the rigs of the two pipelines, the simulated drives and their payloads, one vehicle's latency at 100 Hz
and 1 kHz (:func:`measure_latency`) and the vehicles x 100 Hz ladder (:func:`measure_scale`)."""

from __future__ import annotations

from typing import Any, Optional

# the performance targets: chain CPU per sample (median), offline replay, one vehicle at 100 Hz and 1 kHz on the
# standard pipeline, vehicles x 100 Hz on the batched one, resident memory of router + 5 services
TARGETS = {"chain_cpu_us": 100.0, "replay_x": 100.0, "p50_ms_100hz": 1.5, "p99_ms_100hz": 3.0, "p99_ms_1khz": 5.0,
           "scale_p99_ms": 10.0, "vehicles_100hz": 100, "rss_mib_total": 300.0}
LADDER = (1, 2, 5, 10, 20, 50, 100, 200)


def ladder_up_to(quick: bool, max_vehicles: Optional[int]) -> Optional[list[int]]:
    """The vehicle counts of the scale ladder (``--quick``: 1 and 2) up to ``max_vehicles`` (at least one step);
    None (the whole ladder) without a maximum."""
    if max_vehicles is None:
        return None
    return [n for n in ((1, 2) if quick else LADDER) if n <= max_vehicles] or [1]


def _standard_rig(vehicle_ids):
    from soilocp.services.bench.live import Rig

    return Rig.standard(vehicle_ids)


def _batched_rig(vehicle_ids):
    from soilocp.services.bench.live import Rig

    return Rig.batched(vehicle_ids)


#: The rig of each live pipeline: ``make_rig(vehicle_ids) -> Rig``
RIGS = {"standard": _standard_rig, "batched": _batched_rig}


def clone_payloads(payloads: list[tuple[int, bytes]], base_vid: str, vid: str) -> list[tuple[int, bytes]]:
    """A drive's payloads as vehicle ``vid``'s (the one ``"vehicle_id"`` of each JSON sample replaced)."""
    old, new = f'"vehicle_id":"{base_vid}"'.encode(), f'"vehicle_id":"{vid}"'.encode()
    return [(seq, p.replace(old, new, 1)) for seq, p in payloads]


def payloads(samples) -> list[tuple[int, bytes]]:
    """(seq, JSON payload) of each sample, as the gateway receives it."""
    return [(s.seq, s.model_dump_json().encode()) for s in samples]


def live_durations(quick: bool) -> tuple[float, float, float]:
    """Seconds of the live rows: one vehicle at 100 Hz, at 1 kHz, and each step of the ladder."""
    return (2.0, 1.0, 1.5) if quick else (20.0, 10.0, 8.0)


def live_drives(quick: bool, log=print):
    """The simulated drives the live rows publish: 100 Hz (long enough for any row) and 1 kHz."""
    from soilocp.services.bench.stages import simulate_drive

    d_100, d_1k, d_scale = live_durations(quick)
    s100 = simulate_drive("bench", max(d_100, d_scale) + 1.0)
    log(f"bench: simulating {d_1k + 1:.1f} s at 1 kHz")
    return s100, simulate_drive("bench", d_1k + 1.0, rate=1000.0)


def measure_latency(make_rig, label: str, p100, p1k, d_100: float, d_1k: float, quick: bool, log=print
                    ) -> list[dict[str, Any]]:
    """One vehicle at 100 Hz then 1 kHz through one rig (``make_rig(vehicle_ids)``), each after its
    ping-pong baseline on the same router; rows of the report's ``latency``."""
    from soilocp.services.bench.live import CpuWindow, drive, open_client, ping_pong

    rows = []
    rig = make_rig(["lat100", "lat1k"])
    log(f"bench: latency, {label} pipeline")
    try:
        rig.start()
        with open_client(rig.endpoint) as session:
            rig.wait_ready(session, 90.0)
            for rate, dur, vid, pl in ((100.0, d_100, "lat100", p100), (1000.0, d_1k, "lat1k", p1k)):
                base = ping_pong(session, rate, min(dur, 1.0 if quick else 5.0))
                win = CpuWindow(rig.pids())
                res = drive(session, {vid: clone_payloads(pl, "bench", vid)}, rate, dur)
                rows.append({"pipeline": label, "rate_hz": rate, "vehicles": 1, "result": res, "baseline": base,
                             "processes": win.finish()})
    finally:
        rig.stop()
    return rows


def measure_scale(make_rig, label: str, p100, ladder, d_scale: float, quick: bool, log=print) -> dict[str, Any]:
    """Vehicles x 100 Hz through fresh rigs, up the ``ladder`` until a count is not carried; the
    report's ``scale[label]``."""
    from soilocp.services.bench.live import CpuWindow, drive, open_client, ping_pong

    steps = []
    best = 0  # most vehicles with p99 < 10 ms and no drop (the target's criterion)
    sustained = 0  # most vehicles carried without a drop, whatever the latency (throughput)
    for n in ladder:
        vids = [f"v{i:03d}" for i in range(n)]
        rig = make_rig(vids)
        log(f"bench: scale, {label} pipeline, {n} vehicle(s) x 100 Hz")
        try:
            rig.start()
            with open_client(rig.endpoint) as session:
                rig.wait_ready(session, 120.0)
                base = ping_pong(session, 100.0 * n, 1.0 if quick else 3.0)
                win = CpuWindow(rig.pids())
                res = drive(session, {v: clone_payloads(p100, "bench", v) for v in vids}, 100.0, d_scale)
                procs = win.finish()
        except RuntimeError as exc:
            steps.append({"vehicles": n, "ok": False, "error": str(exc)})
            break
        finally:
            rig.stop()
        carried = (res["drops"] == 0 and res["rejections"] == 0
                   and res["offered_per_s"] >= 0.95 * res["target_per_s"])
        ok = carried and res["p99"] < TARGETS["scale_p99_ms"]
        steps.append({"vehicles": n, "ok": ok, "carried": carried, "result": res, "baseline": base,
                      "processes": procs})
        if ok and best == sustained:
            best = n
        if not carried:
            break  # on a shared machine the p99 can fail at any count: step on while nothing is lost
        sustained = n
    return {"steps": steps, "max_vehicles": best, "max_vehicles_no_drop": sustained}
