"""``soilocp estimate`` output: JSON Lines or MCAP (by the file's suffix), with K withheld where the
log's provenance says it cannot be identified.  The MCAP also holds each estimated sensor sample on
the sensor channel, so the file carries the same channels as the live Foxglove server."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import IO, Optional

from soilocp.estimation.estimate import EstimateSummary, estimate_samples
from soilocp.ingest.align import Provenance, withhold
from soilocp.validation import capped_lines
from soilocp.estimation.pipeline import PipelineConfig


def estimate_to(sensors: str | Path, out: str | Path, config: PipelineConfig, *, full: bool = False,
                provenance: Optional[Provenance] = None, err: IO[str] = sys.stderr, label: str | None = None,
                withheld: Optional[dict[str, int]] = None, map_prior=None) -> EstimateSummary:
    """Run the chain on the sensor log ``sensors``; write ``out`` (``.mcap``: MCAP channels, else JSONL).

    In an MCAP, each record's sensor sample goes on the sensor channel just before the record's
    estimate channels (a sample the chain rejected has no record and is not written: the log's
    rejections are reported on ``err``).  Withholding K leaves the sensors as they are.

    When the provenance says K is not identifiable, every record is written withheld and
    ``withheld`` (if given) counts the statuses the chain itself had given.  ``map_prior(vehicle_id)``:
    a vehicle's fleet-map prior, or None (:func:`soilocp.estimation.estimate.estimate_samples`)."""
    summary = EstimateSummary()
    label = label or str(sensors)
    reason = provenance.withhold_reason() if provenance is not None else None

    def report(lineno, exc) -> None:
        err.write(f"{label}:{lineno}: rejected ({exc.code}): {exc.message}\n")

    mcap = str(out).endswith(".mcap")
    if mcap:
        from soilocp.export.mcap_out import EstimateMcapWriter

        sink = EstimateMcapWriter(out)

        def put(sample, rec: dict) -> None:
            sink.write_sensor(sample.model_dump())
            sink.write(rec)
    else:
        sink = open(out, "w", encoding="utf-8")
        put = lambda sample, rec: sink.write(json.dumps(rec) + "\n")  # noqa: E731
    withheld = withheld if withheld is not None else {}
    try:
        # read capped: a line over the gateway's byte limit is skipped unread and rejected (too_large)
        with open(sensors, "rb") as fin:
            for sample, rec in estimate_samples(capped_lines(fin), config, on_reject=report, full=full, summary=summary,
                                                    map_prior=map_prior):
                if reason is not None:
                    withheld[rec["status"]] = withheld.get(rec["status"], 0) + 1
                    rec = withhold(rec, reason)
                put(sample, rec)
    finally:
        sink.close()
    if reason is not None:  # the statuses reported are the ones written
        summary.statuses = {"no_estimate": summary.estimates}
        summary.reasons = {("no_estimate", "not_identifiable"): summary.estimates} if summary.estimates else {}
    return summary
