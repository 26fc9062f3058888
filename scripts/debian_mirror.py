#!/usr/bin/env python3
"""Print the Debian mirror URI that this machine's own apt sources use for a suite.

Read at run time from /etc/apt/sources.list and /etc/apt/sources.list.d/*.list|*.sources (both
the one-line and the deb822 formats), so no mirror host is ever written into the repository.
Only ``deb`` entries that carry the wanted suite and the ``main`` component count; a file that
apt itself would skip (any other extension, e.g. ``*.disabled``) is skipped here too.

Usage: debian_mirror.py SUITE [--root /]   ->  prints e.g. the URI of the first matching entry.
Exit status 1 (with a reason on stderr) when no entry matches.
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import sys


def _one_line_entries(text: str):
    """Yield (uri, suite, components) from the one-line ``deb [opts] uri suite comp...`` format."""
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        # options in brackets, e.g. [signed-by=... arch=amd64], are not part of the fields
        line = re.sub(r"\[[^\]]*\]", " ", line)
        fields = line.split()
        if len(fields) < 3 or fields[0] != "deb":
            continue
        yield fields[1], fields[2], fields[3:]


def _deb822_entries(text: str):
    """Yield (uri, suite, components) from deb822 stanzas (``Types:/URIs:/Suites:/Components:``)."""
    for stanza in re.split(r"\n\s*\n", text):
        fields: dict[str, str] = {}
        key = None
        for raw in stanza.splitlines():
            if raw.lstrip().startswith("#"):
                continue
            if raw[:1] in (" ", "\t") and key:  # continuation line
                fields[key] += " " + raw.strip()
                continue
            if ":" in raw:
                key, value = raw.split(":", 1)
                key = key.strip().lower()
                fields[key] = value.strip()
        if fields.get("enabled", "yes").lower() == "no":
            continue
        if "deb" not in fields.get("types", "").split():
            continue
        for uri in fields.get("uris", "").split():
            for suite in fields.get("suites", "").split():
                yield uri, suite, fields.get("components", "").split()


def source_entries(root: str = "/"):
    """All (uri, suite, components) apt would read under ``root``, in apt's file order."""
    etc = os.path.join(root, "etc/apt")
    main_list = os.path.join(etc, "sources.list")
    if os.path.isfile(main_list):
        with open(main_list, encoding="utf-8") as fh:
            yield from _one_line_entries(fh.read())
    for path in sorted(glob.glob(os.path.join(etc, "sources.list.d", "*"))):
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
        if path.endswith(".list"):
            yield from _one_line_entries(text)
        elif path.endswith(".sources"):
            yield from _deb822_entries(text)


def mirror_for(suite: str, root: str = "/") -> str:
    """First mirror URI whose entry names ``suite`` with the ``main`` component."""
    if not suite or "/" in suite:
        raise ValueError(f"suite={suite!r}: expected a Debian codename such as 'bookworm'")
    for uri, entry_suite, components in source_entries(root):
        if entry_suite == suite and "main" in components:
            return uri.rstrip("/")
    raise LookupError(f"no 'deb' entry for suite {suite!r} with component 'main' in {root}etc/apt")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("suite")
    parser.add_argument("--root", default="/")
    args = parser.parse_args()
    try:
        print(mirror_for(args.suite, args.root))
    except (LookupError, ValueError) as exc:
        print(f"debian_mirror: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
