"""A throw-away PostgreSQL + PostGIS server for the map tests: Debian's packages (``postgresql``,
``postgresql-postgis``), a new cluster by ``initdb`` in a temp dir, run as the ``postgres`` user on an
ephemeral loopback port, trust authentication, stopped and removed afterwards."""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import tempfile
import time
from typing import Optional

APT_HINT = "apt-get install -y postgresql postgresql-postgis"


def pg_bindir() -> Optional[str]:
    dirs = sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda d: int(d.split("/")[-2]))
    for d in reversed(dirs):
        if os.path.exists(os.path.join(d, "initdb")) and glob.glob(
                f"/usr/share/postgresql/{d.split('/')[-2]}/extension/postgis.control"):
            return d
    return None


def _as_postgres(cmd: list[str]) -> list[str]:
    if os.geteuid() != 0:
        return cmd
    return ["runuser", "-u", "postgres", "--", *cmd]


class PgServer:
    def __init__(self, port: int):
        self.bindir = pg_bindir()
        if self.bindir is None:
            raise RuntimeError(f"PostgreSQL with PostGIS is not installed ({APT_HINT})")
        self.port = port
        self.dir = tempfile.mkdtemp(prefix="soilocp-pg-")
        self.data = os.path.join(self.dir, "data")
        if os.geteuid() == 0:
            shutil.chown(self.dir, "postgres", "postgres")
        self.url = f"postgresql://postgres@127.0.0.1:{port}/postgres"

    def start(self) -> "PgServer":
        subprocess.run(_as_postgres([f"{self.bindir}/initdb", "-D", self.data, "-U", "postgres", "--auth=trust",
                                     "-E", "UTF8", "--no-sync"]), check=True, capture_output=True, timeout=120)
        subprocess.run(_as_postgres([f"{self.bindir}/pg_ctl", "-D", self.data, "-l", os.path.join(self.dir, "log"),
                                     "-w", "-t", "60", "-o",
                                     f"-p {self.port} -k {self.dir} -c listen_addresses=127.0.0.1 -c fsync=on",
                                     "start"]), check=True, capture_output=True, timeout=90)
        return self

    def new_database(self, name: str) -> str:
        import psycopg

        with psycopg.connect(self.url, autocommit=True) as c:
            c.execute(f'CREATE DATABASE "{name}"')
        return f"postgresql://postgres@127.0.0.1:{self.port}/{name}"

    def stop(self) -> None:
        subprocess.run(_as_postgres([f"{self.bindir}/pg_ctl", "-D", self.data, "-m", "immediate", "-w", "stop"]),
                       capture_output=True, timeout=60)
        for _ in range(20):
            try:
                shutil.rmtree(self.dir)
                return
            except OSError:
                time.sleep(0.2)
