#!/usr/bin/env bash
# The MJX -> C check of one MJX-trained run (docs/MJX_VS_C.md, "MJX-trained policies on the C
# engine"): train pick up or pot on MJX in physics version VERSION (3: the default; 4-9: opt-in,
# see docs/MJX_VS_C.md), keep every checkpoint, then evaluate on both engines,
# paired, over EPISODES fresh episodes of seed 9090: the best checkpoint and the first whose test
# success reached 0.5 (the run records its version: the evaluations simulate it).
#
#   bash experiments/engine_parity/mjx_to_c.sh VERSION TASK SEED OUT [TIME_BUDGET_S] [EPISODES] [RUN_ARGS...]
#
# RUN_ARGS go to experiments/run.py as they are (the tables use --set n_test_episodes=32).
#
# Run it alone on the machine (MJX on a 2-core CPU: ~1.5 min per 5,000 env steps).
set -euo pipefail
version=$1 task=$2 seed=$3 out=$4 budget=${5:-2400} episodes=${6:-300}
shift $(( $# < 6 ? $# : 6 ))
root=$(cd "$(dirname "$0")/../.." && pwd)
mkdir -p "$out"
bash "$root/experiments/timed.sh" python "$root/experiments/run.py" --task "$task" --physics mjx \
  --seed "$seed" --env physics_version="$version" --stop-at-success 0.9 --time-budget "$budget" \
  --set keep_checkpoints=1000 --no-progress --out "$out/run" "$@" > "$out/train.log" 2>&1
first=$(python - "$out/run/metrics.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print(next((r["epoch"] for r in rows if float(r["test_success_rate"]) >= 0.5), ""))
PY
)
python "$root/experiments/evaluate.py" "$out/run" --best --physics c,mjx --episodes "$episodes" \
  --seed 9090 --json "$out/best.json" > "$out/best.log" 2>&1
if [ -n "$first" ]; then
  python "$root/experiments/evaluate.py" "$out/run" --step "$first" --physics c,mjx \
    --episodes "$episodes" --seed 9090 --json "$out/first_0.5.json" > "$out/first_0.5.log" 2>&1
fi
echo "done: $out (first checkpoint >= 0.5: epoch ${first:-none})"
