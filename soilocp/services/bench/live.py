"""The live part of ``soilocp bench``: the deployed processes over a real Zenoh router.

:class:`Rig` starts a router and the pipeline services as separate OS processes (as ``soilocp
run`` does: ``python -m soilocp.cli ...``), on an ephemeral loopback port with explicit endpoints
and multicast scouting off, plus the ping-pong echo process of the baseline.  :func:`drive`
publishes raw samples for N vehicles from the bench process itself, paced at a given rate with
the vehicles' phases spread evenly over the period, and subscribes to every vehicle's OCP key:
the latency of a sample is OCP arrival minus send time, both read from the same clock in the
same process and matched by (vehicle, seq).  :func:`ping_pong` measures the floor: put ->
router -> echo subscriber -> put back -> router -> bench, at the same rate and payload size.
"""

from __future__ import annotations

import os
import re
import socket
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

from soilocp.schemas import keys
from soilocp.services.supervisor.liveliness import wait_alive
from soilocp.services.supervisor.processes import ProcessGroup
from soilocp.services.stages.graph import BATCHED_STAGES, PIPELINE_SERVICES

from soilocp.services.bench.echo import PING_KEY, PONG_KEY
from soilocp.services.bench.stages import summarize

PIPELINE = PIPELINE_SERVICES
_SEQ_RE = re.compile(rb'"seq":\s*(\d+)')
_SUPPRESSED_RE = re.compile(rb'"suppressed":\s*(\d+)')
_CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ----------------------------------------------------------------------------------------------
# per-process CPU and memory from /proc (psutil is not a dependency)
# ----------------------------------------------------------------------------------------------
def proc_cpu_seconds(pid: int) -> Optional[float]:
    """utime + stime of ``pid`` in seconds (from /proc/<pid>/stat), None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) may contain spaces: split after its closing parenthesis
    rest = text[text.rindex(")") + 2:].split()
    return (int(rest[11]) + int(rest[12])) / _CLK_TCK  # fields 14 and 15 of stat(5)


def proc_rss_mib(pid: int) -> Optional[float]:
    """Resident memory of ``pid`` in MiB (VmRSS of /proc/<pid>/status), None if it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def proc_pss_mib(pid: int) -> Optional[float]:
    """Proportional set size of ``pid`` in MiB (Pss of /proc/<pid>/smaps_rollup): its resident pages,
    each shared page divided by the number of processes mapping it.  The sum over processes is what
    they take together; the sum of RSS counts the shared libraries (numpy's OpenBLAS, Zenoh) once
    per process.  None if unavailable."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError):
        return None
    return None


class CpuWindow:
    """CPU use (% of one core) and RSS of named processes over a measurement window."""

    def __init__(self, pids: dict[str, int]):
        self.pids = dict(pids)
        self.t0 = time.monotonic()
        self.c0 = {n: proc_cpu_seconds(p) for n, p in self.pids.items()}

    def finish(self) -> dict[str, dict[str, Optional[float]]]:
        wall = max(time.monotonic() - self.t0, 1e-9)
        out = {}
        for n, p in self.pids.items():
            c1, c0 = proc_cpu_seconds(p), self.c0.get(n)
            cpu = None if c1 is None or c0 is None else 100.0 * (c1 - c0) / wall
            out[n] = {"pid": p, "cpu_percent": cpu, "rss_mib": proc_rss_mib(p), "pss_mib": proc_pss_mib(p)}
        return out


# ----------------------------------------------------------------------------------------------
# the processes
# ----------------------------------------------------------------------------------------------
@dataclass
class Rig:
    """Router + pipeline services (+ echo) as subprocesses of one :class:`ProcessGroup`; always
    reaped by :meth:`stop`."""

    vehicle_ids: list[str]
    services: Sequence[tuple[str, str, list[str]]] = ()  # (name, module, args): python -m module *args
    log_dir: Optional[Path] = None
    group: Optional[ProcessGroup] = None
    endpoint: str = ""
    #: "client": every service a client of the router (each hop client -> router -> client);
    #: "peer": the services are peers that also listen on an ephemeral loopback port, so that
    #: they link to each other directly (the router only introduces them): the pipeline's hops
    links: str = "client"
    #: extra environment of the router and the services: the Zenoh settings under test
    #: (SOILOCP_EXPRESS, SOILOCP_BATCHING; soilocp.services.bench.zenoh_settings)
    env: dict[str, str] = field(default_factory=dict)

    @staticmethod
    def standard(vehicle_ids: list[str]) -> "Rig":
        """The five services of docs/services.md, each serving every vehicle id."""
        return Rig(list(vehicle_ids), [(name, "soilocp.cli", ["service", name]) for name in PIPELINE])

    @staticmethod
    def batched(vehicle_ids: list[str]) -> "Rig":
        """The gateway as deployed; normal forces + observer + soil + OCP in one batched process."""
        return Rig(list(vehicle_ids), [("gateway", "soilocp.cli", ["service", "gateway"]),
                                       ("batch", "soilocp.services.stages.batch", [])])

    def start(self) -> "Rig":
        if self.log_dir is None:
            self.log_dir = Path(tempfile.mkdtemp(prefix="soilocp-bench-"))
        self.group = ProcessGroup(self.log_dir, drop_env=("SOILOCP_",))
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.group.start("router", ["router", "--listen", self.endpoint], env=dict(self.env))
        senv = dict(SOILOCP_VEHICLE_ID=",".join(self.vehicle_ids), SOILOCP_CONNECT=self.endpoint,
                    SOILOCP_LOG_LEVEL="warning", **self.env)
        if self.links == "peer":
            senv.update(SOILOCP_MODE="peer", SOILOCP_LISTEN="tcp/127.0.0.1:0")
        elif self.links != "client":
            raise ValueError(f"links {self.links!r}: must be 'client' or 'peer'")
        for name, module, args in self.services:
            self.group.start(name, args, module=module, env=senv)
        self.group.start("echo", ["--connect", self.endpoint], module="soilocp.services.bench.echo")
        return self

    def pids(self) -> dict[str, int]:
        """Every child's pid, and the bench process itself (its publisher and subscriber)."""
        assert self.group is not None
        return {**{n: p.pid for n, p in self.group.procs.items()}, "bench": os.getpid()}

    def dead(self) -> list[str]:
        return self.group.dead() if self.group is not None else []

    def wait_ready(self, session, timeout: float) -> None:
        """Until every service holds its liveliness token for every vehicle (and the echo its own)."""
        t0 = time.monotonic()
        missing = wait_alive(session, self.vehicle_ids, self._token_names(), timeout, dead=self.dead)
        while not missing and not self.dead():
            if any(r.ok is not None for r in session.liveliness().get("bench/alive/echo", timeout=1.0)):
                return
            if time.monotonic() - t0 > timeout:
                break
            time.sleep(0.2)
        if self.dead():
            raise RuntimeError(f"bench: process(es) {self.dead()} exited during startup; logs in {self.log_dir}")
        raise RuntimeError(f"bench: services not ready after {timeout:.0f} s (missing e.g. "
                           f"{sorted(missing)[:5] or ['echo']}); logs in {self.log_dir}")

    def _token_names(self) -> list[str]:
        names = []
        for name, _module, _args in self.services:
            names += [*BATCHED_STAGES, "ocp"] if name == "batch" else [name]
        return names

    def stop(self, timeout: float = 5.0) -> None:
        if self.group is not None:
            self.group.stop_all(timeout)


def open_client(endpoint: str):
    import zenoh

    from soilocp.services.runtime.config import zenoh_config

    return zenoh.open(zenoh_config("client", [endpoint], [], connect_timeout_ms=10000))


# ----------------------------------------------------------------------------------------------
# pacing
# ----------------------------------------------------------------------------------------------
def _paced(n_streams: int, n_steps: int, rate: float, t0: float):
    """(step, stream, due time): streams spread evenly over each period of ``1/rate`` s."""
    period = 1.0 / rate
    for k in range(n_steps):
        for i in range(n_streams):
            yield k, i, t0 + k * period + i * period / n_streams


def _sleep_until(t: float) -> None:
    # sleep only, never spin: a spinning sender holds the GIL that the OCP subscriber's callback
    # needs, which would add up to the interpreter's switch interval (5 ms) to measured latencies
    d = t - time.perf_counter()
    if d > 0:
        time.sleep(d)


# ----------------------------------------------------------------------------------------------
# baseline: ping-pong through the router
# ----------------------------------------------------------------------------------------------
def ping_pong(session, rate: float, duration: float, payload_size: int = 400, *, express: bool = False,
              shm_provider=None) -> dict[str, Any]:
    """Round trip bench -> router -> echo -> router -> bench, paced at ``rate`` Hz; ms stats.
    ``express``: no batching on the ping publisher; ``shm_provider``: put each ping from a
    zenoh shared-memory buffer (``soilocp.services.bench.transport`` compares the options)."""
    import zenoh

    n = max(1, int(round(rate * duration)))
    sent: dict[int, float] = {}
    got: dict[int, float] = {}
    lock = threading.Lock()
    pad = b" " * max(0, payload_size - 30)

    def _payload(body: bytes):
        if shm_provider is None:
            return body
        buf = shm_provider.alloc(len(body), zenoh.shm.BlockOn(zenoh.shm.GarbageCollect()))
        buf[0:len(body)] = body
        return buf

    sub = session.declare_subscriber(PONG_KEY, arrivals(got, lock))
    pub = session.declare_publisher(PING_KEY, congestion_control=zenoh.CongestionControl.BLOCK, express=express)
    try:
        # warm the path (and wait for the echo's subscription to be known to the router)
        deadline = time.monotonic() + 10.0
        while not got and time.monotonic() < deadline:
            pub.put(_payload(b'{"seq":' + b"0" + b"}"))
            time.sleep(0.05)
        got.clear()
        t0 = time.perf_counter() + 0.01
        for k, _i, due in _paced(1, n, rate, t0):
            _sleep_until(due)
            seq = k + 1
            sent[seq] = time.perf_counter()
            pub.put(_payload(b'{"seq":' + str(seq).encode() + b"}" + pad))
        _wait_all(lambda: len(got) >= len(sent), 2.0)
    finally:
        sub.undeclare()
        pub.undeclare()
    with lock:
        rtt = [(got[s] - t) * 1e3 for s, t in sent.items() if s in got]
    st = summarize(rtt)
    st.update(sent=len(sent), lost=len(sent) - len(rtt), rate_hz=rate)
    return st


def arrivals(got: dict[int, float], lock: threading.Lock, first: bool = False):
    """A subscriber callback that records into ``got`` when each message arrived (``time.perf_counter``), by the
    ``seq`` of its JSON; ``first``: only a seq's first arrival."""

    def record(sample) -> None:
        t = time.perf_counter()
        m = _SEQ_RE.search(sample.payload.to_bytes())
        if m:
            with lock:
                if first:
                    got.setdefault(int(m.group(1)), t)
                else:
                    got[int(m.group(1))] = t

    return record


def _wait_all(pred, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not pred() and time.monotonic() < deadline:
        time.sleep(0.01)


# ----------------------------------------------------------------------------------------------
# the pipeline under load
# ----------------------------------------------------------------------------------------------
def drive(session, payloads: dict[str, list[tuple[int, bytes]]], rate: float, duration: float,
          warmup_s: float = 0.5, drain_s: float = 3.0) -> dict[str, Any]:
    """Publish each vehicle's ``(seq, payload)`` list on its raw key at ``rate`` Hz (vehicles
    phase-shifted), collect OCPs and rejections; latency stats in ms (samples sent after
    ``warmup_s``), drops (sent seqs without an OCP after ``drain_s``), rejections, send lag."""
    import zenoh

    vids = list(payloads)
    n_steps = min(int(round(rate * duration)), min(len(v) for v in payloads.values()))
    sent: dict[tuple[str, int], float] = {}
    got: dict[tuple[str, int], float] = {}
    rejected = [0]
    lock = threading.Lock()

    def _ocp(sample) -> None:
        t = time.perf_counter()
        m = _SEQ_RE.search(sample.payload.to_bytes())
        if m:
            vid = str(sample.key_expr).split("/", 2)[1]
            with lock:
                got[(vid, int(m.group(1)))] = t

    def _rej(sample) -> None:
        m = _SUPPRESSED_RE.search(sample.payload.to_bytes())  # a flood's rejections are sampled
        with lock:
            rejected[0] += 1 + (int(m.group(1)) if m else 0)

    subs = [session.declare_subscriber(keys.any_vehicle_ocp(), _ocp),
            session.declare_subscriber(keys.any_vehicle_rejected(), _rej)]
    pubs = {vid: session.declare_publisher(keys.raw(vid), congestion_control=zenoh.CongestionControl.BLOCK)
            for vid in vids}
    lag: list[float] = []
    try:
        time.sleep(0.3)  # let the router learn the new subscriptions
        t0 = time.perf_counter() + 0.05
        for k, i, due in _paced(len(vids), n_steps, rate, t0):
            _sleep_until(due)
            vid = vids[i]
            seq, payload = payloads[vid][k]
            now = time.perf_counter()
            sent[(vid, seq)] = now
            lag.append((now - due) * 1e3)
            pubs[vid].put(payload)
        t_end = time.perf_counter()
        _wait_all(lambda: len(got) >= len(sent), drain_s)
    finally:
        for e in (*subs, *pubs.values()):
            e.undeclare()
    with lock:
        lat = [(got[key] - t) * 1e3 for key, t in sent.items() if key in got and t - t0 >= warmup_s]
        missing = sum(1 for key in sent if key not in got)
        n_rej = rejected[0]
    st = summarize(lat)
    achieved = len(sent) / max(t_end - t0, 1e-9)
    st.update(vehicles=len(vids), rate_hz=rate, sent=len(sent), received=len(sent) - missing, drops=missing,
              rejections=n_rej, offered_per_s=achieved, target_per_s=rate * len(vids),
              send_lag_p99_ms=summarize(lag)["p99"])
    return st
