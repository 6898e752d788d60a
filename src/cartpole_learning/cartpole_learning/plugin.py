"""``policy``: a learned swing-up and stabiliser as a controller-manager plugin.

Registered in both entry-point groups (``cartpole_control.swingup`` and
``cartpole_control.stabilizer``) under the one name ``policy``, with the same parameters
(``policy.file``, ``policy.max_inference_us``), so that ``swingup:=policy
stabilizer:=policy`` runs the network from hanging to balancing (the manager's catch
trigger (6.4) only hands the state from one instance to the other) and ``swingup:=policy
stabilizer:=lqg`` hands over to the LQR at the catch.

Inference is numpy alone (:mod:`cartpole_learning.policy_file`); the output is the raw
force, to which the manager adds the friction feedforward (6.12) and which it saturates
and hands to the rail guard like any law's. A policy file that is missing or does not
fit, a non-finite output or, in a real-time loop, ``max_overruns`` inferences in a row
whose CPU time is over ``max_inference_us`` hand the rest of the activation to the thesis's
laws: the energy swing-up (7.32) (``pendulum_energy``) or the LQR (8.17) (``lqg``),
activated from the current state and counted (``policy_fallbacks``; every overrun in
``policy_overruns``). Details: (docs/learning.md, "The policy plugin").
"""
from __future__ import annotations

import logging
import math
import os
import time
from typing import ClassVar, Mapping

import numpy as np

from cartpole_control.controller import STABILIZER, SWINGUP, CommandFeedback, Controller, \
    ControllerState, ParameterSpec
from cartpole_control.controllers.lqg import LqgStabilizer
from cartpole_control.controllers.pendulum_energy import PendulumEnergySwingUp

from . import policy_file
from .observation import OBSERVATION_SIZE, Observer, observation

logger = logging.getLogger(__name__)

SHIPPED_POLICY = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'policies',
                              'swingup_balance.npz')
"""The policy shipped with the package (``policy.file`` empty), reproduced by the
``cartpole train`` command recorded in its provenance."""

PARAMETERS = (
    ParameterSpec('file', '', 'Policy file (.npz) written by `cartpole train`; empty: the '
                  'policy shipped with cartpole_learning'),
    ParameterSpec('max_inference_us', 2000.0, 'In a real-time loop, an inference that takes '
                  'more CPU time than this [us] is an overrun, counted in policy_overruns',
                  low=10.0, high=4000.0),
    ParameterSpec('max_overruns', 3, 'So many overruns in a row hand the rest of the '
                  'activation to the fallback law (pendulum_energy swing-up, lqg stabiliser); '
                  '1: the first overrun does', low=1, high=100),
)


class _PolicyController(Controller):
    """The network in one role; :attr:`fallback_class` is the law it falls back to."""

    name = 'policy'
    parameters = PARAMETERS
    fallback_class: ClassVar[type[Controller]]
    adaptive_target = True
    """The catch's energy condition (6.4) aims at the measured pendulum's E*, as for the
    energy swing-up the policy learned from and falls back to."""

    def __init__(self) -> None:
        super().__init__()
        self.policy: policy_file.Policy | None = None
        self.load_error = ''
        self.fallbacks = 0
        self.fallback_reason = ''
        self.inference_us = 0.0
        self.overruns = 0
        """Overruns since configuration (:data:`PARAMETERS`, ``max_inference_us``)."""
        self._in_a_row = 0
        self._fallback: Controller | None = None
        self._falling_back = False
        self._obs = np.zeros(OBSERVATION_SIZE, dtype=np.float32)
        self._observer = Observer()

    def on_configure(self) -> None:
        if self.context.validation_only:
            return  # no files while only checking a change of gains
        path = self.gains['file'] or SHIPPED_POLICY
        try:
            self.policy, self.load_error = policy_file.load(path), ''
            # The first matrix product of a process initialises numpy's BLAS (94 ms
            # measured): done here, outside the control cycle, not in the first update.
            self.policy.force(observation(0.0, 0.0, 0.0, 0.0, 0.0, False, self._obs))
        except policy_file.PolicyFileError as error:
            self.policy, self.load_error = None, str(error)
            logger.warning('policy (%s): %s; the %s runs instead', self.kind, error,
                           self.fallback_class.name)
        fallback = self.fallback_class()
        fallback.configure({}, self.context)
        self._fallback = fallback

    @property
    def law(self) -> str:
        return f'policy:fallback({self.fallback_class.name})' if self._falling_back else 'policy'

    def on_activate(self, state: ControllerState) -> None:
        self._falling_back = False
        self._in_a_row = 0
        self._observer.reset(state.t)
        if self.policy is None:
            self._fall_back(state, self.load_error or 'no policy loaded')

    def _fall_back(self, state: ControllerState, reason: str) -> None:
        self._falling_back = True
        self.fallbacks += 1
        self.fallback_reason = reason
        logger.warning('policy (%s) falls back to %s: %s', self.kind, self.fallback_class.name,
                       reason)
        self._fallback.activate(state)

    def update(self, state: ControllerState) -> float:
        if not self._falling_back:
            # CPU time of this thread: the network's own work; a preemption of the whole
            # loop delays every law alike and is the loop's cycle gap, not an overrun
            start = time.thread_time()
            obs = self._observer.observe(state, self.context, self.kind == STABILIZER,
                                         self._obs)
            force = self.policy.force(obs)
            us = (time.thread_time() - start) * 1e6
            self.inference_us = us
            if not math.isfinite(force):
                self._fall_back(state, 'the network gave a non-finite force')
                return self._fallback.update(state)
            if us <= self.gains['max_inference_us'] or not self.context.real_time:
                self._in_a_row = 0
                return force
            self.overruns += 1
            self._in_a_row += 1
            if self._in_a_row < self.gains['max_overruns']:
                return force  # this cycle's force is computed: late once, still the policy's
            self._fall_back(state, f'overrun: {self._in_a_row} inferences in a row over '
                            f'{self.gains["max_inference_us"]:.0f} us of CPU, the last '
                            f'{us:.0f} us')
        return self._fallback.update(state)

    def command_applied(self, feedback: CommandFeedback) -> None:
        self._observer.feedback(feedback)
        if self._falling_back:
            self._fallback.command_applied(feedback)

    def on_deactivate(self) -> None:
        if self._fallback is not None and self._fallback.active:
            self._fallback.deactivate()
        # law keeps saying what ran until the next activation (the run summary reads it
        # after the catch has deactivated the swing-up)

    def status_values(self) -> Mapping[str, float]:
        return {'policy_us': round(self.inference_us, 1), 'policy_fallbacks': self.fallbacks,
                'policy_overruns': self.overruns}


class PolicySwingUp(_PolicyController):
    """The learned policy as a swing-up law; falls back to the energy swing-up (7.32)."""

    kind = SWINGUP
    fallback_class = PendulumEnergySwingUp


class PolicyStabilizer(_PolicyController):
    """The learned policy as a stabiliser; falls back to the LQR (8.17)."""

    kind = STABILIZER
    fallback_class = LqgStabilizer
