"""``soilocp bench --map``: the fleet soil map's row (docs/map.md).

* **updates/s**: one map service process (SQLite file, WAL, synchronous=FULL, batch commits) fed
  over a real Zenoh router by a flood of soil estimates from ``vehicles`` vehicles; the rate is
  estimates acknowledged (committed and published) per second, from the first put to the last
  acknowledgement.  Also the library alone (:meth:`MapUpdater.apply`, same batches) in process.
* **query p99**: queries of a 1 km x 1 km box over Zenoh (``soilmap/<id>/query``, reply parsed)
  and in process (:meth:`MapStore.query_json`, the service's query handler), on a map of fleet tracks: ``tracks`` straight
  1.4 km drives across the box at random angles, 5 m cells, about one cell row each.
"""

from __future__ import annotations

import math
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from soilocp.schemas import keys
from soilocp.schemas.map import MapCellUpdate, MapQueryReply
from soilocp.schemas.pipeline import SoilEstimate
from soilocp.schemas.position import EstimatePlace

TARGETS = {"updates_per_s": 10_000.0, "query_p99_ms": 20.0}


def _estimate(vid: str, seq: int, k: float, x: float, y: float) -> bytes:
    return SoilEstimate(
        vehicle_id=vid, seq=seq, stamp=seq / 100.0, slip=(0.1,) * 4, informative=(True,) * 4, soil_strength=k,
        soil_strength_std=0.1 * k, log_k_std=0.1, soil_class="EST", soil_class_confidence=0.8, status="ok", reason="",
        last_update_stamp=seq / 100.0, mu=(0.4,) * 4,
        where=EstimatePlace(wheels=(1, 2, 3, 4), frame="bench", xy=((x - 0.27, y + 0.25), (x + 0.23, y + 0.25),
                                                                       (x + 0.23, y - 0.25), (x - 0.27, y - 0.25))),
    ).model_dump_json().encode()


def flood_payloads(vehicles: int, per_vehicle: int, seed: int = 0) -> list[tuple[str, bytes]]:
    """Each vehicle drives at 1 m/s (0.01 m per 100 Hz estimate) along its own line: (key, payload)."""
    rng = random.Random(seed)
    out = []
    for v in range(vehicles):
        vid = f"bench{v}"
        x0, y0, h = rng.uniform(0, 1000), rng.uniform(0, 1000), rng.uniform(0, 2 * math.pi)
        for s in range(per_vehicle):
            d = 0.01 * s
            out.append((keys.soil(vid), _estimate(vid, s, 50.0 * (1 + (s // 500) % 5), x0 + d * math.cos(h),
                                                  y0 + d * math.sin(h))))
    # interleave the vehicles as they would arrive
    order = sorted(range(len(out)), key=lambda i: (i % per_vehicle, i // per_vehicle))
    return [out[i] for i in order]


def track_items(tracks: int, seed: int = 1, t0: float = 1.8e9) -> list[tuple[str, bytes, float]]:
    """Fleet tracks over a 1 km x 1 km box: one estimate per metre along 1.4 km lines."""
    rng = random.Random(seed)
    items = []
    for v in range(tracks):
        vid = f"track{v}"
        h = rng.uniform(0, 2 * math.pi)
        cx, cy = rng.uniform(200, 800), rng.uniform(200, 800)
        for s in range(1400):
            d = s - 700.0
            items.append((keys.soil(vid), _estimate(vid, s, rng.uniform(40, 300), cx + d * math.cos(h),
                                                    cy + d * math.sin(h)), t0 + s))
    return items


def _percentiles(ms: list[float]) -> dict[str, float]:
    a = np.asarray(ms)
    return {"p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max()),
            "n": int(a.size)}


def run_map_bench(quick: bool = False, log: Callable[[str], None] = print) -> dict[str, Any]:
    from soilocp.services.runtime.config import zenoh_config
    from soilocp.map.store import open_store
    from soilocp.map.updater import MapUpdater

    import zenoh

    vehicles, per_vehicle = (20, 1000) if quick else (50, 2000)
    tracks, queries = (10, 50) if quick else (40, 200)
    out: dict[str, Any] = {"vehicles": vehicles, "estimates": vehicles * per_vehicle, "tracks": tracks}
    work = Path(tempfile.mkdtemp(prefix="soilocp-bench-map-"))
    payloads = flood_payloads(vehicles, per_vehicle)

    # in process: the library alone, batches of 5000 (the service's batch_max)
    st = open_store(f"sqlite:{work / 'lib.db'}")
    up = MapUpdater(st)
    items = [(k, p, 1.8e9 + i * 1e-4) for i, (k, p) in enumerate(payloads)]
    t = time.perf_counter()
    for i in range(0, len(items), 5000):
        up.apply(items[i:i + 5000])
    out["library_updates_per_s"] = len(items) / (time.perf_counter() - t)
    st.close()
    log(f"map library: {out['library_updates_per_s']:.0f} estimates/s")

    # live: router + map service processes; the bench floods over Zenoh and waits for the acknowledgements
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ep = f"tcp/127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    logs = [open(work / n, "w") for n in ("router.log", "map.log")]
    procs = [subprocess.Popen([sys.executable, "-m", "soilocp.cli", "router", "--listen", ep], stderr=logs[0], env=env)]
    procs.append(subprocess.Popen([sys.executable, "-m", "soilocp.cli", "service", "map", "--map-id", "bench",
                                   "--connect", ep, "--store", f"sqlite:{work / 'live.db'}"], stderr=logs[1], env=env))
    try:
        conf = zenoh_config("client", [ep], [], connect_timeout_ms=30000, tls_from_environment=False)
        with zenoh.open(conf) as s:
            acked = {"n": 0, "t": 0.0}
            lock = threading.Lock()

            def on_cells(sample):
                m = MapCellUpdate.model_validate_json(sample.payload.to_bytes())
                with lock:
                    for v, (_seq, total) in m.applied.items():
                        acked.setdefault("per", {})[v] = total
                    acked["n"] = sum(acked.get("per", {}).values())
                    acked["t"] = time.perf_counter()

            sub = s.declare_subscriber(keys.map_key("bench", "cells"), on_cells)
            deadline = time.monotonic() + 60
            while not list(s.liveliness().get(keys.map_key("bench", "alive"), timeout=1)):
                if time.monotonic() > deadline:
                    raise RuntimeError("the map service did not come up: " + (work / "map.log").read_text()[-500:])
            pubs: dict[str, Any] = {}
            t0 = time.perf_counter()
            for key, p in payloads:
                pub = pubs.get(key)
                if pub is None:
                    pub = pubs[key] = s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
                pub.put(p)
            t_sent = time.perf_counter()
            deadline = time.monotonic() + 300
            while acked["n"] < len(payloads) and time.monotonic() < deadline:
                time.sleep(0.02)
            out["live_acknowledged"] = acked["n"]
            out["live_updates_per_s"] = acked["n"] / (acked["t"] - t0) if acked["n"] else 0.0
            out["publish_per_s"] = len(payloads) / (t_sent - t0)
            log(f"map service: {out['live_updates_per_s']:.0f} estimates/s acknowledged "
                f"({acked['n']} of {len(payloads)}; the flood left at {out['publish_per_s']:.0f}/s)")
            sub.undeclare()
            for p in pubs.values():
                p.undeclare()

            # queries: a map of fleet tracks, written by the library into the service's own store
            # would race the service; a second service on a track store answers the queries
            tst = open_store(f"sqlite:{work / 'tracks.db'}")
            tup = MapUpdater(tst)
            ti = track_items(tracks)
            for i in range(0, len(ti), 5000):
                tup.apply(ti[i:i + 5000])
            box = (0.0, 0.0, 1000.0, 1000.0)
            cells, _cut = tst.query_box("bench", box, time.time())
            out["box_cells"] = len(cells)
            out["store_cells"] = tst.count_cells()
            lib_ms, lib_cpu = [], []
            tst.prepare_replies()
            for _ in range(queries):
                t, c = time.perf_counter(), time.process_time()
                tst.query_json("bench", box, time.time())
                lib_ms.append(1e3 * (time.perf_counter() - t))
                lib_cpu.append(1e3 * (time.process_time() - c))
            tst.close()
            out["query_library"] = _percentiles(lib_ms)
            out["query_library_cpu"] = _percentiles(lib_cpu)
            procs.append(subprocess.Popen([sys.executable, "-m", "soilocp.cli", "service", "map", "--map-id", "tracks",
                                           "--connect", ep, "--store", f"sqlite:{work / 'tracks.db'}"],
                                          stderr=open(work / "map-tracks.log", "w"), env=env))
            deadline = time.monotonic() + 60
            while not list(s.liveliness().get(keys.map_key("tracks", "alive"), timeout=1)):
                if time.monotonic() > deadline:
                    raise RuntimeError("the track map service did not come up")
            sel = f"{keys.map_key('tracks', 'query')}?frame=bench;bbox=0,0,1000,1000"
            zen_ms, parse_ms = [], []
            for _ in range(queries):
                t = time.perf_counter()
                got = [r.ok.payload.to_bytes() for r in s.get(sel, timeout=10) if r.ok is not None]
                zen_ms.append(1e3 * (time.perf_counter() - t))  # query sent -> the whole reply received
                t = time.process_time()
                rep = [MapQueryReply.model_validate_json(b) for b in got]
                parse_ms.append(1e3 * (time.process_time() - t))
                if not rep or len(rep[0].columns.cell) != len(cells):
                    raise RuntimeError(f"query answered {len(rep[0].columns.cell) if rep else 'nothing'}, "
                                       f"want {len(cells)}")
            out["query_zenoh"] = _percentiles(zen_ms)
            out["reply_bytes"] = len(got[0])
            out["client_parse_cpu"] = _percentiles(parse_ms)
            log(f"map query, 1 km^2 box with {len(cells)} cells: p99 {out['query_zenoh']['p99_ms']:.1f} ms over Zenoh, "
                f"{out['query_library']['p99_ms']:.1f} ms in process")
    finally:
        for p in reversed(procs):
            p.send_signal(signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for f in logs:
            f.close()
    out["targets"] = TARGETS
    out["meets"] = {"updates_per_s": out["live_updates_per_s"] >= TARGETS["updates_per_s"],
                    "query_p99_ms": out["query_zenoh"]["p99_ms"] <= TARGETS["query_p99_ms"]}
    return out


def render_map(row: dict[str, Any], console) -> None:
    from rich.table import Table

    t = Table(title="fleet soil map (one map service, SQLite, 2 cores shared)")
    for c in ("figure", "value", "target", "meets"):
        t.add_column(c)
    m = row["meets"]
    t.add_row("updates/s acknowledged (live, Zenoh, %d vehicles)" % row["vehicles"], f"{row['live_updates_per_s']:.0f}",
              f">= {TARGETS['updates_per_s']:.0f}", "yes" if m["updates_per_s"] else "NO")
    t.add_row("updates/s, library alone", f"{row['library_updates_per_s']:.0f}", "", "")
    t.add_row(f"query p99, 1 km² box ({row['box_cells']} cells), over Zenoh", f"{row['query_zenoh']['p99_ms']:.1f} ms",
              f"<= {TARGETS['query_p99_ms']:.0f} ms", "yes" if m["query_p99_ms"] else "NO")
    t.add_row("query p99, in process (wall / CPU)", f"{row['query_library']['p99_ms']:.1f} / "
              f"{row['query_library_cpu']['p99_ms']:.1f} ms", "", "")
    t.add_row("reply parse into models at the client (CPU p99)", f"{row['client_parse_cpu']['p99_ms']:.1f} ms", "", "")
    console.print(t)
