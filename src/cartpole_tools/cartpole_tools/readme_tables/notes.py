"""What the code cannot say about a topic or service: its content, in the README's words.

Keys are ``(node, topic or service)`` (or ``(node, '*')``) for the per-node tables and the topic
name for the graph's topic table. The check (:mod:`.check`) refuses an
endpoint without a note and a note without an endpoint, so a new topic is
documented when it is added and a removed one leaves no stale line.
"""
from __future__ import annotations

TOPIC_NOTES: dict[str, str] = {
    '/joint_states': '`cart`, `pendulum` positions as the encoders see them (quantised), 200 Hz',
    '/cartpole/state': 'estimated position and velocity of both joints; stamp copied from the '
                       'sample',
    '/cartpole/force_command': '`cart` effort [N]; stamp = stamp of the state it was computed from',
    '/cartpole/force_acting': '`cart` effort [N]: the force the cart feels over the next interval '
                              "by the manager's plant estimate; the command's stamp",
    '/cartpole/controller_status': 'mode, active plugins, the swing-up law that runs '
                                   '(`swingup_law`), energy and its error, raw force, '
                                   'feedforward, force, catch/fall counts and events',
    '/cartpole/true_state': 'ground truth (simulation only)',
    '/cartpole/ekf/health': 'innovation, covariance, resets, missed samples',
    '/cartpole/hw/health': 'lost samples, bad lines, watchdog trips, latency, limit switches',
    '/cartpole/plant_reset': 'the plant (simulator reset) or the position reference (bridge '
                             'homing) moved; reliable, transient local',
    '/cartpole/command_applied': 'sensor_msgs/TimeReference: when each force command took '
                                 'effect (`header.stamp`) and the stamp of the sample it was '
                                 "computed from (`time_ref`): the loop's latency",
    '/clock': 'simulated time for `use_sim_time` (lockstep)',
    '/diagnostics': "every node's health once a second of its clock, one status "
                    '`<node>: <what>` (see "Diagnostics and logs")',
    '/cartpole/recorder/progress': '`stamp` = the sample up to which the recorder holds every '
                                   '200 Hz topic (lockstep with `--record`: complete bags; '
                                   "without a recorder `cartpole run`'s monitor publishes it)",
}
"""Content of each graph topic (the "At a glance" table)."""

ENDPOINT_NOTES: dict[tuple[str, str], str] = {
    ('sim', '/joint_states'):
        "1/Ts = 200 Hz: `name=['cart','pendulum']`, `position=[x, theta]` as the encoders see "
        'them (quantised, unwrapped; theta = pi hanging after reset); `header.stamp` = the '
        "sample's time on the plant's clock, exactly Ts apart (real time: t0 + k Ts, samples "
        'missed during a stall of the process published at once; lockstep: k Ts)',
    ('sim', '/cartpole/true_state'):
        'with each sample, same stamp: ground truth `position=[x, theta]`, `velocity=[x_dot, '
        'theta_dot]`, `effort=[actuator force on the cart, end-stop force on the cart]` (the '
        "stops' peak spring force over the period, 0.0 unless the cart was pressed into a stop "
        "by more than 1 um: the plant's contact state, which `end_stop_contact` is taken from)",
    ('sim', '/clock'): 'before each sample: simulated time of the sample',
    ('sim', '/cartpole/command_applied'):
        'when each force command took effect on the plant: `header.stamp` = that time, '
        '`time_ref` = the stamp of the sample the command was computed from (the command\'s '
        '`header.stamp`), `source` = `sim`; the difference is the loop\'s latency (0 without a '
        'scenario delay: this plant applies a command from its own sample\'s time; the scenario\'s '
        '`delay` and `jitter` on top)',
    ('sim', '/cartpole/recorder/progress'):
        'the progress of the recorder, or without one of `cartpole run`\'s monitor '
        '(`recorder_window` > 0): sample k is stepped past only once it holds every sample '
        'topic up to sample k - `recorder_window`',
    ('sim', '/cartpole/force_command'):
        "`name=['cart']`, `effort=[F]` [N]; held over the next period (zero-order hold). A "
        'message without a finite effort for `cart` is counted and ignored',
    ('sim', '/cartpole/plant_reset'):
        'at each `/sim/reset`, before the reset sample: `stamp` = the time from which samples '
        'show the reset plant (the reset sample\'s stamp in lockstep, the reset\'s time in real '
        'time). Reliable, transient local (the last one is kept for late joiners). The EKF and '
        'the controller manager hand over on it (below)',
    ('sim', '/diagnostics'): 'status `sim: simulation` once a second (see "Diagnostics and logs")',
    ('sim', '/sim/reset'):
        'the plant goes back to the scenario\'s initial state (below)',
    ('ekf', '/joint_states'):
        'joints found by name (`cart`, `pendulum`); a message without them or with a non-finite '
        'position is dropped and counted; a repeated stamp is ignored',
    ('ekf', '/cartpole/force_command'): 'effort of `cart` [N]; held until the next one',
    ('ekf', '/cartpole/force_acting'):
        'effort of `cart` [N]: with `force_input` `acting` the interval after the sample of its '
        'stamp is predicted with it instead of the command (lockstep waits for it once they '
        'come); the same checks as the command',
    ('ekf', '/cartpole/state'):
        "`name=['cart','pendulum']`, `position=[x, theta]` (theta continuous), `velocity=[x_dot, "
        'theta_dot]`, `header.stamp` copied from the sample; published inside the '
        '`/joint_states` callback',
    ('ekf', '/cartpole/ekf/health'): 'one DiagnosticStatus `ekf`, every `health_period`',
    ('ekf', '/diagnostics'): 'status `ekf: estimation` once a second (see "Diagnostics and logs")',
    ('ekf', '/ekf/reset'): 're-initialise from the next sample (reported as `requested`)',
    ('ekf', '/cartpole/plant_reset'):
        'the plant (simulator reset) or the position reference (bridge homing) moved: '
        're-initialise from the first sample stamped at or after `stamp` (reported as `plant '
        'reset`), so the jump is not filtered as an innovation',
    ('controller_manager', '/cartpole/state'):
        '`cart`/`pendulum` position and velocity, found by name',
    ('controller_manager', '/cartpole/force_command'):
        "`name=['cart']`, `effort=[F]`, `header.stamp` = the state's stamp",
    ('controller_manager', '/cartpole/force_acting'):
        "right after each command, its stamp: `name=['cart']`, `effort=[F_acting]`, the force "
        'the cart feels over the next sample interval by the plant estimate (the commands in '
        'flight, each acting the measured latency plus the actuator\'s dead time after its '
        'sample, times the estimated gain; the command when the cycle sent none of its own), '
        "within the amplifier's range: what the EKF predicts with",
    ('controller_manager', '/cartpole/controller_status'):
        'every cycle: one status named `controller_manager`. Level is OK (running or idle) or '
        'ERROR (fault); `message` is the mode. KeyValues: `mode`, `swingup`, `stabilizer`, `enabled` '
        '(`true`/`false`), `energy`, `energy_error`, `raw_force`, `feedforward`, `force`, '
        '`catch_count`, `fall_count`, `event`, `state_stamp`, `swingup_law` (the swing-up '
        "plugin's `law`: its name, or for `time_optimal` `time_optimal:plan` / "
        '`time_optimal:fallback(<why>)`; while stabilising, the law that swung up), '
        '`longest_cycle_gap_s` (the longest wall-clock gap between two cycles since start), '
        '`cycle_compute_s` / `max_cycle_compute_s` (the compute time of this cycle / the '
        'longest since start [s]), `latency_s` (the latency measured from '
        '`/cartpole/command_applied`: the mean of the last 200 reports, 0 before 20), '
        '`predict_horizon_s` (the horizon the prediction used: `latency_s` with '
        '`predict.horizon` `auto`), `omega0_sq` (the estimate of the pendulum\'s m_p g l / J '
        '[1/s^2]), `actuator_gain` / `actuator_delay_s` (the actuator\'s gain the command is '
        'divided by and its estimated extra dead time, added to the horizon with `actuator.delay` '
        '`auto`), `friction_scale` (the estimated scale of the cart\'s friction, which scales the '
        'friction feedforward (6.12) with `actuator.friction` `auto`), then the active plugin\'s own figures (e.g. `mpc_solve_us`, '
        '`mpc_fallbacks`). '
        'Counts are integers, other numbers `repr(float)`. `event` is `catch`, `fall`, `restart`, `plant_reset`, '
        '`fault:<reason>`, `switch:<kind>=<name>` or empty; several events in one cycle are '
        'joined by `;`',
    ('controller_manager', '/diagnostics'):
        'status `controller_manager: control` once a second (see "Diagnostics and logs")',
    ('controller_manager', '/cartpole/command_applied'):
        'the plant\'s report of when each command took effect: `header.stamp - time_ref` is '
        'one sample of the loop\'s latency (`latency_s`)',
    ('controller_manager', '/joint_states'):
        'the encoders\' samples (`cart`, `pendulum` by name), while no stabiliser runs: the '
        'estimate of the pendulum\'s natural frequency (`omega0_sq`)',
    ('controller_manager', '/cartpole/plant_reset'):
        'a new run from the first state stamped at or after `stamp` (see "Plant reset")',
    ('controller_manager', '/controller_manager/restart_swingup'):
        'a new swing-up from fault (or idle while being enabled): clears the fault and re-arms '
        'the rail guard once its brake has stopped the cart. The answer is truthful in every '
        'mode (below)',
    ('hw_bridge', '/joint_states'):
        'one message per valid `S` sample: `cart`, `pendulum` positions in SI (conversions below)',
    ('hw_bridge', '/cartpole/command_applied'):
        'when each command took effect on the rig, in device time: `time_ref` = the stamp of '
        'the sample it answered, `header.stamp` = the device\'s time of the setpoint that '
        'carried it, mapped to the host clock like the samples\' (protocol version 2); '
        '`source` = `hw_bridge`',
    ('hw_bridge', '/cartpole/hw/health'):
        'one status `hw_bridge` every `health_period`, levels as on `/diagnostics` (OK armed, '
        'disarmed or unconfigured, ERROR disconnected, disarmed or unconfigured by a fault); '
        'every key: '
        '[the rig](../rig.md#cartpolehwhealth)',
    ('hw_bridge', '/diagnostics'):
        'status `hw_bridge: serial link` once a second (see "Diagnostics and logs")',
    ('hw_bridge', '/cartpole/plant_reset'):
        'after a homing: stamp = the first sample counted from the new zero',
    ('hw_bridge', '/cartpole/force_command'):
        'effort of `cart` [N]; forwarded as `U` setpoints only while armed',
    ('hw_bridge', '/hw_bridge/home'):
        'send `R` (zero both encoders); refused unless configured and disarmed (inactive)',
    ('hw_bridge', '/hw_bridge/change_state'):
        'the lifecycle, as `ros2 lifecycle set /hw_bridge configure|activate|deactivate|cleanup`: '
        'opens the port and streams disarmed, arms, zeroes and disarms, closes (docs/rig.md); '
        '`success` false when refused (the reason is logged); events on `~/transition_event`',
    ('hw_bridge', '/hw_bridge/get_state'): 'the lifecycle state (`ros2 lifecycle get /hw_bridge`); '
                                           'active = armed',
    ('viewer', '*'): 'drawn in the live view (decimated to at most `max_rate`); with `feed` set '
                     'the samples come from `viewer_tap` instead and only the parameter events '
                     'are subscribed',
    ('recorder', '*'): 'recorded: the serialized message as it arrived (`raw=True`, no '
                       'deserialisation), reliable QoS of depth `queue_depth`',
}
"""Content of each node's topics and services (``(node, '*')``: every endpoint of that node) (the per-node tables)."""

MENTIONED_KEYS: dict[tuple[str, str], tuple[str, str]] = {
    ('controller_manager', '/cartpole/controller_status'):
        ('cartpole_control.manager', 'STATUS_KEYS'),
}
"""Notes that must name every key of a tuple in the code (module, attribute), in backticks."""
