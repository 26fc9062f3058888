"""The commands' error for bad input files (settings, vehicle, map, logs)."""

from __future__ import annotations

import click


class BadInput(click.ClickException):
    """A file or value the user gave cannot be used: its own message (which names the file, the key,
    the value and the fix), no "Usage:" banner, exit status 2 like a usage error."""

    exit_code = 2
