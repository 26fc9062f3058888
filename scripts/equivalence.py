#!/usr/bin/env python3
"""Equivalence of two checkouts of soilocp, shown on every drive the product is judged on (a port or a
refactoring must keep the records): the same sensor logs go through ``soilocp estimate`` of a git ref (default ``main``, checked
out in a temporary ``git worktree`` and installed in its own venv) and of this working tree, and
every output record is compared field by field.

    scripts/equivalence.py                       # main vs the working tree, full drives
    scripts/equivalence.py --ref HEAD~3 --quick  # 8 s drives: a fast check while porting
    scripts/equivalence.py --ref-python /tmp/main/.venv/bin/python   # reuse an env of the ref
    scripts/equivalence.py --keep /tmp/eq --max-minutes 60            # reuse inputs; a time budget
    scripts/equivalence.py --record /work/eq-baseline                 # record this checkout's outputs once
    scripts/equivalence.py --against /work/eq-baseline                # the working tree vs a recording

A recording (``--record DIR``) holds the sensor logs it was made from (``inputs/``), one gzip-compressed
JSONL of ``soilocp estimate`` per drive (``outputs/``) and ``manifest.json`` (the commit, the tree of
``soilocp/`` at it, each drive's arguments, summary line and the SHA-256 of its input).  ``--against DIR``
estimates the same inputs with the working tree and compares within the per-field tolerances of
RECORDED_TOLERANCE instead of bit for bit, and lists every change of status or reason code with its
count: the recording replaces a second install of an older ref once the estimator stops reproducing
the old rounding.

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


# --- a recording of one checkout's outputs, and the working tree compared against it ------------------

#: field -> (relative tolerance, absolute tolerance, why), for ``--against``.  A field not named here
#: takes RECORDED_DEFAULT.  The tolerances allow what a change of floating-point evaluation order (a
#: sum in another order, libm's exp for numpy's, a fused multiply-add) leaves after a whole drive, and
#: no more: a change of a setting's value or of the math shows far above them.
RECORDED_DEFAULT: tuple[float, float, str] = (
    1e-6, 1e-9, "last-bit differences of a reordered sum, carried and amplified by the observer's and the "
    "grid's recursions over a drive (about 1e3 x the 1e-12 of one step at most), with margin")
RECORDED_TOLERANCE: dict[str, tuple[float, float, str]] = {
    # the posterior's median and band on the ln K grid: interpolated between grid nodes, so a change in the
    # belief of 1e-9 moves them continuously, but a node's weight near a tie may move the interpolation's
    # bracket; a 1e-4 relative error in K is 100x below anything the accuracy table prints
    **{f: (1e-4, 1e-9, "posterior quantiles on the ln K grid: continuous in the belief, but bracketed by "
                       "grid nodes; 1e-4 of K is 100x below the accuracy table's printed digit")
       for f in ("k", "k_low", "k_high", "K", "K_low", "K_high", "log_k_sigma", "k_sigma")},
    # confidences and probabilities near 0 and 1 (sums of exponentials of a log-belief): compared absolutely
    **{f: (1e-6, 1e-6, "a probability: 1e-6 absolute is far below any threshold it is compared with")
       for f in ("confidence", "class_confidence", "change_probability", "p_change")},
}
STATUS_FIELDS = ("status", "reason_code")


def _tolerance(name: str) -> tuple[float, float, str]:
    return RECORDED_TOLERANCE.get(name, RECORDED_DEFAULT)


def git_out(*args: str) -> str:
    r = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True)
    return r.stdout.strip() if r.returncode == 0 else ""


def sha256(path: Path) -> str:
    import hashlib
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _localise(drive: Drive, inputs: Path, root: Path) -> dict:
    """The drive as the manifest holds it: every file it reads (log, vehicle file) copied under
    ``inputs`` and named relative to the recording's root, so that the recording stands alone."""
    def local(path: Path) -> str:
        path = Path(path)
        if root not in path.resolve().parents:
            dest = inputs / (f"{drive.group}-{path.name}" if drive.group == "warthog" or path.suffix == ".json"
                             else path.name)
            if not dest.exists():
                shutil.copy2(path, dest)
            path = dest
        return str(path.resolve().relative_to(root.resolve()))
    args = list(drive.estimate_args)
    for i, a in enumerate(args[:-1]):
        if a == "--vehicle":
            args[i + 1] = local(Path(args[i + 1]))
    sensors = local(drive.sensors)
    return {"name": drive.name, "group": drive.group, "sensors": sensors,
            "sensors_sha256": sha256(root / sensors), "estimate_args": args}


def record(root: Path, duration: float | None, jobs: int, only: str | None) -> int:
    """Record this checkout's outputs of every drive under ``root`` (see the module's doc)."""
    import gzip
    t0 = time.time()
    inputs, outputs = root / "inputs", root / "outputs"
    inputs.mkdir(parents=True, exist_ok=True)
    outputs.mkdir(parents=True, exist_ok=True)
    print(f"equivalence: recording {REPO} into {root}", file=sys.stderr)
    drives = make_drives(sys.executable, REPO, inputs, duration, jobs)
    if only:
        drives = [d for d in drives if only in d.group or only in d.name]
    entries = [_localise(d, inputs, root) for d in drives]

    def one(entry: dict) -> dict:
        stem = entry["name"].replace(" ", "_")
        tmp_out = outputs / f"{stem}.jsonl"
        d = Drive(entry["name"], entry["group"], root / entry["sensors"],
                  [str(root / a) if a.startswith("inputs/") else a for a in entry["estimate_args"]])
        summary = estimate(sys.executable, REPO, d, tmp_out)
        with open(tmp_out, "rb") as src, gzip.open(outputs / f"{stem}.jsonl.gz", "wb", compresslevel=6) as dst:
            data = src.read()
            dst.write(data)
        tmp_out.unlink()
        print(f"equivalence: recorded {entry['group']} / {entry['name']}", file=sys.stderr, flush=True)
        return {**entry, "output": f"outputs/{stem}.jsonl.gz", "records": data.count(b"\n"), "summary": summary}

    with ThreadPoolExecutor(max(1, jobs)) as ex:
        recorded = list(ex.map(one, entries))
    manifest = {
        "commit": git_out("rev-parse", "HEAD"),
        "soilocp_tree": git_out("rev-parse", "HEAD:soilocp"),
        "uncommitted": git_out("status", "--porcelain", "--", "soilocp", "pyproject.toml").splitlines(),
        "duration": duration, "python": sys.version.split()[0],
        "recorded_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "seconds": round(time.time() - t0),
        "drives": recorded,
    }
    (root / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    print(f"equivalence: {len(recorded)} drives recorded in {time.time() - t0:.0f} s at {manifest['commit'][:9]}",
          file=sys.stderr)
    return 0


@dataclass
class Against:
    """One drive of the working tree against its recording."""
    entry: dict
    records: tuple[int, int] = (0, 0)
    numbers: int = 0
    over: int = 0
    shape_diffs: int = 0
    worst: dict = field(default_factory=dict)   # field -> largest |a - b| / (rel tol * scale + abs tol)
    transitions: dict = field(default_factory=dict)  # (field, old, new) -> count
    examples: list[str] = field(default_factory=list)
    error: str = ""

    @property
    def status_changes(self) -> int:
        return sum(self.transitions.values())

    @property
    def verdict(self) -> str:
        if self.error:
            return "ERROR"
        if self.over or self.shape_diffs or self.records[0] != self.records[1]:
            return "OUTSIDE"
        return "within" + (" (statuses differ)" if self.status_changes else "")


def _walk_tol(a, b, path: str, res: Against, line: int, skip_numbers: bool) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            res.shape_diffs += 1
            _ex(res, f"line {line} {path}: keys {sorted(a.keys() ^ b.keys())} on one side only")
        for k in sorted(a.keys() & b.keys()):
            _walk_tol(a[k], b[k], f"{path}.{k}" if path else k, res, line, skip_numbers)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            res.shape_diffs += 1
            _ex(res, f"line {line} {path}: {len(a)} vs {len(b)} items")
        for i, (x, y) in enumerate(zip(a, b)):
            _walk_tol(x, y, f"{path}[{i}]", res, line, skip_numbers)
    elif (isinstance(a, (int, float)) and not isinstance(a, bool)
          and isinstance(b, (int, float)) and not isinstance(b, bool)):
        res.numbers += 1
        if skip_numbers or a == b or (math.isnan(a) and math.isnan(b)):
            return
        name = path.split(".")[-1].split("[")[0]
        rel, ab, _ = _tolerance(name)
        allowed = rel * max(abs(a), abs(b)) + ab
        ratio = abs(a - b) / allowed
        if ratio > res.worst.get(name, 0.0):
            res.worst[name] = ratio
        if ratio > 1:
            res.over += 1
            _ex(res, f"line {line} {path}: {a!r} vs {b!r} ({ratio:.1f} x its tolerance)")
    elif a != b or type(a) is not type(b):
        name = path.split(".")[-1]
        if name in STATUS_FIELDS or skip_numbers:
            return  # counted as a status change by the caller; the record's other texts follow its status
        res.shape_diffs += 1
        _ex(res, f"line {line} {path}: {a!r} vs {b!r}")


def _ex(res: Against, text: str) -> None:
    if len(res.examples) < 5:
        res.examples.append(text)


def _statuses(rec, prefix: str = "") -> dict[str, object]:
    """The status and reason code fields of a record, at any depth (a record may nest the soil's)."""
    out: dict[str, object] = {}
    if isinstance(rec, dict):
        for k, v in rec.items():
            p = f"{prefix}.{k}" if prefix else k
            if k in STATUS_FIELDS and not isinstance(v, (dict, list)):
                out[p] = v
            elif isinstance(v, dict):
                out.update(_statuses(v, p))
    return out


def against_one(root: Path, entry: dict, outdir: Path) -> Against:
    import gzip
    res = Against(entry)
    try:
        sensors = root / entry["sensors"]
        if sha256(sensors) != entry["sensors_sha256"]:
            raise RuntimeError(f"{sensors} is not the log the recording was made from (SHA-256 differs)")
        d = Drive(entry["name"], entry["group"], sensors,
                  [str(root / a) if a.startswith("inputs/") else a for a in entry["estimate_args"]])
        new_out = outdir / (entry["name"].replace(" ", "_") + ".jsonl")
        estimate(sys.executable, REPO, d, new_out)
        with gzip.open(root / entry["output"], "rt") as fa, open(new_out) as fb:
            la, lb = fa.read().splitlines(), fb.read().splitlines()
        res.records = (len(la), len(lb))
        for i, (x, y) in enumerate(zip(la, lb), 1):
            a, b = json.loads(x), json.loads(y)
            sa, sb = _statuses(a), _statuses(b)
            changed = False
            for k in sa.keys() | sb.keys():
                if sa.get(k) != sb.get(k):
                    changed = True
                    key = (k, sa.get(k), sb.get(k))
                    res.transitions[key] = res.transitions.get(key, 0) + 1
            # a record whose status changed: its numbers follow the new status (K held or withdrawn), so
            # they are reported by the status change, not compared
            _walk_tol(a, b, "", res, i, skip_numbers=changed)
    except Exception as exc:  # one failing drive is a row of the report, not the end of it
        res.error = str(exc)[-400:]
    print(f"equivalence: {entry['group']} / {entry['name']}: {res.verdict}", file=sys.stderr, flush=True)
    return res


def against_report(results: list[Against], manifest: dict, elapsed: float) -> str:
    head = ("group", "drive", "records", "numbers", "worst field (x tol)", "over tol", "status changes", "verdict")
    rows = []
    for r in results:
        wf = max(r.worst, key=r.worst.get) if r.worst else ""
        recs = f"{r.records[0]}" if r.records[0] == r.records[1] else f"{r.records[0]} vs {r.records[1]}"
        rows.append((r.entry["group"], r.entry["name"], recs, str(r.numbers),
                     f"{wf} ({r.worst[wf]:.2g})" if wf else "-", str(r.over), str(r.status_changes), r.verdict))
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(head)]
    fmt = lambda row: "| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |"  # noqa: E731
    lines = [fmt(head), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *map(fmt, rows), ""]
    n_in = sum(r.verdict.startswith("within") for r in results)
    n_rec = sum(r.records[1] for r in results)
    lines.append(f"working tree vs the recording of {manifest['commit'][:9]}: {n_in}/{len(results)} drives within "
                 f"tolerance; {sum(r.numbers for r in results)} numbers over {n_rec} records; "
                 f"{sum(r.status_changes for r in results)} status/reason changes; {elapsed:.0f} s")
    total: dict = {}
    for r in results:
        for k, n in r.transitions.items():
            total[k] = total.get(k, 0) + n
    if total:
        lines.append("status and reason changes (field: recorded -> now: records, drives):")
        for (f, old, new), n in sorted(total.items(), key=lambda kv: -kv[1]):
            drives = [r.entry["name"] for r in results if (f, old, new) in r.transitions]
            lines.append(f"  {f}: {old} -> {new}: {n} records in {len(drives)} drives ({', '.join(drives[:6])}"
                         f"{', ...' if len(drives) > 6 else ''})")
    worst: dict[str, float] = {}
    for r in results:
        for k, v in r.worst.items():
            worst[k] = max(worst.get(k, 0.0), v)
    if worst:
        lines.append("largest difference per field, in units of its tolerance (rel, abs):")
        for k, v in sorted(worst.items(), key=lambda kv: -kv[1])[:15]:
            rel, ab, _ = _tolerance(k)
            lines.append(f"  {k}: {v:.3g} x ({rel:g}, {ab:g})")
    for r in results:
        for ex in ([r.error] if r.error else []) + r.examples:
            lines.append(f"  {r.entry['name']}: {ex}")
    return "\n".join(lines)


def against(root: Path, jobs: int, only: str | None, keep: str | None) -> int:
    t0 = time.time()
    manifest = json.loads((root / "manifest.json").read_text())
    entries = [e for e in manifest["drives"] if not only or only in e["group"] or only in e["name"]]
    outdir = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="soilocp-against-"))
    outdir.mkdir(parents=True, exist_ok=True)
    try:
        with ThreadPoolExecutor(max(1, jobs)) as ex:
            results = list(ex.map(lambda e: against_one(root, e, outdir), entries))
    finally:
        if not keep:
            shutil.rmtree(outdir, ignore_errors=True)
    print(against_report(results, manifest, time.time() - t0))
    return 0 if all(r.verdict.startswith("within") for r in results) else 1


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
    ap.add_argument("--record", metavar="DIR", help="record this checkout's inputs and outputs of every drive in DIR "
                                                    "(no ref, no comparison)")
    ap.add_argument("--against", metavar="DIR", help="compare the working tree with the recording in DIR, within "
                                                     "RECORDED_TOLERANCE, listing every status change")
    args = ap.parse_args()
    if args.record:
        return record(Path(args.record).resolve(), 8.0 if args.quick else None, args.jobs, args.only)
    if args.against:
        return against(Path(args.against).resolve(), args.jobs, args.only, args.keep)
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
