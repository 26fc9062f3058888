"""A service restarted by whoever runs it (systemd, Docker), not by ``soilocp run``'s supervisor, shows in
the fleet's view.

Real processes, as a systemd unit or a container runs each: a router and the gateway and OCP services of
``rover1``, each its own ``soilocp service``, on an ephemeral loopback port.  The OCP service is killed with
SIGKILL and started again, as ``Restart=always`` or ``restart: unless-stopped`` would.  A monitor that was
listening (the dashboard's) counts the new process from its health; a one-shot ``soilocp fleet status``,
which was not listening, shows the restarted service younger than the others.
"""

from __future__ import annotations

import time

from soilocp.services.fleet.monitor import FleetMonitor
from soilocp.services.fleet.state import FleetState
from zenoh_helpers import Procs, client, endpoint, fleet_status, free_port, wait_alive, wait_for

VID = "rover1"


def test_a_service_restarted_outside_the_supervisor_shows_in_fleet_status(tmp_path):
    ep = endpoint(free_port())
    procs = Procs(tmp_path / "logs")
    try:
        procs.spawn("router", ["router", "--listen", ep])
        for name in ("gateway", "ocp"):
            procs.spawn(name, ["service", name, "--vehicle-id", VID, "--connect", ep])
        with client(ep) as session:
            assert wait_alive(session, VID, ["gateway", "ocp"], timeout=60), procs.tail("ocp")
            state = FleetState()
            monitor = FleetMonitor(session, state, poll_period_s=0.5).start()
            try:
                assert wait_for(lambda: {"gateway", "ocp"} <= set(state.rows()[0]["uptime_s"])
                                if state.rows() else False, 30)
                assert state.rows()[0]["restarts_seen_total"] == 0
                time.sleep(6.0)  # the gateway grows older than the OCP service's next process will be
                victim = procs.procs["ocp"]
                victim.kill()
                victim.wait(10)
                procs.spawn("ocp", ["service", "ocp", "--vehicle-id", VID, "--connect", ep])
                assert wait_for(lambda: state.rows()[0]["restarts_seen_total"] >= 1, 30), state.rows()[0]
                row = state.rows()[0]
                assert set(row["restarts_seen"]) == {"ocp"}, row["restarts_seen"]
                assert row["restarts_seen"]["ocp"]["pid"] != victim.pid
                assert row["restarts_total"] is None  # no supervisor report: none ran
            finally:
                monitor.stop()
        once, table = fleet_status(ep, VID)
        assert once["restarts_total"] is None and once["restarts_seen_total"] == 0  # it was not listening
        assert once["uptime_s"]["ocp"] < once["uptime_s"]["gateway"] - 5.0, once["uptime_s"]
        assert "ocp up" in table, table
        print(f"\nmonitor listening: {row['restarts_seen']}; one-shot status: uptimes {once['uptime_s']}")
    finally:
        procs.close()
