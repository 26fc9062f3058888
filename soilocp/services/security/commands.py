"""``soilocp certs``: development certificates and the fleet router's access control
(services/security/certs.py, services/security/fleet_security.py; docs/deploy.md "A secure fleet")."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click


def _fail(message: str) -> None:
    click.echo(f"soilocp certs: error: {message}", err=True)
    sys.exit(2)


@click.group("certs")
def certs_group() -> None:
    """Certificates for mutual TLS between vehicles, fleet router and fleet tools."""


@certs_group.command("init")
@click.argument("directory", type=click.Path(file_okay=False))
@click.option("--vehicle", "vehicles", multiple=True, help="Vehicle id (repeatable): one certificate each, CN = the id.")
@click.option("--fleet-host", "fleet_hosts", multiple=True,
              help="Name or address the fleet router is reached under (repeatable); default fleet-router, localhost, 127.0.0.1.")
@click.option("--tool", "tools", multiple=True, help="Fleet tool certificate (repeatable); default dashboard.")
@click.option("--days", type=click.IntRange(1, 3650), default=825, show_default=True, help="Validity of the leaf certificates.")
@click.option("--force", is_flag=True, help="Replace an existing development CA (invalidates what it signed).")
@click.option("--if-missing", is_flag=True, help="Keep an existing CA and its certificates and exit 0 (containers).")
def certs_init(directory, vehicles, fleet_hosts, tools, days, force, if_missing) -> None:
    """A development CA in DIRECTORY, and certificates for the fleet router, the tools and each vehicle."""
    from soilocp.services.security.certs import DEFAULT_FLEET_HOSTS, DEFAULT_TOOLS, init_fleet

    if if_missing and not force and (Path(directory) / "ca.key").exists():
        click.echo(f"{directory}: development CA present, kept")
        return
    try:
        files = init_fleet(Path(directory), vehicles or ("rover1", "rover2"), days=days, force=force,
                           fleet_hosts=fleet_hosts or DEFAULT_FLEET_HOSTS, tools=tools or DEFAULT_TOOLS)
    except ValueError as exc:
        _fail(str(exc))
    for f in files:
        click.echo(str(f))


@certs_group.command("issue")
@click.argument("directory", type=click.Path(file_okay=False, exists=True))
@click.argument("name")
@click.option("--host", "hosts", multiple=True, help="Extra DNS name or IP address for the certificate (repeatable).")
@click.option("--days", type=click.IntRange(1, 3650), default=825, show_default=True, help="Validity of the certificate, days.")
def certs_issue(directory, name, hosts, days) -> None:
    """One more certificate (a new vehicle or tool) signed by the development CA in DIRECTORY."""
    from soilocp.services.security.certs import issue

    try:
        click.echo(str(issue(Path(directory), name, hosts=hosts, days=days)))
    except ValueError as exc:
        _fail(str(exc))


@certs_group.command("show")
@click.argument("files", nargs=-1, type=click.Path(dir_okay=False, exists=True))
def certs_show(files) -> None:
    """Common name, issuer, alternative names and expiry of certificate files (JSON lines)."""
    from soilocp.services.security.certs import describe

    for f in files:
        try:
            click.echo(json.dumps(describe(Path(f))))
        except ValueError as exc:
            _fail(f"{f}: {exc}")


@certs_group.command("acl")
@click.option("--vehicle", "vehicles", multiple=True, required=True, help="Vehicle id admitted (repeatable).")
@click.option("--tool", "tools", multiple=True, help="Fleet tool certificate name (repeatable); default dashboard.")
@click.option("--map", "maps", multiple=True, help="Map service id = its certificate name (repeatable; docs/map.md).")
def certs_acl(vehicles, tools, maps) -> None:
    """Print the fleet router's access_control section (for a native zenohd configuration)."""
    from soilocp.services.security.fleet_security import fleet_access_control

    try:
        click.echo(json.dumps(fleet_access_control(vehicles, tools or ("dashboard",), maps), indent=2))
    except ValueError as exc:
        _fail(str(exc))


COMMANDS = [certs_group]
