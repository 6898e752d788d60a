"""The rig's closed loop with the agent inside the controller manager, in a worker thread.

The agent must get the very state a plugin gets on the rig, and that state is made inside
:meth:`ControllerManager.update_values` (the EKF estimate predicted over the measured
latency) just before the active plugin's ``update``, after which the manager's cycle goes
on with the plugin's force (feedforward (6.12), saturation, rail guard). So the loop runs
as on the rig, in a thread of its own: plant, EKF, controller manager with two agent
plugins (one per role, so the catch trigger (6.4) and the fall detector hand over as
between the ``policy`` plugins); each plugin ``update`` sends the state to the
environment and blocks until the agent's force comes back. Nothing is copied or bypassed.

Messages from the loop: ``('state', obs, kind, true_state)`` at each plugin call,
``('end', reason, true_state)`` when the run cannot go on (``impact``: the cart hit a
stop, :attr:`Plant.impacts`; ``fault:<reason>``: the manager faulted), ``('aborted',)``
after :meth:`AgentLoop.abort`, ``('error', text)`` if the loop raised.
See (docs/learning.md, "The environment").
"""
from __future__ import annotations

import threading
import traceback
from queue import SimpleQueue

import numpy as np

from cartpole_control.controller import STABILIZER, SWINGUP, CommandFeedback, Controller, \
    ControllerState
from cartpole_control.manager import FAULT, ControllerManager
from cartpole_core.model import CartPoleParameters
from cartpole_estimation.ekf import EkfConfig, ExtendedKalmanFilter
from cartpole_sim.plant import Plant, Scenario

from .observation import Observer

_ABORT = object()
_CLOSE = object()


class _AgentPlugin(Controller):
    """A plugin whose force is the agent's: :meth:`update` asks the environment."""

    loop: 'AgentLoop'
    adaptive_target = True
    """The catch's energy condition aims at the measured pendulum's E*, as for the energy laws
    the policy imitates and the ``policy`` plugin."""

    def __init__(self) -> None:
        super().__init__()
        self.observer = Observer()

    def on_activate(self, state: ControllerState) -> None:
        self.observer.reset(state.t)

    def update(self, state: ControllerState) -> float:
        return self.loop.exchange(self, state)

    def command_applied(self, feedback: CommandFeedback) -> None:
        self.observer.feedback(feedback)
        self.loop.feedback(self, feedback)


class AgentLoop:
    """Plant, EKF and controller manager stepped in a worker thread, the agent in the plugins.

    ``nominal`` are the parameters of the EKF and the manager (the controllers'
    model); each episode's plant is its scenario applied to them.
    """

    def __init__(self, nominal: CartPoleParameters, manager_parameters: dict | None = None,
                 ekf_config: EkfConfig | None = None) -> None:
        self.nominal = nominal
        self.manager_parameters = dict(manager_parameters or {})
        self.ekf_config = ekf_config or EkfConfig()
        self.to_loop: SimpleQueue = SimpleQueue()
        self.to_env: SimpleQueue = SimpleQueue()
        self._aborted = False
        attrs = {'loop': self}
        swingup = type('AgentSwingUp', (_AgentPlugin,), dict(attrs, kind=SWINGUP, name='agent'))
        stabilizer = type('AgentStabilizer', (_AgentPlugin,),
                          dict(attrs, kind=STABILIZER, name='agent_stabilizer'))
        self.registry = {SWINGUP: {'agent': swingup}, STABILIZER: {'agent_stabilizer': stabilizer}}
        self._thread = threading.Thread(target=self._serve, name='cartpole-agent-loop',
                                        daemon=True)
        self._thread.start()

    # -- the environment's side ------------------------------------------------------
    def start(self, scenario: Scenario, steps: int) -> None:
        """Begin an episode of at most ``steps`` samples; read its messages with :meth:`receive`."""
        self.to_loop.put((scenario, steps))

    def act(self, force: float) -> None:
        """The agent's raw force [N] for the state of the last ``'state'`` message."""
        self.to_loop.put(float(force))

    def receive(self) -> tuple:
        return self.to_env.get()

    def abort(self) -> None:
        """End the episode waiting for an action (the loop answers ``('aborted',)``)."""
        self.to_loop.put(_ABORT)

    def close(self) -> None:
        self.to_loop.put(_CLOSE)
        self._thread.join(timeout=5.0)

    # -- the worker's side --------------------------------------------------------------
    def exchange(self, plugin: Controller, state: ControllerState) -> float:
        """In the worker, from a plugin's update: send the state, wait for the force."""
        kind = plugin.kind
        obs = plugin.observer.observe(state, plugin.context, kind == STABILIZER)
        self.to_env.put(('state', obs, kind, self._true_state()))
        reply = self.to_loop.get()
        if reply is _ABORT or reply is _CLOSE:
            self._aborted = True
            return 0.0
        return reply

    def feedback(self, plugin: Controller, feedback: CommandFeedback) -> None:
        """What the manager did with the plugin's force (nothing to do here; see subclasses)."""

    def _true_state(self) -> np.ndarray:
        return np.array(self._plant.state)

    def _serve(self) -> None:
        while True:
            command = self.to_loop.get()
            if command is _CLOSE:
                return
            if command is _ABORT:
                self.to_env.put(('aborted',))
                continue
            try:
                self._episode(*command)
            except Exception:  # the environment raises it in the agent's thread
                self.to_env.put(('error', traceback.format_exc()))

    def _episode(self, scenario: Scenario, steps: int) -> None:
        p = self.nominal
        plant = self._plant = Plant(p, scenario)
        ekf = ExtendedKalmanFilter(p, self.ekf_config)
        manager = ControllerManager(p, sample_time=p.sample_time, registry=self.registry,
                                    real_time=False, swingup='agent',
                                    stabilizer='agent_stabilizer')
        if self.manager_parameters:
            result = manager.set_parameters(self.manager_parameters)
            if not result.successful:
                raise ValueError(result.reason)
        self._aborted = False
        force = ekf_force = 0.0  # the EKF's: the force as it acts (cartpole/force_acting)
        for_filter = manager.plant_estimate.filter_force(self.ekf_config.force_input)
        drop = scenario.drop
        for _ in range(steps + 1):
            meas = plant.measure()
            if drop and plant.sample_lost():
                plant.step(force)  # the held command; the host sees nothing
            else:
                t = meas.t
                for source, applied in plant.applied_commands():
                    manager.command_applied(source, applied)
                manager.measured(t, meas.x, meas.theta)
                est = ekf.update(t, meas.x, meas.theta, ekf_force)
                out = manager.update_values(est.t, est.x, est.theta, est.x_dot, est.theta_dot)
                if self._aborted:
                    self.to_env.put(('aborted',))
                    return
                if out.mode == FAULT:
                    self.to_env.put(('end', f'fault:{manager.fault_reason}', self._true_state()))
                    return
                force = out.force
                ekf_force = for_filter(est.t, force)
                manager.between_cycles()
                plant.step(force, None, t)
            if plant.impacts:
                self.to_env.put(('end', 'impact', self._true_state()))
                return
        self.to_env.put(('end', 'time', self._true_state()))
