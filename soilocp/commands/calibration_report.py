"""How a wheel calibration is printed at the end of ``soilocp calibrate --from-drive`` and ``soilocp
calibrate-drive`` (one report for both)."""

from __future__ import annotations

from pathlib import Path

import click


def echo_calibration(cal, out_file: str) -> None:
    """A wheel calibration as ``soilocp calibrate --from-drive`` and ``soilocp calibrate-drive`` print it: each
    constant with its 1-sigma or why it was not fitted, each soil with its K and OCPs, the held-out check, what else
    the drive measured, and where the file went."""
    click.echo(f"{'constant':8s} {'value':>10s} {'1-sigma':>10s}")
    for name in ("C1", "C2", "C3", "C4", "C5", "C6"):
        v = getattr(cal.constants, name)
        sd = cal.std.get(name)
        click.echo(f"{name:8s} {v:10.4g} {'' if sd is None else format(sd, '10.2g'):>10s}"
                   + (f"  not fitted: {cal.not_fitted[name]}" if name in cal.not_fitted else ""))
    for soil in cal.soils:
        click.echo(f"soil {soil['soil']} of {soil['source']}: K {soil['K']:.1f} +- {soil['K_std']:.1f}, {soil['pairs']} "
                   f"wheel-samples, slips up to {soil['slip_top']:.2f}: mu_T {soil['mu_T']:.3f}, S_T {soil['S_T']:.3f}")
    h = cal.held_out
    if h:
        click.echo(f"traction residual rms: fit {h['rms_fit']:.4f}, held-out {h['rms_held_out']:.4f} (the paper's curve "
                   f"at its best K: {h['rms_held_out_paper_curve']:.4f})")
    for name in ("payload", "torque_constant", "rolling_resistance"):
        e = cal.extra.get(name)
        if e is None:
            continue
        if e.get("value") is None or "std" not in e:
            click.echo(f"{name}: not fitted: {e.get('reason', '?')}")
        else:
            click.echo(f"{name}: {e['value']:.4g} +- {e['std']:.2g} {e.get('unit', '')}")
    click.echo(f"wrote {out_file}: name it in the vehicle file as \"traction_curve\": \"{Path(out_file).name}\"")
