"""What the supervisor of ``soilocp run`` restarted, where the fleet tools can see it.

The supervisor is the only one that knows a process died and was started again: a restarted service
comes back with a new pid and a small uptime, and a restarted router leaves no trace at all.  So the
run answers ``soilocp/<vid>/supervisor`` (a :class:`~soilocp.schemas.messages.SupervisorStatus`:
each process under its name, its pid and state, how often it was restarted, how long ago the last
time, and the exit status of the one that died) and publishes it again at every restart.
``soilocp fleet status`` and the dashboard read it (:mod:`soilocp.services.fleet.monitor`).

The queryable lives on the run's own client session: when the router is the process that died, the
session reconnects to the restarted router and declares it again by itself.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from typing import Any, Optional

from soilocp.schemas import keys
from soilocp.schemas.messages import SupervisedProcess, SupervisorStatus

from soilocp.services.supervisor.processes import ProcessGroup


class RestartBook:
    """Restarts per process name of one :class:`ProcessGroup`, and the vehicle's supervisor key.

    Parameters
    ----------
    vehicle_id
        The vehicle the run serves: the report goes on ``soilocp/<vehicle_id>/supervisor``.
    group
        The run's processes (the latest child of each name is the one reported).
    restart
        Whether the run restarts what dies (``--restart``); reported so that a reader can tell a
        run that restarts nothing from one that had nothing to restart.
    """

    def __init__(self, vehicle_id: str, group: ProcessGroup, restart: bool):
        self.vehicle_id = keys.check_vehicle_id(vehicle_id)
        self.group = group
        self.restart = bool(restart)
        self._lock = threading.Lock()
        self._restarts: dict[str, list[float]] = {}  # name -> monotonic times of its restarts
        self._last_exit: dict[str, int] = {}
        self._pub: Any = None
        self._decls: list[Any] = []
        self._host = socket.gethostname()

    def record(self, name: str, exit_status: Optional[int], now: Optional[float] = None) -> None:
        """Process ``name`` died with ``exit_status`` and was started again (at monotonic ``now``);
        published at once when a session is attached."""
        with self._lock:
            self._restarts.setdefault(name, []).append(time.monotonic() if now is None else now)
            if exit_status is not None:
                self._last_exit[name] = exit_status
        self.publish()

    def count(self, name: str) -> int:
        """How often ``name`` was restarted."""
        with self._lock:
            return len(self._restarts.get(name, ()))

    def status(self) -> SupervisorStatus:
        """The report as of now."""
        now = time.monotonic()
        latest = {c.name: c for c in list(self.group.children)}  # later children of a name replace earlier
        procs = []
        with self._lock:
            for name, child in latest.items():
                times = self._restarts.get(name, [])
                rc = child.poll()
                state = child.outcome if child.outcome != "running" or rc is None else "died"
                procs.append(SupervisedProcess(
                    name=name, pid=child.pid, state=state, restarts=len(times),
                    last_restart_age_s=round(now - times[-1], 3) if times else None,
                    last_exit=self._last_exit.get(name)))
        return SupervisorStatus(vehicle_id=self.vehicle_id, pid=os.getpid(), host=self._host, restart=self.restart,
                                processes=procs, time=time.time())

    # --- Zenoh ------------------------------------------------------------------------------------
    def attach(self, session) -> None:
        """Answer the supervisor key on ``session`` and publish there at each restart."""
        key = keys.supervisor(self.vehicle_id)

        def _on_query(query) -> None:
            try:
                query.reply(key, self.status().model_dump_json())
            except Exception:  # a query that arrives while the session closes
                pass

        self._pub = session.declare_publisher(key)
        self._decls = [self._pub, session.declare_queryable(key, _on_query)]

    def publish(self) -> None:
        pub = self._pub
        if pub is None:
            return
        try:
            pub.put(self.status().model_dump_json())
        except Exception:  # the session is closing, or the router is the process that died
            pass

    def detach(self) -> None:
        from soilocp.services.runtime.process import undeclare_all

        decls, self._decls, self._pub = self._decls, [], None
        undeclare_all(decls)
