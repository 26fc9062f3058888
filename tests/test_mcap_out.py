"""Estimates out as MCAP: ``soilocp estimate --out E.mcap`` opens with the mcap reader with the
expected channels (those of the live Foxglove server: four estimate channels and the sensors),
JSON schemas and values; the rotating writer keeps the disk use bounded."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from soilocp.cli.main import main
from soilocp.export.channels import topics
from soilocp.export.mcap_out import CHANNEL_SCHEMAS, RotatingMcapWriter
from soilocp.sim.simulator import simulate

#: a line the chain rejects (malformed JSON): it has no record, so no sensor message either
BAD_LINE = '{"vehicle_id": "rover1", "seq": \n'


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("mcap")
    log = d / "s.jsonl"
    with open(log, "w") as f:
        for i, (s, _) in enumerate(simulate("sand", duration=6.0, seed=1)):
            f.write(s.model_dump_json() + "\n")
            if i == 100:
                f.write(BAD_LINE)
    runner = CliRunner()
    for out in ("E.mcap", "E.jsonl"):
        r = runner.invoke(main, ["estimate", str(log), "--out", str(d / out)])
        assert r.exit_code == 0, r.output
    return d


def test_estimate_mcap_channels_schemas_and_values(logs):
    recs = [json.loads(x) for x in (logs / "E.jsonl").read_text().splitlines()]
    with open(logs / "E.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        chans = {c.topic: c for c in summary.channels.values()}
        assert set(chans) == set(topics("rover1")) == {
            f"/soilocp/rover1/{k}" for k in ("soil_strength", "ocp", "wheels", "status", "sensors")}
        for topic, c in chans.items():
            sch = summary.schemas[c.schema_id]
            assert c.message_encoding == "json" and sch.encoding == "jsonschema"
            name, schema = CHANNEL_SCHEMAS[topic.rsplit("/", 1)[1]]
            assert sch.name == name and json.loads(sch.data) == schema
            assert summary.statistics.channel_message_counts[c.id] == len(recs)
        soil = [(m.log_time, json.loads(m.data)) for _, _, m in reader.iter_messages(topics=["/soilocp/rover1/soil_strength"])]
    assert [t for t, _ in soil] == [round(r["stamp"] * 1e9) for r in recs]
    with_k = [(m, r) for (_, m), r in zip(soil, recs) if r["soil_strength"] is not None]
    assert with_k, "the drive should give estimates"
    m, r = with_k[-1]
    assert m["K"] == r["soil_strength"] and m["K_plus_std"] == pytest.approx(r["soil_strength"] + r["soil_strength_std"])
    assert m["status"] == r["status"] and m["soil_class"] == r["soil_class"]


def test_estimate_mcap_sensor_messages_are_the_input_samples(logs):
    """The sensor channel holds each estimated sample as it was in the log: every value, and the
    sample's own stamp as log time; the rejected line is not there."""
    recs = [json.loads(x) for x in (logs / "E.jsonl").read_text().splitlines()]
    samples = [json.loads(x) for x in (logs / "s.jsonl").read_text().splitlines() if x + "\n" != BAD_LINE]
    assert len(samples) == len(recs) == 600
    with open(logs / "E.mcap", "rb") as f:
        got = [(m.log_time, m.publish_time, json.loads(m.data))
               for _, _, m in make_reader(f).iter_messages(topics=["/soilocp/rover1/sensors"])]
    assert [t for t, _, _ in got] == [p for _, p, _ in got] == [round(s["stamp"] * 1e9) for s in samples]
    assert [m for _, _, m in got] == samples  # every field, every value, exactly as in the log


def test_rotating_writer_bounds_file_size_and_count(tmp_path, logs):
    recs = [json.loads(x) for x in (logs / "E.jsonl").read_text().splitlines()]
    w = RotatingMcapWriter(tmp_path / "F.mcap", max_bytes=20_000, max_files=3)
    for r in recs:
        w.write(r)
    w.close()
    files = sorted(tmp_path.glob("F_*.mcap"))
    assert [p.name for p in files] == [p.name for p in w.files] and len(files) == 3
    assert w.index > 3  # older files were rotated out
    total = 0
    for p in files:
        assert p.stat().st_size < 20_000 + 40_000  # one chunk + summary past the limit at most
        with open(p, "rb") as f:
            total += sum(1 for _ in make_reader(f).iter_messages(topics=["/soilocp/rover1/status"]))
    # the newest files hold the newest records, in order, ending with the last one
    with open(files[-1], "rb") as f:
        last = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/soilocp/rover1/status"])][-1]
    assert last["seq"] == recs[-1]["seq"] and 0 < total < len(recs)


def test_withheld_k_keeps_the_sensor_channel(tmp_path):
    """A log whose provenance cannot identify K: the estimate channels say no_estimate, the sensor
    channel still holds every sample as it was."""
    from soilocp.ingest.align import Provenance

    log = tmp_path / "s.jsonl"
    log.write_text("".join(s.model_dump_json() + "\n" for s, _ in simulate("sand", duration=2.0, seed=3)))
    Provenance(source="test", ground_speed="absent", identifiable=False, reasons=["no ground speed"]).write(log)
    r = CliRunner().invoke(main, ["estimate", str(log), "--out", str(tmp_path / "E.mcap")])
    assert r.exit_code == 0, r.output
    with open(tmp_path / "E.mcap", "rb") as f:
        got: dict[str, list] = {}
        for _, ch, m in make_reader(f).iter_messages():
            got.setdefault(ch.topic.rsplit("/", 1)[1], []).append((m.log_time, json.loads(m.data)))
    samples = [json.loads(x) for x in log.read_text().splitlines()]
    assert [m for _, m in got["sensors"]] == samples
    assert [t for t, _ in got["sensors"]] == [t for t, _ in got["soil_strength"]] == [round(s["stamp"] * 1e9) for s in samples]
    assert {(m["K"], m["status"]) for _, m in got["soil_strength"]} == {(None, "no_estimate")}
