"""The fleet soil map as a foxglove.Grid (docs/map.md): ``soilocp map export --foxglove-grid`` writes
an MCAP file whose grid, decoded with the schema it carries (protobuf, the Foxglove SDK's), holds
each cell's mu_T, K and band at the cell's place, and NaN where the map has no cell."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from map_helpers import estimate, item
from soilocp.map.cells import CellConfig
from soilocp.map.fusion import FusionConfig
from soilocp.map.store import open_store
from soilocp.map.updater import MapUpdater
from soilocp.model.ocp import ocp_from_soil_strength


def _grid_class(schema_data: bytes):
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(schema_data).file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.Grid"))


def decode_grids(path) -> dict[str, object]:
    """{topic: decoded foxglove.Grid} of an MCAP file, decoded from the schema in the file."""
    from mcap.reader import make_reader

    out = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            assert (schema.name, schema.encoding, channel.message_encoding) == ("foxglove.Grid", "protobuf", "protobuf")
            out[channel.topic] = _grid_class(schema.data).FromString(message.data)
    return out


def test_export_foxglove_grid_equals_the_maps_cells(tmp_path):
    db = tmp_path / "m.db"
    st = open_store(f"sqlite:{db}", CellConfig(cell_size=2.0), FusionConfig())
    up = MapUpdater(st)
    # cells at (ix, iy) = (0,0), (3,0), (1,2), (-2,1) of frame f, one of frame g, one in WGS84 (no grid)
    places = {(1.0, 1.0): 60.0, (7.0, 0.5): 250.0, (3.0, 5.0): 120.0, (-3.0, 2.5): 90.0}
    items = [item(estimate("r1", i + 1, k, 0.1 + 0.05 * i, xy=(p,))) for i, (p, k) in enumerate(places.items())]
    items.append(item(estimate("r2", 1, 300.0, 0.2, xy=((0.5, 0.5),), frame="g")))
    items.append(item(estimate("r3", 1, 70.0, 0.2, xy=None, latlon=((47.0, 8.0),))))
    res = up.apply(items)
    assert not res.refused
    cells = {c.cell: c for c in st.all_cells(1_800_000_000.0)}
    st.close()
    out = tmp_path / "grid.mcap"
    r = subprocess.run([sys.executable, "-m", "soilocp.cli", "map", "export", "--store", f"sqlite:{db}", "--map-id",
                        "fleet", "--foxglove-grid", str(out)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "2 grid(s)" in r.stdout and "WGS84" in r.stdout
    grids = decode_grids(out)
    assert sorted(grids) == ["/soilmap/fleet/f/grid", "/soilmap/fleet/g/grid"]
    g = grids["/soilmap/fleet/f/grid"]
    names = [f.name for f in g.fields]
    assert names == ["mu_T", "K", "K_lo", "K_hi", "log_k_std"] and g.frame_id == "f"
    assert (g.cell_size.x, g.cell_size.y, g.column_count) == (2.0, 2.0, 6)  # ix -2 .. 3
    assert (g.pose.position.x, g.pose.position.y, g.pose.orientation.w) == (-4.0, 0.0, 1.0)
    assert g.cell_stride == 4 * len(names) and g.row_stride == g.column_count * g.cell_stride
    assert all(f.type == 7 for f in g.fields)  # FLOAT32
    vals = np.frombuffer(g.data, dtype="<f4").reshape(-1, g.column_count, len(names))
    assert vals.shape[0] == 3  # iy 0 .. 2
    assert g.timestamp.seconds > 1.7e9
    filled = 0
    for row in range(vals.shape[0]):
        for col in range(g.column_count):
            ix, iy = col - 2, row
            c = cells.get(f"f/2/{ix}/{iy}")
            if c is None:
                assert np.isnan(vals[row, col]).all()
                continue
            filled += 1
            # the cell's place: its centre is at the grid's corner + (col + 0.5, row + 0.5) cell sizes
            assert (g.pose.position.x + (col + 0.5) * 2.0, g.pose.position.y + (row + 0.5) * 2.0) == c.center
            want = [ocp_from_soil_strength(c.K).mu_T, c.K, c.K_lo, c.K_hi, c.log_k_std]
            assert vals[row, col].tolist() == pytest.approx(want, rel=1e-6)
    assert filled == len(places)
    (gg,) = np.frombuffer(grids["/soilmap/fleet/g/grid"].data, dtype="<f4").reshape(1, 1, 5)[0]
    assert gg[1] == pytest.approx(300.0, rel=1e-6) and not math.isnan(gg[0])


async def _watch_grids(port: int, topic: str, until, deadline: float) -> list:
    """Subscribe to ``topic`` on the Foxglove server; decoded grids until ``until(grids)``."""
    import asyncio
    import base64
    import json
    import struct
    import time

    import websockets

    while True:
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], max_size=None)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    grids, cls = [], None
    async with ws:
        while time.monotonic() < deadline and not until(grids):
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.1, deadline - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "advertise":
                    for ch in op["channels"]:
                        if ch["topic"] == topic:
                            assert (ch["encoding"], ch["schemaName"], ch["schemaEncoding"]) == (
                                "protobuf", "foxglove.Grid", "protobuf")
                            cls = _grid_class(base64.b64decode(ch["schema"]))
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                                {"id": 1, "channelId": ch["id"]}]}))
                continue
            opcode, sid, _t = struct.unpack_from("<BIQ", frame, 0)
            if opcode == 0x01 and sid == 1:
                grids.append(cls.FromString(frame[13:]))
    return grids


def _grid_cells(g) -> dict[tuple[float, float], list[float]]:
    """{cell centre: [mu_T, K, K_lo, K_hi, log_k_std]} of the grid's filled cells."""
    nf = len(g.fields)
    vals = np.frombuffer(g.data, dtype="<f4").reshape(-1, g.column_count, nf)
    return {(g.pose.position.x + (c + 0.5) * g.cell_size.x, g.pose.position.y + (r + 0.5) * g.cell_size.y):
            vals[r, c].tolist() for r in range(vals.shape[0]) for c in range(g.column_count)
            if not np.isnan(vals[r, c]).all()}


@pytest.mark.timeout(180)
def test_live_foxglove_serves_the_maps_grid_and_follows_its_updates(tmp_path):
    """A map service holding cells, ``soilocp foxglove --map m --map-frame f``, a WebSocket client:
    the first grid is the stored map; an estimate published to the fleet then appears in the grid."""
    import asyncio
    import time

    from soilocp.schemas import keys
    from zenoh_helpers import Procs, client, endpoint, free_port, wait_for

    db = tmp_path / "m.db"
    st = open_store(f"sqlite:{db}", CellConfig(cell_size=2.0), FusionConfig())
    MapUpdater(st).apply([item(estimate("r1", 1, 60.0, 0.1, xy=((1.0, 1.0),))),
                          item(estimate("r1", 2, 250.0, 0.2, xy=((7.0, 0.5),)))])
    st.close()
    ep, ws_port = endpoint(free_port()), free_port()
    procs = Procs(tmp_path / "logs")
    try:
        procs.spawn("router", ["router", "--listen", ep])
        procs.spawn("map", ["service", "map", "--map-id", "m", "--connect", ep, "--store", f"sqlite:{db}",
                            "--cell-size", "2"])
        with client(ep) as s:
            assert wait_for(lambda: list(s.liveliness().get(keys.map_key("m", "alive"), timeout=1)), 60), \
                procs.tail("map")
            procs.spawn("fox", ["foxglove", "--connect", ep, "--port", str(ws_port), "--map", "m", "--map-frame", "f"])
            deadline = time.monotonic() + 90
            first = asyncio.run(_watch_grids(ws_port, "/soilmap/m/f/grid", lambda g: len(g) >= 1, deadline))
            assert first, procs.tail("fox")
            got = _grid_cells(first[0])
            assert sorted(got) == [(1.0, 1.0), (7.0, 1.0)]
            assert got[(1.0, 1.0)][1] == pytest.approx(60.0, rel=1e-5)
            assert got[(7.0, 1.0)][0] == pytest.approx(ocp_from_soil_strength(got[(7.0, 1.0)][1]).mu_T, rel=1e-5)

            def put_new():
                s.put(keys.soil("r2"), estimate("r2", 1, 120.0, 0.15, xy=((3.0, 5.0),)).model_dump_json())

            put_new()
            later = asyncio.run(_watch_grids(ws_port, "/soilmap/m/f/grid",
                                             lambda g: bool(g) and (3.0, 5.0) in _grid_cells(g[-1]), deadline))
            assert later and (3.0, 5.0) in _grid_cells(later[-1]), procs.tail("fox")
            cells = _grid_cells(later[-1])
            assert len(cells) == 3 and cells[(3.0, 5.0)][1] == pytest.approx(120.0, rel=1e-5)
            assert cells[(3.0, 5.0)][4] == pytest.approx(0.15, rel=1e-3)
    finally:
        procs.close()
