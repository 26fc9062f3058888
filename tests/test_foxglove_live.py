"""Foxglove live: a real ``soilocp run --foxglove`` (router, five services and the synthetic vehicle as
OS processes) and a standalone ``soilocp foxglove`` for the whole fleet, each watched by a real
WebSocket client speaking Foxglove's protocol (serverInfo, advertise, subscribe, binary message
data); what they serve equals what a Zenoh subscriber sees on the same keys, sample for sample."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import struct
import subprocess
import sys
import time
from collections import defaultdict

import pytest

from soilocp.schemas import keys

from zenoh_helpers import Procs, client, endpoint, free_port, wait_for

pytestmark = [pytest.mark.timeout(240), pytest.mark.e2e]

VID = "rover1"
# the channels of the MCAP export (tests/test_mcap_out.py): four estimate channels and the sensors
EXPECTED = {f"/soilocp/{VID}/{s}" for s in ("soil_strength", "ocp", "wheels", "status", "sensors")}
# foxglove-sdk (0.30) speaks the Foxglove WebSocket protocol under this name: the protocol of
# foxglove.websocket.v1, renamed; the old name is refused at the handshake (HTTP 400)
SUBPROTOCOL = "foxglove.sdk.v1"
WANT_PER_CHANNEL = 300  # 3 s of the 100 Hz drive
WANT_WITH_K = 20  # messages that carry a K estimate


async def _connect(port: int, deadline: float):
    import websockets

    while True:
        try:
            return await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None)
        except OSError:  # not listening yet
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)


async def _watch(port: int, deadline: float, on_first_sensors=None) -> dict:
    """Connect, subscribe to every channel advertised (also later ones), collect decoded messages;
    ``on_first_sensors()`` is called once the first sensor message has arrived."""
    from websockets.exceptions import ConnectionClosed

    ws = await _connect(port, deadline)
    out: dict = {"subprotocol": ws.subprotocol, "server_info": None, "channels": {}, "messages": defaultdict(list),
                 "status": []}
    subs: dict[int, int] = {}
    async with ws:
        while time.monotonic() < deadline:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.1, deadline - time.monotonic()))
            except (asyncio.TimeoutError, ConnectionClosed):  # the asserts below say what is missing
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "serverInfo":
                    out["server_info"] = op
                elif op["op"] == "status":  # a warning or error from the server (a refused subscription, ...)
                    out["status"].append(op)
                elif op["op"] == "advertise":
                    new = []
                    for ch in op["channels"]:
                        # every advertise is subscribed, a channel advertised again too, as Foxglove does: the
                        # fleet server advertises a channel again when foxglove-sdk refused its subscription
                        # (test_a_subscription_refused_by_the_sdk_...); the status messages say which were
                        out["channels"][ch["id"]] = ch
                        sid = len(subs) + 1
                        subs[sid] = ch["id"]
                        new.append({"id": sid, "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                continue
            # message data: opcode 0x01, subscription id (u32 LE), log time ns (u64 LE), payload
            opcode, sid, log_time = struct.unpack_from("<BIQ", frame, 0)
            assert opcode == 0x01, frame[:16]
            topic = out["channels"][subs[sid]]["topic"]
            out["messages"][topic].append((log_time, json.loads(frame[13:])))
            msgs = out["messages"]
            if on_first_sensors is not None and topic.endswith("/sensors"):
                on_first_sensors()
                on_first_sensors = None
            if (set(msgs) == EXPECTED and all(len(v) >= WANT_PER_CHANNEL for v in msgs.values())
                    and sum(m["K"] is not None for _t, m in msgs[f"/soilocp/{VID}/soil_strength"]) >= WANT_WITH_K):
                break
    return out


def _check_against_zenoh(got: dict, ocp_z: dict, raw_z: dict) -> int:
    """Every served message equals the Zenoh record of the same seq, field by field; its log time is
    the sample's stamp.  Returns how many OCP records were compared."""
    by = {t.rsplit("/", 1)[1]: v for t, v in got["messages"].items()}
    compared = 0
    for suffix, msgs in by.items():
        for log_time, m in msgs:
            z = (raw_z if suffix == "sensors" else ocp_z).get(m["seq"])
            if z is None:  # before the test's own subscriber was up
                continue
            assert m["vehicle_id"] == VID and m["stamp"] == z["stamp"]
            assert log_time == round(z["stamp"] * 1e9)
            if suffix == "soil_strength":
                compared += 1
                assert (m["K"], m["K_std"], m["soil_class"], m["soil_class_confidence"], m["status"], m["reason"]) == (
                    z["soil_strength"], z["soil_strength_std"], z["soil_class"], z["soil_class_confidence"],
                    z["status"], z["reason"])
                if z["soil_strength"] is not None:
                    assert m["K_plus_std"] == pytest.approx(z["soil_strength"] + z["soil_strength_std"])
                    assert m["K_minus_std"] == pytest.approx(z["soil_strength"] - z["soil_strength_std"])
            elif suffix == "ocp":
                assert (m["mu_T"], m["S_T"], m["S_E"], m["te_at_S_E"], m["status"]) == (
                    z["mu_T"], z["S_T"], z["S_E"], z["te_at_S_E"], z["status"])
            elif suffix == "wheels":
                assert m["slip"] == z["slip"] and m["traction"] == z["mu"]
            elif suffix == "status":
                assert (m["status"], m["reason"]) == (z["status"], z["reason"])
            else:
                for f in ("specific_force", "roll", "pitch", "yaw_rate", "wheel_speed", "wheel_torque", "ground_speed"):
                    assert m[f] == z[f], f
    return compared


def test_run_foxglove_and_fleet_foxglove_serve_the_zenoh_stream(tmp_path):
    ep = endpoint(free_port())
    ws_run, ws_fleet = free_port(), free_port()
    procs = Procs(tmp_path / "logs")
    run = subprocess.Popen([sys.executable, "-m", "soilocp.cli", "run", "--synthetic", "sand", "--duration", "20",
                            "--vehicle-id", VID, "--listen", ep, "--foxglove", f"127.0.0.1:{ws_run}", "--plain",
                            "--log-dir", str(tmp_path / "run")],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
                           env={k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")})
    try:
        procs.spawn("fleet_fox", ["foxglove", "--connect", ep, "--port", str(ws_fleet)])
        ocp_z: dict[int, dict] = {}
        raw_z: dict[int, dict] = {}

        def store(into: dict):
            def cb(sample) -> None:
                rec = json.loads(sample.payload.to_bytes())
                if isinstance(rec, dict) and rec.get("vehicle_id") == VID:  # not the test's own bad puts
                    into[rec["seq"]] = rec
            return cb

        with client(ep) as s:
            import zenoh

            subs = [s.declare_subscriber(keys.ocp(VID), store(ocp_z)), s.declare_subscriber(keys.raw(VID), store(raw_z))]
            deadline = time.monotonic() + 150

            def put_bad() -> None:
                """Bad data on the vehicle's key while a client watches: counted by the fleet server, never served."""
                bad = {"vehicle_id": "rover2", "seq": 0, "stamp": 1.0, "specific_force": [0, 0, 9.81], "roll": 0,
                       "pitch": 0, "yaw_rate": 0, "wheel_speed": [0] * 4, "wheel_torque": [0] * 4, "ground_speed": 0}
                for payload in (b'{"not": "a sample"}', json.dumps(bad).encode()):
                    s.put(keys.raw(VID), payload, congestion_control=zenoh.CongestionControl.BLOCK)

            async def both():
                return await asyncio.gather(_watch(ws_run, deadline), _watch(ws_fleet, deadline, put_bad))

            in_run, fleet = asyncio.run(both())
            assert wait_for(lambda: '"invalid": 2' in procs.log_text("fleet_fox"), 60), procs.tail("fleet_fox")
            for sub in subs:
                sub.undeclare()
        procs.procs["fleet_fox"].send_signal(signal.SIGTERM)
        assert procs.procs["fleet_fox"].wait(30) == 0, procs.tail("fleet_fox")
        out, _ = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
            run.wait()
        procs.close()
    assert run.returncode == 0, out
    assert "Foxglove: received" in out, out
    for got in (in_run, fleet):
        assert got["subprotocol"] == SUBPROTOCOL and got["server_info"]["op"] == "serverInfo"
        chans = {c["topic"]: c for c in got["channels"].values()}
        assert set(chans) == EXPECTED
        for c in chans.values():
            assert c["encoding"] == "json" and c["schemaEncoding"] == "jsonschema"
            assert json.loads(c["schema"])["type"] == "object" and c["schemaName"].startswith("soilocp.")
        assert set(got["messages"]) == EXPECTED, ({t: len(v) for t, v in got["messages"].items()}, got["status"],
                                                  sorted(c["topic"] for c in got["channels"].values()))
        assert all(len(v) >= WANT_PER_CHANNEL for v in got["messages"].values()), \
            {t: len(v) for t, v in got["messages"].items()}
        assert _check_against_zenoh(got, ocp_z, raw_z) >= WANT_PER_CHANNEL // 2
        soil = [m for _t, m in got["messages"][f"/soilocp/{VID}/soil_strength"]]
        assert sum(m["K"] is not None for m in soil) >= WANT_WITH_K
    # no fake: the fleet server's sensor stream is the vehicle's, bad payloads excluded
    assert all(m["vehicle_id"] == VID for _t, m in fleet["messages"][f"/soilocp/{VID}/sensors"])


def test_a_taken_port_or_a_bad_address_is_a_clear_error_before_anything_starts(tmp_path):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        for args, says in (
            (["foxglove", "--port", str(port), "--connect", endpoint(free_port())], f"127.0.0.1:{port}"),
            (["run", "--synthetic", "sand", "--foxglove", f"127.0.0.1:{port}", "--listen", endpoint(free_port()),
              "--log-dir", str(tmp_path / "run")], "Address already in use"),
            (["run", "--synthetic", "sand", "--foxglove", "localhost:http"], "expected HOST:PORT"),
        ):
            r = subprocess.run([sys.executable, "-m", "soilocp.cli", *args], capture_output=True, text=True, timeout=60)
            assert r.returncode == 2 and says in r.stderr + r.stdout, r.stderr + r.stdout
    assert not (tmp_path / "run" / "router.log").exists()  # nothing was started


def _sensor_sample(seq: int) -> bytes:
    return json.dumps({"vehicle_id": VID, "seq": seq, "stamp": float(seq), "specific_force": [0, 0, 9.81], "roll": 0,
                       "pitch": 0, "yaw_rate": 0, "wheel_speed": [0] * 4, "wheel_torque": [0] * 4,
                       "ground_speed": 0}).encode()


def test_a_subscription_refused_by_the_sdk_gets_the_channel_advertised_again_then_served():
    """foxglove-sdk sends a new channel's advertise before it records the channel for that client, so
    a client that answers fast enough (a loaded machine) has its subscribe refused as "Unknown channel
    ID" and is never told of the channel again. The fleet server (channels made as vehicles appear)
    sees the refusal in the SDK's log and advertises that channel afresh. The SDK's own refusal is real
    here (an id the client was never told); the refusal of one of our channels, which needs the race,
    is the same log record."""
    import io
    import logging

    from websockets.sync.client import connect

    from soilocp.services.io.foxglove_live import FoxgloveLive, _RefusedSubscriptions
    from soilocp.services.runtime.log import JsonLog

    log = io.StringIO()
    live = FoxgloveLive("127.0.0.1", 0, (), log=JsonLog("foxglove", stream=log))
    try:
        live._worker.start()  # as attach() does, without a Zenoh session: samples are offered directly
        with connect(live.url, subprotocols=[SUBPROTOCOL], max_size=None) as ws:

            def next_op(op: str) -> dict:
                while True:
                    frame = ws.recv(timeout=30)
                    if isinstance(frame, str) and json.loads(frame)["op"] == op:
                        return json.loads(frame)

            next_op("serverInfo")
            # the SDK logs a refusal before it answers the client, so the id is known once the status is in
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 999_999}]}))
            assert "Unknown channel ID: 999999" in next_op("status")["message"]
            assert 999_999 in live._refused.ids

            live._worker.offer(("sensors", keys.raw(VID), _sensor_sample(0)))  # a vehicle appears
            (first,) = next_op("advertise")["channels"]
            assert first["topic"] == f"/soilocp/{VID}/sensors"
            # the client's subscribe to it lost the race: refused, as the SDK logs it
            logging.getLogger(_RefusedSubscriptions.LOGGER).error(
                "Client 127.0.0.1:1 attempted to subscribe to unknown channel: %d", first["id"])

            live._worker.offer(("sensors", keys.raw(VID), _sensor_sample(1)))
            assert next_op("unadvertise")["channelIds"] == [first["id"]]
            (again,) = next_op("advertise")["channels"]
            assert again["topic"] == first["topic"] and again["id"] != first["id"]
            # then as a Foxglove client: subscribe to every advertise (on a loaded machine the SDK can
            # refuse this one too, and the channel comes again) while the vehicle's samples go on
            subs = {}
            deadline = time.monotonic() + 60
            seq, frame = 2, None
            while frame is None and time.monotonic() < deadline:
                if again is not None:
                    sid = len(subs) + 2  # 1 went to the unknown id above
                    subs[sid] = again["topic"]
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sid, "channelId": again["id"]}]}))
                    again = None
                live._worker.offer(("sensors", keys.raw(VID), _sensor_sample(seq)))
                seq += 1
                try:
                    got = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                if isinstance(got, bytes):
                    frame = got
                elif json.loads(got)["op"] == "advertise":
                    (again,) = json.loads(got)["channels"]
            assert frame is not None, "no message on the channel advertised again"
            opcode, sid, log_time = struct.unpack_from("<BIQ", frame, 0)
            m = json.loads(frame[13:])
            assert (opcode, subs[sid], m["vehicle_id"], log_time) == (
                0x01, f"/soilocp/{VID}/sensors", VID, round(m["stamp"] * 1e9))
        # the id that is not ours was dropped; ours was advertised again (more than once if the race
        # came back), and the vehicle still has one sensors channel
        assert list(live._channels) == [(VID, "sensors")] and 999_999 not in live._refused.ids
        assert log.getvalue().count("subscription_refused_readvertised") >= 1, log.getvalue()
    finally:
        live.close()
