"""Ask a map service for the cells in a box over Zenoh (the CLI, the dashboard, a vehicle's prior)."""

from __future__ import annotations

from typing import Sequence

from soilocp.schemas import keys
from soilocp.schemas.map import MapQueryReply


def query_map(connect: Sequence[str], map_id: str, frame: str, bbox: Sequence[float], timeout: float = 5.0,
              session=None) -> MapQueryReply:
    """One query ``soilmap/<map_id>/query?frame=F;bbox=...``; RuntimeError when nobody answers or
    the service refuses (its reason)."""
    import zenoh

    from soilocp.services.runtime.config import zenoh_config

    sel = f"{keys.map_key(map_id, 'query')}?frame={frame};bbox={','.join(repr(float(q)) for q in bbox)}"

    def ask(s):
        for reply in s.get(sel, timeout=timeout):
            if reply.ok is not None:
                return MapQueryReply.model_validate_json(reply.ok.payload.to_bytes())
            raise RuntimeError(f"map {map_id!r}: {reply.err.payload.to_string()}")
        raise RuntimeError(f"map {map_id!r}: no map service answered within {timeout:g} s")

    if session is not None:
        return ask(session)
    try:
        with zenoh.open(zenoh_config("client", list(connect), [], connect_timeout_ms=int(timeout * 1000))) as s:
            return ask(s)
    except zenoh.ZError as exc:
        raise RuntimeError(f"no router answered on {', '.join(connect)}: {exc}") from None
