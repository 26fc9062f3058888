"""``soilocp dashboard``: a Starlette app showing the fleet live.

The server process holds the only Zenoh session: a :class:`soilocp.services.fleet.monitor.FleetMonitor` feeds a
:class:`soilocp.services.fleet.state.FleetState` (subscriptions + periodic queries); the page gets the data by
server-sent events (``GET /events``, ``text/event-stream``) and never talks Zenoh.  The same data
is available as JSON (``GET /api/vehicles``, ``GET /api/vehicles/{id}``, ``GET /api/constants``).
The traction-slip curve is computed here, with the library's :func:`soilocp.model.traction.net_traction`,
so the physics has a single source.

The router may be absent at start: a connector thread retries until it answers (the page says
"connecting"), and the app serves meanwhile.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import threading
import time
from pathlib import Path
from typing import Any, Optional

from soilocp.schemas import keys
from soilocp.services.stages.graph import PIPELINE_SERVICES
from soilocp.model.constants import DEFAULT_CONSTANTS, ModelConstants

from soilocp.services.fleet.monitor import FleetMonitor
from soilocp.services.fleet.state import FleetState
from soilocp.services.runtime.log import JsonLog
from soilocp.services.runtime.process import open_session

STATIC_DIR = Path(__file__).with_name("static")
#: Seconds between two server-sent events.
PUSH_PERIOD_S = 0.5


def _dumps(obj: Any) -> str:
    # allow_nan=False: a NaN would make the page's JSON.parse fail; FleetState never emits one
    return json.dumps(obj, allow_nan=False, separators=(",", ":"))


class DashboardHub:
    """Owns the Zenoh session, the monitor and the state for the app's lifetime."""

    def __init__(self, connect: list[str], *, constants: ModelConstants = DEFAULT_CONSTANTS,
                 poll_period_s: float = 1.0, log: Optional[JsonLog] = None):
        if not connect:
            raise ValueError("connect: at least one router endpoint is needed")
        self.connect = list(connect)
        self.constants = constants
        self.poll_period_s = poll_period_s
        self.state = FleetState(constants=constants)
        self.log = log or JsonLog("dashboard", "info")
        self.stop_event = threading.Event()
        self.session = None
        self.monitor: Optional[FleetMonitor] = None
        self.tracks = None  # soilocp.services.fleet.map_view.TrackRecorder, once connected
        self.connected_at: Optional[float] = None
        self._thread: Optional[threading.Thread] = None

    # --- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._connect, name="dashboard-connect", daemon=True)
        self._thread.start()

    def _connect(self) -> None:
        session = open_session("client", self.connect, [], multicast=False, stop=self.stop_event, log=self.log)
        if session is None:
            return
        if self.stop_event.is_set():
            session.close()
            return
        self.session = session  # close() closes it, whatever the connect thread reached
        self.monitor = FleetMonitor(session, self.state, poll_period_s=self.poll_period_s).start()
        from soilocp.services.fleet.map_view import TrackRecorder  # the map view's vehicle tracks (docs/map.md)

        self.tracks = TrackRecorder(session).start()
        # "connected" (connected_at) only once every subscriber is declared: a client that waits for it
        # does not race this thread; the declarations still reach the router asynchronously, so a
        # publisher that must not lose a message confirms delivery itself (tests/test_map_dashboard.py)
        if not self.stop_event.is_set():
            self.connected_at = time.time()

    def close(self) -> None:
        self.stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        if self.monitor is not None:
            self.monitor.stop()
        if getattr(self, "tracks", None) is not None:
            self.tracks.stop()
        if self.session is not None:
            self.session.close()
            self.session = None
        self.log.info("stopped")

    # --- views --------------------------------------------------------------------------------
    def router(self) -> dict[str, Any]:
        return {"endpoints": self.connect, "connected": self.session is not None and self.connected_at is not None,
                "connected_at": self.connected_at,
                "dropped": self.state.dropped, "bad_payloads": self.state.bad_payloads}

    def constants_view(self) -> dict[str, Any]:
        c = self.constants
        return {"soils": c.soils, "pipeline_services": list(PIPELINE_SERVICES),
                "constants": c.model_dump(mode="json")}

    def fleet(self) -> dict[str, Any]:
        return {"time": time.time(), "router": self.router(), "vehicles": self.state.rows()}

    def update(self, cursors: dict[str, tuple[int, int]]) -> dict[str, Any]:
        """One server-sent event: every vehicle's row, curve, wheels and the history points this
        client has not seen yet (``cursors``: vid -> (history epoch, last point id), updated)."""
        vehicles = []
        for vid in self.state.vehicle_ids():
            epoch, last = cursors.get(vid, (None, 0))
            d = self.state.detail(vid, after_id=last, epoch=epoch)
            if d is None:  # forgotten meanwhile
                continue
            d.pop("health", None)
            if d["history"]:
                cursors[vid] = (d["history_epoch"], d["history"][-1]["id"])
            else:
                cursors[vid] = (d["history_epoch"], last if not d["history_full"] else 0)
            vehicles.append(d)
        return {"time": time.time(), "router": self.router(), "soils": self.constants.soils, "vehicles": vehicles}


def create_app(hub: DashboardHub):
    """The Starlette app; the hub is started and closed by the app's lifespan."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    @contextlib.asynccontextmanager
    async def lifespan(_app):
        hub.start()
        try:
            yield
        finally:
            await asyncio.to_thread(hub.close)

    def _json(obj: Any, status_code: int = 200) -> Response:
        return Response(_dumps(obj), status_code=status_code, media_type="application/json")

    async def index(_request: Request):
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"})

    async def api_vehicles(_request: Request):
        return _json(hub.fleet())

    async def api_vehicle(request: Request):
        vid = request.path_params["vehicle_id"]
        try:
            keys.check_vehicle_id(vid)
        except ValueError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        d = hub.state.detail(vid)
        if d is None:
            return JSONResponse({"error": f"vehicle {vid!r} has not been seen"}, status_code=404)
        return _json({"time": time.time(), "router": hub.router(), "vehicle": d})

    async def api_constants(_request: Request):
        return _json(hub.constants_view())

    async def events(request: Request):
        async def stream():
            cursors: dict[str, tuple[int, int]] = {}
            yield "retry: 2000\n\n"
            while not hub.stop_event.is_set():
                if await request.is_disconnected():
                    break
                payload = _dumps(hub.update(cursors))
                yield f"event: fleet\ndata: {payload}\n\n"
                for _ in range(5):  # wake up often enough to end promptly at shutdown
                    if hub.stop_event.is_set():
                        break
                    await asyncio.sleep(PUSH_PERIOD_S / 5)

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def map_page(_request: Request):
        return FileResponse(STATIC_DIR / "map.html", headers={"Cache-Control": "no-store"})

    async def api_map(request: Request):
        """The fleet soil map around ?frame=F (wgs84 default);bbox=xmin,ymin,xmax,ymax;map=ID (fleet)."""
        from soilocp.services.fleet.map_view import map_view
        from soilocp.services.map.service import parse_query

        q = request.query_params
        frame = q.get("frame", "wgs84")
        box = q.get("bbox") or ("-180,-90,180,90" if frame == "wgs84" else "-1e6,-1e6,1e6,1e6")
        try:
            keys.check_map_id(q.get("map", "fleet"))
            frame, bbox, _ = parse_query(f"frame={frame};bbox={box}")
        except ValueError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        view = await asyncio.to_thread(map_view, hub.session, getattr(hub, "tracks", None), q.get("map", "fleet"),
                                       frame, bbox)
        return _json(view)

    routes = [
        Route("/", index),
        Route("/map", map_page),
        Route("/api/map", api_map),
        Route("/api/vehicles", api_vehicles),
        Route("/api/vehicles/{vehicle_id}", api_vehicle),
        Route("/api/constants", api_constants),
        Route("/events", events),
        Mount("/static", StaticFiles(directory=str(STATIC_DIR)), name="static"),
    ]
    return Starlette(routes=routes, lifespan=lifespan)


def serve(hub: DashboardHub, host: str, port: int) -> int:
    """Serve until SIGINT/SIGTERM; the lifespan closes the Zenoh session.  Returns the exit status
    (0 after a signal: stopping the dashboard is its normal end)."""
    import uvicorn

    class _Server(uvicorn.Server):
        def handle_exit(self, sig, frame) -> None:
            # end the event streams now, so the graceful shutdown need not cancel them
            hub.stop_event.set()
            super().handle_exit(sig, frame)

        # uvicorn re-raises a captured signal after its graceful shutdown (a KeyboardInterrupt
        # traceback here); we only want the graceful shutdown.
        @contextlib.contextmanager
        def capture_signals(self):
            import signal

            if threading.current_thread() is not threading.main_thread():
                yield
                return
            old = {s: signal.signal(s, self.handle_exit) for s in (signal.SIGINT, signal.SIGTERM)}
            try:
                yield
            finally:
                for s, h in old.items():
                    signal.signal(s, h)

    config = uvicorn.Config(create_app(hub), host=host, port=port, log_level="warning", access_log=False,
                            lifespan="on", timeout_graceful_shutdown=2, ws="none")
    server = _Server(config)
    hub.log.info("serving", url=f"http://{host}:{port}/", connect=hub.connect)
    server.run()
    return 0 if server.started else 1
