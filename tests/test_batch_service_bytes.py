"""The batched service's handling (soilocp.services.stages.batch), in process without Zenoh: every published OCP
payload is byte for byte that of the plain flush (the normal forces by ``normal_forces(vehicle, ...)``, a
list of quads to ``BatchPipeline.step``), one vehicle at a time and batched; the service's faster path
(its solver held, the forces block passed whole) must not move a byte."""

from __future__ import annotations

import io
import itertools

import numpy as np

from soilocp.services.runtime.config import load_service_config
from soilocp.services.runtime.log import JsonLog
from soilocp.services.runtime.worker import WorkItem
from soilocp.services.stages.batch import BatchOcpService
from soilocp.model.normal_force import normal_forces
from soilocp.sim.simulator import simulate


class _Pub:
    def __init__(self):
        self.out: list[str] = []

    def put(self, payload) -> None:
        self.out.append(payload)


class _PlainFlush(BatchOcpService):
    """The flush as it was before the per-sample work was trimmed (the reference)."""

    def flush(self) -> None:
        while self.n_pending:
            vids = [vid for vid, q in self.pending.items() if q]
            samples = [self.pending[vid].popleft() for vid in vids]
            self.n_pending -= len(samples)
            idx = np.array([self.index[v] for v in vids])
            fz = normal_forces(self.batch.config.vehicle, np.array([s.specific_force for s in samples], dtype=float))
            out = self.batch.step(idx, samples, [np.asarray(f).tolist() for f in fz])
            self.steps += 1
            for vid, est in zip(vids, out):
                self.stores[vid].add(est)
                self.pubs[vid].put(est.model_dump_json())


def _published(cls, drives: dict[str, list[bytes]], depths) -> tuple[dict[str, list[str]], int]:
    vids = list(drives)
    cfg = load_service_config("ocp", overrides=dict(vehicle_ids=vids), env={})
    svc = cls(cfg, JsonLog("ocp", "error", stream=io.StringIO()))
    for v in vids:
        svc.pubs[v] = _Pub()
    depth = itertools.cycle(depths)
    svc.worker.depth = lambda: next(depth)  # the queue behind this item: decides when the service flushes
    for k in range(max(map(len, drives.values()))):
        for v in vids:
            if k < len(drives[v]):
                svc._handle_safe(WorkItem(v, "sample", drives[v][k], 0.0, f"soilocp/{v}/sensors/clean"))
    svc.flush()
    return {v: svc.pubs[v].out for v in vids}, svc.steps


def _drives(vids, scenarios, duration=1.5):
    return {v: [s.model_dump_json().encode() for s, _t in simulate(sc, duration=duration, rate=1000.0, seed=i,
                                                                    vehicle_id=v)]
            for i, (v, sc) in enumerate(zip(vids, scenarios))}


def test_one_vehicle_publishes_the_same_bytes():
    drives = _drives(["b1"], ["mixed"])
    got, steps = _published(BatchOcpService, drives, [0])
    want, _ = _published(_PlainFlush, drives, [0])
    assert steps == len(drives["b1"]) == len(got["b1"])
    assert got == want


def test_batched_vehicles_publish_the_same_bytes():
    drives = _drives(["va", "vb", "vc"], ["sandy-slope", "mixed", "mixed"])
    depths = [3, 2, 1, 0, 5, 4, 0, 0, 1, 0, 7, 9, 9, 0]  # some flushes wait, then step several vehicles together
    got, steps = _published(BatchOcpService, drives, depths)
    want, _ = _published(_PlainFlush, drives, depths)
    n = sum(map(len, drives.values()))
    assert sum(map(len, got.values())) == n and steps < n  # every sample published, vehicles stepped together
    assert got == want
