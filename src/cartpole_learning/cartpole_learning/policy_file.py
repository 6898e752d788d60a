"""The policy file: network weights, observation normalisation, action scaling, provenance.

One ``.npz`` (numpy's zip of arrays, read with ``allow_pickle=False``: a file
cannot run code) holds everything the ``policy`` plugin needs, so inference is
numpy alone (no torch on the rig):

- ``observation_names``: the order of :data:`cartpole_learning.observation.OBSERVATION_NAMES`;
- ``obs_mean``, ``obs_var``, ``obs_clip``, ``obs_epsilon``: the running
  normalisation of training (stable-baselines3's ``VecNormalize``),
  ``o_n = clip((o - mean) / sqrt(var + eps), -clip, clip)``;
- ``weights_<i>``, ``bias_<i>``: the actor's layers (PyTorch's ``Linear``
  layout, out x in), ``tanh`` between them, the last one linear: the mean
  action, which the deterministic policy uses;
- ``action_scale`` [N]: the raw force is ``clip(a, -1, 1) * action_scale``;
- ``provenance``: JSON (command, seed, steps, wall time, commit, ranges, ...).

:func:`load` checks every shape and finiteness and raises :class:`PolicyFileError`
with the reason; :meth:`Policy.force` is the forward pass.
"""
from __future__ import annotations

# zipfile decodes the .npz's member names with cp437: imported with the plugin, not read
# from disk in the manager's executor while a switch loads a policy file.
import encodings.cp437  # noqa: F401
import json
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .observation import OBSERVATION_NAMES

FORMAT = 'cartpole-policy/1'
"""The format tag stored in every file; :func:`load` refuses another."""


class PolicyFileError(ValueError):
    """A policy file that cannot be used (missing, unreadable, wrong shapes, non-finite)."""


@dataclass(frozen=True)
class Policy:
    """A loaded policy: normalisation, tanh MLP, action scale (see the module docstring)."""

    obs_mean: np.ndarray
    obs_scale: np.ndarray
    """1 / sqrt(var + eps), precomputed."""
    obs_clip: float
    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    action_scale: float
    provenance: dict[str, Any] = field(default_factory=dict)
    path: str = ''

    def action(self, obs: np.ndarray) -> float:
        """The network's mean action for one observation, clipped to [-1, 1] (a
        non-finite one is returned as it is)."""
        h = np.clip((obs - self.obs_mean) * self.obs_scale, -self.obs_clip, self.obs_clip)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = w @ h + b
            if i < last:
                h = np.tanh(h)
        a = float(h[0])
        if a != a or a in (math.inf, -math.inf):
            return a  # non-finite: passed on for the caller to refuse, never clipped to +-1
        return min(1.0, max(-1.0, a))

    def force(self, obs: np.ndarray) -> float:
        """The raw force [N] for one observation: ``clip(a, -1, 1) * action_scale``."""
        return self.action(obs) * self.action_scale


def save(path: str, obs_mean, obs_var, obs_clip: float, obs_epsilon: float,
         weights, biases, action_scale: float, provenance: dict[str, Any]) -> None:
    """Write a policy file (``path`` ends in ``.npz``); :func:`load` reads it back."""
    arrays: dict[str, np.ndarray] = {
        'format': np.array(FORMAT),
        'observation_names': np.array(OBSERVATION_NAMES),
        'obs_mean': np.asarray(obs_mean, dtype=np.float64),
        'obs_var': np.asarray(obs_var, dtype=np.float64),
        'obs_clip': np.array(float(obs_clip)),
        'obs_epsilon': np.array(float(obs_epsilon)),
        'action_scale': np.array(float(action_scale)),
        'provenance': np.array(json.dumps(provenance, sort_keys=True)),
    }
    for i, (w, b) in enumerate(zip(weights, biases)):
        arrays[f'weights_{i}'] = np.asarray(w, dtype=np.float64)
        arrays[f'bias_{i}'] = np.asarray(b, dtype=np.float64)
    with open(path, 'wb') as f:
        np.savez_compressed(f, **arrays)


def _scalar(data, name: str) -> float:
    value = float(data[name])
    if not math.isfinite(value):
        raise PolicyFileError(f'{name} is not finite')
    return value


def load(path: str) -> Policy:
    """Read and check a policy file; :class:`PolicyFileError` says what is wrong."""
    if not os.path.isfile(path):
        raise PolicyFileError(f'no policy file at {path!r}')
    try:
        with np.load(path, allow_pickle=False) as data:
            contents = {name: data[name] for name in data.files}
    except Exception as error:  # a zip that is not one, a truncated file, a pickled array
        raise PolicyFileError(f'{path}: not a policy file ({type(error).__name__}: {error})') \
            from None
    missing = [k for k in ('format', 'observation_names', 'obs_mean', 'obs_var', 'obs_clip',
                           'obs_epsilon', 'action_scale', 'weights_0', 'bias_0')
               if k not in contents]
    if missing:
        raise PolicyFileError(f'{path}: missing {missing}')
    if str(contents['format']) != FORMAT:
        raise PolicyFileError(f'{path}: format {str(contents["format"])!r}, expected {FORMAT!r}')
    names = tuple(str(n) for n in contents['observation_names'])
    if names != OBSERVATION_NAMES:
        raise PolicyFileError(f'{path}: observation {list(names)}, this plugin builds '
                              f'{list(OBSERVATION_NAMES)}')
    n = len(OBSERVATION_NAMES)
    weights, biases = [], []
    width = n
    i = 0
    while f'weights_{i}' in contents:
        w = np.asarray(contents[f'weights_{i}'], dtype=np.float64)
        b = np.asarray(contents.get(f'bias_{i}', np.zeros(0)), dtype=np.float64)
        if w.ndim != 2 or w.shape[1] != width or b.shape != (w.shape[0],):
            raise PolicyFileError(f'{path}: layer {i} has weights {w.shape} and bias {b.shape}, '
                                  f'expected (*, {width}) and (*,)')
        weights.append(w)
        biases.append(b)
        width = w.shape[0]
        i += 1
    if width != 1:
        raise PolicyFileError(f'{path}: the last layer gives {width} outputs, expected 1 (a force)')
    mean = np.asarray(contents['obs_mean'], dtype=np.float64)
    var = np.asarray(contents['obs_var'], dtype=np.float64)
    if mean.shape != (n,) or var.shape != (n,):
        raise PolicyFileError(f'{path}: normalisation of shape {mean.shape}/{var.shape}, '
                              f'expected ({n},)')
    arrays = [mean, var, *weights, *biases]
    if not all(np.all(np.isfinite(a)) for a in arrays) or np.any(var < 0.0):
        raise PolicyFileError(f'{path}: non-finite weights or normalisation, or a negative variance')
    clip, eps, scale = (_scalar(contents, k) for k in ('obs_clip', 'obs_epsilon', 'action_scale'))
    if clip <= 0.0 or eps < 0.0 or scale <= 0.0 or np.any(var + eps <= 0.0):
        raise PolicyFileError(f'{path}: obs_clip, action_scale must be > 0, obs_epsilon >= 0')
    try:
        provenance = json.loads(str(contents.get('provenance', '{}')))
    except ValueError:
        provenance = {}
    return Policy(mean, 1.0 / np.sqrt(var + eps), clip, tuple(weights), tuple(biases), scale,
                  provenance, os.path.abspath(path))
