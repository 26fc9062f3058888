"""``soilocp foxglove`` and ``soilocp run --foxglove``: the live estimates and sensors of one vehicle
or a fleet, served to Foxglove over its WebSocket protocol by ``foxglove-sdk`` (not a hand-written
server).

A Zenoh subscriber on ``soilocp/<vid>/ocp`` and ``soilocp/<vid>/sensors/raw`` (``--vehicle-id``,
repeatable) or on every vehicle's (``soilocp/*/...``) only enqueues; one worker drains the bounded
queue (a full queue drops the newest sample and counts it), validates each payload against its
contract and logs it on the channels of :mod:`soilocp.export.channels` (the MCAP export's channels,
built by the same functions, plus the sensor channel), with log time = the sample's own stamp.
A payload that fails its contract, or whose vehicle id is not its key's, is counted and not served.
While no Foxglove client subscribes to a vehicle's channels its samples are not even parsed.

``soilocp run --foxglove`` runs the same :class:`FoxgloveLive` inside the run, on the run's own
client session (see :func:`soilocp.services.supervisor.run.run_system`).
"""

from __future__ import annotations

import logging
import re
import threading
import time
from typing import Any, Optional

import click

from soilocp.schemas import keys
from soilocp.services.io.streams import STREAMS, decode, selectors
from soilocp.services.runtime.log import JsonLog
from soilocp.services.runtime.process import exit_now
from soilocp.services.runtime.worker import BoundedWorker
from soilocp.export.channels import (CHANNEL_SCHEMAS, encode, log_time_ns, map_grid_message, map_grid_topic,
                                     split_estimate, split_sensor, topic)

QUEUE_MAX = 10_000  # samples; ~50 s of one vehicle's sensors and OCPs at 100 Hz
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765  # Foxglove's usual WebSocket port
DEFAULT_ADDRESS = f"{DEFAULT_HOST}:{DEFAULT_PORT}"


class _RefusedSubscriptions(logging.Handler):
    """The channel ids whose subscription foxglove-sdk refused as unknown to the client.

    foxglove-sdk (since its PR #523; still so in 0.30.3), websocket/connected_client.rs
    ``advertise_channels``, sends a new channel's advertise to each connected client *before* it
    records the channel as advertised to that client. A client that answers within that gap (a
    loaded machine: the thread making the channel is preempted by the woken server and client
    threads) has its subscribe refused as "Unknown channel ID" and is never told of the channel
    again: its panel stays empty. The SDK logs each refusal through Python ``logging``
    (``pyo3-log``, its default), the only place the server side can see it; the worker then
    advertises that channel afresh (:meth:`FoxgloveLive._readvertise_refused`)."""

    LOGGER = "foxglove.websocket.connected_client"
    _REFUSED = re.compile(r"attempted to subscribe to unknown channel: (\d+)")

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.ids: set[int] = set()

    def emit(self, record: logging.LogRecord) -> None:
        # runs on a server thread that holds the client's channel map: record the id, touch nothing
        # of the SDK's (the worker does, on its own thread)
        m = self._REFUSED.search(record.getMessage())
        if m:
            with self.lock:
                self.ids.add(int(m.group(1)))

    def take(self) -> set[int]:
        with self.lock:
            ids, self.ids = self.ids, set()
        return ids

    def give_back(self, ids: set[int]) -> None:
        """Ids taken and not repaired yet (repairs go one at a time)."""
        if ids:
            with self.lock:
                self.ids |= ids


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT``, ``:PORT`` or ``PORT`` (these two on 127.0.0.1) -> (host, port);
    ValueError says why."""
    s = str(text).strip()
    host, _sep, port_s = s.rpartition(":")
    host = host or DEFAULT_HOST
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        port = int(port_s)
    except ValueError:
        port = -1
    if not host or not 0 <= port <= 65535:
        raise ValueError(f"Foxglove address {text!r}: expected HOST:PORT (port 0-65535, 0 = any free port), "
                         f"e.g. {DEFAULT_ADDRESS}")
    return host, port


class FoxgloveLive:
    """A Foxglove WebSocket server (started at construction) fed by a Zenoh session (:meth:`attach`).

    ``vehicle_ids`` empty: every vehicle, its channels made when its first sample arrives;
    otherwise those vehicles' channels are advertised at once.
    """

    def __init__(self, host: str, port: int, vehicle_ids: tuple[str, ...] | list[str] = (), *,
                 log: Optional[JsonLog] = None, name: str = "soilocp", queue_max: int = QUEUE_MAX,
                 maps: tuple[str, ...] | list[str] = (), map_frames: tuple[str, ...] | list[str] = ()):
        import foxglove

        self.vehicle_ids = [keys.check_vehicle_id(v) for v in vehicle_ids]
        # fleet soil maps served as a foxglove.Grid per local frame (docs/map.md): their cells, as the
        # map service's committed updates (soilmap/<id>/cells) and a first query per map_frames bring them
        self.maps = [keys.check_map_id(m) for m in maps]
        self.map_frames = list(map_frames)
        self._map_cells: dict[tuple[str, str], dict[str, Any]] = {}
        self._grid_dirty: set[tuple[str, str]] = set()
        self._grid_logged: dict[tuple[str, str], float] = {}
        self.log = log or JsonLog("foxglove")
        self._foxglove = foxglove
        # a context of our own: no global channel registry shared with anything else in the process
        self._ctx = foxglove.Context()
        self._channels: dict[tuple[str, str], Any] = {}
        self.counts = {"received": 0, "served": 0, "unwatched": 0, "invalid": 0, "dropped": 0, "errors": 0}
        if self.maps:
            self.counts.update(map_updates=0, grids=0)
        self._lock = threading.Lock()  # channels are made on the worker and read by close()
        self._refused = _RefusedSubscriptions()
        for vid in self.vehicle_ids:
            for suffix in CHANNEL_SCHEMAS:
                self._channel(vid, suffix)
        # the grids of the frames asked for exist before the server starts, so a client finds them in
        # its first advertise (a channel made later can have its subscription refused, see
        # _RefusedSubscriptions, and is then advertised again)
        for m in self.maps:
            for frame in self.map_frames:
                self._grid_channel(m, frame)
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self._ctx)
        except RuntimeError as exc:  # FoxgloveError: port taken, unknown host
            raise ValueError(f"Foxglove server on {host}:{port}: {exc}") from None
        # attached once the server runs: a server that failed to start leaves no handler on the SDK's logger
        logging.getLogger(_RefusedSubscriptions.LOGGER).addHandler(self._refused)
        self.host = host
        self._worker = BoundedWorker("foxglove", self._handle, queue_max, self._dropped, self._failed)
        self._subs: list[Any] = []

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def _channel(self, vid: str, suffix: str):
        return self._get((vid, suffix))

    def _grid_channel(self, map_id: str, frame: str):
        return self._get(("@map", map_grid_topic(map_id, frame)))  # '@': no vehicle id has it

    def _get(self, key: tuple[str, str]):
        ch = self._channels.get(key)
        if ch is None:
            with self._lock:
                ch = self._channels[key] = self._new_channel(key)
        return ch

    def _new_channel(self, key: tuple[str, str]):
        fg = self._foxglove
        if key[0] == "@map":
            from foxglove.messages import Grid

            sch = Grid.get_schema()
            return fg.Channel(key[1], message_encoding="protobuf", context=self._ctx,
                              schema=fg.Schema(name=sch.name, encoding=sch.encoding, data=sch.data))
        name, schema = CHANNEL_SCHEMAS[key[1]]
        return fg.Channel(topic(*key), message_encoding="json", context=self._ctx,
                          schema=fg.Schema(name=name, encoding="jsonschema", data=encode(schema)))

    def _readvertise_refused(self) -> None:
        """Close and make again one of our channels whose subscription the SDK refused (see
        :class:`_RefusedSubscriptions`): every client gets an unadvertise and a new advertise, and
        subscribes again as a Foxglove client does; a refused id that is not ours is ignored.  One per
        call: the worker returns to its queue between two (below); the others stay in ``_refused``."""
        ids = self._refused.take()
        pending = [(key, ch) for key, ch in self._channels.items() if ch.id() in ids]
        self._refused.give_back({ch.id() for _key, ch in pending[1:]})
        for key, ch in pending[:1]:
            # close() holds the GIL (the SDK does not release it there) while it takes each client's
            # channel map, and a server thread that logs a refusal holds that client's map while it waits for
            # the GIL.  Refusals of the advertise race come while a channel is made (Channel() releases the
            # GIL), not during close(); a client's subscribe to an id it does not have (a bogus id, or one this
            # close() has just removed) can come at any time: the sleep lets such a pending log take the GIL
            # first, and one repair per worker item keeps two close() calls from following each other.  The
            # risk is narrowed, not removed; the lasting fix is the SDK's (record the channel before
            # advertising it, as before its PR #523)
            time.sleep(0.001)
            with self._lock:
                ch.close()
                try:
                    new = self._channels[key] = self._new_channel(key)
                except Exception:
                    del self._channels[key]  # made again, with a fresh advertise, at its next sample
                    raise
            self.log.warning("subscription_refused_readvertised", topic=new.topic(), channel_id=ch.id(),
                             new_channel_id=new.id())

    def attach(self, session) -> list[str]:
        """Subscribe on ``session`` and start the worker; returns the key expressions subscribed."""
        self._worker.start()
        streams = selectors(self.vehicle_ids)
        streams += [("map", keys.map_key(m, "cells")) for m in self.maps]
        for kind, sel in streams:
            self._subs.append(session.declare_subscriber(sel, self._callback(kind)))
        for m in self.maps:  # the map as it is now; the updates then keep it current
            for frame in self.map_frames:
                sel = f"{keys.map_key(m, 'query')}?frame={frame};bbox=-1e7,-1e7,1e7,1e7"
                for r in session.get(sel, timeout=10):
                    if r.ok is not None:
                        self._worker.offer(("map_reply", str(r.ok.key_expr), r.ok.payload.to_bytes()))
                    else:
                        self.log.warning("map_query_failed", map_id=m, frame=frame, error=r.err.payload.to_string()[:200])
        return [sel for _kind, sel in streams]

    def tick(self) -> None:
        """Log the map grids due (call about twice a second): a changed grid at most once a second,
        and every grid watched again every 2 s, so a client that subscribes late sees the map."""
        if self.maps:
            self._worker.offer(("tick", "", b""))

    def _handle_map(self, kind: str, key: str, payload: bytes) -> None:
        from soilocp.schemas.map import WGS84, MapCellUpdate, MapQueryReply

        if kind != "tick":
            map_id = key.split("/")[1]
            try:
                cells = (MapCellUpdate.model_validate_json(payload).cells if kind == "map"
                         else MapQueryReply.model_validate_json(payload).cells)
            except ValueError as exc:
                self.counts["invalid"] += 1
                self.log.warning("invalid_map_message", key=key, error=str(exc)[:200])
                return
            self.counts["map_updates"] += 1
            for c in cells:
                if c.frame != WGS84:  # H3 cells are not a raster
                    self._map_cells.setdefault((map_id, c.frame), {})[c.cell] = c
                    self._grid_dirty.add((map_id, c.frame))
        from soilocp.map.grid import raster

        now = time.time()
        for mf, cells_by_id in self._map_cells.items():
            last = self._grid_logged.get(mf, 0.0)
            due = (mf in self._grid_dirty and now - last >= 1.0) or now - last >= 2.0
            ch = self._grid_channel(*mf)
            if not due or not ch.has_sinks():
                continue
            ch.log(map_grid_message(raster(list(cells_by_id.values())), now).encode(), log_time=log_time_ns(now))
            self._grid_dirty.discard(mf)
            self._grid_logged[mf] = now
            self.counts["grids"] += 1

    def _callback(self, kind: str):
        counts, offer = self.counts, self._worker.offer

        def on_sample(sample) -> None:
            counts["received"] += 1
            offer((kind, str(sample.key_expr), sample.payload.to_bytes()))

        return on_sample

    def _handle(self, item: tuple[str, str, bytes]) -> None:
        if self._refused.ids:  # on the worker: the only thread that makes channels once serving
            self._readvertise_refused()
        kind, key, payload = item
        if kind in ("map", "map_reply", "tick"):
            self._handle_map(kind, key, payload)
            return
        vid, _rest = keys.split_key(key)
        suffixes = STREAMS[kind][2]
        channels = [self._channel(vid, s) for s in suffixes]
        if not any(ch.has_sinks() for ch in channels):
            self.counts["unwatched"] += 1
            return
        try:
            data = decode(kind, key, payload)
        except ValueError as exc:
            self.counts["invalid"] += 1
            if self.counts["invalid"] <= 5:
                self.log.warning("invalid_sample", key=key, error=str(exc)[:200])
            return
        messages = split_estimate(data) if kind == "ocp" else split_sensor(data)
        t = log_time_ns(data["stamp"])
        for ch, suffix in zip(channels, suffixes):
            ch.log(encode(messages[suffix]), log_time=t)
        self.counts["served"] += 1

    def _dropped(self, _item: Any) -> None:
        self.counts["dropped"] += 1
        n = self.counts["dropped"]
        if n <= 10 or n % 1000 == 0:
            self.log.warning("queue_full_drop", dropped_total=n)

    def _failed(self, item: Any, exc: BaseException) -> None:
        self.counts["errors"] += 1
        if self.counts["errors"] <= 20:
            self.log.error("processing_error", key=item[1], error=f"{type(exc).__name__}: {exc}"[:300])

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # already gone with its session
                pass
        self._subs.clear()
        self._worker.stop()
        logging.getLogger(_RefusedSubscriptions.LOGGER).removeHandler(self._refused)
        self.server.stop()
        with self._lock:
            for ch in self._channels.values():
                ch.close()


def run_foxglove(connect: list[str], vehicle_ids: list[str], host: str, port: int, *,
                 duration: Optional[float] = None, log: Optional[JsonLog] = None, maps: tuple[str, ...] = (),
                 map_frames: tuple[str, ...] = ()) -> int:
    """``soilocp foxglove``: serve until SIGINT/SIGTERM (or ``duration`` s); 0 when stopped cleanly."""
    from soilocp.services.runtime.process import install_stop_handlers, open_session, watch_parent

    log = log or JsonLog("foxglove")
    live = FoxgloveLive(host, port, vehicle_ids, log=log, maps=maps, map_frames=map_frames)  # ValueError: port, id
    click.echo(f"soilocp foxglove: {live.url} (in Foxglove: Open connection, Foxglove WebSocket; "
               "layout docs/foxglove/soilocp-layout.json)", err=True)
    stop = threading.Event()
    install_stop_handlers(stop, log)
    watch_parent(stop, log)
    session = None
    try:
        session = open_session("client", connect, [], multicast=False, stop=stop, log=log)
        if session is None:
            return 0
        selectors = live.attach(session)
        log.info("serving", url=live.url, keys=selectors, vehicle_ids=vehicle_ids or "all")
        t_end = None if duration is None else time.monotonic() + duration
        last = dict(live.counts)
        while not stop.wait(0.5):
            if t_end is not None and time.monotonic() >= t_end:
                break
            live.tick()
            if live.counts != last:  # progress for operators (and tests)
                last = dict(live.counts)
                log.info("progress", **last)
    finally:
        live.close()
        if session is not None:
            session.close()
    log.info("stopped", **live.counts)
    return 0


@click.command("foxglove")
@click.option("--vehicle-id", "vehicle_ids", multiple=True,
              help="Vehicle to serve (repeatable); default: every vehicle, as it appears")
@click.option("--connect", multiple=True, help="Router endpoint (repeatable); env SOILOCP_CONNECT; default tcp/127.0.0.1:7447.")
@click.option("--host", default=DEFAULT_HOST, show_default=True, help="Address the WebSocket server binds to.")
@click.option("--port", type=click.IntRange(0, 65535), default=DEFAULT_PORT, show_default=True,
              help="WebSocket port (0: any free port, printed).")
@click.option("--duration", type=float, help="Stop after this many seconds (default: at SIGINT/SIGTERM).")
@click.option("--map", "maps", multiple=True,
              help="Also serve this fleet soil map's cells as a foxglove.Grid per local frame (repeatable).")
@click.option("--map-frame", "map_frames", multiple=True,
              help="Local frame whose cells are asked of the map service at start (repeatable); else the grid "
                   "fills from the cells updated while serving.")
def foxglove_cmd(vehicle_ids, connect, host, port, duration, maps, map_frames) -> None:
    """Serve the live estimates and sensors of a vehicle or the fleet to Foxglove (WebSocket)."""
    import sys

    from soilocp.services.fleet.commands import tool_endpoints
    from soilocp.services.runtime.config import ConfigError
    from soilocp.services.security.fleet_security import check_client_tls

    try:
        eps = tool_endpoints(connect)
        check_client_tls(eps)
        if duration is not None and not duration > 0:
            raise ValueError(f"--duration {duration!r}: must be > 0 s")
        code = run_foxglove(eps, list(vehicle_ids), host, port, duration=duration, maps=maps, map_frames=map_frames)
    except (ValueError, ConfigError) as exc:
        click.echo(f"soilocp foxglove: error: {exc}", err=True)
        sys.exit(2)
    # the session and the server are closed: leave without interpreter finalisation, which can hang in Zenoh's
    # native runtime (soilocp.services.runtime.process.exit_now) while the stop handlers' native watchdog is armed
    exit_now(code)


COMMANDS = [foxglove_cmd]
