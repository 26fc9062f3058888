"""The gateway process is lean and refuses an oversized payload before parsing it: its resident memory
stays small, and a flood of huge messages cannot make it allocate."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from soilocp.schemas.messages import Rejection
from soilocp.schemas.sensor import SensorSample
from soilocp.services.stages.gateway import RawSampleChecker
from soilocp.validation import MAX_PAYLOAD_BYTES as DEFAULT_MAX_PAYLOAD_BYTES

ROOT = Path(__file__).resolve().parents[1]


def test_gateway_module_loads_no_numpy_and_no_estimation_package():
    """What `soilocp service gateway` imports for its work: the gateway module, its stage service and
    the service runtime.  None of it may pull numpy or soilocp.estimation (the physics)."""
    code = (
        "import sys, json\n"
        "import soilocp.services.stages.gateway, soilocp.services.runtime.service, soilocp.services.stages.stage_service\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('numpy', 'scipy', 'filterpy')\n"
        "                        or m.startswith('soilocp.estimation') or m == 'soilocp._core')))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == []


def _sample_padded_to(n: int) -> bytes:
    """A valid sample whose JSON is padded with insignificant whitespace to exactly n bytes."""
    raw = SensorSample(vehicle_id="rover1", seq=1, stamp=0.01, specific_force=(0.0, 0.0, 9.81), roll=0.0,
                       pitch=0.0, yaw_rate=0.0, wheel_speed=(1.0,) * 4, wheel_torque=(1.0,) * 4,
                       ground_speed=0.15).model_dump_json().encode()
    return raw[:-1] + b" " * (n - len(raw)) + b"}"


def test_oversized_payload_is_refused_before_parsing_and_named():
    """One byte over the limit, a payload that would parse as a valid sample is refused as
    too_large: the size is checked first.  At the limit the same sample is accepted."""
    over, at = _sample_padded_to(DEFAULT_MAX_PAYLOAD_BYTES + 1), _sample_padded_to(DEFAULT_MAX_PAYLOAD_BYTES)
    rej = RawSampleChecker("rover1").check(over, received_at=1.0)
    assert isinstance(rej, Rejection) and rej.code == "too_large"
    assert rej.payload_size == DEFAULT_MAX_PAYLOAD_BYTES + 1 and str(DEFAULT_MAX_PAYLOAD_BYTES) in rej.message
    assert rej.seq is None and rej.stamp is None  # nothing was read out of it
    assert isinstance(RawSampleChecker("rover1").check(at, received_at=1.0), SensorSample)


def test_limit_is_configurable_and_the_default_fits_every_valid_sample():
    """The largest valid sample (64-character id, every number at full precision, pretty-printed)
    fits the default with a margin; a service config can set another limit."""
    from soilocp.services.runtime.config import ServiceConfig

    big = SensorSample(vehicle_id="v" * 64, seq=2**62, stamp=1.7e9 + 0.123456789012345,
                       specific_force=(-1.2345678901234567e-10,) * 3, roll=-0.12345678901234567,
                       pitch=-0.12345678901234567, yaw_rate=-0.12345678901234567,
                       wheel_speed=(-123.45678901234567,) * 4, wheel_torque=(-123.45678901234567,) * 4,
                       ground_speed=-1.2345678901234567)
    pretty = json.dumps(json.loads(big.model_dump_json()), indent=4).encode()
    assert 4 * len(pretty) < DEFAULT_MAX_PAYLOAD_BYTES
    assert isinstance(RawSampleChecker("v" * 64).check(pretty, received_at=1.0), SensorSample)
    assert ServiceConfig().max_payload_bytes == DEFAULT_MAX_PAYLOAD_BYTES
    small = RawSampleChecker("rover1", max_payload_bytes=ServiceConfig(max_payload_bytes=300).max_payload_bytes)
    assert small.check(_sample_padded_to(301), received_at=1.0).code == "too_large"
