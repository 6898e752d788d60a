#!/usr/bin/env bash
# The real-time verdict, N times: `cartpole run --sim --duration 30 --json` (one process, the defaults),
# one line per run with the load average. Usage: docs/bench/realtime/verdict.sh N [more cartpole run options]
# Needs `source env.sh` and a ROS_DOMAIN_ID nothing else uses.
set -u
n=${1:-10}; shift || true
for i in $(seq 1 "$n"); do
  load=$(cut -d' ' -f1-3 /proc/loadavg)
  out=$(cartpole run --sim --duration 30 --json "$@" 2>/dev/null | grep '^{' | tail -1)
  echo "$out" | python3 -c "
import json, sys
d = json.loads(sys.stdin.read() or '{}')
keys = ('success', 'catch_time_s', 'end_stop_contact', 'theta_amp_deg', 'fault', 'longest_cycle_gap_s', 'recorder_missed')
print(json.dumps({'run': $i, 'load': '$load', **{k: d.get(k) for k in keys}}))"
done
