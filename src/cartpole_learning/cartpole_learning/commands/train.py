"""`cartpole train`: PPO on the rig's simulated loop, written as a policy file (docs/learning.md).

Needs the training extra (``pip install -r requirements-train.txt``); without
it the command says so and exits 2. docs/learning.md has what it does and how
long it takes.
"""
from __future__ import annotations

import argparse
import os
import sys

HELP = 'train a learned swing-up and stabiliser (PPO) and write its policy file'
"""The line of ``cartpole --help``."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', default='policy.npz', metavar='FILE.npz',
                        help='the policy file to write (default policy.npz; the SB3 model and '
                             'its normalisation go beside it for a later look)')
    parser.add_argument('--seed', type=int, default=0, help='seed of everything (default 0)')
    parser.add_argument('--rounds', type=int, default=6,
                        help='DAgger rounds; round 0 runs the teacher alone (default 6)')
    parser.add_argument('--episodes', type=int, default=40,
                        help='episodes per round (default 40)')
    parser.add_argument('--epochs', type=int, default=30,
                        help='passes of the fit over the aggregated data per round (default 30)')
    parser.add_argument('--workers', type=int, default=2,
                        help='processes that run the episodes (default 2)')
    parser.add_argument('--ppo-steps', type=int, default=0, metavar='N',
                        help='then N steps of PPO from the imitated policy (default 0: none)')
    parser.add_argument('--ranges', default=None, metavar='FILE.yaml',
                        help='range table of the randomised plant (the combined benchmark\'s '
                             'format, docs/robustness.md; missing keys keep the published ranges)')
    parser.add_argument('--plant-params', default=None, metavar='FILE.yaml',
                        help='nominal plant parameters (CartPoleParameters YAML, e.g. from '
                             '`cartpole identify`): the model of the EKF, the manager and the '
                             'teacher, and the centre of the ranges; default: thesis values')
    parser.add_argument('--duration', type=float, default=6.0, metavar='S',
                        help='simulated seconds per episode (default 6)')


def main(args: argparse.Namespace) -> int:
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
    except ImportError as error:
        print(f'cartpole train needs the training extra ({error}); install it with\n'
              '  pip install -r requirements-train.txt', file=sys.stderr)
        return 2
    from cartpole_learning.training import TrainConfig, train
    table = {}
    if args.ranges:
        from cartpole_sim.scenario_ranges import load_ranges
        try:
            table = load_ranges(args.ranges).to_dict()
        except (OSError, ValueError) as error:
            print(f'cartpole train: {args.ranges}: {error}', file=sys.stderr)
            return 2
    nominal = {}
    if args.plant_params:
        import dataclasses

        from cartpole_bringup.boundary import InputError, plant_parameters
        try:
            nominal = dataclasses.asdict(plant_parameters(args.plant_params))
        except InputError as error:
            print(f'cartpole train: {error}', file=sys.stderr)
            return 2
    if min(args.rounds, args.episodes, args.epochs, args.workers) <= 0 or args.ppo_steps < 0:
        print('--rounds, --episodes, --epochs and --workers must be > 0, --ppo-steps >= 0',
              file=sys.stderr)
        return 2
    config = TrainConfig(seed=args.seed, rounds=args.rounds, episodes=args.episodes,
                         epochs=args.epochs, workers=args.workers, ppo_steps=args.ppo_steps,
                         duration=args.duration, table=table, nominal=nominal)
    try:
        provenance = train(config, os.path.abspath(args.out), log=lambda s: print(s, flush=True))
    except ValueError as error:
        print(f'cartpole train: {error}', file=sys.stderr)
        return 2
    print(f'wrote {args.out}: {provenance["steps"]} steps in {provenance["wall_time_s"]} s '
          f'(seed {provenance["seed"]}, commit {provenance["commit"]})')
    return 0
