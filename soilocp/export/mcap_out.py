"""Estimates and sensors as MCAP (JSON messages with JSON schemas): Foxglove opens them beside the
robot's bag, with the layout of ``docs/foxglove/``.

Per vehicle every channel of :mod:`soilocp.export.channels`: the four estimate channels (soil
strength K with its band, OCPs, per-wheel slip and traction, status) from each OCP record, and the
sensor channel from each sensor sample, log time = the sample's own stamp; the live Foxglove server
(``soilocp foxglove``) serves the same channels, built by the same functions.

:class:`EstimateMcapWriter` writes one file; :class:`RotatingMcapWriter` keeps a bounded total
size by starting a new file at ``max_bytes`` and deleting the oldest beyond ``max_files``.
"""

from __future__ import annotations

from pathlib import Path
from typing import IO, Optional, Union

from soilocp.export.channels import CHANNEL_SCHEMAS, encode, log_time_ns, split_estimate, split_sensor, topic


class EstimateMcapWriter:
    """Write OCP records (:meth:`write`) and sensor samples (:meth:`write_sensor`) to one MCAP file (or
    binary stream); channels are made per vehicle on first use."""

    def __init__(self, output: Union[str, Path, IO[bytes]], chunk_size: int = 256 * 1024):
        from mcap.writer import CompressionType, Writer

        self._own = not hasattr(output, "write")
        self._fh = open(output, "wb") if self._own else output
        # zstd: JSON compresses ~10x; Foxglove and the mcap library (which depends on zstandard) read it
        self._w = Writer(self._fh, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="soilocp")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.messages = 0  # OCP records
        self.samples = 0  # sensor samples

    def _channel(self, vid: str, suffix: str) -> int:
        t = topic(vid, suffix)
        cid = self._channels.get(t)
        if cid is None:
            name, schema = CHANNEL_SCHEMAS[suffix]
            sid = self._schemas.get(name)
            if sid is None:
                sid = self._schemas[name] = self._w.register_schema(name, "jsonschema", encode(schema))
            cid = self._channels[t] = self._w.register_channel(t, "json", sid)
        return cid

    def _add(self, src: dict, messages: dict[str, dict]) -> None:
        t = log_time_ns(src["stamp"])
        for suffix, msg in messages.items():
            self._w.add_message(self._channel(src["vehicle_id"], suffix), log_time=t, publish_time=t,
                                data=encode(msg), sequence=int(src["seq"]) & 0xFFFFFFFF)

    def write(self, rec: dict) -> None:
        """One OCP record (``soilocp.schemas.pipeline.OcpEstimate`` as a dict) -> the estimate channels."""
        self._add(rec, split_estimate(rec))
        self.messages += 1

    def write_sensor(self, sample: dict) -> None:
        """One sensor sample (``soilocp.schemas.sensor.SensorSample`` as a dict) -> the sensor channel."""
        self._add(sample, split_sensor(sample))
        self.samples += 1

    def tell(self) -> int:
        return self._fh.tell()

    def close(self) -> None:
        self._w.finish()
        if self._own:
            self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class RotatingMcapWriter:
    """MCAP files ``<stem>_0000.mcap``, ``<stem>_0001.mcap``, ... of about ``max_bytes`` each, at most
    ``max_files`` kept (the oldest deleted): the disk used stays below ~ max_bytes x max_files."""

    def __init__(self, out: Union[str, Path], max_bytes: int = 64 * 1024 * 1024, max_files: int = 10):
        if max_bytes < 4096:
            raise ValueError(f"max_bytes {max_bytes!r}: must be >= 4096")
        if max_files < 1:
            raise ValueError(f"max_files {max_files!r}: must be >= 1")
        p = Path(out)
        self.dir, self.stem = p.parent, p.stem if p.suffix == ".mcap" else p.name
        self.max_bytes, self.max_files = max_bytes, max_files
        self.index = 0
        self.files: list[Path] = []
        self._w: Optional[EstimateMcapWriter] = None
        self.messages = 0  # OCP records
        self.samples = 0  # sensor samples

    def _open(self) -> None:
        path = self.dir / f"{self.stem}_{self.index:04d}.mcap"
        self.index += 1
        # chunks a fraction of the file, so the size check sees the data soon after it arrives
        self._w = EstimateMcapWriter(path, chunk_size=max(1024, min(256 * 1024, self.max_bytes // 8)))
        self.files.append(path)
        while len(self.files) > self.max_files:
            old = self.files.pop(0)
            old.unlink(missing_ok=True)

    def _current(self) -> EstimateMcapWriter:
        if self._w is None:
            self._open()
        return self._w

    def _rotate_if_full(self) -> None:
        if self._w.tell() >= self.max_bytes:
            self._w.close()
            self._w = None

    def write(self, rec: dict) -> None:
        self._current().write(rec)
        self.messages += 1
        self._rotate_if_full()

    def write_sensor(self, sample: dict) -> None:
        self._current().write_sensor(sample)
        self.samples += 1
        self._rotate_if_full()

    def close(self) -> None:
        if self._w is not None:
            self._w.close()
            self._w = None


def write_map_grids(output: Union[str, Path], map_id: str, cells, stamp: float) -> list[str]:
    """The map's cells of each local frame as one ``foxglove.Grid`` message (channels.map_grid_message)
    on ``/soilmap/<map_id>/<frame>/grid``, log time ``stamp``; returns the topics written.  WGS84
    (H3) cells have no grid and are left out."""
    from foxglove.messages import Grid
    from mcap.writer import CompressionType, Writer

    from soilocp.schemas.map import WGS84
    from soilocp.export.channels import map_grid_message, map_grid_topic
    from soilocp.map.grid import raster

    frames: dict[str, list] = {}
    for c in cells:
        if c.frame != WGS84:
            frames.setdefault(c.frame, []).append(c)
    schema = Grid.get_schema()
    t = log_time_ns(stamp)
    with open(output, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="soilocp")
        sid = w.register_schema(schema.name, schema.encoding, schema.data)
        out = []
        for frame in sorted(frames):
            tp = map_grid_topic(map_id, frame)
            cid = w.register_channel(tp, "protobuf", sid)
            w.add_message(cid, log_time=t, publish_time=t, data=map_grid_message(raster(frames[frame]), stamp).encode())
            out.append(tp)
        w.finish()
    return out
