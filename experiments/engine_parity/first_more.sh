#!/usr/bin/env bash
# The first checkpoint at 0.5 of an mjx_to_c.sh output folder, evaluated again on both engines
# over more fresh episodes of another seed (docs/MJX_VS_C.md, "Physics version 8": every
# version-8 row's weak checkpoint gets 600 episodes of seed 9191 besides the table's 300 of 9090).
#
#   bash experiments/engine_parity/first_more.sh OUT [EPISODES] [SEED]
set -euo pipefail
out=$1 episodes=${2:-600} seed=${3:-9191}
root=$(cd "$(dirname "$0")/../.." && pwd)
first=$(python - "$out/run/metrics.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print(next((r["epoch"] for r in rows if float(r["test_success_rate"]) >= 0.5), ""))
PY
)
[ -n "$first" ] || { echo "no checkpoint reached 0.5 in $out" >&2; exit 1; }
python "$root/experiments/evaluate.py" "$out/run" --step "$first" --physics c,mjx \
  --episodes "$episodes" --seed "$seed" --json "$out/first_0.5_${episodes}_${seed}.json" \
  > "$out/first_0.5_${episodes}_${seed}.log" 2>&1
echo "done: $out epoch $first, $episodes episodes of seed $seed"
