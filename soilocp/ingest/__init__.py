"""Importers of real robots' logs (ROS 2 bags, multi-rate CSV) into the sensor log (JSON Lines).

:func:`import_source` is the one entry point: a bag path or CSV files by role, a map file, an
output path; it writes the log and ``<log>.provenance.json`` (:class:`~.align.Provenance`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from soilocp.ingest.align import Provenance, read_provenance, withhold  # noqa: F401
from soilocp.ingest.mapfile import TopicMap, load_map  # noqa: F401


def import_source(bag: Optional[str | Path], csv_files: Optional[dict[str, str]], tmap: TopicMap, out: str | Path, *,
                  strict: bool = False, progress: bool = True) -> tuple[Provenance, list[str]]:
    """Import a ROS 2 bag (``bag``) or CSV logs (``csv_files``: role -> path); (provenance, issue lines)."""
    if (bag is None) == (not csv_files):
        raise ValueError("give a bag or --csv ROLE=FILE files, not both and not neither")
    if bag is not None:
        from soilocp.ingest.rosbag_import import import_bag

        return import_bag(bag, tmap, out, strict=strict, progress=progress)
    from soilocp.ingest.csv_import import import_csv

    return import_csv(csv_files, tmap, out)
