"""Estimates as MCAP (JSON messages with JSON schemas): Foxglove opens them beside the robot's bag.

Per vehicle four channels, log time = the sensor sample's stamp (Unix ns when the source had
Unix header stamps, so the estimates line up with the bag in Foxglove's timeline):

* ``/soilocp/<vid>/soil_strength``: K, its 1-sigma, K - std and K + std (plot all three), class,
  class probability, status, reason;
* ``/soilocp/<vid>/ocp``: mu_T, S_T, S_E, tractive efficiency at S_E, status;
* ``/soilocp/<vid>/wheels``: per-wheel slip (eq. 1) and net traction mu (eq. 6), wheels 1..4
  (LR, LF, RF, RR), plus their names;
* ``/soilocp/<vid>/status``: status and reason only (for a state-transitions panel).

:class:`EstimateMcapWriter` writes one file; :class:`RotatingMcapWriter` keeps a bounded total
size by starting a new file at ``max_bytes`` and deleting the oldest beyond ``max_files``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import IO, Optional, Union

NS = 1_000_000_000
WHEEL_NAMES = ["1 left-rear", "2 left-front", "3 right-front", "4 right-rear"]

_NUM = {"type": ["number", "null"]}
_STR = {"type": ["string", "null"]}
_BASE = {"vehicle_id": {"type": "string"}, "seq": {"type": "integer"}, "stamp": {"type": "number", "description": "s"}}


def _schema(title: str, props: dict, description: str) -> dict:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "description": description,
            "type": "object", "properties": {**_BASE, **props}, "required": list(_BASE) + list(props)}


#: channel suffix -> (schema name, JSON schema)
CHANNEL_SCHEMAS: dict[str, tuple[str, dict]] = {
    "soil_strength": ("soilocp.SoilStrength", _schema("SoilStrength", {
        "K": _NUM, "K_std": _NUM, "K_minus_std": _NUM, "K_plus_std": _NUM,
        "soil_class": _STR, "soil_class_confidence": _NUM, "status": {"type": "string"}, "reason": {"type": "string"},
    }, "Soil strength K (null: no estimate) with its 1-sigma band")),
    "ocp": ("soilocp.Ocp", _schema("Ocp", {
        "mu_T": _NUM, "S_T": _NUM, "S_E": _NUM, "te_at_S_E": _NUM, "status": {"type": "string"},
    }, "Optimal control parameters: max traction mu_T (eq. 8), its slip S_T (eq. 7), best-efficiency slip S_E (eq. 10)")),
    "wheels": ("soilocp.Wheels", _schema("Wheels", {
        "slip": {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4},
        "traction": {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4},
        "wheel_names": {"type": "array", "items": {"type": "string"}},
    }, "Per-wheel slip (eq. 1) and net traction coefficient mu (eq. 6), wheels 1..4")),
    "status": ("soilocp.Status", _schema("Status", {"status": {"type": "string"}, "reason": {"type": "string"}},
                                         "Estimate status: ok | uncertain | holding | no_estimate | stale")),
}


def split_estimate(rec: dict) -> dict[str, dict]:
    """One OCP record (schemas.pipeline.OcpEstimate as a dict) -> the message of each channel."""
    base = {"vehicle_id": rec["vehicle_id"], "seq": rec["seq"], "stamp": rec["stamp"]}
    k, sd = rec.get("soil_strength"), rec.get("soil_strength_std")
    band = k is not None and sd is not None
    status, reason = rec.get("status", ""), rec.get("reason", "")
    return {
        "soil_strength": {**base, "K": k, "K_std": sd, "K_minus_std": k - sd if band else None,
                          "K_plus_std": k + sd if band else None, "soil_class": rec.get("soil_class"),
                          "soil_class_confidence": rec.get("soil_class_confidence"), "status": status, "reason": reason},
        "ocp": {**base, "mu_T": rec.get("mu_T"), "S_T": rec.get("S_T"), "S_E": rec.get("S_E"),
                "te_at_S_E": rec.get("te_at_S_E"), "status": status},
        "wheels": {**base, "slip": list(rec["slip"]), "traction": list(rec["mu"]), "wheel_names": WHEEL_NAMES},
        "status": {**base, "status": status, "reason": reason},
    }


def topic(vehicle_id: str, suffix: str) -> str:
    return f"/soilocp/{vehicle_id}/{suffix}"


class EstimateMcapWriter:
    """Write OCP records to one MCAP file (or binary stream); channels are made per vehicle on first use."""

    def __init__(self, output: Union[str, Path, IO[bytes]], chunk_size: int = 256 * 1024):
        from mcap.writer import CompressionType, Writer

        self._own = not hasattr(output, "write")
        self._fh = open(output, "wb") if self._own else output
        # zstd: JSON compresses ~10x; Foxglove and the mcap library (which depends on zstandard) read it
        self._w = Writer(self._fh, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile="", library="soilocp")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.messages = 0

    def _channel(self, vid: str, suffix: str) -> int:
        t = topic(vid, suffix)
        cid = self._channels.get(t)
        if cid is None:
            name, schema = CHANNEL_SCHEMAS[suffix]
            sid = self._schemas.get(name)
            if sid is None:
                sid = self._schemas[name] = self._w.register_schema(name, "jsonschema", json.dumps(schema).encode())
            cid = self._channels[t] = self._w.register_channel(t, "json", sid)
        return cid

    def write(self, rec: dict) -> None:
        t = int(round(float(rec["stamp"]) * NS))
        for suffix, msg in split_estimate(rec).items():
            self._w.add_message(self._channel(rec["vehicle_id"], suffix), log_time=t, publish_time=t,
                                data=json.dumps(msg).encode(), sequence=int(rec["seq"]) & 0xFFFFFFFF)
        self.messages += 1

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
        self.messages = 0

    def _open(self) -> None:
        path = self.dir / f"{self.stem}_{self.index:04d}.mcap"
        self.index += 1
        # chunks a fraction of the file, so the size check sees the data soon after it arrives
        self._w = EstimateMcapWriter(path, chunk_size=max(1024, min(256 * 1024, self.max_bytes // 8)))
        self.files.append(path)
        while len(self.files) > self.max_files:
            old = self.files.pop(0)
            old.unlink(missing_ok=True)

    def write(self, rec: dict) -> None:
        if self._w is None:
            self._open()
        self._w.write(rec)
        self.messages += 1
        if self._w.tell() >= self.max_bytes:
            self._w.close()
            self._w = None

    def close(self) -> None:
        if self._w is not None:
            self._w.close()
            self._w = None
