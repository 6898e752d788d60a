"""Every option of every `cartpole` subcommand, reached: hostile values are refused in one line.

The options are found by walking the argparse tree (:func:`cartpole_bringup.cli.build_parser`,
the ``cartpole.commands`` entry points' subcommands and ``cartpole emulate``'s own
parser), so an option added tomorrow is fuzzed without a line here. Each option
with a value gets a battery by its kind: numbers get ``nan``, infinities and
+-1e308 (refused, and a huge one with the bound in the message), options that
size the work (steps, speeds, periods) also 1e-300; paths a directory, a missing
file, a file that is not YAML and a path below a regular file; free text the
empty string and 10,000 characters; choices a name that is none of them. Flags
are added to a valid command line. Each input must end in a refusal (exit 2, one
line ``cartpole SUB: error: ...`` naming the option) or in the real work: run
for real where it ends within seconds (``offline``, ``analyze``, ``bag``,
``emulate`` in a forked child), else stopped where it would begin
(:data:`WORK`). No traceback either way.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import io
import os
import re
import signal
import sys
from pathlib import Path

import pytest

from cartpole_bringup import cli

_spec = importlib.util.spec_from_file_location(
    'bag_synth', Path(__file__).parents[2] / 'cartpole_analysis' / 'test' / 'bag_synth.py')
bag_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bag_synth)

NUMERIC = ('float', 'int', '_probability')
HOSTILE_NUMBERS = ('nan', 'inf', '-inf', '1e308', '-1e308')
HUGE = ('1e308', '-1e308', str(10**30), str(-10**30))
SIZING = re.compile(r'step|speed|every|period|rate')
"""Option names that size the work: a tiny value means a huge amount of it."""
BOUND_WORDS = re.compile(r'<=|>=|<|>|at most|at least|\[.*,.*\]|between|range|within')

WORK = [  # (module, attribute): where work would begin that takes more than seconds
    ('rclpy', 'init'),
    ('cartpole_bringup.commands.plan', 'prepare_for_run'),
    ('cartpole_control.trajectory_optimization', 'swingup_bounds'),
    ('cartpole_control.controllers.time_optimal', 'solve_plan_for'),
    ('cartpole_tools.identification.fit', 'identify'),
    ('cartpole_tools.identification.pulse_player', 'rehearse'),
    ('cartpole_tools.commands.bench', 'bench_control'),
    ('cartpole_tools.commands.bench', 'bench_robustness'),
    ('cartpole_tools.commands.bench', 'bench_offline'),
    ('cartpole_tools.commands.bench', 'bench_loop'),
    ('cartpole_tools.soak.session', 'run_soak'),
    ('cartpole_learning.commands.train', 'require_training_extra'),  # then the training
]

WORK_LIMIT_S = 60
"""Wall seconds an accepted input's real work may take (a command that runs on is a hole)."""

KNOWN_HOLES: set[str] = set()
KNOWN_HOLE_COMMANDS: dict[str, str] = {}
"""Subcommands whose every problem is known (the merge that fixes one removes it)."""
"""``'SUB --option value'`` inputs (or ``'SUB --option'``: any value) handled wrongly today that other work in progress refuses;
the merge that closes one removes it (a listed input that is refused fails the test)."""


class WorkStarted(Exception):
    """Raised where a long subcommand's work would begin (the input was accepted)."""


def _work(*args, **kwargs):
    raise WorkStarted


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _walk(sub, path + (name,))
        elif action.option_strings and not isinstance(action, argparse._HelpAction):
            yield path, action


def every_option() -> list[tuple[tuple[str, ...], argparse.Action]]:
    """(subcommand path, action) of every option of the `cartpole` command."""
    from cartpole_emulator.emulator import build_parser as emulator_parser

    found = [(p, a) for p, a in _walk(cli.build_parser()) if p != ('emulate',)]
    return found + [(('emulate',), a) for _, a in _walk(emulator_parser())]


def battery(action: argparse.Action, files: dict) -> list[tuple[str, bool]]:
    """(value, must it be refused) for one option."""
    if action.nargs == 0:
        return [('', False)]       # a flag: added to a valid command line
    kind = getattr(action.type, '__name__', None)
    if action.choices is not None and action.type is None:
        return [('no-such-choice', True)]
    if kind == 'int':
        huge = 'seed' not in action.dest  # any integer seeds a generator: no work in its size
        return [('nan', True), ('1.5', True), (str(10**30), huge), (str(-10**30), True)]
    if kind in NUMERIC:
        tiny = [('1e-300', True)] if SIZING.search(action.dest) else []
        return [(v, True) for v in HOSTILE_NUMBERS] + tiny
    if kind == 'Path' or action.metavar in ('FILE', 'FILE.yaml', 'ELF', 'PATH', 'DIR'):
        return [(str(files['directory']), False), (str(files['missing']), False),
                (str(files['not_yaml']), False), (str(files['a_file'] / 'below'), True)]
    return [('', False), ('x' * 10_000, False), ('a:b:c', False)]


BASE = {  # a valid command line of each subcommand; {bag} is a good synthetic bag
    ('run',): ['run', '--sim', '--duration', '1'],
    ('offline',): ['offline', '--duration', '0.05', '--no-wait'],
    ('analyze',): ['analyze', '{bag}'],
    ('bag', 'info'): ['bag', 'info', '{bag}'],
    ('bag', 'repair'): ['bag', 'repair', '{bag}'],
    ('bound',): ['bound'],
    ('plan',): ['plan'],
    ('identify',): ['identify', '{bag}'],
    ('soak',): ['soak', '--duration', '60'],
    ('emulate',): ['emulate', '--duration', '0.3'],
}


def base_argv(path: tuple[str, ...], bag: Path) -> list[str]:
    argv = BASE.get(path) or list(path)
    return [str(bag) if a == '{bag}' else a for a in argv]


def with_option(base: list[str], action: argparse.Action, value: str) -> list[str]:
    """``base`` with the option set to ``value`` (replacing the base's own value of it)."""
    opt = action.option_strings[-1]
    argv = list(base)
    for name in action.option_strings:
        if name in argv:
            i = argv.index(name)
            del argv[i:i + (1 if action.nargs == 0 else 2)]
    if action.nargs == 0:
        return argv + [opt]
    return argv + [f'{opt}={value}']


def invoke(argv: list[str]) -> tuple[int | None, str, BaseException | None]:
    """``cartpole ARGV`` in this process (emulate in a forked child, bounded); (code, stderr,
    error)."""
    if argv[0] == 'emulate':
        return _forked(argv)
    err = io.StringIO()
    code, error = None, None

    def too_long(signum, frame):
        raise TimeoutError(f'still running after {WORK_LIMIT_S} s')
    previous = signal.signal(signal.SIGALRM, too_long)
    signal.alarm(WORK_LIMIT_S)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException as exc:  # noqa: BLE001 - anything else is a traceback or the work
            error = exc
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)
    return code, err.getvalue(), error


def _forked(argv: list[str]) -> tuple[int | None, str, BaseException | None]:
    """``cartpole ARGV`` in a child forked from this process: its own process (emulate sets
    real-time priorities, signal handlers and threads) without a new interpreter's imports
    (0.5 s an input)."""
    import select
    import tempfile
    import traceback

    with tempfile.TemporaryFile() as captured:
        pid = os.fork()
        if pid == 0:  # the child: stderr to the file, stdout away, exit with main's code
            code = 1
            try:
                os.dup2(captured.fileno(), 2)
                os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
                sys.stdout = open(1, 'w', closefd=False)
                sys.stderr = open(2, 'w', buffering=1, closefd=False)
                try:
                    code = cli.main(argv) or 0
                except SystemExit as exc:
                    code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
                except BaseException:  # noqa: BLE001 - reported as the traceback it is
                    traceback.print_exc()
                sys.stderr.flush()
            finally:
                os._exit(code)
        done = os.pidfd_open(pid)
        try:
            if not select.select([done], [], [], 30.0)[0]:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                return None, '', TimeoutError('still running after 30 s')
        finally:
            os.close(done)
        code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
        captured.seek(0)
        err = captured.read().decode(errors='replace')
    error = RuntimeError(err[-300:]) if 'Traceback' in err else None
    return code, err, error


def children() -> list[str]:
    """The command lines of this process's living children (a viewer left running, say)."""
    from cartpole_tools.bench.procfs import children as child_pids, stat_fields

    found = []
    for pid in child_pids(os.getpid()):
        fields = stat_fields(pid)
        try:
            if fields is not None and fields[0] != 'Z':
                found.append(Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ')
                             .decode(errors='replace')[:120])
        except OSError:
            continue   # gone meanwhile
    return found


def judge(argv: list[str], action: argparse.Action, value: str, must_refuse: bool,
          huge: bool) -> str | None:
    """What is wrong with the outcome of ``argv`` (None: a clean refusal or clean work)."""
    before = set(children())
    code, err, error = invoke(argv)
    left = set(children()) - before
    if left:
        return f'left a process running: {sorted(left)[0]}'
    lines = [line for line in err.splitlines() if line.strip()]
    if isinstance(error, WorkStarted) or (error is None and code in (0, 1) and not must_refuse):
        return 'accepted' if must_refuse else None
    if error is not None:
        return f'traceback: {type(error).__name__}: {str(error)[:160]}'
    if code != 2:
        return f'exit {code}' + (' (accepted)' if must_refuse else '')
    if len(lines) != 1 or ': error: ' not in lines[0]:
        return f'{len(lines)} lines: {err.strip()[-200:]!r}'
    if not any(name in lines[0] for name in action.option_strings) and \
            not (value and value[:40] in lines[0]):
        return f'the line names no option: {lines[0][:160]!r}'
    if huge and not BOUND_WORDS.search(lines[0]):
        return f'the line says no bound: {lines[0][:160]!r}'
    return None


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp('reach')
    (root / 'a_directory').mkdir()
    (root / 'not_yaml.yaml').write_text('a: [1, 2\n')
    (root / 'a_file').write_text('x')
    return {'directory': root / 'a_directory', 'missing': root / 'no' / 'such.yaml',
            'not_yaml': root / 'not_yaml.yaml', 'a_file': root / 'a_file', 'root': root}


@pytest.fixture(scope='module')
def good_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp('reach_bag') / 'run' / 'bag'
    bag_synth.write_run(bag, custom_data={'x_ref': repr(bag_synth.X_REF)})
    return bag


@pytest.fixture(scope='module', autouse=True)
def long_work_stopped():
    with pytest.MonkeyPatch.context() as mp:
        for module, name in WORK:
            mp.setattr(importlib.import_module(module), name, _work)
        yield


def test_the_walk_finds_every_subcommand_and_its_options():
    options = every_option()
    paths = {p for p, _ in options}
    for sub in cli.subcommand_modules():
        assert any(p[0] == sub for p in paths), sub
    assert {('emulate',), ('soak',), ('bench', 'loop'), ('bag', 'repair')} <= paths
    assert len(options) >= 180


def _paths():
    """Every subcommand path; ``emulate`` (a process an input, a few seconds each) is slow."""
    return [pytest.param(p, id=' '.join(p), marks=[pytest.mark.slow] if p == ('emulate',) else [])
            for p in sorted({p for p, _ in every_option()})]


@pytest.mark.parametrize('path', _paths())
def test_every_option_refuses_hostile_values_cleanly(path, files, good_bag, tmp_path,
                                                     monkeypatch):
    monkeypatch.chdir(tmp_path)  # what accepted text makes (a figure named a:b:c.png) lands here
    problems, tried, holes_seen = [], 0, set()
    for p, action in every_option():
        if p != path:
            continue
        for value, must_refuse in battery(action, files):
            bag = tmp_path / f'bag{tried}'
            if path == ('bag', 'repair'):
                import shutil
                shutil.copytree(good_bag, bag)
            else:
                bag = good_bag
            argv = with_option(base_argv(path, bag), action, value)
            tried += 1
            problem = judge(argv, action, value, must_refuse,
                            huge=value in HUGE and must_refuse)
            key = f'{" ".join(path)} {action.option_strings[-1]} {value[:20]}'
            hole = next((h for h in KNOWN_HOLES if key.startswith(h)), None)
            if problem and hole is None:
                problems.append(f'{key}: {problem}')
            elif problem:
                holes_seen.add(hole)
    for hole in KNOWN_HOLES:
        if hole.split(' --')[0] == ' '.join(path) and hole not in holes_seen:
            problems.append(f'{hole}: handled now, remove it from KNOWN_HOLES')
    assert tried > 0
    if ' '.join(path) in KNOWN_HOLE_COMMANDS:
        assert problems, f'{" ".join(path)}: no problem left, remove it from KNOWN_HOLE_COMMANDS'
        return
    assert problems == [], '\n'.join(problems)
