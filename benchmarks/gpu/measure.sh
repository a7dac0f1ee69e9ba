#!/usr/bin/env bash
# Issue 11 point 4, prepared for a machine with a GPU: throughput (adapter vs bare engine) and
# scaling curves of both backends, written with their provenance under $OUT_DIR. One command, so
# that a lent GPU machine's short lease is spent measuring. From the repository root:
#
#   DEVICE=cuda:0 bash benchmarks/gpu/measure.sh                 # -> results/gpu/
#   DEVICE=cpu ENVS="1 4" NUM_ENVS=4 HORIZON=4 OUT_DIR=/tmp/gpu_rehearsal bash benchmarks/gpu/measure.sh
#                                                                # a rehearsal of the same steps on the CPU
#
# Each step prints its own progress; a step that fails is reported and the others still run (exit 1
# at the end if any failed). Graph capture: the adapters capture Warp graphs by default on CPU only;
# on CUDA the plain runs are eager and the "_graphs" runs add --backend-option graph_capture=1.
set -uo pipefail
cd "$(dirname "$0")/../.."
DEVICE=${DEVICE:-cuda:0}
OUT_DIR=${OUT_DIR:-results/gpu}
ENVS=${ENVS:-"1 16 256 1024 4096"}
NUM_ENVS=${NUM_ENVS:-64}
HORIZON=${HORIZON:-32}
MAX_SECONDS=${MAX_SECONDS:-90}   # per env count of a scaling curve; larger counts are skipped with a note
PYTHON=${PYTHON:-python}
mkdir -p "$OUT_DIR"
failed=0

step() {  # step NAME COMMAND...: run one measurement, keep going if it fails
    local name=$1
    shift
    echo "== $name: $*"
    if ! "$@"; then
        echo "!! $name failed"
        failed=1
    fi
}

for backend in newton mujoco_warp; do
    for task in ant go2; do
        step "throughput $backend/$task" "$PYTHON" -m harness throughput --backend "$backend" --task "$task" \
            --device "$DEVICE" --num-envs "$NUM_ENVS" --horizon "$HORIZON" --windows 3 \
            --out "$OUT_DIR/throughput_${backend}_${task}.json"
        # shellcheck disable=SC2086  # ENVS is a list of counts
        step "scaling $backend/$task" "$PYTHON" -m harness scaling --backend "$backend" --task "$task" \
            --device "$DEVICE" --envs $ENVS --max-seconds "$MAX_SECONDS" --out "$OUT_DIR/scaling_${backend}_${task}"
    done
    step "throughput $backend/ant, graph capture" "$PYTHON" -m harness throughput --backend "$backend" --task ant \
        --device "$DEVICE" --num-envs "$NUM_ENVS" --horizon "$HORIZON" --windows 3 --backend-option graph_capture=1 \
        --out "$OUT_DIR/throughput_${backend}_ant_graphs.json"
done
# shellcheck disable=SC2086
step "scaling newton/soft_jumper" "$PYTHON" -m harness scaling --backend newton --task soft_jumper \
    --device "$DEVICE" --envs $ENVS --max-seconds "$MAX_SECONDS" --out "$OUT_DIR/scaling_newton_soft_jumper"
csvs=("$OUT_DIR"/scaling_*.csv)
if [ -e "${csvs[0]}" ]; then
    step "scaling plot" "$PYTHON" -m harness scaling-plot --csv "${csvs[@]}" --out "$OUT_DIR/scaling_all.png"
fi
echo "measured on $DEVICE into $OUT_DIR (failed steps: $failed)"
exit "$failed"
