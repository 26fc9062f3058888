"""In-process cost of each pipeline stage, and the offline replay rate (part 1 of ``soilocp bench``).

Every stage is timed sample by sample on a real simulated drive (the simulator's ``mixed``
scenario by default), with the same objects the services run: validation is
``parse_sample`` + ``SampleValidator`` on the JSON line (the gateway's check), then
``NormalForceStage``, ``ObserverStage`` (one step of the observer kernel, N = 1, including the per-step ZOH
discretisation), ``SoilStage`` and ``OcpStage``.  ``messages`` is what the live services add on
top of the physics: encoding and decoding of the four internal messages (one hop each).
"""

from __future__ import annotations

import math
import time
from typing import Any, Optional, Sequence

import numpy as np

from soilocp.schemas.pipeline import NormalForces, ObserverOutput, SoilEstimate
from soilocp.schemas.sensor import SensorSample

STAGES = ("validation", "normal_forces", "observer", "soil_strength", "ocp", "messages")


def summarize(values: Sequence[float]) -> dict[str, Any]:
    """Median / p90 / p99 / max / mean / n of a list of numbers (NaN when empty)."""
    a = np.asarray(values, dtype=float)
    if a.size == 0:
        nan = float("nan")
        return {"n": 0, "p50": nan, "p90": nan, "p99": nan, "max": nan, "mean": nan}
    return {
        "n": int(a.size),
        "p50": float(np.percentile(a, 50)),
        "p90": float(np.percentile(a, 90)),
        "p99": float(np.percentile(a, 99)),
        "max": float(a.max()),
        "mean": float(a.mean()),
    }


def simulate_drive(vehicle_id: str, duration: float, rate: float = 100.0, scenario: str = "mixed",
                   seed: int = 1) -> list[SensorSample]:
    """A real simulated drive (``soilocp.sim.simulator.simulate``) as a list of samples."""
    from soilocp.sim.simulator import simulate

    if not (duration > 0 and math.isfinite(duration)):
        raise ValueError(f"duration {duration!r}: must be a finite number of seconds > 0")
    return [s for s, _t in simulate(scenario, duration=duration, rate=rate, seed=seed, vehicle_id=vehicle_id)]


def stage_costs(samples: Sequence[SensorSample], config=None) -> dict[str, dict[str, Any]]:
    """Microseconds per sample of each stage over ``samples`` (one vehicle, in order)."""
    from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline
    from soilocp.validation import SampleValidator, parse_sample

    if not samples:
        raise ValueError("samples: need at least one sample to time the stages")
    pipe = VehiclePipeline(config or PipelineConfig())
    validator = SampleValidator()
    lines = [s.model_dump_json().encode() for s in samples]
    times: dict[str, list[float]] = {k: [] for k in STAGES}
    cpu: dict[str, list[float]] = {k: [] for k in STAGES}
    wall, tcpu = time.perf_counter_ns, time.thread_time_ns
    for line in lines:
        stamps = [(wall(), tcpu())]
        sample = parse_sample(line)
        validator.check(sample)
        stamps.append((wall(), tcpu()))
        nf = pipe.normal.step(sample)
        stamps.append((wall(), tcpu()))
        ob = pipe.observer.step(sample, nf)
        stamps.append((wall(), tcpu()))
        so = pipe.soil.step(ob)
        stamps.append((wall(), tcpu()))
        oc = pipe.ocp.step(so)
        stamps.append((wall(), tcpu()))
        # one encode + decode per internal hop, as the services do (clean sample, forces,
        # observer output, soil estimate, OCP)
        SensorSample.model_validate_json(sample.model_dump_json())
        NormalForces.model_validate_json(nf.model_dump_json())
        ObserverOutput.model_validate_json(ob.model_dump_json())
        SoilEstimate.model_validate_json(so.model_dump_json())
        oc.model_dump_json()
        stamps.append((wall(), tcpu()))
        for i, name in enumerate(STAGES):
            times[name].append((stamps[i + 1][0] - stamps[i][0]) / 1000.0)
            cpu[name].append((stamps[i + 1][1] - stamps[i][1]) / 1000.0)
    out = {name: summarize(v) for name, v in times.items()}
    # CPU time of the thread: what the stage costs, whatever else the machine is running
    for name, v in cpu.items():
        c = summarize(v)
        out[name].update(cpu_p50=c["p50"], cpu_p99=c["p99"], cpu_mean=c["mean"])
    n = len(lines)
    out["total"] = summarize([sum(times[k][i] for k in STAGES) for i in range(n)])
    c = summarize([sum(cpu[k][i] for k in STAGES) for i in range(n)])
    out["total"].update(cpu_p50=c["p50"], cpu_p99=c["p99"], cpu_mean=c["mean"])
    return out


def cpu_share(seconds: float = 0.3) -> dict[str, float]:
    """How much of a core this process gets right now: CPU time / wall time of a busy loop
    (1.0 on an idle machine; 0.1 when ten runnable threads share the core)."""
    w0, c0 = time.perf_counter(), time.thread_time()
    x = 0
    while time.perf_counter() - w0 < seconds:
        x += 1
    wall, cpu = time.perf_counter() - w0, time.thread_time() - c0
    return {"wall_s": wall, "cpu_s": cpu, "share": cpu / wall if wall > 0 else float("nan")}


def replay_rate(samples: Sequence[SensorSample], config=None, rate_hz: float = 100.0) -> dict[str, Any]:
    """Offline replay speed of ``soilocp.estimation.estimate.estimate_lines`` on the drive's JSON lines."""
    from soilocp.estimation.estimate import estimate_lines
    from soilocp.estimation.pipeline import PipelineConfig

    lines = [s.model_dump_json() for s in samples]
    t0, c0 = time.perf_counter(), time.thread_time()
    n = sum(1 for _ in estimate_lines(lines, config or PipelineConfig()))
    dt, dc = time.perf_counter() - t0, time.thread_time() - c0
    sps = n / dt if dt > 0 else float("inf")
    cps = n / dc if dc > 0 else float("inf")  # per CPU second: the rate on an idle core
    return {"samples": n, "seconds": dt, "cpu_seconds": dc, "samples_per_s": sps, "x_real_time": sps / rate_hz,
            "samples_per_cpu_s": cps, "x_real_time_cpu": cps / rate_hz, "rate_hz": rate_hz}


def batch_costs(samples: Sequence[SensorSample], counts: Sequence[int], config=None,
                steps: Optional[int] = None) -> dict[str, dict[str, Any]]:
    """Microseconds per vehicle-sample of the batched observer + soil + OCP (``soilocp.estimation.batch``)
    stepping ``n`` vehicles together, for each n in ``counts`` (every vehicle replays the drive): the whole
    step (stacking the samples, the chain, the soil and OCP records), and its estimation math alone
    (``math_*``: the normal forces of the block, eqs. 21-25, and the one ``ChainCore.step`` call with the
    observer's clock, on inputs stacked beforehand)."""
    from soilocp.estimation.batch import BatchPipeline
    from soilocp.estimation.pipeline import NormalForceStage, PipelineConfig, observer_inputs
    from soilocp.model.normal_force import NormalForceSolver

    cfg = config or PipelineConfig()
    samples = list(samples[: steps or len(samples)])
    nfs = NormalForceStage(cfg)
    forces = [np.asarray(nfs.step(s).normal_force) for s in samples]
    solve = NormalForceSolver(cfg.vehicle)
    out: dict[str, dict[str, Any]] = {}
    for n in counts:
        bp, bm = BatchPipeline(cfg, n), BatchPipeline(cfg, n)
        idx = np.arange(n)
        per: list[float] = []
        per_cpu: list[float] = []
        math_cpu: list[float] = []
        for s, fz in zip(samples, forces):
            block, fzs = [s] * n, [fz] * n
            t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
            bp.step(idx, block, fzs)  # stacking the inputs and building the OCP records included
            per.append((time.perf_counter_ns() - t0) / 1000.0 / n)
            per_cpu.append((time.thread_time_ns() - c0) / 1000.0 / n)
            inputs, sf = observer_inputs(block, fzs), np.array([s.specific_force] * n)
            c0 = time.thread_time_ns()
            inputs.normal_force = solve(sf)
            bm.observer.run(bm.chain.step, idx, inputs)
            math_cpu.append((time.thread_time_ns() - c0) / 1000.0 / n)
        out[str(n)] = summarize(per)
        c = summarize(per_cpu)
        out[str(n)].update(cpu_p50=c["p50"], cpu_p99=c["p99"], cpu_mean=c["mean"])
        c = summarize(math_cpu)
        out[str(n)].update(math_cpu_p50=c["p50"], math_cpu_p99=c["p99"])
    return out
