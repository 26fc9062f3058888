"""The deployed processes carry only what they run (resident memory).

Checked on the real processes, as ``soilocp run`` and the bench start them: a native extension a
process has imported is mapped in ``/proc/<pid>/maps`` (pydantic's core, numpy's), so the test sees
what the process loaded, whatever path imported it.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs Linux /proc")

#: native extensions that mark a heavy import: pydantic (and so the message models), numpy (the physics)
PYDANTIC, NUMPY = "pydantic_core/_pydantic_core", "numpy/_core/_multiarray_umath"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _mapped(pid: int) -> str:
    return Path(f"/proc/{pid}/maps").read_text()


def _start(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("SOILOCP_")}
    return subprocess.Popen([sys.executable, "-m", "soilocp.cli", *args], cwd=ROOT, env={**clean, **env},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _stop(p: subprocess.Popen) -> str:
    p.terminate()
    try:
        _out, err = p.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        p.kill()
        _out, err = p.communicate()
    return err.decode(errors="replace")


def _wait_listening(port: int, p: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert p.poll() is None, f"router exited with {p.returncode}"
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return
        except OSError:
            time.sleep(0.2)
    raise AssertionError(f"router not listening on {port} after {timeout} s")


def _wait_alive(endpoint: str, service: str, timeout: float = 90.0) -> None:
    """Until the service holds its liveliness token: it has built its stage and declared everything."""
    import zenoh

    from soilocp.schemas import keys
    from soilocp.services.runtime.settings import zenoh_config

    with zenoh.open(zenoh_config("client", [endpoint], [], connect_timeout_ms=10000)) as session:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(r.ok is not None for r in session.liveliness().get(keys.alive("rover1", service), timeout=1.0)):
                return
            time.sleep(0.2)
    raise AssertionError(f"{service} not alive after {timeout} s")


def test_router_process_maps_neither_pydantic_nor_numpy():
    """The router only forwards bytes: a running ``soilocp router`` has not imported pydantic (the
    message models) or numpy: its command is registered apart from the services' command module, which loads both."""
    port = _free_port()
    router = _start(["router", "--listen", f"tcp/127.0.0.1:{port}"], {"SOILOCP_LOG_LEVEL": "warning"})
    try:
        _wait_listening(port, router)
        maps = _mapped(router.pid)
    finally:
        err = _stop(router)
    assert "zenoh" in maps, err  # the check sees the router's extensions at all
    assert PYDANTIC not in maps and NUMPY not in maps, err


def test_gateway_process_maps_no_numpy_and_a_stage_service_does():
    """The gateway, running and connected, has loaded no numpy (docs/services.md: it carries no
    physics); the observer service, whose kernels still take numpy arrays, has (the check can fail)."""
    port = _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = _start(["router", "--listen", endpoint], {"SOILOCP_LOG_LEVEL": "warning"})
    procs: dict[str, subprocess.Popen] = {}
    try:
        _wait_listening(port, router)
        env = {"SOILOCP_CONNECT": endpoint, "SOILOCP_LOG_LEVEL": "warning", "SOILOCP_VEHICLE_ID": "rover1"}
        for name in ("gateway", "observer"):
            procs[name] = _start(["service", name], env)
        for name in procs:
            _wait_alive(endpoint, name)
        maps = {name: _mapped(p.pid) for name, p in procs.items()}
    finally:
        errs = {name: _stop(p) for name, p in procs.items()}
        _stop(router)
    assert PYDANTIC in maps["gateway"] and NUMPY not in maps["gateway"], errs["gateway"]
    assert NUMPY in maps["observer"], errs["observer"]


def _one_record(service: str, in_key: str, payload: str, out_key: str) -> tuple[list[bytes], str, str]:
    """Start a router and ``service`` (vehicle rover1), put ``payload`` on ``in_key`` until a record
    comes on ``out_key``; the records got, the service's ``/proc/PID/maps`` after it, and its stderr."""
    import zenoh

    from soilocp.services.runtime.settings import zenoh_config

    port = _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = _start(["router", "--listen", endpoint], {"SOILOCP_LOG_LEVEL": "warning"})
    proc = None
    maps = ""
    try:
        _wait_listening(port, router)
        env = {"SOILOCP_CONNECT": endpoint, "SOILOCP_LOG_LEVEL": "warning", "SOILOCP_VEHICLE_ID": "rover1"}
        proc = _start(["service", service], env)
        _wait_alive(endpoint, service)
        got: list[bytes] = []
        with zenoh.open(zenoh_config("client", [endpoint], [], connect_timeout_ms=10000)) as session:
            sub = session.declare_subscriber(out_key, lambda smp: got.append(smp.payload.to_bytes()))
            deadline = time.monotonic() + 60
            while not got and time.monotonic() < deadline:
                session.put(in_key, payload)
                time.sleep(0.5)
            sub.undeclare()
        maps = _mapped(proc.pid)
    finally:
        err = _stop(proc) if proc is not None else ""
        _stop(router)
    return got, maps, err


def test_ocp_publisher_computes_a_record_without_loading_numpy():
    """The OCP publisher needs the pipeline's settings and eqs. 7-10 of one K, not the physics: running,
    and after it has turned a soil estimate into an OCP record (so that no lazy import on the step's
    path is missed), it has loaded no numpy.  Its record equals the library's for that K."""
    from soilocp.schemas import keys
    from soilocp.schemas.pipeline import OcpEstimate, SoilEstimate
    from soilocp.model.ocp import ocp_arrays

    soil = SoilEstimate(vehicle_id="rover1", seq=7, stamp=0.07, slip=(0.1,) * 4, informative=(True,) * 4,
                        soil_strength=120.0, soil_strength_std=6.0, log_k_std=0.05, soil_class="sand",
                        soil_class_confidence=0.9, status="ok", last_update_stamp=0.07, mu=(0.3,) * 4)
    got, maps, err = _one_record("ocp", keys.soil("rover1"), soil.model_dump_json(), keys.ocp("rover1"))
    assert got, err
    rec = OcpEstimate.model_validate_json(got[0])
    want = ocp_arrays([120.0])
    assert (rec.mu_T, rec.S_T, rec.S_E, rec.te_at_S_E) == tuple(want[n][0] for n in ("mu_T", "S_T", "S_E", "te_at_S_E"))
    assert PYDANTIC in maps and NUMPY not in maps, err


def test_normal_force_service_computes_a_record_without_loading_numpy():
    """The normal-force service needs the vehicle and eqs. 16-25 of one specific force: running, and
    after it has turned a sensor sample into a NormalForces record (so that no lazy import on the
    step's path is missed), it has loaded no numpy.  Its record equals the library's (the bank's
    solver, numpy arrays) to the bit."""
    from soilocp.schemas import keys
    from soilocp.schemas.pipeline import NormalForces
    from soilocp.schemas.sensor import SensorSample
    from soilocp.model.normal_force import normal_forces
    from soilocp.model.vehicle import DEFAULT_VEHICLE

    sample = SensorSample(vehicle_id="rover1", seq=3, stamp=0.03, wheel_speed=(2.0,) * 4, wheel_torque=(1.5,) * 4,
                          specific_force=(1.3, -0.4, 9.7), yaw_rate=0.1, pitch=-0.05, roll=0.02, ground_speed=None)
    got, maps, err = _one_record("normal-force", keys.clean("rover1"), sample.model_dump_json(),
                                 keys.normal_forces("rover1"))
    assert got, err
    rec = NormalForces.model_validate_json(got[0])
    assert rec.seq == 3 and rec.normal_force == tuple(normal_forces(DEFAULT_VEHICLE, [1.3, -0.4, 9.7]).tolist())
    assert "soilocp/_core" in maps, err  # the check sees the service's extensions at all
    assert PYDANTIC in maps and NUMPY not in maps, err


def test_key_functions_need_no_pydantic():
    """``soilocp.schemas.keys`` (the router's ACLs, every key of the pipeline) imports no pydantic model:
    the package's models are re-exported lazily, and still importable from ``schemas``."""
    code = ("import sys; import soilocp.schemas.keys, soilocp.services.router, soilocp.services.runtime.settings; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('pydantic', 'pydantic_core', 'numpy') "
            "or m in ('soilocp.schemas.sensor', 'soilocp.schemas.pipeline', 'soilocp.schemas.messages', 'soilocp.services.runtime.config')))")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"
    from soilocp.schemas import VEHICLE_ID_PATTERN, SensorSample
    from soilocp.schemas.sensor import VEHICLE_ID_PATTERN as in_sensor

    assert VEHICLE_ID_PATTERN == in_sensor and SensorSample.__module__ == "soilocp.schemas.sensor"
    with pytest.raises(AttributeError, match="no attribute 'NotAModel'"):
        import soilocp.schemas

        soilocp.schemas.NotAModel  # noqa: B018


def test_zenoh_settings_are_configurable_and_checked():
    """express and batching (docs/performance.md, "Zenoh settings, chosen"): defaults as measured,
    set from the environment for the services and the router, a bad value named."""
    import json

    from soilocp.services.router import router_settings
    from soilocp.services.runtime.config import ConfigError, load_service_config
    from soilocp.services.runtime.settings import zenoh_config

    cfg = load_service_config("observer", env={})
    assert (cfg.express, cfg.batching, cfg.mode) == (False, True, "client")
    cfg = load_service_config("observer", env={"SOILOCP_EXPRESS": "true", "SOILOCP_BATCHING": "0"})
    assert (cfg.express, cfg.batching) == (True, False)
    with pytest.raises(ConfigError, match="express='maybe'"):
        load_service_config("observer", env={"SOILOCP_EXPRESS": "maybe"})
    assert router_settings(None, (), (), env={})["batching"] is True
    assert router_settings(None, (), (), env={"SOILOCP_BATCHING": "false"})["batching"] is False
    with pytest.raises(ConfigError, match="batching='sometimes'"):
        router_settings(None, (), (), env={"SOILOCP_BATCHING": "sometimes"})
    key = "transport/link/tx/queue/batching/enabled"
    assert json.loads(zenoh_config("client", [], [], batching=False, tls_from_environment=False).get_json(key)) is False
    assert json.loads(zenoh_config("client", [], [], tls_from_environment=False).get_json(key)) is True
