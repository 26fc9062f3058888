#!/usr/bin/env bash
# Instructions per sample of the offline chain (soilocp.estimation.estimate.estimate_lines), counted by
# valgrind's callgrind: a figure that does not depend on how busy the machine is.
# Ir(n = N2 samples) - Ir(n = N1 samples), divided by N2 - N1: start-up and imports cancel out.  The two totals
# (~1.4e9 each) vary by a few 1e6 from run to run, so N2 - N1 must be ~1000 for a figure good to ~1 %
# (with 100 it swings by +-10 %).
#   scripts/instructions_per_sample.sh [PYTHON] [N1] [N2]      (default .venv/bin/python 200 1200)
set -euo pipefail
PY=${1:-.venv/bin/python}; N1=${2:-200}; N2=${3:-1200}
DRIVE=$(mktemp --suffix=.jsonl)
trap 'rm -f "$DRIVE"' EXIT
"$PY" - "$DRIVE" "$N2" <<'PYEOF'
import sys
from soilocp.services.bench.stages import simulate_drive
n = int(sys.argv[2])
with open(sys.argv[1], "w") as fh:
    fh.write("\n".join(s.model_dump_json() for s in simulate_drive("bench", n / 100.0 + 1.0)[:n]))
PYEOF
ir() {
  valgrind --tool=callgrind --callgrind-out-file=/dev/null "$PY" -c "
import sys
from soilocp.estimation.estimate import estimate_lines
from soilocp.estimation.pipeline import PipelineConfig
lines = open('$DRIVE').read().splitlines()[:$1]
sum(1 for _ in estimate_lines(lines, PipelineConfig()))" 2>&1 | grep -o "Collected : [0-9]*" | awk '{print $3}'
}
A=$(ir "$N1"); B=$(ir "$N2")
echo "instructions per sample: $(( (B - A) / (N2 - N1) ))  (Ir $A for $N1 samples, $B for $N2)"
