"""``cartpole train``'s work: DAgger on the teacher laws, optionally PPO, the policy file.

Needs the training extra (``pip install -r requirements-train.txt``: torch
CPU-only, stable-baselines3); nothing else of the package imports them.
:func:`train` runs the rounds of :mod:`cartpole_learning.imitation` (episodes
in ``workers`` processes, the fit in this one, torch on one thread), then
with ``ppo_steps`` stable-baselines3's PPO from the imitated actor (one
environment per process, ``VecNormalize`` starting from the imitation's
normalisation), and writes the actor, the normalisation, the action scale
and the provenance into the numpy policy file the plugin loads
(:mod:`cartpole_learning.policy_file`). The actor has stable-baselines3's
layout (Linear-Tanh-Linear-Tanh-Linear), so either stage's weights export
the same way.
"""
from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable

import numpy as np

from cartpole_core.model import CartPoleParameters

from cartpole_sim.scenario_ranges import RangeTable

from . import policy_file
from .env import SwingUpEnv
from .imitation import TEACHER
from .observation import OBSERVATION_SIZE, VARIANCE_FLOOR


@dataclass
class TrainConfig:
    """What one training run does; every field goes into the policy file's provenance."""

    seed: int = 0
    rounds: int = 8
    """DAgger rounds (:mod:`cartpole_learning.imitation`); round 0 is the teacher alone."""
    episodes: int = 80
    """Episodes per round (split over the workers)."""
    epochs: int = 30
    """Passes of the least-squares fit over the aggregated data, per round."""
    workers: int = 2
    ppo_steps: int = 0
    """PPO steps after the imitation (stable-baselines3), from the imitated actor; 0 = none."""
    envs: int = 8
    n_steps: int = 512
    batch_size: int = 512
    learning_rate: float = 1.0e-4
    gamma: float = 0.995
    gae_lambda: float = 0.95
    clip_range: float = 0.1
    log_std_init: float = -2.0
    teacher: tuple[str, str] = TEACHER
    """The laws DAgger imitates: (swing-up, stabiliser) plugin names."""
    net_arch: tuple[int, ...] = (64, 64)
    duration: float = 8.0
    upright_start: float = 0.25
    push_time: tuple[float, float] = (4.0, 7.0)
    """When a drawn push starts within an episode [s] (the table's own is for 30 s runs)."""
    nominal: dict[str, Any] = field(default_factory=dict)
    """Nominal plant parameters (fields of CartPoleParameters; empty: the thesis's)."""
    table: dict[str, Any] = field(default_factory=dict)
    """Range table fields (:class:`~cartpole_sim.scenario_ranges.RangeTable`); the others
    keep the published ranges."""


def _make_env(config: TrainConfig, rank: int) -> Callable[[], SwingUpEnv]:
    def make() -> SwingUpEnv:
        env = SwingUpEnv(CartPoleParameters(**config.nominal), table=config.table,
                         duration=config.duration, upright_start=config.upright_start,
                         push_time=config.push_time)
        env.reset(seed=config.seed * 1000 + rank)
        return env
    return make


def commit() -> str:
    """The repository's commit (with ``+dirty`` for uncommitted changes), or 'unknown'."""
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        head = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=here, capture_output=True,
                              text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'],
                               cwd=here, capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return 'unknown'
    return (head + ('+dirty' if dirty.strip() else '')) if head else 'unknown'


def build_actor(net_arch, size: int):
    """The actor as stable-baselines3's MlpPolicy builds it: Linear-Tanh-...-Linear."""
    import torch
    layers, width = [], size
    for hidden in net_arch:
        layers += [torch.nn.Linear(width, hidden), torch.nn.Tanh()]
        width = hidden
    layers.append(torch.nn.Linear(width, 1))
    return torch.nn.Sequential(*layers)


def sequential_layers(actor) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(weights, biases) of the Linear layers of a torch Sequential, as float64 arrays."""
    import torch
    linear = [m for m in actor if isinstance(m, torch.nn.Linear)]
    return ([m.weight.detach().cpu().numpy().astype(np.float64) for m in linear],
            [m.bias.detach().cpu().numpy().astype(np.float64) for m in linear])


def train(config: TrainConfig, out: str, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Imitate (DAgger), optionally fine-tune with PPO, write the policy file ``out``.

    Returns the provenance written into the file.
    """
    import multiprocessing

    import gymnasium
    import torch

    from .imitation import collect, fit, prepare_teacher, student_arrays

    torch.set_num_threads(1)
    torch.manual_seed(config.seed)
    start = time.perf_counter()
    load_before = os.getloadavg()
    code = commit()  # the code this run trains with, before anything can change it
    scale = CartPoleParameters(**config.nominal).force_max
    actor = build_actor(config.net_arch, OBSERVATION_SIZE)
    clip, eps = 10.0, 1e-8
    obs_all: list[np.ndarray] = []
    labels_all: list[np.ndarray] = []
    mean = var = None
    history = []
    prepare_teacher(CartPoleParameters(**config.nominal), tuple(config.teacher), log)
    context = multiprocessing.get_context('forkserver')
    with context.Pool(config.workers) as pool:
        for r in range(config.rounds):
            beta = 0.5 ** r
            student = None if r == 0 else student_arrays(*sequential_layers(actor), mean, var,
                                                         clip, eps, scale)
            share = [config.episodes // config.workers + (w < config.episodes % config.workers)
                     for w in range(config.workers)]
            jobs = [dict(seed=config.seed * 100_003 + r * 1009 + w, episodes=n, student=student,
                         beta=beta, table=config.table, duration=config.duration,
                         upright_start=config.upright_start, push_time=config.push_time,
                         nominal=config.nominal, teacher=tuple(config.teacher))
                    for w, n in enumerate(share) if n]
            results = pool.map(collect, jobs)
            ends: dict[str, int] = {}
            for res in results:
                obs_all.append(res['obs'])
                labels_all.append(res['labels'])
                for k, v in res['ends'].items():
                    ends[k] = ends.get(k, 0) + v
            falls = sum(res['falls'] for res in results)
            obs = np.concatenate(obs_all)
            labels = np.concatenate(labels_all)
            if mean is None:
                mean, var = obs.mean(axis=0).astype(np.float64), obs.var(axis=0).astype(np.float64)
                var = np.maximum(var, VARIANCE_FLOOR)
            log(f'round {r}: beta {beta:.3f}, {len(obs)} samples, ends {ends}, falls {falls}, '
                f'{time.perf_counter() - start:.0f} s')
            mse = fit(actor, obs, labels, mean, var, clip, eps, config.epochs, config.seed + r, log)
            history.append({'round': r, 'beta': beta, 'samples': int(len(obs)), 'ends': ends,
                            'falls': falls, 'mse': mse})
    weights, biases = sequential_layers(actor)
    ppo = {}
    if config.ppo_steps > 0:
        weights, biases, mean, var, ppo = _fine_tune(config, actor, mean, var, clip, log)
    wall = time.perf_counter() - start
    import stable_baselines3
    provenance = {
        'command': ' '.join(['cartpole', 'train'] + sys.argv[2:]) if sys.argv[1:2] == ['train']
        else ' '.join(sys.argv),
        'seed': config.seed, 'steps': int(sum(len(o) for o in obs_all)) + ppo.get('steps', 0),
        'wall_time_s': round(wall, 1), 'commit': code, 'config': asdict(config),
        'ranges': RangeTable.from_dict(config.table).to_dict(),
        'algorithm': f'DAgger on {config.teacher[0]} + {config.teacher[1]}'
        + (' then PPO' if ppo else ''),
        'rounds': history, 'ppo': ppo,
        'versions': {'torch': torch.__version__, 'gymnasium': gymnasium.__version__,
                     'stable_baselines3': stable_baselines3.__version__,
                     'numpy': np.__version__, 'python': platform.python_version()},
        'machine': {'cpus': os.cpu_count(), 'loadavg_before': [round(v, 2) for v in load_before],
                    'loadavg_after': [round(v, 2) for v in os.getloadavg()]},
    }
    policy_file.save(out, mean, var, clip, eps, weights, biases, scale, provenance)
    torch.save(actor.state_dict(), os.path.splitext(out)[0] + '.actor.pt')
    return provenance


def _fine_tune(config: TrainConfig, actor, mean, var, clip: float, log):
    """PPO from the imitated actor; returns its layers, normalisation and a summary."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecNormalize

    venv = VecNormalize(SubprocVecEnv([_make_env(config, i) for i in range(config.envs)]),
                        norm_obs=True, norm_reward=True, clip_obs=clip, gamma=config.gamma)
    venv.obs_rms.mean, venv.obs_rms.var, venv.obs_rms.count = mean.copy(), var.copy(), 1e6
    model = PPO('MlpPolicy', venv, n_steps=config.n_steps, batch_size=config.batch_size,
                learning_rate=config.learning_rate, gamma=config.gamma,
                gae_lambda=config.gae_lambda, clip_range=config.clip_range, seed=config.seed,
                device='cpu', verbose=0,
                policy_kwargs=dict(net_arch=dict(pi=list(config.net_arch),
                                                 vf=list(config.net_arch)),
                                   activation_fn=torch.nn.Tanh,
                                   log_std_init=config.log_std_init))
    linear = [m for m in actor if isinstance(m, torch.nn.Linear)]
    targets = [m for m in model.policy.mlp_extractor.policy_net
               if isinstance(m, torch.nn.Linear)] + [model.policy.action_net]
    with torch.no_grad():
        for source, target in zip(linear, targets):
            target.weight.copy_(source.weight)
            target.bias.copy_(source.bias)
    model.learn(total_timesteps=config.ppo_steps)
    weights, biases = actor_layers(model)
    summary = {'steps': int(model.num_timesteps)}
    venv.close()
    return weights, biases, venv.obs_rms.mean, venv.obs_rms.var, summary


def actor_layers(model) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The deterministic actor of an SB3 PPO model as (weights, biases), tanh between them."""
    import torch
    linear = [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    linear.append(model.policy.action_net)
    weights = [m.weight.detach().cpu().numpy().astype(np.float64) for m in linear]
    biases = [m.bias.detach().cpu().numpy().astype(np.float64) for m in linear]
    return weights, biases


