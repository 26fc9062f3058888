"""The Foxglove layout shipped in docs/ cannot rot: every panel is placed, every topic it references
is a channel soilocp publishes, and every message path resolves to numbers in real messages: the
MCAP export of a simulated drive, which holds every channel (the estimates and the sensors), so the
layout opens that file with no empty panel."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from soilocp.export.channels import topics
from soilocp.sim.simulator import simulate
from soilocp.cli.main import main

LAYOUT = Path(__file__).resolve().parents[1] / "docs" / "foxglove" / "soilocp-layout.json"
VID = "rover1"  # the layout's vehicle (docs/foxglove.md: how to point it at another)
_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)((?:\[(?:\d+|:)\])*)$")


def _leaves(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    return _leaves(node["first"]) + _leaves(node["second"])


def _message_paths(layout: dict) -> list[tuple[str, str]]:
    """(panel type, message path) of every path the panels read."""
    out = []
    for panel_id, cfg in layout["configById"].items():
        kind = panel_id.split("!")[0]
        out += [(kind, p["value"]) for p in cfg.get("paths", [])]
        if "xAxisPath" in cfg:
            out.append((kind, cfg["xAxisPath"]["value"]))
        if "topicPath" in cfg:
            out.append((kind, cfg["topicPath"]))
    return out


def _resolve(message: dict, fields: str):
    """Evaluate a Foxglove message path's field part (``a.b[0]``, ``a[:]``) on a decoded message."""
    values = [message]
    for seg in fields.split("."):
        m = _SEGMENT.match(seg)
        assert m, f"unsupported message-path segment {seg!r}"
        values = [v[m.group(1)] for v in values]
        for idx in re.findall(r"\[(\d+|:)\]", m.group(2)):
            values = [x for v in values for x in v] if idx == ":" else [v[int(idx)] for v in values]
    return values


@pytest.fixture(scope="module")
def published(tmp_path_factory) -> dict[str, list[dict]]:
    """Real messages per topic: the MCAP export of a simulated drive, nothing else."""
    d = tmp_path_factory.mktemp("layout")
    log = d / "s.jsonl"
    log.write_text("".join(s.model_dump_json() + "\n" for s, _ in simulate("sand", duration=6.0, seed=1, vehicle_id=VID)))
    r = CliRunner().invoke(main, ["estimate", str(log), "--out", str(d / "E.mcap")])
    assert r.exit_code == 0, r.output
    out: dict[str, list[dict]] = {}
    with open(d / "E.mcap", "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages():
            out.setdefault(ch.topic, []).append(json.loads(m.data))
    return out


def test_layout_panels_are_all_placed():
    layout = json.loads(LAYOUT.read_text())
    assert set(layout) >= {"configById", "layout"}
    leaves = _leaves(layout["layout"])
    assert sorted(leaves) == sorted(layout["configById"]), "every panel placed once, every placed panel configured"


def test_layout_topics_are_published_channels_and_paths_resolve(published):
    layout = json.loads(LAYOUT.read_text())
    paths = _message_paths(layout)
    assert paths
    ours = set(topics(VID))
    assert set(published) == ours  # the MCAP export holds every channel, the sensors included
    used = set()
    for kind, path in paths:
        topic, _, fields = path.partition(".")
        assert topic in ours, f"{path}: topic {topic!r} is not a channel soilocp publishes ({sorted(ours)})"
        used.add(topic)
        if not fields:
            continue
        resolved = [_resolve(m, fields) for m in published[topic]]
        if kind == "Plot":
            good = [vs for vs in resolved if vs and all(isinstance(v, (int, float)) and math.isfinite(v) for v in vs)]
        else:  # state transitions: any value (the status string)
            good = [vs for vs in resolved if vs and all(v is not None for v in vs)]
        assert good, f"{path}: no message of {topic} gives {'numbers' if kind == 'Plot' else 'values'} there"
    # the dashboard's plots: K with its band, OCPs, slips, status; and the sensors
    assert used == ours
