"""``soilocp control compare``: closed-loop slip controllers against fixed-slip baselines."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click


@click.group("control")
def control_group() -> None:
    """Wheel-slip controllers that act on the OCPs (closed loop on the simulator)."""


@control_group.command("compare")
@click.option("--scenario", "scenarios", multiple=True, metavar="NAME",
              help="Closed-loop scenario (repeatable; default: all). See --list.")
@click.option("--controller", "controllers", multiple=True, metavar="NAME",
              help="Controller (repeatable; default: speed, fixed_0.15, fixed_0.20, ocp_traction, ocp_efficiency).")
@click.option("--list", "list_only", is_flag=True, help="List the scenarios and exit.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Write the results as JSON here.")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False), help="Write one PNG per scenario here.")
@click.option("--duration", type=float, help="Cap every run at this many simulated seconds (short checks).")
@click.option("--seed", type=int, default=0, show_default=True, help="Sensor-noise seed.")
@click.option("--markdown", is_flag=True, help="Print the table as Markdown (for the README).")
def compare_cmd(scenarios, controllers, list_only, json_out, plots_dir, duration, seed, markdown) -> None:
    """Drive each scenario with each controller, the estimation chain in the loop; print a table."""
    from soilocp.control.compare import TABLE_HEADER, compare, gains_over_fixed, markdown_table, plot_traces, table_rows
    from soilocp.control.controllers import CONTROLLER_NAMES, make_policy
    from soilocp.control.rig import RIG_SCENARIOS

    if list_only:
        for r in RIG_SCENARIOS.values():
            click.echo(f"{r.name}: {r.description}")
        return
    if duration is not None and not duration > 0:
        raise click.BadParameter(f"--duration {duration!r}: must be > 0 s")
    try:
        for c in controllers:
            make_policy(c)
        doc, traces = compare(scenarios or None, controllers or CONTROLLER_NAMES, seed=seed, duration=duration,
                              progress=lambda s, c: click.echo(f"  running {s} / {c}", err=True))
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc
    if markdown:
        click.echo(markdown_table(doc))
    else:
        from rich.console import Console
        from rich.table import Table

        t = Table(title="closed-loop comparison (estimation chain in the loop)", title_justify="left")
        for h in TABLE_HEADER:
            t.add_column(h, justify="left" if h in ("scenario", "controller") else "right", no_wrap=True)
        for row in table_rows(doc):
            t.add_row(*row)
        Console(width=120).print(t)
    for entry in doc["scenarios"]:
        g = gains_over_fixed(entry)
        if g:
            what = {"drawbar": "pull", "climb": "max grade", "drive": "energy saved per metre"}[entry["kind"]]
            click.echo(f"{entry['name']}: {what} vs the best fixed slip: "
                       + ", ".join(f"{c} {100 * v:+.1f} %" for c, v in g.items()))
    if json_out:
        Path(json_out).write_text(json.dumps(doc, indent=2) + "\n")
        click.echo(f"JSON -> {json_out}", err=True)
    if plots_dir:
        for p in plot_traces(traces, plots_dir):
            click.echo(f"plot -> {p}", err=True)
    sys.stdout.flush()


COMMANDS = [control_group]
