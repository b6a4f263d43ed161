#!/usr/bin/env bash
# Every GPU check in one go, for a machine with an NVIDIA GPU (a lent one is held for minutes only):
#   1. the CPU/CUDA parity cases of tests/cuda_parity.py, in parallel (each compiles its own kernels),
#      checked against the tolerances of tests/test_cuda.py;
#   2. 200 steps on the GPU against 200 on the CPU (tests/test_cuda.py::test_long_gpu_run...);
#   3. the GPU benchmark (sph bench --backend cuda): float32 with lists and with the cell walk, float64
#      with lists, STEPS steps (default 100) per case; then float32 at the smallest size with the other
#      cell size (run.cells_per_support): lists with cells of H, the walk with cells of H / 2 (the
#      defaults are H / 2 with lists, H with the walk, measured just before);
#   4. what a kernel launch costs the host (scripts/investigations/launch_overhead.py);
#   5. the largest run that fits (BIG particles, default 300 M, walking; BIG=0 skips it);
#   6. two peer processes sharing the GPU against one, at PEERS_SIZE particles (default 4 M; 0 skips),
#      and the two peers again with decomposition.overlap = false (what overlapping the halo gains);
#   7. the same scene on all CPU cores for the ratio (CPU_BENCH=0 skips it).
#
#   bash scripts/gpu_check.sh OUTDIR [SIZES...]     (default sizes: 1000000 2000000 4000000)
#
# About 9 minutes on one H200 with 16 cores (2026-12-04; the overlap-off run of 6 was added later and
# is bounded to 2 minutes: set PEERS_SIZE=0 if time is short). PY selects the interpreter (default:
# .venv/bin/python if present, else python3). Writes OUTDIR/log.txt, parity.json, gpu.json, gpu_cells_lists.json, gpu_cells_walk.json, gpu_big.json,
# gpu_peers.json, gpu_peers_no_overlap.json and cpu.json; every step runs even when one before failed, and the exit status is 1
# if any failed.
set -u
OUTDIR=${1:-runs/gpu}
shift || true
SIZES=${*:-1000000 2000000 4000000}
mkdir -p "$OUTDIR"
if [ -z "${PY:-}" ]; then
    if [ -x .venv/bin/python ]; then PY=.venv/bin/python; else PY=python3; fi
fi
export PYTHONUNBUFFERED=1
LOG="$OUTDIR/log.txt"
TMP=$(mktemp -d)
status=0
say() { echo "== $(date -u +%H:%M:%S) $*" | tee -a "$LOG"; }

say "machine"
{ nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
  nproc
  $PY -c "import sys, numpy, numba, numba_cuda; print(sys.version.split()[0], 'numpy', numpy.__version__,
'numba', numba.__version__, 'numba-cuda', numba_cuda.__version__)"
  $PY -c "from sphcore.backends import cuda; print(cuda.probe())"; } >>"$LOG" 2>&1

say "parity cases, in parallel"
CASES=${CASES:-$($PY -c "import sys; sys.argv=['x']; sys.path.insert(0, 'tests'); import cuda_parity; print(' '.join(cuda_parity.CASES))")}
for c in $CASES; do
    ( NUMBA_NUM_THREADS=2 SPH_CACHE_DIR="$TMP/cache_$c" timeout 170 $PY tests/cuda_parity.py "$c" \
        >"$TMP/$c.json" 2>"$TMP/$c.log"; echo "$c exit $?" >>"$TMP/$c.log" ) &
done
wait
for c in $CASES; do tail -n 3 "$TMP/$c.log" >>"$LOG"; done
$PY - "$TMP" "$OUTDIR/parity.json" $CASES >>"$LOG" 2>&1 <<'EOF'
import json, sys
from pathlib import Path
sys.path.insert(0, "tests")
from test_cuda import TOL
tmp, out, cases = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3:]
results, bad = {}, []
for c in cases:
    try:
        results[c] = json.loads((tmp / f"{c}.json").read_text().strip().splitlines()[-1])[c]
    except Exception as exc:  # a crashed case: its log says why
        results[c] = {"error": repr(exc)}
        bad.append(c)
        continue
    r = results[c]
    precision = "f32" if c.endswith("f32") else "f64"
    for part in (r, r.get("stage", {}), r.get("steps", {})):
        for flag in ("same_particles", "same_order", "same_counts", "same_neighbour_lists"):
            if flag in part and not part[flag]:
                bad.append(f"{c}.{flag}")
        for f, tol in TOL[precision].items():
            if f in part and part[f] > tol:
                bad.append(f"{c}.{f}={part[f]:.3g} > {tol:g}")
out.write_text(json.dumps(results, indent=1))
print("parity:", "PASS" if not bad else "FAIL " + ", ".join(bad))
sys.exit(1 if bad else 0)
EOF
[ $? -eq 0 ] || status=1

say "long run: 200 steps GPU vs CPU"
SPH_CACHE_DIR="$TMP/cache_tiny_f64" timeout 90 $PY -m pytest -q -p no:cacheprovider -m gpu \
    "tests/test_cuda.py::test_long_gpu_run_stays_close_to_cpu" >>"$LOG" 2>&1 || status=1

say "GPU benchmark: sizes $SIZES; float32 with lists and walking, float64 with lists"
SPH_CACHE_DIR="$TMP/cache_bench" timeout 150 $PY -m launch.cli bench --backend cuda --sizes $SIZES \
    --precisions f32 --neighbours lists walk --steps ${STEPS:-100} --json "$OUTDIR/gpu.json" >>"$LOG" 2>&1 \
    || status=1
SPH_CACHE_DIR="$TMP/cache_bench" timeout 100 $PY -m launch.cli bench --backend cuda --sizes $SIZES \
    --precisions f64 --neighbours lists --steps ${STEPS:-100} --json "$OUTDIR/gpu_f64.json" >>"$LOG" 2>&1 \
    || status=1

say "the other cell size: lists with cells of H, the walk with cells of H / 2 (float32)"
SMALLEST=$(echo $SIZES | tr ' ' '\n' | sort -n | head -n 1)
for pair in "lists 1" "walk 2"; do
    set -- $pair
    { cat configs/dam_break.toml; printf '\n[run]\ncells_per_support = %s\n' "$2"; } > "$TMP/cells_$2.toml"
    SPH_CACHE_DIR="$TMP/cache_bench" timeout 45 $PY -m launch.cli bench --backend cuda --sizes $SMALLEST \
        --precisions f32 --neighbours "$1" --steps ${STEPS:-100} --config "$TMP/cells_$2.toml" \
        --json "$OUTDIR/gpu_cells_$1.json" >>"$LOG" 2>&1 || status=1
done

say "what a kernel launch costs the host"
timeout 60 $PY scripts/investigations/launch_overhead.py >>"$LOG" 2>&1 || status=1

if [ "${BIG:-300000000}" != 0 ]; then
    say "GPU memory: ${BIG:-300000000} particles stepping, f32, cell walk (device bytes per particle)"
    SPH_CACHE_DIR="$TMP/cache_bench" timeout 150 $PY -m launch.cli bench --backend cuda --sizes ${BIG:-300000000} \
        --precisions f32 --neighbours walk --steps 2 --json "$OUTDIR/gpu_big.json" >>"$LOG" 2>&1 || status=1
fi

if [ "${PEERS_SIZE:-4000000}" != 0 ]; then
    say "two peer processes sharing the GPU against one: ${PEERS_SIZE:-4000000} particles, f32"
    SPH_CACHE_DIR="$TMP/cache_bench" timeout 200 $PY -m launch.cli bench --backend cuda --sizes ${PEERS_SIZE:-4000000} \
        --precisions f32 --peers 1 2 --steps 100 --json "$OUTDIR/gpu_peers.json" >>"$LOG" 2>&1 || status=1
    say "the same two peers waiting for every halo exchange first (decomposition.overlap = false)"
    { cat configs/dam_break.toml; printf '\n[decomposition]\noverlap = false\n'; } > "$TMP/no_overlap.toml"
    SPH_CACHE_DIR="$TMP/cache_bench" timeout 120 $PY -m launch.cli bench --backend cuda --sizes ${PEERS_SIZE:-4000000} \
        --precisions f32 --peers 2 --steps 50 --config "$TMP/no_overlap.toml" \
        --json "$OUTDIR/gpu_peers_no_overlap.json" >>"$LOG" 2>&1 || status=1
fi

if [ "${CPU_BENCH:-1}" != 0 ]; then
    say "CPU benchmark on $(nproc) cores: 1000000 particles"
    SPH_CACHE_DIR="$TMP/cache_bench" timeout 90 $PY -m launch.cli bench --sizes 1000000 --precisions f32 \
        --threads "$(nproc)" --steps 20 --json "$OUTDIR/cpu.json" >>"$LOG" 2>&1 || status=1
fi
say "done (status $status)"
rm -rf "$TMP"
exit $status
