"""What a Foxglove client receives from ``cartpole run --sim --view`` (docs/benchmarks.md, the live view).

    python docs/bench/view/measure.py [SECONDS] [--processes]

Starts ``cartpole run --sim --duration SECONDS+10 --view 127.0.0.1:0 --json``
(real time), connects a Foxglove WebSocket client
(:class:`cartpole_analysis.viewer.client.ViewerClient`) to every viewer channel,
and subscribes ``/cartpole/state`` over DDS in this process. After 5 s it
measures for SECONDS: per channel the messages received per wall second and
per second of their own stamps, the largest gap between consecutive stamps,
and for the scene the largest difference between the drawn cart (the
estimate's) and the ``/cartpole/state`` of the same stamp. Prints one JSON
line with the load average and the run's summary verdict. Needs
``source env.sh`` and a free ROS_DOMAIN_ID; it measures wall-clock behaviour,
so nothing else real-time should run meanwhile.
"""
import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'src' / 'cartpole_bringup' / 'test'))

import foxglove_support  # noqa: E402  (the tests' protobuf reader of the advertised schema)

from cartpole_analysis.viewer.server import TOPICS  # noqa: E402
from cartpole_analysis.viewer.client import ViewerClient  # noqa: E402

WARMUP_S = 5.0


def main() -> int:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 and sys.argv[1][0].isdigit() else 20.0
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    cmd = [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--duration',
           str(seconds + WARMUP_S + 10.0), '--view', '127.0.0.1:0', '--json']
    if '--processes' in sys.argv:
        cmd.append('--processes')
    rclpy.init()
    node = rclpy.create_node('view_measure')
    estimates = {}
    node.create_subscription(
        JointState, '/cartpole/state',
        lambda m: estimates.__setitem__(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                                        m.position[0]), QoSProfile(depth=200))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinning = threading.Event()
    spinning.set()

    def spin():
        while spinning.is_set():
            executor.spin_once(timeout_sec=0.1)
    threading.Thread(target=spin, daemon=True).start()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    url = None
    for line in proc.stderr:
        match = re.search(r'live view on (ws://\S+)', line)
        if match:
            url = match.group(1)
            break
    if url is None:
        print(proc.communicate()[1], file=sys.stderr)
        return 1
    threading.Thread(target=proc.stderr.read, daemon=True).start()
    client = ViewerClient(url, TOPICS.values(), timeout=30.0)
    time.sleep(WARMUP_S)
    counts0, t0 = dict(client.counts), time.monotonic()
    time.sleep(seconds)
    counts1, t1 = dict(client.counts), time.monotonic()
    out, _ = proc.communicate(timeout=120)
    spinning.clear()
    client.close()
    summary = json.loads(out.strip().splitlines()[-1])
    result = {'command': ' '.join(['cartpole'] + cmd[3:]), 'seconds': seconds,
              'load_average': os.getloadavg(), 'success': summary['success'], 'channels': {}}
    schema = foxglove_support.Schema.from_advertised(client.channels[TOPICS['scene']])
    for name, topic in TOPICS.items():
        messages = client.received(topic)
        window = [m.log_time_ns for m in messages]
        per_wall = (counts1[topic] - counts0[topic]) / (t1 - t0)
        entry = {'received': len(messages), 'per_wall_s': round(per_wall, 2)}
        if len(window) > 1 and name != 'events':
            span = (window[-1] - window[0]) * 1e-9
            gaps = [(b - a) * 1e-6 for a, b in zip(window, window[1:])]
            entry.update(per_stamp_s=round((len(window) - 1) / span, 2),
                         min_gap_ms=round(min(gaps), 3), max_gap_ms=round(max(gaps), 3))
        result['channels'][topic] = entry
    errors = []
    for message in client.received(TOPICS['scene']):
        if message.log_time_ns in estimates:
            entities = {e['id']: e for e in
                        schema.decode('foxglove.SceneUpdate', message.payload)['entities']}
            drawn = entities['estimate']['lines'][1]['points'][0]['x']
            errors.append(abs(drawn - estimates[message.log_time_ns]))
    result['scene_vs_state'] = {'matched': len(errors),
                                'max_abs_mm': round(1e3 * max(errors), 6) if errors else None}
    print(json.dumps(result))
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
