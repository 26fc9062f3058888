"""The live view of ``soilocp run``: a rich table on a terminal, a plain line otherwise, and the
summary tables at the end."""

from __future__ import annotations

from typing import Any, Optional

from soilocp.services.stages.graph import PIPELINE_SERVICES
from soilocp.schemas.messages import SlipSetpoint
from soilocp.schemas.pipeline import OcpEstimate


from soilocp.services.supervisor.processes import ProcessGroup


def _fmt(x: Optional[float], spec: str = ".3f") -> str:
    return "-" if x is None else format(x, spec)


def _row(snap: dict[str, Any], source_ended: bool = False) -> dict[str, str]:
    est: Optional[OcpEstimate] = snap["est"]
    k = "-"
    cls = "-"
    status = "waiting"
    if est is not None:
        if est.soil_strength is not None:
            k = f"{est.soil_strength:.1f} ± {_fmt(est.soil_strength_std, '.1f')}"
        if est.soil_class:
            cls = est.soil_class + (f" ({est.soil_class_confidence:.2f})" if est.soil_class_confidence is not None else "")
            if not est.confirmed:
                cls += " unconfirmed"
        status = est.status if est.reason_code == "none" else f"{est.status} ({est.reason_code})"
    fresh = "STALE" if snap["stale"] and est is not None else ("fresh" if est is not None else "-")
    if source_ended and fresh == "STALE":
        fresh = "source ended"  # silence after the end of the drive is expected, not a fault
    alive = snap["alive"]
    want = PIPELINE_SERVICES
    sp: Optional[SlipSetpoint] = snap.get("setpoint")
    n_alive = sum(1 for s in want if s in alive)
    return {
        "K ± std": k,
        "soil class": cls,
        "mu_T": _fmt(est.mu_T if est else None),
        "S_T": _fmt(est.S_T if est else None),
        "S_E": _fmt(est.S_E if est else None),
        "status": f"{status} / {fresh}",
        "samples/s": f"{snap['rate']:.1f}",
        "rejections": str(snap["rejections"]),
        "services alive": f"{n_alive}/{len(want)}" + ("" if n_alive == len(want) else
                                                      " (missing " + ",".join(s for s in want if s not in alive) + ")"),
        **({} if sp is None else {"slip set-point": f"{_fmt(sp.slip[0] if sp.slip else None)} ({sp.source})"}),
    }


def live_table(vid: str, snap: dict[str, Any], elapsed: float, title_extra: str = "", *, width: int = 200,
               source_ended: bool = False):
    """One row per vehicle on a wide terminal; a field/value column pair on a narrow one."""
    from rich.table import Table

    row = _row(snap, source_ended)
    title = f"soilocp run — {vid} — t={elapsed:.1f} s{title_extra}"
    if width < 130:
        t = Table(title=title, title_justify="left", show_header=False)
        t.add_column("field", style="bold")
        t.add_column("value", no_wrap=True)
        for name, value in row.items():
            t.add_row(name, value)
        return t
    t = Table(title=title, title_justify="left")
    t.add_column("vehicle")
    for name in row:
        t.add_column(name, no_wrap=True,
                     justify="right" if name not in ("soil class", "status", "services alive") else "left")
    t.add_row(vid, *row.values())
    return t


def plain_line(vid: str, snap: dict[str, Any], elapsed: float) -> str:
    row = _row(snap)
    return f"t={elapsed:6.1f}s {vid} " + " ".join(f"{k.replace(' ', '_')}={v.replace(' ', '')}" for k, v in row.items())


def summary_tables(vid: str, snap: dict[str, Any], group: ProcessGroup, elapsed: float, width: int = 200):
    from rich.table import Table

    ended = any(c.name == "vehicle" and c.outcome == "done" for c in group.children)
    top = live_table(vid, snap, elapsed, " — summary", width=width, source_ended=ended)
    t = Table(title="processes", title_justify="left")
    # short headers: the table must fit an 80-column terminal
    for col in ("process", "pid", "outcome", "rc", "recv", "pub", "rej", "drop", "err"):
        t.add_column(col, no_wrap=True, justify="left" if col in ("process", "outcome") else "right",
                     min_width={"process": 13, "pid": 7, "outcome": 7, "recv": 5, "pub": 5}.get(col))
    for child in group.children:
        h = snap["health"].get(child.name)
        rc = child.proc.returncode if child.proc else None
        t.add_row(child.name, str(child.pid), child.outcome, "-" if rc is None else str(rc),
                  *(str(getattr(h, f)) if h else "-" for f in ("received", "published", "rejected", "dropped", "errors")))
    return top, t


#: why a service drops inputs (ServiceHealth.detail's counters), in words
DROP_REASONS = {
    "unjoined": "their normal forces arrived too late to be joined (observer join_timeout_s)",
    "queue_full": "the service's worker queue was full (it could not keep up)",
    "out_of_order": "they came out of order (a restarted gateway)",
}


def drop_lines(health: dict, replay_speed: Optional[float]) -> list[str]:
    """One line per service that dropped inputs: how many and why (its health's detail counters), and
    for a replay at ``--speed 0`` (``replay_speed`` 0) what to do about it."""
    out = []
    for name, h in sorted(health.items()):
        if not h.dropped:
            continue
        why = [f"{n} {DROP_REASONS.get(k, k)}" for k, n in sorted(h.detail.items())
               if k in DROP_REASONS and isinstance(n, int) and n]
        out.append(f"DROPPED: {name} dropped {h.dropped} of {h.received} inputs"
                   + (": " + "; ".join(why) if why else ""))
    if out and replay_speed == 0:
        out.append("  --speed 0 replays faster than the services keep up, and what they drop gets no estimate: "
                   "replay at --speed 1 (real time), or run soilocp estimate on the log (every sample, offline)")
    return out
