"""CPU time and bytes of the MCAP sensor channel alone: parse each line of a sensor log with the
contract's parser and write it on the sensor channel, as ``soilocp estimate --out E.mcap`` does
(docs/foxglove.md, "What the sensor channel costs").

    .venv/bin/python scripts/mcap_sensor_cost.py S.jsonl [REPEATS]
"""

from __future__ import annotations

import io
import sys
import time

from soilocp.schemas.sensor import parse_sensor_line
from soilocp.export.mcap_out import EstimateMcapWriter


def main(path: str, repeats: int = 5) -> None:
    with open(path, encoding="utf-8") as f:
        lines = [x for x in f if x.strip()]
    cpu = []
    for rep in range(repeats):
        buf = io.BytesIO()
        w = EstimateMcapWriter(buf)
        t0 = time.process_time()
        for line in lines:
            w.write_sensor(parse_sensor_line(line).model_dump())
        w.close()
        cpu.append(time.process_time() - t0)
        print(f"run {rep}: {cpu[-1]:.3f} s CPU for {len(lines)} samples, {buf.tell()} bytes")
    print(f"min {min(cpu):.3f} s CPU = {min(cpu) / len(lines) * 1e6:.0f} us per sample")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 5)
