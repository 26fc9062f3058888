# Quick start targets: each sets up .venv/ itself on a fresh machine (Python 3.11+).
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed

.PHONY: demo test test-all setup clean

# the compiled core (a Rust crate built by maturin, the build backend): editing it rebuilds the install
CORE_SRC := $(wildcard soilocp/_core/Cargo.toml soilocp/_core/Cargo.lock soilocp/_core/src/*.rs soilocp/_core/src/*/*.rs)

CORE_STAMP := $(VENV)/.installed-core
NEED_CARGO = @command -v cargo >/dev/null || { echo "building soilocp needs a Rust toolchain (cargo, rustc >= 1.74): see README, Building from source"; exit 1; }

# the whole development install: soilocp with every extra and the test tools (pytest, mkdocs, ...).
# A core built before abi3 (soilocp/_core.cpython-*.so) would shadow the new soilocp/_core.abi3.so: removed.
$(STAMP): pyproject.toml $(CORE_SRC)
	$(NEED_CARGO)
	@echo "make: installing soilocp with every extra and the test tools into $(VENV)/ (editable; builds the Rust core)"
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	rm -f soilocp/_core.*.so
	$(BIN)/pip install --quiet -e ".[test]"
	touch $(STAMP) $(CORE_STAMP)

# what the demo needs: soilocp with its core dependencies only (no test tools, no extras)
$(CORE_STAMP): pyproject.toml $(CORE_SRC)
	$(NEED_CARGO)
	@echo "make demo: installing soilocp (core dependencies only: numpy, scipy, pydantic, zenoh, click, rich, rosbags, mcap, pyyaml) into $(VENV)/;"
	@echo "           the first time this downloads ~100 MB and compiles the Rust core (a few minutes on 2 cores)"
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	rm -f soilocp/_core.*.so
	$(BIN)/pip install --progress-bar on -e .
	touch $(CORE_STAMP)

setup: $(STAMP)

## The main job: a simulated rover through the router and all five services, live on screen.
demo: $(CORE_STAMP)
	@echo "make demo: soilocp run --synthetic mixed --duration 40 (a rover over sand, gravel, grass and firm soil; Ctrl-C stops it)"
	$(BIN)/soilocp run --synthetic mixed --duration 40

## The whole test suite.
test: $(STAMP)
	$(BIN)/python -m pytest -q -ra

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis soilocp/_core/target soilocp/_core.*.so
