"""The map's database: an embedded SQLite file by default, PostgreSQL + PostGIS for a fleet that
outgrows one machine.  Same tables, same upsert, same fusion (:mod:`soilocp.map.fusion`).

Tables::

    cells(cell PK, frame, cx, cy, <fused state>, ver)   a cell, its centre (PostGIS: + geom, GiST index), its
                                                        fused state, and the commit number that last changed it
    obs(cell, vehicle, ln_k, var, seq, stamp, seen_at, n)   PK (cell, vehicle): the vehicle's latest estimate there
    vehicles(vehicle PK, last_seq, applied)             the committed-updates ledger per vehicle
    meta(key PK, value)                                 cell size and H3 resolution: a store refuses another grid

Durability: :meth:`MapStore.apply` is one transaction and returns only after it committed; the
service acknowledges (publishes) a batch only after that.  SQLite runs in WAL mode with
``synchronous=FULL`` (the WAL is fsynced at every commit: nothing committed is lost to kill -9,
nor to a power cut); PostgreSQL commits are durable by its own WAL (``synchronous_commit`` on).
"""

from __future__ import annotations

import os
import sqlite3
import threading
from collections.abc import Sequence
from contextlib import closing
from typing import Optional

from soilocp.schemas.map import MapCell

from soilocp.map.cells import CellConfig
from soilocp.map.fusion import FusionConfig, Observation, aged_columns, cells_of_columns, fuse_cells
from soilocp.map.replies import ReplyCache

_TABLES = [
    "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    # ln_k .. vehicles: the cell's fused state at time t (fusion.fuse_cells), written with every change
    "CREATE TABLE IF NOT EXISTS cells (cell TEXT PRIMARY KEY, frame TEXT NOT NULL, cx DOUBLE PRECISION NOT NULL, "
    "cy DOUBLE PRECISION NOT NULL, ln_k DOUBLE PRECISION, var DOUBLE PRECISION, t DOUBLE PRECISION, n BIGINT, "
    "last_seen DOUBLE PRECISION, vehicles TEXT, ver BIGINT{geom})",
    "CREATE TABLE IF NOT EXISTS obs (cell TEXT NOT NULL, vehicle TEXT NOT NULL, ln_k DOUBLE PRECISION NOT NULL, "
    "var DOUBLE PRECISION NOT NULL, seq BIGINT NOT NULL, stamp DOUBLE PRECISION NOT NULL, "
    "seen_at DOUBLE PRECISION NOT NULL, n BIGINT NOT NULL, PRIMARY KEY (cell, vehicle)){without_rowid}",
    "CREATE TABLE IF NOT EXISTS vehicles (vehicle TEXT PRIMARY KEY, last_seq BIGINT NOT NULL, applied BIGINT NOT NULL)",
]

# A row is replaced only by a newer estimate of the same vehicle (fusion module docstring).
_UPSERT_OBS = (
    "INSERT INTO obs (cell, vehicle, ln_k, var, seq, stamp, seen_at, n) VALUES (?, ?, ?, ?, ?, ?, ?, ?) "
    "ON CONFLICT (cell, vehicle) DO UPDATE SET ln_k = excluded.ln_k, var = excluded.var, seq = excluded.seq, "
    "stamp = excluded.stamp, seen_at = excluded.seen_at, n = obs.n + excluded.n "
    "WHERE excluded.stamp > obs.stamp OR (excluded.stamp = obs.stamp AND excluded.seq > obs.seq) "
    "OR excluded.seen_at - obs.seen_at > ?")
_UPSERT_VEHICLE = (
    "INSERT INTO vehicles (vehicle, last_seq, applied) VALUES (?, ?, ?) ON CONFLICT (vehicle) DO UPDATE SET "
    "last_seq = excluded.last_seq, applied = vehicles.applied + excluded.applied")
_ROWS = ("SELECT c.cell, c.frame, c.cx, c.cy, o.vehicle, o.ln_k, o.var, o.n, o.seen_at FROM cells c "
         "JOIN obs o ON o.cell = c.cell ")
_FUSED = "SELECT cell, cx, cy, ln_k, var, t, n, last_seen, vehicles FROM cells WHERE n IS NOT NULL "
_SET_FUSED = "UPDATE cells SET ln_k = ?, var = ?, t = ?, n = ?, last_seen = ?, vehicles = ?, ver = ? WHERE cell = ?"
_CHANGED = "SELECT frame, cell, cx, cy, ln_k, var, t, n, last_seen, vehicles FROM cells WHERE n IS NOT NULL "


class StoreError(RuntimeError):
    """The database cannot be opened or does not fit this map's configuration."""


class MapStore:
    """Common logic; subclasses give the connection, the parameter style and the box query."""

    url: str
    _param = "?"

    def __init__(self, cells: Optional[CellConfig], fusion: FusionConfig):
        # no cell config: a reader (soilocp map query/export) that takes the grid the store was built with
        self._adopt = cells is None
        self.cell_config, self.fusion = cells or CellConfig(), fusion
        self._local = threading.local()
        self._reply_cache = None

    # --- dialect ---------------------------------------------------------------------------------
    def _connect(self):
        raise NotImplementedError

    def _sql(self, q: str) -> str:
        return q if self._param == "?" else q.replace("?", self._param)

    def _conn(self):
        """One connection per thread (the service writes on its worker, answers queries on another)."""
        c = getattr(self._local, "conn", None)
        if c is None:
            c = self._local.conn = self._connect()
        return c

    def _insert_cells_sql(self) -> str:
        return "INSERT INTO cells (cell, frame, cx, cy) VALUES (?, ?, ?, ?) ON CONFLICT (cell) DO NOTHING"

    def _box_sql(self) -> str:
        return _FUSED + "AND frame = ? AND cx BETWEEN ? AND ? AND cy BETWEEN ? AND ?"

    def _box_params(self, frame: str, bbox: Sequence[float]) -> tuple:
        xmin, ymin, xmax, ymax = bbox
        return (frame, xmin, xmax, ymin, ymax)

    # --- schema ----------------------------------------------------------------------------------
    def _init_schema(self, geom: str = "", without_rowid: str = "", extra: Sequence[str] = ()) -> None:
        c = self._conn()
        cur = c.cursor()
        for t in _TABLES:
            cur.execute(t.format(geom=geom, without_rowid=without_rowid))
        cur.execute("SELECT * FROM cells WHERE 1 = 0")
        if "ver" not in [d[0] for d in cur.description]:  # a store made before the change counter
            cur.execute("ALTER TABLE cells ADD COLUMN ver BIGINT")
        cur.execute("CREATE INDEX IF NOT EXISTS cells_ver ON cells (ver)")
        for q in extra:
            cur.execute(q)
        want = {"cell_size": f"{self.cell_config.cell_size:g}", "h3_resolution": str(self.cell_config.h3_resolution)}
        cur.execute("SELECT key, value FROM meta")
        have = dict(cur.fetchall())
        if self._adopt and have:
            self.cell_config = CellConfig(cell_size=float(have.get("cell_size", want["cell_size"])),
                                          h3_resolution=int(have.get("h3_resolution", want["h3_resolution"])))
            want = {"cell_size": f"{self.cell_config.cell_size:g}",
                    "h3_resolution": str(self.cell_config.h3_resolution)}
        for k, v in want.items():
            if k in have and have[k] != v:
                c.rollback()
                raise StoreError(f"{self.url}: the map was built with {k} = {have[k]}, this service has {v}: "
                                 "use another database (cells of two grids must not mix)")
            if k not in have:
                cur.execute(self._sql("INSERT INTO meta (key, value) VALUES (?, ?)"), (k, v))
        c.commit()

    # --- writing ---------------------------------------------------------------------------------
    def apply(self, batch: Sequence[tuple[Observation, int]], ledger: dict[str, tuple[int, int]]) -> None:
        """One transaction: the cells, the per-vehicle rows (``(observation, estimates it stands for)``,
        one per (cell, vehicle)), and the ledger ``{vehicle: (last seq, estimates applied)}``.
        Returns after the commit; raises (rolled back) otherwise."""
        c = self._conn()
        try:
            with closing(c.cursor()) as cur:
                self._apply(cur, batch, ledger)
            c.commit()
        except BaseException:
            c.rollback()
            raise

    def _apply(self, cur, batch: Sequence[tuple[Observation, int]], ledger: dict[str, tuple[int, int]]) -> None:
        """:meth:`apply`'s statements on ``cur``, inside its transaction (the same SQL for both databases)."""
        gap = self.fusion.restart_gap_s
        cur.executemany(self._sql(self._insert_cells_sql()), sorted({self._cell_row(o.cell) for o, _n in batch}))
        cur.executemany(self._sql(_UPSERT_OBS), [(o.cell.cell, o.vehicle, o.ln_k, o.var, o.seq, o.stamp,
                                                  o.seen_at, n, gap) for o, n in batch])
        cur.executemany(self._sql(_UPSERT_VEHICLE), [(v, s, n) for v, (s, n) in sorted(ledger.items())])
        self._refresh(cur, batch)

    def _cell_row(self, cell) -> tuple:
        """The parameters of :meth:`_insert_cells_sql` for a cell."""
        return (cell.cell, cell.frame, cell.cx, cell.cy)

    def _refresh(self, cur, batch) -> None:
        """Re-fuse the batch's cells from their rows, in the same transaction (fusion.fuse_cells)."""
        ids = sorted({o.cell.cell for o, _n in batch})
        rows = []
        for i in range(0, len(ids), 500):
            part = ids[i:i + 500]
            cur.execute(self._sql(_ROWS + f"WHERE c.cell IN ({', '.join('?' * len(part))})"), part)
            rows += cur.fetchall()
        # the commit's number marks the cells it changed (ReplyCache reads them back)
        cur.execute("SELECT MAX(ver) FROM cells")
        ver = int(cur.fetchone()[0] or 0) + 1
        cur.executemany(self._sql(_SET_FUSED), [(lk, v, last, n, last, ",".join(veh), ver, cell)
                                                for cell, lk, v, n, last, veh in fuse_cells(rows, self.fusion.ageing_rate)])

    # --- reading ---------------------------------------------------------------------------------
    def query_columns(self, frame: str, bbox: Sequence[float], now: float, limit: int = 100_000
                      ) -> tuple[dict, bool]:
        """Cells of ``frame`` whose centre lies in ``bbox`` (xmin, ymin, xmax, ymax; lon/lat for
        wgs84), ordered by centre (x, then y) and aged to ``now``, as reply columns
        (fusion.aged_columns); and whether ``limit`` cut them."""
        cur = self._conn().cursor()
        # ordered by position: the box index's own order (no sort); centres are distinct within a frame
        cur.execute(self._sql(self._box_sql() + " ORDER BY cx, cy LIMIT ?"), (*self._box_params(frame, bbox), limit + 1))
        rows = cur.fetchall()
        self._end_read()
        cut = len(rows) > limit
        return aged_columns(rows[:limit], frame, now, self.fusion.ageing_rate), cut

    def changed_cells(self, since: int) -> tuple[int, list[tuple]]:
        """The current commit number and the cells a commit numbered >= ``since`` changed (all cells
        for since < 0; none while the number is still ``since``): ``(frame, cell, cx, cy, ln_k, var, t, n,
        last_seen, vehicles)``.  ``>=``: a commit of another writer of a shared database may carry
        the number last seen."""
        cur = self._conn().cursor()
        cur.execute("SELECT MAX(ver) FROM cells")
        ver = int(cur.fetchone()[0] or 0)
        if since < 0:
            cur.execute(_CHANGED)
        elif ver > since:  # nothing committed since: nothing to read (the common case of a query)
            cur.execute(self._sql(_CHANGED + "AND ver >= ?"), (since,))
        rows = cur.fetchall() if since < 0 or ver > since else []
        self._end_read()
        return ver, rows

    def query_json(self, frame: str, bbox: Sequence[float], now: float, limit: int = 100_000, ready_only: bool = False
                   ) -> Optional[tuple[bytes, int, bool, float]]:
        """:meth:`query_columns` as the JSON (bytes) of the reply's ``columns`` (soilocp.schemas.map.MapCellColumns),
        their number, whether ``limit`` cut them, and the time they are aged to (``now`` on the
        replies' ageing clock: the start of its one-second step); from memory, kept up to date from
        the cells' commit numbers (:class:`soilocp.map.replies.ReplyCache`: one per store, for one
        caller at a time).  ``ready_only``: None unless the frame is laid out for that time already
        (no read of the store: the caller knows nothing was committed since the last read)."""
        return self._replies().columns_json(frame, bbox, now, limit, ready_only)

    def _replies(self) -> ReplyCache:
        if self._reply_cache is None:
            self._reply_cache = ReplyCache(self.changed_cells, self.fusion.ageing_rate)
        return self._reply_cache

    def prepare_replies(self, now: Optional[float] = None) -> None:
        """Lay out the stored cells for :meth:`query_json` now, not at its first query; again between
        queries: the last commits, and the ageing clock's next step ahead of it."""
        self._replies().warm(now)

    def query_box(self, frame: str, bbox: Sequence[float], now: float, limit: int = 100_000
                  ) -> tuple[list[MapCell], bool]:
        """:meth:`query_columns` as MapCell models."""
        cols, cut = self.query_columns(frame, bbox, now, limit)
        return cells_of_columns(cols), cut

    def cells_by_id(self, ids: Sequence[str], now: float) -> list[MapCell]:
        out: list[MapCell] = []
        cur = self._conn().cursor()
        ids = sorted(set(ids))
        for i in range(0, len(ids), 500):
            part = ids[i:i + 500]
            cur.execute(self._sql(_FUSED.replace("cell, cx", "frame, cell, cx")
                                  + f"AND cell IN ({', '.join('?' * len(part))}) ORDER BY cell"), part)
            out += self._by_frame(cur.fetchall(), now)
        self._end_read()
        return sorted(out, key=lambda c: c.cell)

    def all_cells(self, now: float, frame: Optional[str] = None) -> list[MapCell]:
        cur = self._conn().cursor()
        q = _FUSED.replace("cell, cx", "frame, cell, cx")
        if frame is None:
            cur.execute(q + "ORDER BY cell")
        else:
            cur.execute(self._sql(q + "AND frame = ? ORDER BY cell"), (frame,))
        out = self._by_frame(cur.fetchall(), now)
        self._end_read()
        return sorted(out, key=lambda c: c.cell)

    def _by_frame(self, rows, now: float) -> list[MapCell]:
        frames: dict[str, list] = {}
        for r in rows:
            frames.setdefault(r[0], []).append(tuple(r[1:]))
        return [c for f, rs in frames.items() for c in cells_of_columns(aged_columns(rs, f, now, self.fusion.ageing_rate))]

    def ledger(self) -> dict[str, tuple[int, int]]:
        """{vehicle: (last committed seq, committed estimates)}."""
        cur = self._conn().cursor()
        cur.execute("SELECT vehicle, last_seq, applied FROM vehicles")
        out = {v: (int(s), int(n)) for v, s, n in cur.fetchall()}
        self._end_read()
        return out

    def obs_rows(self) -> list[tuple]:
        """Every (cell, vehicle, ln_k, var, seq, stamp, n) row, sorted (tests, convergence checks)."""
        cur = self._conn().cursor()
        cur.execute("SELECT cell, vehicle, ln_k, var, seq, stamp, n FROM obs ORDER BY cell, vehicle")
        out = [tuple(r) for r in cur.fetchall()]
        self._end_read()
        return out

    def count_cells(self) -> int:
        cur = self._conn().cursor()
        cur.execute("SELECT COUNT(*) FROM cells")
        n = int(cur.fetchone()[0])
        self._end_read()
        return n

    def _end_read(self) -> None:
        """End the read transaction (PostgreSQL opens one per statement batch)."""

    def close(self) -> None:
        c = getattr(self._local, "conn", None)
        if c is not None:
            c.close()
            self._local.conn = None


class SqliteStore(MapStore):
    """The embedded default: one SQLite file, WAL, synchronous=FULL."""

    def __init__(self, path: str, cells: Optional[CellConfig], fusion: FusionConfig):
        super().__init__(cells, fusion)
        self.path = os.path.abspath(path)
        self.url = f"sqlite:{self.path}"
        d = os.path.dirname(self.path)
        if not os.path.isdir(d):
            raise StoreError(f"{self.url}: directory {d!r} does not exist")
        self._init_schema(without_rowid=" WITHOUT ROWID",
                          # covering: a box query reads the index alone, in its order
                          extra=["CREATE INDEX IF NOT EXISTS cells_box ON cells (frame, cx, cy, cell, ln_k, var, t, n, "
                                 "last_seen, vehicles)"])

    def _connect(self):
        try:
            c = sqlite3.connect(self.path, timeout=30.0, check_same_thread=True)
            c.execute("PRAGMA journal_mode=WAL")
            c.execute("PRAGMA synchronous=FULL")
        except sqlite3.Error as exc:
            raise StoreError(f"{self.url}: cannot open: {exc}") from None
        return c


class PostgresStore(MapStore):
    """PostgreSQL with PostGIS: the cell centres are also a PostGIS point (SRID 0: a local frame's
    metres and WGS84's lon/lat share the column; a box query never mixes frames) with a GiST index."""

    _param = "%s"

    def __init__(self, url: str, cells: Optional[CellConfig], fusion: FusionConfig):
        super().__init__(cells, fusion)
        self.url = url
        self._init_schema(
            geom=", geom geometry(Point, 0) NOT NULL",
            extra=["CREATE INDEX IF NOT EXISTS cells_geom ON cells USING GIST (geom)",
                   "CREATE INDEX IF NOT EXISTS cells_frame ON cells (frame)"])

    def _init_schema(self, **kw) -> None:
        c = self._conn()
        with c.cursor() as cur:
            cur.execute("CREATE EXTENSION IF NOT EXISTS postgis")
        c.commit()
        super()._init_schema(**kw)

    def _connect(self):
        try:
            import psycopg
        except ImportError as exc:  # pragma: no cover - a dependency of the package
            raise StoreError(f"PostgreSQL store needs psycopg: {exc}") from None
        try:
            return psycopg.connect(self.url, connect_timeout=10)
        except psycopg.Error as exc:
            raise StoreError(f"{_redact(self.url)}: cannot connect: {str(exc).strip()[:300]}") from None

    def _insert_cells_sql(self) -> str:
        return ("INSERT INTO cells (cell, frame, cx, cy, geom) VALUES (?, ?, ?, ?, ST_MakePoint(?, ?)) "
                "ON CONFLICT (cell) DO NOTHING")

    def _cell_row(self, cell) -> tuple:
        return (cell.cell, cell.frame, cell.cx, cell.cy, cell.cx, cell.cy)  # the centre again for the PostGIS point

    def _box_sql(self) -> str:
        return _FUSED + "AND frame = ? AND geom && ST_MakeEnvelope(?, ?, ?, ?, 0)"

    def _box_params(self, frame, bbox):
        xmin, ymin, xmax, ymax = bbox
        return (frame, xmin, ymin, xmax, ymax)

    def _end_read(self) -> None:
        self._conn().rollback()


def _redact(url: str) -> str:
    import re

    return re.sub(r"://([^:/@]+):[^@]*@", r"://\1:***@", url)


def open_store(url: str, cells: Optional[CellConfig] = None, fusion: Optional[FusionConfig] = None) -> MapStore:
    """``sqlite:PATH`` (or a bare path) -> :class:`SqliteStore`; ``postgresql://...`` -> :class:`PostgresStore`.
    Without ``cells`` the store keeps the grid it was built with (a new one gets the defaults)."""
    fusion = fusion or FusionConfig()
    if url.startswith(("postgresql://", "postgres://")):
        return PostgresStore(url, cells, fusion)
    path = url[len("sqlite:"):] if url.startswith("sqlite:") else url
    if path.startswith("//"):
        path = path[2:]
    if not path:
        raise StoreError("empty store path: give sqlite:PATH or postgresql://...")
    return SqliteStore(path, cells, fusion)
