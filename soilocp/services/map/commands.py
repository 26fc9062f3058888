"""Console commands of the fleet soil map: ``soilocp service map`` (the service process) and
``soilocp map query`` / ``soilocp map export --geojson`` (docs/map.md)."""

from __future__ import annotations

import json
import math
import sys
import time

import click

from soilocp.schemas.map import WGS84


@click.command("map")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help="Map service config file (JSON).")
@click.option("--map-id", help="This map's id (keys soilmap/<map_id>/...); env SOILOCP_MAP_ID (default fleet).")
@click.option("--store", help="sqlite:PATH (default soilmap.db) or postgresql://user@host/db; env SOILOCP_MAP_STORE.")
@click.option("--connect", multiple=True, help="Zenoh endpoint to connect to (repeatable); env SOILOCP_CONNECT.")
@click.option("--listen", multiple=True, help="Zenoh endpoint to listen on (repeatable, peer mode).")
@click.option("--mode", type=click.Choice(["client", "peer"]), help="Zenoh mode (default client).")
@click.option("--cell-size", type=float, help="Square cell side in a local frame, m (default 5).")
@click.option("--h3-resolution", type=int, help="H3 resolution of WGS84 cells (default 12).")
@click.option("--ageing-rate", type=float, help="Growth of an estimate's ln K variance per hour (default 0.02).")
@click.option("--log-level", type=click.Choice(["debug", "info", "warning", "error"]))
def map_service_cmd(config_path, map_id, store, connect, listen, mode, cell_size, h3_resolution, ageing_rate,
                    log_level) -> None:
    """Run the fleet soil map service until SIGINT/SIGTERM."""
    from soilocp.services.commands import _exit_now, _fatal
    from soilocp.services.map.config import load_map_config
    from soilocp.services.map.service import run_map_service
    from soilocp.services.runtime.config import ConfigError
    from soilocp.map.store import StoreError

    try:
        cfg = load_map_config(config_path, dict(map_id=map_id, store=store, connect=connect, listen=listen, mode=mode,
                                                cell_size=cell_size, h3_resolution=h3_resolution,
                                                ageing_rate=ageing_rate, log_level=log_level))
        _exit_now(run_map_service(cfg))
    except (ConfigError, StoreError) as exc:
        _fatal("soilocp service map", str(exc))


@click.group("service")
def _service_group() -> None:
    """Run one service."""


_service_group.add_command(map_service_cmd)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
def process_main() -> None:
    """soilocp: the map service process."""


process_main.add_command(_service_group)


# --- soilocp map ---------------------------------------------------------------------------------
def _bbox(text):
    if text is None:
        return None
    try:
        box = tuple(float(q) for q in text.split(","))
    except ValueError:
        raise click.BadParameter(f"{text!r}: four numbers xmin,ymin,xmax,ymax") from None
    if len(box) != 4 or not all(math.isfinite(q) for q in box) or box[0] > box[2] or box[1] > box[3]:
        raise click.BadParameter(f"{text!r}: four finite numbers xmin,ymin,xmax,ymax with min <= max")
    return box


def _cells(store_url, connect, map_id, frame, bbox, timeout):
    """Cells from the database directly (--store) or from a running map service (Zenoh query)."""
    now = time.time()
    if store_url:
        from soilocp.map.store import open_store

        st = open_store(store_url)
        try:
            if bbox is None:
                return st.all_cells(now, frame)
            return st.query_box(frame or WGS84, bbox, now)[0]
        finally:
            st.close()
    if bbox is None:
        raise click.UsageError("a query over Zenoh needs --bbox (or read the database with --store)")
    from soilocp.services.map.client import query_map

    return query_map(list(connect) or ["tcp/127.0.0.1:7447"], map_id, frame or WGS84, bbox, timeout).cells


_common = [
    click.option("--store", "store_url", help="Read this database directly: sqlite:PATH or postgresql://..."),
    click.option("--connect", multiple=True, help="Else ask the map service through this router (repeatable)."),
    click.option("--map-id", default="fleet", show_default=True, help="The map service's id (keys soilmap/<map_id>/...)."),
    click.option("--frame", help="wgs84 (H3 cells, bbox in lon/lat) or a local frame's name (bbox in m)."),
    click.option("--bbox", help="xmin,ymin,xmax,ymax"),
    click.option("--timeout", type=float, default=5.0, show_default=True, help="Zenoh: seconds to wait."),
]


def _with_common(f):
    for opt in reversed(_common):
        f = opt(f)
    return f


def _cells_or_exit(command: str, store_url, connect, map_id, frame, bbox, timeout):
    """The box and its cells (:func:`_cells`); exit status 1 with the reason when they cannot be read."""
    box = _bbox(bbox)
    try:
        return box, _cells(store_url, connect, map_id, frame, box, timeout)
    except (ValueError, RuntimeError) as exc:
        click.echo(f"soilocp map {command}: {exc}", err=True)
        sys.exit(1)


@click.group("map")
def map_group() -> None:
    """The fleet soil map: query it, export it (docs/map.md)."""


@map_group.command("query")
@_with_common
@click.option("--json", "as_json", is_flag=True, help="One JSON object (MapQueryReply's cells) instead of a table.")
def map_query(store_url, connect, map_id, frame, bbox, timeout, as_json) -> None:
    """The cells in a box: K, its 95 % band, count, last seen, vehicles."""
    box, cells = _cells_or_exit("query", store_url, connect, map_id, frame, bbox, timeout)
    if as_json:
        click.echo(json.dumps({"frame": frame or WGS84, "bbox": box, "cells": [c.model_dump(mode="json") for c in cells]}))
        return
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"soil map — {len(cells)} cell(s)")
    for col in ("cell", "centre", "K", "95 % band", "count", "age", "vehicles"):
        t.add_column(col)
    now = time.time()
    for c in cells:
        t.add_row(c.cell, f"{c.center[0]:.6g}, {c.center[1]:.6g}", f"{c.K:.1f}", f"{c.K_lo:.1f}–{c.K_hi:.1f}",
                  str(c.count), f"{now - c.last_seen:.0f} s", ",".join(c.vehicles))
    Console().print(t)


@map_group.command("export")
@_with_common
@click.option("--geojson", "out", type=click.Path(dir_okay=False), help="Output GeoJSON file.")
@click.option("--foxglove-grid", "grid_out", type=click.Path(dir_okay=False),
              help="Output MCAP file: a foxglove.Grid (mu_T, K, band) per local frame, for Foxglove's 3D panel.")
def map_export(store_url, connect, map_id, frame, bbox, timeout, out, grid_out) -> None:
    """Write the cells as a GeoJSON FeatureCollection of polygons (K, band, mu_T, count, vehicles)
    and/or as a Foxglove grid of each local frame in an MCAP file."""
    from soilocp.map.geojson import feature_collection

    if not out and not grid_out:
        click.echo("soilocp map export: give --geojson FILE and/or --foxglove-grid FILE.mcap", err=True)
        sys.exit(2)
    box, cells = _cells_or_exit("export", store_url, connect, map_id, frame, bbox, timeout)
    if out:
        with open(out, "w", encoding="utf-8") as f:
            json.dump(feature_collection(cells), f)
            f.write("\n")
        click.echo(f"{out}: {len(cells)} cell(s)")
    if grid_out:
        import time

        from soilocp.export.mcap_out import write_map_grids

        topics = write_map_grids(grid_out, map_id, cells, time.time())
        click.echo(f"{grid_out}: {len(topics)} grid(s) {' '.join(topics)}"
                   + (" (WGS84 cells have no grid: use --geojson)" if any(c.frame == "wgs84" for c in cells) else ""))


COMMANDS = [map_group]
