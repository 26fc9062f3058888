"""Batched normal forces + observer + soil strength + OCP publisher for many vehicles in one process.

A drop-in for the four services ``normal-force``, ``observer``, ``soil-strength`` and ``ocp`` of
one deployment (the gateway stays as it is): it subscribes to every vehicle's ``sensors/clean``,
computes the normal forces of all pending samples in one call (:func:`soilocp.model.normal_force`'s
solver, eqs. 21-25), steps all vehicles that have a sample together with
:class:`soilocp.estimation.estimator.Estimator` (the estimator's whole step, one core call for all of them, each
vehicle's map prior an input of it), and publishes each ``OcpEstimate`` on ``soilocp/<vid>/ocp`` — the same numbers as
the per-vehicle services and ``soilocp estimate`` (``tests/test_batch.py``).  It *is* the OCP
publisher (subclass of :class:`~soilocp.services.stages.ocp.OcpService`: same queryable, history, stale
reports, health on ``soilocp/<vid>/status/ocp``) and also holds the ``normal-force``,
``observer`` and ``soil-strength`` liveliness tokens, so sources and ``soilocp run`` see a
complete pipeline.  The internal ``normal_forces``, ``observer`` and ``soil`` keys are not
published (nothing downstream needs them): two Zenoh hops and three JSON round trips less per
sample than the five-service chain.

Batching is opportunistic: samples wait only while more input is already queued, so a lone
vehicle is stepped at once (no added latency) and under load one numpy step serves every
vehicle with a pending sample.

``python -m soilocp.services.stages.batch --vehicle-id v1 --vehicle-id v2 --connect tcp/127.0.0.1:7447``
(or ``SOILOCP_VEHICLE_ID=v1,v2``; the settings of any service, section ``soilocp.services.stages.ocp``).
"""

from __future__ import annotations

import sys
from collections import deque
from typing import Any

import numpy as np

from soilocp.schemas import keys
from soilocp.schemas.sensor import SensorSample
from soilocp.estimation.estimator import Estimator
from soilocp.model.normal_force import NormalForceSolver

from soilocp.services.runtime.process import exit_now
from soilocp.services.runtime.worker import WorkItem
from soilocp.services.stages.config import pipeline_config
from soilocp.services.stages.graph import BATCHED_STAGES, BY_NAME
from soilocp.services.stages.ocp import OcpService

#: Flush the joined samples once this many are waiting per served vehicle, even if input is queued.
MAX_PENDING_PER_VEHICLE = 4


class BatchOcpService(OcpService):
    """The OCP row, computing the rows before it (``BATCHED_STAGES``) itself for every vehicle."""

    def __init__(self, cfg, log):
        super().__init__(cfg, log)
        pc = pipeline_config(cfg)
        self.vids = list(cfg.vehicle_ids)
        self.index = {vid: i for i, vid in enumerate(self.vids)}
        # the soil-strength service's opt-in map prior (map_prior / SOILOCP_MAP_PRIOR), the same feed and prior
        self.feed = None
        if cfg.map_prior is not None:
            from soilocp.services.stages.map_prior_feed import MapPriorFeed

            self.feed = MapPriorFeed(self, cfg.map_prior, self.vids, pc.vehicle)
        self.batch = Estimator(pc, len(self.vids), None if self.feed is None else [self.feed.priors[v] for v in self.vids])
        self.pending: dict[str, deque] = {vid: deque() for vid in self.vids}
        self.n_pending = 0
        self.max_pending = MAX_PENDING_PER_VEHICLE * len(self.vids)
        self.last_seq: dict[str, int] = {}
        self.solve = NormalForceSolver(pc.vehicle)  # the core's solver, built once (not per sample)
        self.steps = 0

    def declare(self, session, vehicle_id: str) -> None:
        super().declare(session, vehicle_id)  # OCP publisher, status publisher, queryable (+ an idle soil subscriber)
        first = BY_NAME[BATCHED_STAGES[0]].inputs[0]  # the clean samples, as the normal-force row takes them
        self.subscribe(session, first.key(vehicle_id), vehicle_id, "sample")
        # this process implements those rows: their tokens say so to sources, `run` and the fleet
        for stage in BATCHED_STAGES:  # after the subscription: inputs are ready
            self.keep(session.liveliness().declare_token(keys.alive(vehicle_id, stage)))

    def handle(self, item: WorkItem) -> None:
        vid = item.vehicle_id
        c = self.counters[vid]
        c.last_input_wall = item.wall
        if item.kind == "sample":
            sample = SensorSample.model_validate_json(item.payload)
            last = self.last_seq.get(vid)
            if last is not None and sample.seq <= last:
                # only after a gateway restart: the observer must not see time run backwards
                c.dropped += 1
                c.bump("out_of_order")
            else:
                self.last_seq[vid] = sample.seq
                self.pending[vid].append(sample)
                self.n_pending += 1
        if self.n_pending and (self.worker.depth() == 0 or self.n_pending >= self.max_pending):
            self.flush()

    def flush(self) -> None:
        """Step every vehicle with a pending joined sample, oldest first, until none is left."""
        while self.n_pending:
            vids = [vid for vid, q in self.pending.items() if q]
            samples = [self.pending[vid].popleft() for vid in vids]
            self.n_pending -= len(samples)
            idx = np.array([self.index[v] for v in vids])
            # normal forces of every stepped vehicle in one call (zero-warp solution, eqs. 21-25)
            fz = self.solve(np.array([s.specific_force for s in samples], dtype=float))
            if self.feed is not None:
                before = [self.feed.priors[v].entered for v in vids]
                for vid, s in zip(vids, samples):
                    self.feed.saw(vid, s)
            out = self.batch.step(idx, samples, fz)
            if self.feed is not None:
                for vid, s, b in zip(vids, samples, before):
                    self.feed.count(vid, s.seq, b)
            self.steps += 1
            for vid, est in zip(vids, out):
                self.stores[vid].add(est)
                self.pubs[vid].put(est.model_dump_json())
                c = self.counters[vid]
                c.published += 1
                c.last_seq, c.last_stamp = est.seq, est.stamp

    def health_extra(self, vehicle_id: str) -> dict[str, Any]:
        out = super().health_extra(vehicle_id)
        out["detail"] = {**out["detail"], "batched": True, "batch_steps": self.steps,
                         "pending": len(self.pending[vehicle_id])}
        return out


def main(argv: list[str] | None = None) -> int:
    import argparse

    from soilocp.services.runtime.config import ConfigError, load_service_config

    from soilocp.services.runtime.service import run_service

    ap = argparse.ArgumentParser(prog="python -m soilocp.services.stages.batch",
                                 description="Batched observer + soil strength + OCP publisher for many vehicles.")
    ap.add_argument("--config", dest="config_path", help="service config file (JSON); env SOILOCP_CONFIG")
    ap.add_argument("--vehicle-id", dest="vehicle_ids", action="append", help="vehicle id (repeatable)")
    ap.add_argument("--connect", action="append", help="router endpoint (repeatable)")
    ap.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    ap.add_argument("--stale-timeout", type=float, dest="stale_timeout_s")
    ap.add_argument("--pipeline-config", help="physics PipelineConfig file (JSON)")
    a = ap.parse_args(argv)
    overrides = dict(vehicle_ids=a.vehicle_ids, connect=a.connect, log_level=a.log_level,
                     stale_timeout_s=a.stale_timeout_s, pipeline_config=a.pipeline_config)
    try:
        cfg = load_service_config("ocp", config_path=a.config_path, overrides=overrides)
        return run_service(BatchOcpService, cfg)
    except (ConfigError, ValueError) as exc:
        print(f"python -m soilocp.services.stages.batch: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    exit_now(main())  # as `soilocp service`: no interpreter finalisation after an orderly shutdown
