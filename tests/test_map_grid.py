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


def decode_grids(path) -> dict[str, object]:
    """{topic: decoded foxglove.Grid} of an MCAP file, decoded from the schema in the file."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap.reader import make_reader

    out = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            assert (schema.name, schema.encoding, channel.message_encoding) == ("foxglove.Grid", "protobuf", "protobuf")
            fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
            pool = descriptor_pool.DescriptorPool()
            for fd in fds.file:
                pool.Add(fd)
            cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
            out[channel.topic] = cls.FromString(message.data)
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
    r = subprocess.run([sys.executable, "-m", "soilocp_cli", "map", "export", "--store", f"sqlite:{db}", "--map-id",
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
