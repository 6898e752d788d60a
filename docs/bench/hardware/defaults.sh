#!/usr/bin/env bash
# cartpole run --hw --hw-arm with the defaults against cartpole emulate, N times in a row.
set -u
n=${1:-10}
for i in $(seq 1 "$n"); do
  load=$(cut -d' ' -f1-3 /proc/loadavg)
  link=/tmp/cp-emu-$$-$i
  cartpole emulate --link "$link" > /tmp/emu-$$.log 2>&1 &
  emu=$!
  for k in $(seq 1 100); do [ -e "$link" ] && break; sleep 0.1; done
  out=$(cartpole run --hw --port "$link" --hw-arm --duration 20 --json 2>/tmp/hwrun-$$.err | grep '^{' | tail -1)
  kill -INT $emu; wait $emu
  echo "$out" | python3 -c "
import json, sys
d = json.loads(sys.stdin.read() or '{}')
keys = ('success', 'catch_time_s', 'end_stop_contact', 'theta_amp_deg', 'x_err_max_m', 'force_rms_n', 'force_p2p_n', 'fault', 'longest_cycle_gap_s', 'swingup_law')
print(json.dumps({'run': $i, 'load': '$load', **{k: d.get(k) for k in keys}}))"
done
