"""``cartpole/SwingUp-v0``: the gymnasium environment of this rig, registered on import.

Each episode draws a plant from the combined benchmark's range table
(:mod:`cartpole_learning.ranges`) and runs the rig's own closed loop
(:mod:`cartpole_learning.closed_loop`: plant, EKF and controller manager, nothing copied),
so the agent learns on what the ``policy`` plugin meets on the rig. The agent is the
manager's plugin: the observation is :func:`cartpole_learning.observation.observation` of
the state the manager hands a plugin (never the true state); the action ``a`` in [-1, 1]
is the raw force ``a * action_scale``; one step is one control cycle (5 ms). An episode
ends at an impact on a stop, a manager fault or a fall after the catch, each with
``-failure_penalty``, and is truncated after ``duration``. The reward, of the true state
after the command acted, asks for up and still, near x*, with little and smooth force.

``gymnasium.make("cartpole/SwingUp-v0")`` after ``import cartpole_learning.env``;
``gymnasium.make_vec(..., vectorization_mode="async")`` runs one per process.
The reward's terms, the randomisation and the speed: (docs/learning.md, "The environment").
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import gymnasium as gym
import numpy as np

from cartpole_control.controller import STABILIZER, SWINGUP
from cartpole_core.model import CartPoleParameters, wrap_angle

from cartpole_sim.scenario_ranges import RangeTable

from . import ranges
from .closed_loop import AgentLoop
from .observation import OBSERVATION_BOUND, OBSERVATION_SIZE

ENV_ID = 'cartpole/SwingUp-v0'
FALL = 'fall'


class SwingUpEnv(gym.Env):
    """The rig's closed loop with the agent as the controller manager's plugin (module docstring).

    Parameters
    ----------
    nominal
        The controllers' (and the EKF's) model; the plant is each scenario applied to it.
    table
        The range table (:class:`~cartpole_sim.scenario_ranges.RangeTable`, or a
        mapping of its fields: the others keep the published ranges); ``None``: the
        published ranges.
    push_time
        When a drawn push starts [s]; ``None`` keeps the table's (10-15 s, for 30 s runs).
    duration
        Simulated seconds of an episode.
    upright_start
        Fraction of episodes that start near upright at x*.
    manager_parameters
        The controller manager's parameters for the episodes (e.g. ``rail.margin``).
    """

    metadata = {'render_modes': []}

    def __init__(self, nominal: CartPoleParameters | None = None,
                 table: RangeTable | Mapping[str, Any] | None = None, duration: float = 6.0,
                 push_time: tuple[float, float] | None = (2.5, 5.0),
                 upright_start: float = 0.25, failure_penalty: float = 300.0,
                 manager_parameters: Mapping[str, Any] | None = None) -> None:
        super().__init__()
        self.nominal = nominal or CartPoleParameters()
        self.table = table if isinstance(table, RangeTable) else RangeTable.from_dict(table)
        self.push_time = None if push_time is None else tuple(push_time)
        if not (duration > 0.0 and math.isfinite(duration)):
            raise ValueError(f'duration must be > 0, got {duration!r}')
        self.steps = int(round(duration / self.nominal.sample_time))
        self.upright_start = float(upright_start)
        self.failure_penalty = float(failure_penalty)
        self.action_scale = self.nominal.force_max
        self.x_ref = float((manager_parameters or {}).get('x_ref', self.nominal.x_middle))
        self.observation_space = gym.spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND,
                                                (OBSERVATION_SIZE,),
                                                np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self._loop = AgentLoop(self.nominal, dict(manager_parameters or {}))
        self._running = False
        self._obs = np.zeros(OBSERVATION_SIZE, dtype=np.float32)
        self._kind = SWINGUP
        self._previous = 0.0
        self.scenario = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if self._running:
            self._loop.abort()
            self._wait('aborted')
            self._running = False
        while True:
            self.scenario = self._draw()
            self._loop.start(self.scenario, self.steps)
            message = self._loop.receive()
            self._check(message)
            if message[0] == 'state':  # (an episode that fails before its first cycle is redrawn)
                break
        self._running = True
        _, self._obs, self._kind, _ = message
        self._previous = 0.0
        return self._obs.copy(), {'scenario': self.scenario}

    def _draw(self):
        return ranges.draw(self.table, self.np_random, self.x_ref, self.upright_start,
                           self.push_time)

    def step(self, action):
        if not self._running:
            raise RuntimeError('step() before reset() or after the episode ended')
        a = float(np.clip(np.asarray(action, dtype=np.float64).reshape(-1)[0], -1.0, 1.0))
        self._loop.act(a * self.action_scale)
        message = self._loop.receive()
        self._check(message)
        info: dict[str, Any] = {}
        terminated = False
        if message[0] == 'state':
            _, obs, kind, true_state = message
            if self._kind == STABILIZER and kind == SWINGUP:
                terminated, info['end'] = True, FALL
            self._obs, self._kind = obs, kind
        else:
            _, reason, true_state = message
            self._running = False
            if reason != 'time':
                terminated, info['end'] = True, reason
        reward = self.reward(true_state, a, self._previous)
        self._previous = a
        if terminated:
            reward -= self.failure_penalty
        truncated = not terminated and message[0] == 'end'  # the duration is over
        if terminated or truncated:
            if self._running:
                self._loop.abort()
                self._wait('aborted')
                self._running = False
        return self._obs.copy(), float(reward), terminated, truncated, info

    def reward(self, true_state, action: float, previous: float) -> float:
        """The reward of the module docstring for the true state after the command acted."""
        x, theta = float(true_state[0]), float(true_state[1])
        th = wrap_angle(theta)
        return ((1.0 + math.cos(th)) / 2.0 + math.exp(-(th / 0.035) ** 2)
                - 0.5 * ((x - self.x_ref) / 0.385) ** 2
                - 0.02 * action ** 2 - 0.1 * (action - previous) ** 2)

    def _check(self, message: tuple) -> None:
        if message[0] == 'error':
            self._running = False
            raise RuntimeError(f'the closed loop failed:\n{message[1]}')

    def _wait(self, kind: str) -> None:
        while True:
            message = self._loop.receive()
            self._check(message)
            if message[0] == kind:
                return

    def close(self) -> None:
        if self._running:
            self._loop.abort()
            self._wait('aborted')
            self._running = False
        self._loop.close()
        super().close()


gym.register(id=ENV_ID, entry_point=SwingUpEnv, disable_env_checker=False)
