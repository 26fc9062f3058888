"""What a long-running process needs around its Zenoh session: stop on SIGINT/SIGTERM (also as
PID 1 in a container), stop when the supervising parent is gone, and a session that waits for
its router."""

from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
import time
from typing import Any, Optional

from soilocp.services.runtime.settings import ENV_EXIT_WITH_PARENT, zenoh_config
from soilocp.services.runtime.log import JsonLog

def install_stop_handlers(stop: threading.Event, log: Optional[JsonLog] = None, *, grace_s: float = 1.8) -> None:
    """SIGINT/SIGTERM set ``stop`` (from a thread: the handler itself takes no lock); a second signal, or a
    shutdown hanging past ``grace_s``, exits at once.

    SIGTERM is handled explicitly: as PID 1 in a container the default action is ignored.

    The watchdog is a Python thread, so a native call that holds the GIL (the class of
    zenoh-python undeclare/close deadlocks, eclipse-zenoh/zenoh-python#434) would stop it too.
    faulthandler's own watchdog needs no GIL: ``native_grace_s`` after the signal it writes every
    thread's stack to stderr (the service's log) and exits with status 1, before a supervisor's
    SIGKILL, so that such a hang is both bounded and located.
    """
    native_grace_s = grace_s + 1.5
    signalled: list[int] = []

    def _stop_then_watch(signum: int) -> None:
        # on a thread of its own, not in the handler: the handler runs on the main thread between two of its
        # bytecodes, possibly inside stop.wait() with the event's lock held, and Event.set() there deadlocks
        # (the dumped stack of a hung shutdown: run_service -> Event.wait -> _handler -> Event.set -> lock)
        if log:
            log.info("signal", signal=signal.Signals(signum).name)
        stop.set()
        time.sleep(grace_s)
        if log:
            log.error("forced_exit", reason=f"shutdown took longer than {grace_s} s")
        os._exit(0)

    def _handler(signum, _frame) -> None:
        if signalled:
            os._exit(130 if signum == signal.SIGINT else 143)
        signalled.append(signum)
        faulthandler.dump_traceback_later(native_grace_s, exit=True)
        threading.Thread(target=_stop_then_watch, args=(signum,), name="shutdown-watchdog", daemon=True).start()

    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)


def watch_parent(stop: threading.Event, log: Optional[JsonLog] = None, *, period_s: float = 0.5) -> None:
    """If ``$SOILOCP_EXIT_WITH_PARENT`` is 1, set ``stop`` once the parent process is gone
    (the process is re-parented), so that children of a killed ``soilocp run`` never linger."""
    if os.environ.get(ENV_EXIT_WITH_PARENT) != "1":
        return
    parent = os.getppid()

    def _watch() -> None:
        while not stop.wait(period_s):
            if os.getppid() != parent:
                faulthandler.dump_traceback_later(1.8 + 1.5, exit=True)  # as install_stop_handlers
                if log:
                    log.warning("parent_gone", parent_pid=parent)
                stop.set()
                time.sleep(1.8)  # same grace as a signal, then go
                os._exit(0)

    threading.Thread(target=_watch, name="parent-watch", daemon=True).start()


def undeclare_all(entities: list[Any]) -> None:
    """Undeclare Zenoh entities (subscribers, publishers, queryables, tokens) newest first, and
    forget them; one already gone with its session is not an error."""
    for entity in reversed(entities):
        try:
            entity.undeclare()
        except Exception:  # already gone with the session: nothing left to release
            pass
    entities.clear()


def open_session(
    mode: str,
    connect: list[str],
    listen: list[str],
    *,
    multicast: bool,
    stop: threading.Event,
    log: JsonLog,
    retry_s: float = 1.0,
    batching: bool = True,
):
    """Open a Zenoh session; in client mode, retry until a router answers or ``stop`` is set.

    Each attempt waits ``retry_s`` for the router (``connect/timeout_ms``), so a service started
    before its router waits for it and still reacts to SIGTERM within ~``retry_s``.  Returns None
    if stopped before connecting.
    """
    import zenoh

    attempt = 0
    while not stop.is_set():
        attempt += 1
        timeout_ms = int(retry_s * 1000) if mode == "client" else None
        conf = zenoh_config(mode, connect, listen, multicast=multicast, connect_timeout_ms=timeout_ms,
                            batching=batching)
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            if mode != "client":
                raise
            if attempt == 1 or attempt % 10 == 0:
                log.warning("waiting_for_router", connect=connect, attempt=attempt, error=str(exc)[:200])
            stop.wait(0.1)
            continue
        log.info("session_open", mode=mode, connect=connect, listen=listen, zid=str(session.zid()), attempts=attempt)
        return session
    return None


def fatal(prefix: str, message: str, code: int = 2) -> None:
    """A fatal configuration error: one line on stderr, exit status ``code``."""
    print(f"{prefix}: error: {message}", file=sys.stderr, flush=True)
    sys.exit(code)


def exit_now(code: int) -> None:
    """Leave right after an orderly shutdown (sessions closed, logs flushed), skipping interpreter
    finalisation: with Zenoh's native runtime it can hang past the 2 s a supervisor allows."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
