# Quick start targets: each sets up .venv/ itself on a fresh machine (Python 3.11+).
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed

.PHONY: demo test test-all setup clean

# the compiled core (a Rust crate built by maturin, the build backend): editing it rebuilds the install
CORE_SRC := $(wildcard soilocp/_core/Cargo.toml soilocp/_core/Cargo.lock soilocp/_core/src/*.rs soilocp/_core/src/*/*.rs)

$(STAMP): pyproject.toml $(CORE_SRC)
	@command -v cargo >/dev/null || { echo "building soilocp needs a Rust toolchain (cargo, rustc >= 1.74): see README, Building from source"; exit 1; }
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[test]"
	touch $(STAMP)

setup: $(STAMP)

## The main job: a simulated rover through the router and all five services, live on screen.
demo: $(STAMP)
	$(BIN)/soilocp run --synthetic mixed --duration 40

## The whole test suite.
test: $(STAMP)
	$(BIN)/python -m pytest -q -ra

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis soilocp/_core/target soilocp/_core.*.so
