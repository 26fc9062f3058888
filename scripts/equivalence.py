#!/usr/bin/env python3
"""Equivalence of two checkouts of soilocp, shown on every drive the product is judged on (a port or a
refactoring must keep the records): the same sensor logs go through ``soilocp estimate`` of a git ref (default ``main``, checked
out in a temporary ``git worktree`` and installed in its own venv) and of this working tree, and
every output record is compared field by field.

    scripts/equivalence.py                       # main vs the working tree, full drives
    scripts/equivalence.py --ref HEAD~3 --quick  # 8 s drives: a fast check while porting
    scripts/equivalence.py --ref-python /tmp/main/.venv/bin/python   # reuse an env of the ref
    scripts/equivalence.py --keep /tmp/eq --max-minutes 60            # reuse inputs; a time budget

The drives:

* the product's scenarios (``soilocp simulate --list``), each in both controller modes, estimated
  with and without motion-resistance compensation;
* the 25 robustness variants (``soilocp.sim.variants``, seed 0);
* the skid-steer drives: the accuracy scenarios on docs/maps/skid-steer-rover.json (excitation);
* the three Warthog logs of shared/data/real/warthog, with their vehicle-guess.json.

The sensor logs are simulated once, by the ref's code, so that both estimators read identical
input (the simulator itself calls the traction law that is being ported).

What "equal" means:

* every string field (status, reason, soil class, ...), every boolean, every null and the set of
  keys of every record: identical;
* every number: |a - b| <= 1e-9 max(|a|, |b|) + 1e-12 (the absolute term only for quantities that
  are zero up to rounding, e.g. a slip of 1e-17), unless FIELD_TOLERANCE names the field with a
  reason (where a port changes the order of a summation);
* the number of records and the summary line's statuses and rejection count: identical.

Exit status 0 when every drive is equal, 1 otherwise.  The report is a table, one row per drive.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# shared/ sits beside the clone (CI) or two levels up (a worktree under wt/); SOILOCP_WARTHOG_DIR overrides
WARTHOG = Path(os.environ.get("SOILOCP_WARTHOG_DIR") or next(
    (p for p in (REPO.parent / "shared/data/real/warthog", REPO.parent.parent / "shared/data/real/warthog")
     if p.is_dir()), REPO.parent / "shared/data/real/warthog"))
SKID_VEHICLE = "docs/maps/skid-steer-rover.json"
SKID_SCENARIOS = ("sand", "gravel", "grass", "firm", "sandy-slope", "mixed")  # soilocp accuracy's defaults

REL, ABS = 1e-9, 1e-12
#: field -> (relative tolerance, why).  Empty: no port so far changed a summation order that shows.
FIELD_TOLERANCE: dict[str, tuple[float, str]] = {}


@dataclass
class Drive:
    name: str
    group: str
    sensors: Path
    estimate_args: list[str] = field(default_factory=list)


@dataclass
class Result:
    drive: Drive
    records: tuple[int, int] = (0, 0)
    numbers: int = 0
    strings: int = 0
    max_rel: float = 0.0
    max_rel_field: str = ""
    over: int = 0
    text_diffs: int = 0
    shape_diffs: int = 0
    summary_equal: bool = True
    examples: list[str] = field(default_factory=list)
    error: str = ""
    skipped: bool = False

    @property
    def equal(self) -> bool:
        return not (self.error or self.over or self.text_diffs or self.shape_diffs or not self.summary_equal
                    or self.records[0] != self.records[1])


def run(cmd: list[str], cwd: Path, timeout: float = 3600, env: dict | None = None) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} (in {cwd}) exited {r.returncode}:\n{r.stderr[-3000:]}")
    return r


def clean_env() -> dict:
    """The environment without this venv's variables, so that each Python finds its own install."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME")}
    cargo = Path.home() / ".cargo/bin"
    if cargo.is_dir():
        env["PATH"] = f"{cargo}{os.pathsep}{env.get('PATH', '')}"
    return env


def checkout_ref(ref: str, tmp: Path) -> Path:
    wt = tmp / "ref"
    run(["git", "worktree", "add", "--detach", str(wt), ref], cwd=REPO)
    return wt


def install_ref(wt: Path, tmp: Path) -> str:
    """A venv of the ref, with the ref installed from its checkout (its own build backend)."""
    venv = tmp / "venv"
    run([sys.executable, "-m", "venv", str(venv)], cwd=tmp)
    py = str(venv / "bin/python")
    print(f"equivalence: installing {wt} into {venv} (its build backend; a few minutes)", file=sys.stderr)
    run([py, "-m", "pip", "install", "--quiet", str(wt)], cwd=tmp, timeout=3600, env=clean_env())
    return py


def place_extension(py: str, wt: Path, tmp: Path) -> None:
    """Copy the ref's compiled core (soilocp._core, built by its install) into its checkout: the ref's
    commands run in the checkout, where the source folder soilocp/_core/ (the crate) would otherwise
    be imported as an empty namespace package in place of the extension."""
    origin = run([py, "-c", "import soilocp._core as c; print(c.__file__ or '')"], cwd=tmp, env=clean_env()).stdout.strip()
    if origin.endswith(".so") and not (wt / "soilocp" / Path(origin).name).exists():
        shutil.copy2(origin, wt / "soilocp" / Path(origin).name)


SIMULATE_VARIANTS = r"""
import sys
from pathlib import Path
from soilocp.sim.variants import list_variants
out, duration = Path(sys.argv[1]), (float(sys.argv[2]) if sys.argv[2] != "none" else None)
for v in list_variants():
    with open(out / f"variant-{v.name}.jsonl", "w") as fh:
        for sample, _ in v.simulate(0, duration=duration):
            fh.write(sample.model_dump_json() + "\n")
    print(v.name)
"""

COUNT_VARIANTS = "from soilocp.sim.variants import list_variants; print(len(list_variants()))"
LIST_SCENARIOS = "from soilocp.sim.scenarios import list_scenarios\nfor s in list_scenarios(): print(s.name)"


def make_drives(py: str, cwd: Path, inputs: Path, duration: float | None, jobs: int) -> list[Drive]:
    """Simulate every sensor log once, with the given (the ref's) interpreter."""
    env = clean_env()
    dur = [] if duration is None else ["--duration", str(duration)]
    scenarios = run([py, "-c", LIST_SCENARIOS], cwd=cwd, env=env).stdout.split()
    sims: list[tuple[list[str], Drive | list[Drive]]] = []
    drives: list[Drive] = []
    for name in scenarios:
        for mode in ("excitation", "cruise"):
            log = inputs / f"scenario-{name}-{mode}.jsonl"
            sims.append(([py, "-m", "soilocp.cli", "simulate", "--scenario", name, "--mode", mode, "--seed", "0",
                          *dur, "--out", str(log)], []))
            drives.append(Drive(f"{name} {mode}", "scenario", log))
            drives.append(Drive(f"{name} {mode} no-comp", "scenario", log, ["--no-compensation"]))
    skid = str(REPO / SKID_VEHICLE)
    for name in SKID_SCENARIOS:
        log = inputs / f"skid-{name}.jsonl"
        sims.append(([py, "-m", "soilocp.cli", "simulate", "--scenario", name, "--mode", "excitation", "--seed", "0",
                      "--vehicle", skid, *dur, "--out", str(log)], []))
        drives.append(Drive(f"skid {name}", "skid-steer", log, ["--vehicle", skid]))
    # a --keep directory's logs are reused (the same ref simulates the same drives)
    todo = [cmd for cmd, _ in sims if not Path(cmd[-1]).is_file()]
    have_variants = len(list(inputs.glob("variant-*.jsonl"))) == int(run([py, "-c", COUNT_VARIANTS], cwd=cwd, env=env).stdout)
    with ThreadPoolExecutor(max(1, jobs)) as ex:
        futures = [ex.submit(run, cmd, cwd, 3600, env) for cmd in todo]
        if not have_variants:
            futures.append(ex.submit(run, [py, "-c", SIMULATE_VARIANTS, str(inputs), str(duration or "none")], cwd, 3600,
                                     env))
        for f in futures:
            f.result()
    for log in sorted(inputs.glob("variant-*.jsonl")):
        drives.append(Drive(log.stem.removeprefix("variant-"), "variant", log))
    guess = WARTHOG / "vehicle-guess.json"
    for log in sorted(WARTHOG.glob("*.jsonl")):
        drives.append(Drive(log.stem, "warthog", log, ["--vehicle", str(guess)]))
    return drives


def estimate(py: str, cwd: Path, drive: Drive, out: Path) -> str:
    """``soilocp estimate`` of one drive; returns its summary line (stderr) without the timing."""
    r = run([py, "-m", "soilocp.cli", "estimate", str(drive.sensors), "--out", str(out), *drive.estimate_args],
            cwd=cwd, env=clean_env())
    line = next((ln for ln in r.stderr.splitlines() if " estimates from " in ln), "")
    # "N estimates from L lines (R rejected) in T s = X samples/s; statuses {...}; observer resets ..."
    head, _, rest = line.partition(" in ")
    return head + ";" + rest.partition(";")[2].rpartition(" -> ")[0]


def _walk(a, b, path: str, res: Result, line: int) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            res.shape_diffs += 1
            _example(res, f"line {line} {path}: keys {sorted(a.keys() ^ b.keys())} on one side only")
        for k in a.keys() & b.keys():
            _walk(a[k], b[k], f"{path}.{k}" if path else k, res, line)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            res.shape_diffs += 1
            _example(res, f"line {line} {path}: {len(a)} vs {len(b)} items")
        for i, (x, y) in enumerate(zip(a, b)):
            _walk(x, y, f"{path}[{i}]", res, line)
    elif isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str) or a is None or b is None:
        res.strings += 1
        if a != b or type(a) is not type(b):
            res.text_diffs += 1
            _example(res, f"line {line} {path}: {a!r} vs {b!r}")
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
        res.numbers += 1
        if a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)):
            return
        name = path.split(".")[-1].split("[")[0]
        rel_tol = FIELD_TOLERANCE.get(name, (REL, ""))[0]
        diff = abs(a - b)
        scale = max(abs(a), abs(b))
        rel = diff / scale if scale > 0 else math.inf
        if rel > res.max_rel:
            res.max_rel, res.max_rel_field = rel, name
        if not diff <= rel_tol * scale + ABS:
            res.over += 1
            _example(res, f"line {line} {path}: {a!r} vs {b!r} (rel {rel:.2e})")
    else:
        res.shape_diffs += 1
        _example(res, f"line {line} {path}: {type(a).__name__} vs {type(b).__name__}")


def _example(res: Result, text: str) -> None:
    if len(res.examples) < 5:
        res.examples.append(text)


def compare(drive: Drive, ref_out: Path, new_out: Path, ref_summary: str, new_summary: str) -> Result:
    res = Result(drive, summary_equal=ref_summary == new_summary)
    if not res.summary_equal:
        _example(res, f"summary: {ref_summary!r} vs {new_summary!r}")
    with open(ref_out) as fa, open(new_out) as fb:
        la, lb = fa.read().splitlines(), fb.read().splitlines()
    res.records = (len(la), len(lb))
    for i, (x, y) in enumerate(zip(la, lb), 1):
        _walk(json.loads(x), json.loads(y), "", res, i)
    return res


def one_drive(drive: Drive, ref_py: str, ref_cwd: Path, outdir: Path, deadline: float = math.inf) -> Result:
    if time.time() > deadline:
        return Result(drive, error="not run: --max-minutes reached", skipped=True)
    stem = drive.name.replace(" ", "_")
    ref_out, new_out = outdir / f"{stem}.ref.jsonl", outdir / f"{stem}.new.jsonl"
    try:
        ref_summary = estimate(ref_py, ref_cwd, drive, ref_out)
        new_summary = estimate(sys.executable, REPO, drive, new_out)
        res = compare(drive, ref_out, new_out, ref_summary, new_summary)
    except Exception as exc:  # one failing drive is a row of the report, not the end of it
        res = Result(drive, error=str(exc)[-400:])
    print(f"equivalence: {drive.group} / {drive.name}: {'equal' if res.equal else 'NOT equal'} "
          f"({res.numbers} numbers, max rel {res.max_rel:.1e})", file=sys.stderr, flush=True)
    return res


def report(results: list[Result], ref: str, elapsed: float) -> str:
    head = ("group", "drive", "records", "numbers", "texts", "max rel diff (field)", "numbers over tol",
            "text diffs", "summary", "verdict")
    rows = []
    for r in results:
        worst = f"{r.max_rel:.1e} ({r.max_rel_field})" if r.max_rel_field else "0"
        recs = f"{r.records[0]}" if r.records[0] == r.records[1] else f"{r.records[0]} vs {r.records[1]}"
        rows.append((r.drive.group, r.drive.name, recs, str(r.numbers), str(r.strings), worst, str(r.over),
                     str(r.text_diffs + r.shape_diffs), "same" if r.summary_equal else "DIFFERS",
                     "equal" if r.equal else ("not run" if r.skipped else "ERROR" if r.error else "DIFFERENT")))
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(head)]
    fmt = lambda row: "| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |"  # noqa: E731
    lines = [fmt(head), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *map(fmt, rows)]
    n_eq = sum(r.equal for r in results)
    n_skip = sum(r.skipped for r in results)
    tot_num = sum(r.numbers for r in results)
    tot_txt = sum(r.strings for r in results)
    worst = max(results, key=lambda r: r.max_rel)
    lines.append("")
    lines.append(f"{ref} vs working tree: {n_eq}/{len(results)} drives equal ({n_skip} not run); {tot_num} numbers and {tot_txt} "
                 f"statuses/reasons/classes/flags compared; largest relative difference {worst.max_rel:.1e} "
                 f"({worst.drive.name}, {worst.max_rel_field or '-'}); tolerance {REL:g} relative + {ABS:g}; "
                 f"{elapsed:.0f} s")
    for r in results:
        for ex in ([r.error] if r.error and not r.skipped else []) + r.examples:
            lines.append(f"  {r.drive.name}: {ex}")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref", default="main", help="git ref to compare the working tree with (default: main)")
    ap.add_argument("--ref-python", help="a Python that already has the ref installed (skips the venv); it is "
                                         "run in the ref's temporary worktree")
    ap.add_argument("--quick", action="store_true", help="8 s simulated drives instead of the scenarios' own")
    ap.add_argument("--jobs", type=int, default=2, help="drives estimated at once (default 2)")
    ap.add_argument("--keep", help="keep the inputs and outputs in this directory")
    ap.add_argument("--only", help="only drives whose group or name contains this text")
    ap.add_argument("--max-minutes", type=float, help="start no drive after this many minutes (the rest are "
                                                      "reported as not run, and the exit status is 1)")
    args = ap.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # so that `finally` removes the worktree
    t0 = time.time()
    tmp = Path(tempfile.mkdtemp(prefix="soilocp-equivalence-"))
    wt = None
    try:
        wt = checkout_ref(args.ref, tmp)
        ref_py = args.ref_python or install_ref(wt, tmp)
        place_extension(ref_py, wt, tmp)
        work = Path(args.keep) if args.keep else tmp / "work"
        (work / "inputs").mkdir(parents=True, exist_ok=True)
        (work / "outputs").mkdir(parents=True, exist_ok=True)
        print("equivalence: simulating the drives with the ref's code", file=sys.stderr)
        drives = make_drives(ref_py, wt, work / "inputs", 8.0 if args.quick else None, args.jobs)
        if args.only:
            drives = [d for d in drives if args.only in d.group or args.only in d.name]
        print(f"equivalence: {len(drives)} drives through both checkouts", file=sys.stderr)
        deadline = t0 + 60 * args.max_minutes if args.max_minutes else math.inf
        # the groups interleaved, so that a time budget still samples every group
        by_group: dict[str, list[Drive]] = {}
        for d in drives:
            by_group.setdefault(d.group, []).append(d)
        order = [d for i in range(len(drives)) for g in by_group.values() if i < len(g) for d in [g[i]]]
        with ThreadPoolExecutor(max(1, args.jobs)) as ex:
            done = dict(zip(map(id, order), ex.map(lambda d: one_drive(d, ref_py, wt, work / "outputs", deadline), order)))
        results = [done[id(d)] for d in drives]
        print(report(results, args.ref, time.time() - t0))
        return 0 if all(r.equal for r in results) else 1
    finally:
        if wt is not None:
            subprocess.run(["git", "worktree", "remove", "--force", str(wt)], cwd=REPO, capture_output=True)
            subprocess.run(["git", "worktree", "prune"], cwd=REPO, capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
