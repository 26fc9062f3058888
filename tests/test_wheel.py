"""The wheel: ``maturin build --release`` makes one abi3 wheel that installs, without extras and without a
Rust toolchain, into a clean virtual environment, where ``soilocp estimate`` runs and a command that needs
an extra says which one.  Prints the install's size and distributions (the lean install's measure)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NETWORK_ERRORS = ("Could not find a version", "No matching distribution", "Failed to establish a new connection",
                  "Temporary failure in name resolution", "Network is unreachable", "ConnectionError")


def _wheel(tmp: Path) -> Path:
    """``SOILOCP_WHEEL`` when set (a wheel built beforehand), else ``maturin build --release`` now (cargo's
    target/ of the editable install makes it incremental)."""
    given = os.environ.get("SOILOCP_WHEEL")
    if given:
        return Path(given)
    maturin = Path(sys.executable).parent / "maturin"
    if not maturin.exists():
        pytest.fail("maturin is not installed in this environment: pip install -e '.[test]' (make setup)")
    out = tmp / "dist"
    r = subprocess.run([str(maturin), "build", "--release", "--out", str(out)], cwd=ROOT, capture_output=True,
                       text=True, timeout=1500)
    assert r.returncode == 0, r.stderr[-3000:]
    (wheel,) = out.glob("soilocp-*.whl")
    return wheel


def _site_size(venv: Path) -> tuple[float, int]:
    (site,) = venv.glob("lib/python*/site-packages")
    total = sum(p.stat().st_size for p in site.rglob("*") if p.is_file() and not p.is_symlink())
    return total / 1e6, sum(1 for _ in site.glob("*.dist-info"))


@pytest.mark.e2e
@pytest.mark.timeout(1800)
def test_abi3_wheel_installs_lean_and_estimates(tmp_path):
    wheel = _wheel(tmp_path)
    assert "-cp311-abi3-" in wheel.name, wheel.name
    names = zipfile.ZipFile(wheel).namelist()
    assert "soilocp/_core.abi3.so" in names and not any(n.startswith("soilocp/_core/") for n in names)
    tops = sorted({n.split("/")[0] for n in names if not n.split("/")[0].endswith((".dist-info", ".data"))})
    print(f"\nwheel {wheel.name}: {wheel.stat().st_size / 1e6:.1f} MB; top-level import names {tops}")
    assert tops == ["soilocp"], f"the wheel installs import names other than the project's own: {tops}"
    assert "soilocp/services/fleet/dashboard/static/index.html" in names and "soilocp/schemas/sensor.py" in names
    venv = tmp_path / "clean"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    base_mb, base_n = _site_size(venv)
    pip = subprocess.run([str(venv / "bin" / "pip"), "install", "--quiet", str(wheel)], capture_output=True,
                         text=True, timeout=900, env={**os.environ, "PATH": "/usr/bin:/bin"})  # no cargo on PATH
    if pip.returncode != 0 and any(e in pip.stderr for e in NETWORK_ERRORS):
        pytest.skip("the package index cannot be reached: " + pip.stderr.strip().splitlines()[-1])
    assert pip.returncode == 0, pip.stderr[-3000:]
    mb, n = _site_size(venv)
    listed = json.loads(subprocess.run([str(venv / "bin" / "pip"), "list", "--format", "json"], capture_output=True,
                                       text=True, check=True).stdout)
    print(f"clean venv + wheel without extras: {mb - base_mb:.0f} MB in site-packages, {n - base_n} distributions: "
          + ", ".join(sorted(d["name"] for d in listed if d["name"] not in ("pip", "setuptools"))))
    soilocp = str(venv / "bin" / "soilocp")
    env = {**os.environ, "PATH": f"{venv / 'bin'}:/usr/bin:/bin"}
    for args in (["simulate", "--scenario", "sand", "--duration", "6", "--out", "s.jsonl", "--truth", "t.jsonl"],
                 ["estimate", "s.jsonl", "--out", "e.jsonl"]):
        r = subprocess.run([soilocp, *args], cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
        assert r.returncode == 0, r.stderr[-3000:]
    recs = [json.loads(x) for x in (tmp_path / "e.jsonl").read_text().splitlines()]
    assert len(recs) == 600 and any(x["status"] == "ok" for x in recs)
    r = subprocess.run([soilocp, "plot", "--estimates", "e.jsonl", "--out", "plots"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 1 and "pip install 'soilocp[plot]'" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([str(venv / "bin" / "python"), "-c", "import soilocp; print(len(soilocp.estimate('s.jsonl')))"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0 and r.stdout.strip() == "600", r.stderr[-2000:]
