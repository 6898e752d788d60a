"""DAgger: the policy learns the thesis's laws on the randomised rig, from the state it sees.

Dataset aggregation (Ross, Gordon and Bagnell, "A reduction of imitation
learning and structured prediction to no-regret online learning", AISTATS
2011): round 0 runs the teacher (by default the ``time_optimal`` swing-up, a minimum-time
plan tracked by time-varying LQR, and the ``lqg`` stabiliser, the manager's plugins with
their default gains but those of :data:`TEACHER_GAINS`; any installed pair with
``cartpole train --teacher``) on episodes drawn
from the range table and records every state a plugin is handed with the
teacher's raw force; each later round runs the network fitted so far (in a
fraction ``1 - beta`` of the episodes; ``beta`` halves each round) and the
teacher labels the states the network visits, which is what makes the clone
recover from its own mistakes. The network (the actor layout of
:mod:`cartpole_learning.training`) is fitted by least squares on all rounds.

The episodes run :meth:`AgentLoop._episode` in-process (no agent thread): the
plugins ask :class:`TeacherLoop` for the force, so the teacher and the
network see exactly what the ``policy`` plugin will see.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from cartpole_control.controller import STABILIZER, SWINGUP, CommandFeedback, Controller, \
    ControllerState
from cartpole_control.controllers.lqg import ROBUST_GAIN
from cartpole_control.registry import load_controllers
from cartpole_core.model import CartPoleParameters
from cartpole_sim.scenario_ranges import RangeTable

from . import policy_file, ranges
from .closed_loop import AgentLoop

TEACHER = ('time_optimal', 'lqg')
"""The default teacher: (swing-up, stabiliser) plugin names. The fastest pair that holds on
the combined benchmark (its nominal catch 1.54 s, 184 of 200 draws); the default pair
``pendulum_energy`` + ``lqg`` teaches a 2.8 s swing-up (docs/learning.md)."""
TEACHER_GAINS: dict[str, dict[str, Any]] = {'lqg': ROBUST_GAIN,
                                             'time_optimal': {'abort_x': 0.3, 'abort_theta': 1.5}}
"""Gains a teacher plugin takes instead of its defaults: ``lqg`` teaches with its robust gain
alone (its default until 2026-12-05; with the precise gain near upright rest as teacher the
seed-0 student held 177 of 200 combined draws, against 188). ``time_optimal`` keeps
tracking its plan up to 0.3 m and 1.5 rad off it (its own limits 0.12 m, 0.5 rad): DAgger
asks the teacher in the student's states, which stray further from the plan than the
law's own, and with the law's limits it gave up the plan there, so that 2 of 3 training
seeds learnt its fall-back (nominal catch 2.6-2.8 s) instead of the plan (docs/learning.md)."""


def teacher_classes(teacher: tuple[str, str] = TEACHER) -> dict[str, type[Controller]]:
    """The teacher's plugin classes by kind; ValueError naming the known ones for a bad name
    (a learned policy cannot teach: ``policy`` is refused)."""
    classes = {}
    for kind, name in zip((SWINGUP, STABILIZER), teacher):
        known = {k: v for k, v in load_controllers(kind).items() if k != 'policy'}
        if name not in known:
            raise ValueError(f'{kind} {name!r}: expected one of {sorted(known)}')
        classes[kind] = known[name]
    return classes


def prepare_teacher(nominal: CartPoleParameters, teacher: tuple[str, str] = TEACHER,
                    progress=None) -> None:
    """The teacher's slow work before any episode, for the benchmark's start (hanging at
    rest at the left stop): ``time_optimal`` solves its plan for ``nominal`` now if it is not
    in the plan cache (seconds, said to ``progress``), so that every episode's teacher
    tracks the plan instead of swinging up with its fall-back while a background solve runs.
    The manager's own :meth:`~cartpole_control.manager.ControllerManager.prepare`, with the
    gains the teacher takes (:data:`TEACHER_GAINS`), so that it prepares the teacher's plan."""
    from cartpole_control.manager import ControllerManager
    from cartpole_sim.plant import Scenario

    teacher_classes(teacher)  # a clear error for a bad name first
    gains = {f'{name}.{key}': value for name in teacher
             for key, value in TEACHER_GAINS.get(name, {}).items()}
    manager = ControllerManager(nominal, sample_time=nominal.sample_time, real_time=False,
                                swingup=teacher[0], stabilizer=teacher[1], **gains)
    manager.prepare(ControllerState(0.0, *Scenario().initial_state()), progress)


class TeacherLoop(AgentLoop):
    """The closed loop whose plugins act with the teacher or the student, labelled by the teacher."""

    def __init__(self, nominal: CartPoleParameters,
                 teacher: tuple[str, str] = TEACHER) -> None:
        super().__init__(nominal)
        self.teacher_classes = teacher_classes(teacher)
        self.scale = nominal.force_max
        self.student: policy_file.Policy | None = None
        self.student_acts = False
        self.observations: list[np.ndarray] = []
        self.labels: list[float] = []
        self.falls = 0
        self._teachers: dict[str, Controller] | None = None
        self._kind = ''

    def begin(self, student_acts: bool) -> None:
        self.student_acts = student_acts and self.student is not None
        self._teachers = None
        self._kind = ''

    def exchange(self, plugin: Controller, state: ControllerState) -> float:
        kind = plugin.kind
        if self._teachers is None:
            self._teachers = {k: cls() for k, cls in self.teacher_classes.items()}
            for teacher in self._teachers.values():
                teacher.configure(dict(TEACHER_GAINS.get(teacher.name, {})), plugin.context)
        teacher = self._teachers[kind]
        if kind != self._kind:
            if self._kind:
                self._teachers[self._kind].deactivate()
                if self._kind == STABILIZER:
                    self.falls += 1
            teacher.activate(state)
            self._kind = kind
        label = float(teacher.update(state))
        obs = plugin.observer.observe(state, plugin.context, kind == STABILIZER)
        self.observations.append(obs)
        self.labels.append(max(-1.0, min(1.0, label / self.scale)))
        if self.student_acts:
            return self.student.force(obs)
        return label

    def feedback(self, plugin: Controller, feedback: CommandFeedback) -> None:
        if self._kind:
            self._teachers[self._kind].command_applied(feedback)


def collect(job: dict[str, Any]) -> dict[str, Any]:
    """Run ``job['episodes']`` episodes (a worker's share of a round); returns the data."""
    nominal = CartPoleParameters(**(job.get('nominal') or {}))
    loop = TeacherLoop(nominal, tuple(job.get('teacher') or TEACHER))
    if job.get('student') is not None:
        loop.student = policy_file.Policy(**job['student'])
    rng = np.random.default_rng(job['seed'])
    table = RangeTable.from_dict(job.get('table') or {})
    steps = int(round(job['duration'] / nominal.sample_time))
    ends: dict[str, int] = {}
    for _ in range(job['episodes']):
        scenario = ranges.draw(table, rng, nominal.x_middle, job['upright_start'],
                               job['push_time'])
        loop.begin(rng.uniform() >= job['beta'])
        loop._episode(scenario, steps)
        message = loop.receive()
        end = message[1] if message[0] == 'end' else message[0]
        ends[end] = ends.get(end, 0) + 1
    loop.close()
    return {'obs': np.array(loop.observations, dtype=np.float32),
            'labels': np.array(loop.labels, dtype=np.float32), 'ends': ends,
            'falls': loop.falls}


def student_arrays(weights, biases, mean, var, clip: float, eps: float,
                   scale: float) -> dict[str, Any]:
    """The keyword arguments of :class:`policy_file.Policy` for a network in memory."""
    return dict(obs_mean=np.asarray(mean, np.float64),
                obs_scale=1.0 / np.sqrt(np.asarray(var, np.float64) + eps), obs_clip=clip,
                weights=tuple(weights), biases=tuple(biases), action_scale=scale)


def fit(actor, obs: np.ndarray, labels: np.ndarray, mean: np.ndarray, var: np.ndarray,
        clip: float, eps: float, epochs: int, seed: int, log) -> float:
    """Least squares of ``actor`` (a torch module on normalised observations) on the labels."""
    import torch
    gen = torch.Generator().manual_seed(seed)
    x = torch.as_tensor(np.clip((obs - mean) / np.sqrt(var + eps), -clip, clip),
                        dtype=torch.float32)
    y = torch.as_tensor(labels, dtype=torch.float32).reshape(-1, 1)
    optimiser = torch.optim.Adam(actor.parameters(), lr=1e-3)
    n = len(x)
    batch = 1024
    loss = math.nan
    for epoch in range(epochs):
        order = torch.randperm(n, generator=gen)
        total = 0.0
        for i in range(0, n, batch):
            idx = order[i:i + batch]
            optimiser.zero_grad()
            out = torch.clamp(actor(x[idx]), -1.0, 1.0)
            batch_loss = torch.mean((out - y[idx]) ** 2)
            batch_loss.backward()
            optimiser.step()
            total += batch_loss.item() * len(idx)
        loss = total / n
    log(f'    fit: {n} samples, {epochs} epochs, mse {loss:.2e}')
    return loss
