"""The one process supervisor of soilocp: ``soilocp run``, the bench and the integration tests
start their router and services through :class:`ProcessGroup`.

Each child is ``python -m MODULE ARGS`` (the command line by default) in a session of its own
(the terminal's Ctrl-C reaches only the supervisor, which stops the children in reverse order),
with its output appended to ``<log_dir>/<name>.log``.  Children of a supervisor that is killed
notice their new parent and stop themselves (``SOILOCP_EXIT_WITH_PARENT``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Optional

from soilocp.services.runtime.config import ENV_EXIT_WITH_PARENT

#: Services stop in < 2 s; the margin is for a heavily loaded machine.
STOP_TIMEOUT_S = 5.0


@dataclass
class Child:
    name: str
    argv: list[str]
    log_path: Path
    proc: Optional[subprocess.Popen] = None
    stopping: bool = False
    outcome: str = "running"  # running | done | died | stopped | killed

    @property
    def pid(self) -> Optional[int]:
        return self.proc.pid if self.proc else None

    def start(self, env: dict[str, str], *, cwd: Optional[Path] = None, new_session: bool = True) -> None:
        fh = open(self.log_path, "ab")
        try:
            self.proc = subprocess.Popen(self.argv, stdin=subprocess.DEVNULL, stdout=fh, stderr=fh, env=env,
                                         cwd=cwd, start_new_session=new_session)
        finally:
            fh.close()

    def poll(self) -> Optional[int]:
        return None if self.proc is None else self.proc.poll()


class ProcessGroup:
    """Children started in order and stopped in reverse order; every one is reaped.

    ``drop_env``: prefixes of environment variables not passed on (the caller passes those
    settings explicitly); ``env`` adds to the children's environment.
    """

    def __init__(self, log_dir: Path, *, drop_env: Iterable[str] = ("SOILOCP_CONFIG",),
                 env: Optional[dict[str, str]] = None, exit_with_parent: bool = True):
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.children: list[Child] = []
        drop = tuple(drop_env)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith(drop)} if drop else dict(os.environ)
        self.env["PYTHONUNBUFFERED"] = "1"
        if exit_with_parent:
            self.env[ENV_EXIT_WITH_PARENT] = "1"
        self.env.update(env or {})

    def start(self, name: str, args: Iterable[str], *, module: str = "soilocp.cli",
              env: Optional[dict[str, str]] = None) -> Child:
        """Start ``python -m module *args`` as child ``name`` (a later child of the same name
        replaces it in :attr:`procs`; both are reaped)."""
        return self.start_argv(name, [sys.executable, "-m", module, *args], env=env)

    def start_argv(self, name: str, argv: list[str], *, env: Optional[dict[str, str]] = None,
                   cwd: Optional[Path] = None, new_session: bool = True) -> Child:
        """Start any command as child ``name`` (e.g. one wrapped in ``ip netns exec``)."""
        child = Child(name, list(argv), self.log_dir / f"{name}.log")
        child.start({**self.env, **(env or {})}, cwd=cwd, new_session=new_session)
        self.children.append(child)
        return child

    @property
    def procs(self) -> dict[str, subprocess.Popen]:
        """The latest child of each name."""
        return {c.name: c.proc for c in self.children if c.proc is not None}

    def alive(self) -> dict[str, bool]:
        return {n: p.poll() is None for n, p in self.procs.items()}

    def dead(self) -> dict[str, int]:
        """``{name: exit status}`` of the children (latest of each name) that have exited."""
        return {n: p.returncode for n, p in self.procs.items() if p.poll() is not None}

    def log_text(self, name: str) -> str:
        path = self.log_dir / f"{name}.log"
        return path.read_text(errors="replace") if path.exists() else ""

    def tail(self, name: str, n: int = 15) -> str:
        return "\n".join(self.log_text(name).splitlines()[-n:])

    def stop_all(self, timeout: float = STOP_TIMEOUT_S) -> dict[str, Optional[int]]:
        """SIGTERM to every running child in reverse order, wait up to ``timeout``, then SIGKILL.
        Returns each name's exit status (the latest child of that name)."""
        return self.stop(None, timeout)

    def stop(self, names: Optional[Iterable[str]] = None, timeout: float = STOP_TIMEOUT_S) -> dict[str, Optional[int]]:
        """:meth:`stop_all`, for the children named (all when None)."""
        chosen = None if names is None else set(names)
        children = [c for c in self.children if chosen is None or c.name in chosen]
        for child in reversed(children):
            if child.proc and child.proc.poll() is None:
                child.stopping = True
                try:
                    child.proc.send_signal(signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + timeout
        for child in reversed(children):
            if child.proc is None:
                continue
            try:
                child.proc.wait(max(0.05, deadline - time.monotonic()))
                if child.outcome == "running":
                    # -SIGTERM: stopped while still starting, before its handlers were installed
                    ok = child.proc.returncode in (0, -signal.SIGTERM)
                    child.outcome = "stopped" if ok else "died"
            except subprocess.TimeoutExpired:
                child.proc.kill()
                child.proc.wait()
                child.outcome = "killed"
        return {n: p.returncode for n, p in self.procs.items() if chosen is None or n in chosen}

    close = stop_all
