#!/usr/bin/env bash
# Every GPU figure docs/BENCHMARKS.md asks for, on one GPU machine, in under 8 minutes, into one CSV:
# the Hough detectors (sync and async), the RoboBee closed loop, the snake env with the mjx backend
# at batches up to 4,096, and the sweep engine's trials/s (in one process, and as Ray tasks).
#
#   benchmarks/gpu.sh [OUT_DIR]          (default results/gpu; writes OUT_DIR/gpu.csv and each bench's CSV)
#
# A dry run on a CPU checks the script itself at small sizes: CPU_DRY_RUN=1 TRIALS=2 SWEEP_SEEDS=4
# STEPS="sweep" benchmarks/gpu.sh /tmp/gpu (no install, no GPU asked for).
#
# It installs what it needs first: from the wheels in $WHEELS (a folder, for a machine without a
# package registry) when set, else from the registry: this checkout without its pins (the machine's
# JAX with CUDA is kept), MuJoCo, MJX, MJX-Warp, Brax, Ray, and the peers the benchmarks compare with.
# Each step has its own time limit, so one that hangs costs only its share of the 8 minutes.
set -uo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$ROOT/results/gpu}"
PY="${PYTHON:-python3}"
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
cd "$ROOT"
LOG="$OUT/gpu.log"
: >"$LOG"
began=$SECONDS
TRIALS="${TRIALS:-4096}"
SWEEP_SEEDS="${SWEEP_SEEDS:-8192}"
STEPS="${STEPS:-hough robobee snake sweep}"

step() {  # step SECONDS NAME COMMAND...: run it with a limit, note how it ended
    local limit=$1 name=$2
    shift 2
    echo "== $name (limit ${limit}s, at $((SECONDS - began))s)" | tee -a "$LOG"
    timeout "$limit" "$@" >>"$LOG" 2>&1
    local rc=$?
    echo "$name,$rc,$((SECONDS - began))" >>"$OUT/steps.csv"
    [ $rc -eq 0 ] || echo "   $name ended with status $rc (see $LOG)" | tee -a "$LOG"
}

echo "step,status,at_s" >"$OUT/steps.csv"

# Time limits (s): install 90, hough 75, robobee 75, snake 120, sweep 90: 450 s, under 8 minutes with the checks.
# ---------------------------------------------------------------- 1. install
MUJOCO_VERSION="$("$PY" -c 'import mujoco; print(mujoco.__version__)' 2>/dev/null || echo 4.0.0)"
PACKAGES=(
    "mujoco==$MUJOCO_VERSION" "mujoco-mjx==$MUJOCO_VERSION" "mujoco-warp==$MUJOCO_VERSION" warp-lang
    "brax>=0.12,<0.15" "ray>=2.40,<3" "optax>=0.2.4,<0.3" "tqdm>=4.66,<5"
    "scikit-image>=0.22,<0.26" "opencv-python-headless>=4.8,<5" "brian2>=2.7,<2.10"
)
if [ -n "${CPU_DRY_RUN:-}" ]; then
    echo "dry run: nothing installed" | tee -a "$LOG"
elif [ -n "${WHEELS:-}" ]; then
    step 90 install "$PY" -m pip install -q --no-index --no-deps --no-compile --target /tmp/site "$WHEELS"/*.whl
    export PYTHONPATH="/tmp/site:${PYTHONPATH:-}"
else
    step 90 install "$PY" -m pip install -q "${PACKAGES[@]}"
fi
# The checkout itself, without its dependency pins (they are for Python 3.11 machines).
export PYTHONPATH="$ROOT:${PYTHONPATH:-}"
export PYTHONUNBUFFERED=1 MUJOCO_GL=egl CI=true
"$PY" - <<'EOF' 2>&1 | tee -a "$LOG"
import jax
print("machine:", jax.devices(), "jax", jax.__version__)
import os
assert os.environ.get("CPU_DRY_RUN") or jax.default_backend() == "gpu", "no GPU seen by JAX: these would be CPU figures"
EOF
[ "${PIPESTATUS[0]}" -eq 0 ] || { echo "no GPU: stopping" | tee -a "$LOG"; exit 1; }

# ---------------------------------------------------------------- 2. the benchmarks
wanted() { [[ " $STEPS " == *" $1 "* ]]; }
wanted hough && step 75 hough "$PY" -m spikejax.cli bench hough --trials "$TRIALS" --repeats 3 --out "$OUT/hough" --no-progress
wanted robobee && step 75 robobee "$PY" -m spikejax.cli bench robobee --trials "$TRIALS" --repeats 2 --duration 0.5 \
    --no-network --out "$OUT/robobee" --no-progress
wanted snake && step 120 snake "$PY" -m spikejax.cli bench snake --trials "$TRIALS" --repeats 2 --out "$OUT/snake" --no-progress
wanted sweep && step 90 sweep "$PY" - "$OUT/sweep" "$SWEEP_SEEDS" <<'EOF'
"""The sweep engine's trials/s on the gait sweep: in this process, then as Ray tasks (one GPU a task).

The cluster is started and each side run once on a few seeds first, so that the timed runs count
neither the cluster's start nor the workers' (their compilation is counted apart, compile_s).
"""
import json, sys, time
from pathlib import Path
from spikejax.benchmarking import write_csv
from spikejax.sweep import cluster, load_sweep, run_sweep

out, seeds = Path(sys.argv[1]), int(sys.argv[2])
cluster.connect(True)
rows = []
for where in ("local", "ray"):
    run_sweep(load_sweep("sweeps/gait_convergence.toml", seeds=2), out / f"{where}-warm-up", progress=False,
              ray=where == "ray", compile_cache=out / "cache")
    spec = load_sweep("sweeps/gait_convergence.toml", seeds=seeds)
    began = time.perf_counter()
    run_sweep(spec, out / where, progress=False, ray=where == "ray", compile_cache=out / "cache")
    wall = time.perf_counter() - began
    run = json.loads((out / where / "metadata.json").read_text())["runs"][-1]
    rows.append({"where": where, "trials": spec.n_trials, "chunk": spec.chunk_size, "wall_s": round(wall, 3),
                 "compile_s": run["compile_seconds"],
                 "trials_per_s": round(spec.n_trials / max(wall - run["compile_seconds"], 1e-9), 1)})
    print(rows[-1], flush=True)
cluster.disconnect()
write_csv(out / "sweep.csv", rows, list(rows[0]))
EOF

# ---------------------------------------------------------------- 3. one CSV
"$PY" - "$OUT" <<'EOF' 2>&1 | tee -a "$LOG"
"""Every bench's CSV in one, a column naming the bench; the steps' statuses appended."""
import csv, sys
from pathlib import Path

out = Path(sys.argv[1])
rows, columns = [], ["bench"]
for path in sorted(out.glob("*/*.csv")) + [out / "steps.csv"]:
    with open(path, newline="") as file:
        for row in csv.DictReader(file):
            rows.append({"bench": path.stem if path.parent != out else "steps", **row})
            columns += [c for c in row if c not in columns]
with open(out / "gpu.csv", "w", newline="") as file:
    writer = csv.DictWriter(file, fieldnames=columns, restval="")
    writer.writeheader()
    writer.writerows(rows)
print(f"{out / 'gpu.csv'}: {len(rows)} rows")
EOF
echo "done in $((SECONDS - began)) s" | tee -a "$LOG"
