#!/usr/bin/env bash
# Runs a command and prefixes each line of its output (stdout and stderr) with the seconds since
# this script started, so that the epochs' lines of `run.py --no-progress` give the wall clock
# from process start (env build, grasped-state recording, compilation and evaluation included).
#
#   bash experiments/timed.sh python experiments/run.py --task pickup --no-progress | tee log.txt
set -uo pipefail
start=$(date +%s.%N)
"$@" 2>&1 | while IFS= read -r line; do
  now=$(date +%s.%N)
  awk -v a="$now" -v b="$start" -v l="$line" 'BEGIN { printf "%8.1f %s\n", a - b, l }'
done
