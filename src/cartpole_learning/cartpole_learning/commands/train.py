"""`cartpole train`: PPO on the rig's simulated loop, written as a policy file (docs/learning.md).

Needs the training extra (``pip install -r requirements-train.txt``); without
it the command says so in one line and exits 2, as for any refused option.
docs/learning.md has what it does and how long it takes.
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
    parser.add_argument('--rounds', type=int, default=8,
                        help='DAgger rounds; round 0 runs the teacher alone (default 8)')
    parser.add_argument('--episodes', type=int, default=80,
                        help='episodes per round (default 80)')
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
    parser.add_argument('--teacher', default='time_optimal:lqg', metavar='SWINGUP:STABILIZER',
                        help='the laws the policy imitates, two controller plugin names '
                             '(default time_optimal:lqg: its minimum-time plan is solved first '
                             'if it is not in the plan cache)')
    parser.add_argument('--duration', type=float, default=8.0, metavar='S',
                        help='simulated seconds per episode (default 8)')


BOUNDS = {'seed': (0, 2**32 - 1), 'rounds': (1, 50), 'episodes': (1, 1000), 'epochs': (1, 1000),
          'workers': (1, 64), 'ppo_steps': (0, 20_000_000), 'duration': (0.5, 30.0)}
"""Each sizing option's [low, high]: within them a training ends within hours at most
(docs/learning.md, "Training: `cartpole train`" has the times)."""


def checked(args: argparse.Namespace):
    """(TrainConfig, output path) from the options, or InputError naming the option and bound."""
    import dataclasses

    from cartpole_bringup import boundary

    from cartpole_learning.training import TrainConfig
    for name, (low, high) in BOUNDS.items():
        boundary.number('--' + name.replace('_', '-'), getattr(args, name), low, high)
    out = boundary.output_file(args.out, '--out', ('.npz',))
    table = {}
    if args.ranges:
        from cartpole_sim.scenario_ranges import load_ranges
        boundary.input_file(args.ranges, '--ranges')
        try:
            table = load_ranges(args.ranges).to_dict()
        except (OSError, ValueError) as error:
            raise boundary.InputError(f'--ranges {error}') from None
    nominal = {}
    if args.plant_params:
        nominal = dataclasses.asdict(boundary.plant_parameters(args.plant_params))
    from cartpole_learning.imitation import teacher_classes
    teacher = tuple(args.teacher.split(':'))
    if len(teacher) != 2:
        raise boundary.InputError(f'--teacher {args.teacher!r}: expected SWINGUP:STABILIZER, '
                                  'e.g. pendulum_energy:lqg')
    try:
        teacher_classes(teacher)
    except ValueError as error:
        raise boundary.InputError(f'--teacher {error}') from None
    config = TrainConfig(seed=args.seed, teacher=teacher, rounds=args.rounds, episodes=args.episodes,
                         epochs=args.epochs, workers=args.workers, ppo_steps=args.ppo_steps,
                         duration=args.duration, table=table, nominal=nominal)
    return config, out


def require_training_extra() -> None:
    """InputError in one line when torch or stable-baselines3 is missing."""
    from cartpole_bringup.boundary import InputError
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
    except ImportError as error:
        raise InputError(f'needs the training extra ({error}): pip install -r '
                         'requirements-train.txt (docs/learning.md)') from None


def main(args: argparse.Namespace) -> int:
    config, out = checked(args)
    require_training_extra()
    from cartpole_learning.training import train
    try:
        provenance = train(config, os.path.abspath(out), log=lambda s: print(s, flush=True))
    except ValueError as error:
        print(f'cartpole train: error: {error}', file=sys.stderr)
        return 2
    print(f'wrote {out}: {provenance["steps"]} steps in {provenance["wall_time_s"]} s '
          f'(seed {provenance["seed"]}, commit {provenance["commit"]})')
    return 0
