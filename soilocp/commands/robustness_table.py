"""``soilocp accuracy --robustness``: run the variants and print one row per variant."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

COLUMNS = ("variant", "identifiable", "K med err", "K p90 err", "2-std cov", "std/K med", "conv. change",
           "|mu_T| err", "|S_T| err", "|S_E| err", "mu_T p90", "S_T p90", "no_estimate", "not_observable",
           "model_mismatch", "ok>30%", "ok OCP off", "verdict")


def _fmt(v, spec):
    return "—" if v is None else format(v, spec)


def _cells(r, shown) -> list[str]:
    ident = r["identifiable"] + (f": {r['why_limited']}" if r["why_limited"] else "")
    shares = [_fmt(r["status_shares"].get(s, 0.0), ".0%") for s in shown]
    verdict = "met" if r["pass"] else "missed: " + ", ".join(r["missed"])
    conv = _fmt(r["change_convergence_s"], ".2f") if r["terrain_changes"] else "n/a"
    return [
        r["variant"], ident, _fmt(r["k_median_rel"], ".1%"), _fmt(r["k_p90_rel"], ".1%"), _fmt(r["band_coverage"], ".1%"),
        _fmt(r["std_rel_median"], ".3f"), conv, _fmt(r["mu_T_err"], ".3f"), _fmt(r["S_T_err"], ".3f"),
        _fmt(r["S_E_err"], ".3f"), _fmt(r["mu_T_p90"], ".3f"), _fmt(r["S_T_p90"], ".3f"), *shares,
        "—" if r["tyre"] else str(r["confident_wrong"]), str(r["ok_ocp_off"]), verdict,
    ]  # fmt: skip


def run_and_print(variants, seed: int, seeds: int, duration, jobs: int, json_out, markdown: bool = False,
                  config=None, drive: str = "") -> None:
    """``config`` (a PipelineConfig; None = the defaults) is the estimator's, named in the title by
    ``drive`` ("; config FILE")."""
    from soilocp.analysis.robustness import ROBUSTNESS_TARGETS, SHOWN_STATUSES, rows_json, run_robustness, summarize
    from soilocp.sim.variants import list_variants

    if seeds < 1:
        raise click.UsageError(f"--seeds must be >= 1, got {seeds}")
    try:
        t0 = time.perf_counter()
        runs = run_robustness(variants or None, range(seed, seed + seeds), duration, jobs, config)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    rows = summarize(runs)
    t = ROBUSTNESS_TARGETS
    table = Table(title=(
        f"Robustness vs simulator truth ({'estimator as configured' if config else 'nominal estimator'}; worst segment / "
        f"seed; settle {t['settle_s']:g} s; seeds {seed}..{seed + seeds - 1}{drive})"
    ))
    for col in COLUMNS:
        table.add_column(col, justify="left" if col in ("variant", "identifiable", "verdict") else "right", no_wrap=True)
    for r in rows:
        table.add_row(*_cells(r, SHOWN_STATUSES))
    if markdown:  # for the README
        def md(cells):
            return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

        click.echo(md(COLUMNS) + "\n|" + "---|" * len(COLUMNS))
        for r in rows:
            click.echo(md(_cells(r, SHOWN_STATUSES)))
    else:
        Console(width=260).print(table)
    known = {v.name: v for v in list_variants()}
    for r in rows:
        v = known[r["variant"]]
        judged = (f"; K and the OCPs judged from {v.judged_from:g} s, once the first swing has accelerated and braked "
                  "(ok>30% and the band from the settle on)") if v.judged_from > 0 else ""
        click.echo(f"  {r['variant']}: {v.description}{judged}")
    click.echo(
        f"targets: identifiable: K med <= {t['k_median_rel']:.0%}, p90 <= {t['k_p90_rel']:.0%}, within "
        f"+-{t['convergence_band']:.0%} in < {t['convergence_s']:g} s after a change, 2-std coverage >= "
        f"{t['band_coverage']:.0%}, std/K <= {t['std_rel_median']:g}, OCP errors <= {t['ocp_median_abs']:g}; limited "
        f"and no: judged by the band and the reason, not by K: 2-std coverage where a band is served, and >= "
        f"{t['reason_named_share']:.0%} of the flagged records name what limits K ('reason'); all: no settled record "
        f"with status 'ok' and K > {t['unflagged_error_rel']:.0%} off ('ok>30%', the count, worst seed), and none with "
        f"status 'ok' and mu_T > {t['unflagged_ocp_error']['mu_T']:g} or S_T > {t['unflagged_ocp_error']['S_T']:g} off "
        f"('ok OCP off'); another tyre (tyre-*): judged by its OCPs, mu_T p90 <= {t['tyre_mu_T_p90_abs']:g} and S_T p90 <= "
        f"{t['tyre_S_T_p90_abs']:g} off the true curve's peak ('OCP p90'), not by K (on that tyre's own scale)"
    )
    rates = [r["estimate_rate"] for r in rows]
    click.echo(f"estimate rate >= {min(rates):.0f} samples/s; {len(runs)} runs in {time.perf_counter() - t0:.0f} s")
    if json_out:
        Path(json_out).write_text(rows_json(rows, runs))
    missed = [r["variant"] for r in rows if not r["pass"]]
    if missed:
        click.echo("targets missed: " + ", ".join(missed), err=True)
        sys.exit(1)
