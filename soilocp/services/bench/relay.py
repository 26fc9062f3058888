"""Relay stages: the live pipeline's processes without the estimation, for the floor of the live rows.

Each relay is the real service class of its row (``soilocp.services.stages.registry``, the batched
service, the controller) run by the real runtime (``run_service``: same config, Zenoh session,
publishers, worker queue, liveliness, health), with only the work replaced:

* ``zenoh`` level: the worker puts the received payload bytes on the row's output key.  What is
  left is processes + hops + the callback -> queue -> worker hand-off + scheduling.  The observer
  forwards its ``forces`` input only (the later of its two, as its join would), the batched service
  its clean samples.
* ``messages`` level: the row's own handling runs (input parsed with the real model, the
  observer's join by seq, the OCP store and queryable, the batched service's pending queue) and
  its library stage is replaced by a :class:`RelayStep` that returns a recorded real output with
  the vehicle, seq and stamp of its input.  The gateway and the controller are the real ones:
  what they do is message handling (validation, a set-point policy of a few comparisons).

``python -m soilocp.services.bench.relay NAME --level zenoh|messages [--templates FILE]``, NAME a row of
``soilocp.services.stages.graph``, ``batch`` or ``controller``; settings from the environment, as every
service (``SOILOCP_VEHICLE_ID``, ``SOILOCP_CONNECT``...).  :mod:`soilocp.services.bench.floor` starts them.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, Optional, Sequence

LEVELS = ("zenoh", "messages")
#: The rows whose library stage a messages-level relay replaces (their outputs are recorded).
RECORDED = ("normal-force", "observer", "soil-strength", "ocp")
#: The input a zenoh-level relay forwards, per row (the others are received and ignored).
FORWARDED_KIND = {"observer": "forces", "batch": "sample", "controller": "ocp"}


class RelayStep:
    """A library stage's stand-in: ``step(*inputs)`` returns the recorded output, with the vehicle,
    seq and stamp of the first input (the real stages take them from there too)."""

    def __init__(self, template):
        self.template = template

    def step(self, first, *_rest):
        # model_copy skips validation: the serialisation that follows is the real cost, not this
        return self.template.model_copy(update={"vehicle_id": first.vehicle_id, "seq": first.seq,
                                                "stamp": first.stamp})


def record_templates(samples: Sequence[Any]) -> dict[str, str]:
    """One real output per recorded row (JSON), from the library stages on ``samples``: of each
    row's outputs over the drive, the one of median size."""
    from soilocp.estimation.pipeline import PipelineConfig, VehiclePipeline

    pipe = VehiclePipeline(PipelineConfig())
    outs: dict[str, list[str]] = {name: [] for name in RECORDED}
    for s in samples:
        for name, out in zip(RECORDED, pipe.process_all(s)):  # the four stages' messages, in order
            outs[name].append(out.model_dump_json())
    picked = {}
    for name, texts in outs.items():
        steady = texts[len(texts) // 5:] or texts  # the start is the observer warming up, not the steady state
        picked[name] = sorted(steady, key=len)[len(steady) // 2]
    return picked


def _health_plain(self, vehicle_id: str) -> dict[str, Any]:
    # the observer's health_extra reads its library stage's bank, which a relay does not have
    return {}


def relay_class(name: str, level: str, templates: Optional[dict[str, str]] = None) -> type:
    """The service class of relay ``name`` at ``level`` (a subclass of the real one)."""
    if level not in LEVELS:
        raise ValueError(f"level {level!r}: must be one of {', '.join(LEVELS)}")
    base = _real_class(name)
    attrs: dict[str, Any] = {}
    if name in RECORDED:
        # no stage factory: the process neither imports nor builds the physics
        attrs["spec"] = replace(base.spec, stage=None)
    if name == "observer":
        attrs["health_extra"] = _health_plain
    if level == "zenoh":
        attrs["handle"] = _forwarder(FORWARDED_KIND.get(name))
    elif name in RECORDED:
        attrs["__init__"] = _with_relay_steps(base, _template(templates, name))
    elif name == "batch":
        attrs["flush"] = _batch_flush(_template(templates, "ocp"))
    if not attrs:
        return base  # the gateway and the controller at the messages level: the real services
    return type(f"Relay[{name},{level}]", (base,), attrs)


def _with_relay_steps(base: type, template):
    def __init__(self, cfg, log):
        base.__init__(self, cfg, log)
        self.stages = {vid: RelayStep(template) for vid in cfg.vehicle_ids}

    return __init__


def _real_class(name: str) -> type:
    if name == "batch":
        from soilocp.services.stages.batch import BatchOcpService

        return BatchOcpService
    if name == "controller":
        from soilocp.services.control.controller import ControllerService

        return ControllerService
    from soilocp.services.stages.registry import stage_service

    return stage_service(name)


def _template(templates: Optional[dict[str, str]], name: str):
    from soilocp.services.stages.graph import BY_NAME

    if not templates or name not in templates:
        raise ValueError(f"relay {name}: the messages level needs a recorded {name} output (--templates)")
    return BY_NAME[name].output_model.model_validate_json(templates[name])


def _forwarder(kind: Optional[str]):
    def handle(self, item) -> None:
        if kind is not None and item.kind != kind:
            return
        self.pubs[item.vehicle_id].put(item.payload)
        self.counters[item.vehicle_id].published += 1

    return handle


def _batch_flush(template):
    step = RelayStep(template)

    def flush(self) -> None:
        # the batched service's flush (oldest sample of every vehicle first), the batch step replaced
        while self.n_pending:
            vids = [vid for vid, q in self.pending.items() if q]
            samples = [self.pending[vid].popleft() for vid in vids]
            self.n_pending -= len(samples)
            self.steps += 1
            for vid, s in zip(vids, samples):
                est = step.step(s)
                self.stores[vid].add(est)
                self.pubs[vid].put(est.model_dump_json())
                c = self.counters[vid]
                c.published += 1
                c.last_seq, c.last_stamp = est.seq, est.stamp

    return flush


def main(argv: Optional[list[str]] = None) -> int:
    from soilocp.services.runtime.config import ConfigError, load_service_config
    from soilocp.services.runtime.process import exit_now
    from soilocp.services.runtime.service import run_service

    ap = argparse.ArgumentParser(prog="python -m soilocp.services.bench.relay",
                                 description="A pipeline row that relays instead of estimating (the bench's floor).")
    ap.add_argument("name", help="a pipeline row, 'batch' or 'controller'")
    ap.add_argument("--level", choices=LEVELS, required=True)
    ap.add_argument("--templates", help="JSON file of recorded outputs per row (messages level)")
    a = ap.parse_args(argv)
    try:
        templates = json.loads(Path(a.templates).read_text()) if a.templates else None
        cls = relay_class(a.name, a.level, templates)
        cfg = load_service_config("ocp" if a.name == "batch" else a.name)
        kwargs = {"control": "ocp_traction"} if a.name == "controller" else {}
        exit_now(run_service(cls, cfg, **kwargs))
    except (ConfigError, ValueError, OSError, KeyError) as exc:
        print(f"python -m soilocp.services.bench.relay: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
