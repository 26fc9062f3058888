"""The compiled core's own checks: `cargo fmt --check`, `cargo clippy -D warnings` and `cargo test`
(the Rust unit tests hold each kernel to the test vectors of docs/method.md)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

CRATE = Path(__file__).resolve().parents[1] / "soilocp" / "_core"
CARGO = shutil.which("cargo") or (str(Path.home() / ".cargo/bin/cargo") if (Path.home() / ".cargo/bin/cargo").exists() else None)

pytestmark = pytest.mark.skipif(CARGO is None, reason="cargo is not installed: the Rust checks need a Rust toolchain")


def _cargo(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, CARGO_TERM_COLOR="never")
    env["PATH"] = f"{Path(CARGO).parent}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run([CARGO, *args], cwd=CRATE, env=env, capture_output=True, text=True, timeout=900)


def test_cargo_fmt_is_clean():
    r = _cargo("fmt", "--check")
    assert r.returncode == 0, f"cargo fmt --check:\n{r.stdout}\n{r.stderr}"


def test_cargo_clippy_has_no_warnings():
    r = _cargo("clippy", "--all-targets", "--", "-D", "warnings")
    assert r.returncode == 0, f"cargo clippy:\n{r.stderr[-5000:]}"


def test_cargo_test_passes():
    r = _cargo("test")
    assert r.returncode == 0, f"cargo test:\n{r.stdout[-5000:]}\n{r.stderr[-3000:]}"
    passed = [int(m) for m in re.findall(r"test result: ok\. (\d+) passed", r.stdout)]
    assert sum(passed) > 0, f"cargo test ran no test:\n{r.stdout[-2000:]}"
