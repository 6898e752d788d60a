#!/bin/bash
# The measurements of docs/benchmarks.md, "Faults, kills and clashes" (issue 11).
# Real time: run under the shared lock, e.g.  flock /work/wt/rt.lock docs/bench/faults/measure.sh
# Env: ROS_DOMAIN_ID (a free one), OUT (results directory, default /tmp/cartpole-faults).
HERE=$(cd "$(dirname "$0")" && pwd)
cd "$HERE/../../.." && source env.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
R=${OUT:-/tmp/cartpole-faults}; mkdir -p $R
echo "== start $(uptime)"
echo "== SIGKILL of one node, simulator, --processes, real time"
for n in controller_manager ekf sim recorder; do
  rm -rf $R/k_$n
  python $HERE/killnode.py $n $R/k_$n --after 4 -- --sim --processes --duration 30 > $R/k_$n.out 2>&1
  python $HERE/killbag.py $R/k_$n
done
echo "== SIGKILL of one node, rig (cartpole emulate in this process), --processes, real time"
for n in hw_bridge controller_manager; do
  rm -rf $R/hw_$n; LINK=$R/emu-link-$n; rm -f $LINK
  python $HERE/../../../test/emulator_probe.py $LINK 45 $R/emu_$n.json > $R/emu_$n.out 2>&1 &
  EMU=$!
  for i in $(seq 50); do [ -e $LINK ] && break; sleep 0.1; done
  python $HERE/killnode.py $n $R/hw_$n --after 8 -- --hw --port $LINK --hw-arm --processes \
      --duration 30 --stabilizer smc > $R/hw_$n.out 2>&1
  cat $R/hw_$n/*/summary.json | python -c "import json,sys; d=json.load(sys.stdin); print('$n: fault', d['fault'])"
  wait $EMU
  python $HERE/hw_after_kill.py $R/emu_$n.json $R/hw_$n.out
done
echo "== SIGKILL of the whole run (one process, real time), then cartpole bag repair"
rm -rf $R/k_run
python $HERE/killnode.py run $R/k_run --after 8.8 -- --sim --duration 30 > $R/k_run.out 2>&1
LS=$(python -c "t=open('$R/k_run.out').read(); import json; print(json.loads(t[t.index('{\n'):])['last_seen_stamp_s'])")
python $HERE/recovered.py $R/k_run $LS
cartpole bag repair $R/k_run/*/bag
echo "== orderly real-time --processes stop"
for i in 1 2 3; do
  cartpole run --sim --processes --duration 6 --json > $R/orderly_$i.json 2> $R/orderly_$i.err
  echo "rc $? stderr: $(grep -v RTPS $R/orderly_$i.err | tr '\n' ' ' | cut -c1-300)"
done
echo "== end $(uptime)"
