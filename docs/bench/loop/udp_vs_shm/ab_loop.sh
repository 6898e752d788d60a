#!/bin/bash
cd /work/main && source env.sh >/dev/null 2>&1; export ROS_DOMAIN_ID=175
for round in 1 2; do
  for mode in udp shm; do
    if [ $mode = shm ]; then
      env -u CARTPOLE_DISCOVERY_RANGE FASTRTPS_DEFAULT_PROFILES_FILE=/tmp/old_profiles.xml ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \
        cartpole bench loop --duration 20 --modes processes --out /tmp/ab_${mode}_$round > /tmp/ab_${mode}_$round.log 2>&1
    else
      cartpole bench loop --duration 20 --modes processes --out /tmp/ab_${mode}_$round > /tmp/ab_${mode}_$round.log 2>&1
    fi
    echo "$round $mode rc=$? $(uptime)"
  done
done
