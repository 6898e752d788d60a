"""Fuzz test of the `cartpole` command's boundary: generated bad values and damaged files.

Every subcommand's parser and loaders are driven in-process (``cli.main``)
with inputs that must be refused: numbers that are not finite or outside
their range, pushes after the end of the run, defective parameter files,
output paths that cannot be written, damaged bags. Each must give

- no traceback (no exception out of ``cli.main`` but SystemExit),
- exit code 2 for a refused input (1 where the issue wants a failed operation:
  ``bag info`` of a damaged bag, ``bag repair`` of an unrepairable one),
- exactly one line on stderr, ``cartpole SUB: error: ...`` for a refusal,
  naming the option or the file,

and no work may start: the functions that would run the loop, the graph, a
solve or a fit are replaced by one that raises :class:`WorkStarted`, so every
example takes milliseconds. The examples are derandomised (the same inputs on
every run). ``CARTPOLE_FUZZ_COUNT=1`` records the failures instead of failing
and prints the counts. test_cli_reach.py reaches every option of every subcommand.
"""
from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cartpole_bringup import cli

_spec = importlib.util.spec_from_file_location(
    'bag_synth', Path(__file__).parents[2] / 'cartpole_analysis' / 'test' / 'bag_synth.py')
bag_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bag_synth)

# The last test counts the examples its siblings ran in this process: under `make test`'s
# --dist loadgroup they must all run on one worker (the count once came to 360 of 400 there).
pytestmark = pytest.mark.xdist_group('cli_fuzz')

COUNT_ONLY = os.environ.get('CARTPOLE_FUZZ_COUNT') == '1'
TRIED: dict[str, int] = {}
FAILED: dict[str, list[str]] = {}


class WorkStarted(Exception):
    """Raised where a subcommand's real work would begin (the input was accepted)."""


def _work(*args, **kwargs):
    raise WorkStarted


WORK = [  # (module, attribute): where each subcommand's work begins
    ('cartpole_bringup.offline.closed_loop', 'run_closed_loop'),
    ('cartpole_bringup.commands.plan', 'prepare_for_run'),
    ('rclpy', 'init'),
    ('cartpole_control.trajectory_optimization', 'swingup_bounds'),
    ('cartpole_control.controllers.time_optimal', 'solve_plan_for'),
    ('cartpole_analysis.analysis.analyze', 'analyze_bag'),
    ('cartpole_tools.identification.bag_input', 'load_recording'),
    ('cartpole_tools.identification.fit', 'identify'),
    ('cartpole_tools.identification.pulse_player', 'rehearse'),
    ('cartpole_tools.commands.bench', 'bench_control'),
    ('cartpole_tools.commands.bench', 'bench_robustness'),
    ('cartpole_tools.commands.bench', 'bench_offline'),
    ('cartpole_tools.commands.bench', 'bench_loop'),
]

SETTINGS = settings(max_examples=120, deadline=None, derandomize=True, database=None,
                    suppress_health_check=list(HealthCheck))


@pytest.fixture(scope='module', autouse=True)
def no_work():
    """Replace every place where work would begin by :func:`_work`; report the counts."""
    import importlib
    with pytest.MonkeyPatch.context() as mp:
        for module, name in WORK:
            mp.setattr(importlib.import_module(module), name, _work)
        yield
    total = sum(TRIED.values())
    failed = sum(len(v) for v in FAILED.values())
    lines = [f'cartpole fuzz: {total} generated inputs, {failed} failed']
    kinds: dict[str, int] = {}
    for failures in FAILED.values():
        for text in failures:
            kind = text.rpartition(' -> ')[2] if ' -> ' in text else text.partition(': ')[2]
            kind = kind.split(':')[0].split(',')[0].strip()
            kinds[kind] = kinds.get(kind, 0) + 1
    lines += [f'  failure kind {k!r}: {n}' for k, n in sorted(kinds.items(), key=lambda kv: -kv[1])]
    for key in sorted(TRIED):
        lines.append(f'  {key}: {TRIED[key]} tried, {len(FAILED.get(key, []))} failed')
        lines += [f'    {f}' for f in FAILED.get(key, [])[:3]]
    print('\n' + '\n'.join(lines))


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    """Defective input files and a directory of output targets, made once."""
    root = tmp_path_factory.mktemp('fuzz')
    made = {
        'directory': root / 'a_directory',
        'missing': root / 'no' / 'such.yaml',
        'not_yaml': ('a: [1, 2\n', 'a: b: c\n', '\t- x\n', ': :\n', '{a: 1\n'),
        'binary': (b'\x00\xff\xfe\x89PNG\r\n', b'\xff' * 40),
        'list': ('[1, 2, 3]\n', '- m_c: 1\n'),
        'scalar': ('42\n', 'hello\n', 'true\n'),
        'negative_mass': ('m_c: -5\n', 'cartpole_plant:\n  m_p: -0.1\n', 'l: 0\n'),
        'nan_mass': ('m_c: .nan\n', 'm_p: .inf\n', 'cartpole_plant: {l: .nan}\n'),
        'mixed_keys': ('m_c: 1\n1: 2\n', '{[1]: 2}\n', '? [a]\n: 1\n'),
        'unknown_key': ('mass: 1\n', 'cartpole_plant: {m_cart: 4}\n'),
        'string_value': ('m_c: heavy\n', 'm_c: [1, 2]\n'),
    }
    (root / 'a_directory').mkdir()
    (root / 'a_directory.png').mkdir()  # a figure path that is a directory
    out = {'directory': [made['directory']], 'missing': [made['missing']]}
    for kind, contents in made.items():
        if kind in out:
            continue
        out[kind] = []
        for i, content in enumerate(contents):
            path = root / f'{kind}_{i}.yaml'
            (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
            out[kind].append(path)
    params = {
        'ekf_unknown': 'ekf:\n  ros__parameters:\n    qq: 1\n',
        'ekf_bad_q': 'ekf:\n  ros__parameters:\n    q: [1, 2]\n',
        'ekf_not_a_number': 'ekf:\n  ros__parameters:\n    friction_steepness: fast\n',
        'manager_unknown': 'controller_manager:\n  ros__parameters:\n    swingup: nope\n',
        'manager_bad_gain': 'controller_manager:\n  ros__parameters:\n    lqg:\n      r: -1.0\n',
        'manager_x_ref': 'controller_manager:\n  ros__parameters:\n    x_ref: .nan\n',
        'section_list': 'controller_manager: [1, 2]\n',
        'no_ros_parameters': 'ekf:\n  q: [1, 1, 1, 1]\n',
        'key_types': 'ekf:\n  ros__parameters:\n    1: 2\n',
    }
    for kind, content in params.items():
        path = root / f'params_{kind}.yaml'
        path.write_text(content)
        out.setdefault('params_only', []).append(path)
        if not kind.startswith('ekf') and kind != 'no_ros_parameters' and kind != 'key_types':
            out.setdefault('params_manager', []).append(path)
    (root / 'a_file.txt').write_text('x')
    out['a_file'] = [root / 'a_file.txt']
    out['root'] = root
    return out


@pytest.fixture(scope='module')
def good_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp('fuzz_bag') / 'run' / 'bag'
    bag_synth.write_run(bag, custom_data={'x_ref': repr(bag_synth.X_REF)})
    return bag


# -- running one input -------------------------------------------------------------------------
def invoke(argv: list[str]) -> tuple[int | None, str, str, BaseException | None]:
    out, err = io.StringIO(), io.StringIO()
    code, error = None, None
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            if not isinstance(exc.code, (int, type(None))):
                err.write(f'{exc.code}\n')
        except BaseException as exc:  # noqa: BLE001 - every other exception is a traceback
            error = exc
    return code, out.getvalue(), err.getvalue(), error


def check(key: str, argv: list[str], names: list[str], codes=(2,)) -> None:
    """Run ``argv``; record (and, unless counting, fail on) anything but a clean refusal."""
    TRIED[key] = TRIED.get(key, 0) + 1
    code, _, err, error = invoke(argv)
    lines = [line for line in err.splitlines() if line.strip()]
    problem = None
    if isinstance(error, WorkStarted):
        problem = 'accepted: the work started'
    elif error is not None:
        problem = f'traceback: {type(error).__name__}: {str(error)[:120]}'
    elif code not in codes:
        problem = f'exit code {code}, wanted {codes}: {err.strip()[:160]!r}'
    elif len(lines) != 1:
        problem = f'{len(lines)} lines on stderr: {err.strip()[:160]!r}'
    elif not any(name in lines[0] for name in names):
        problem = f'the line names none of {names}: {lines[0][:160]!r}'
    elif code == 2 and ': error: ' not in lines[0]:
        problem = f'a refusal without "SUB: error:": {lines[0][:160]!r}'
    if problem is None:
        return
    FAILED.setdefault(key, []).append(f'{" ".join(argv)[:200]} -> {problem}')
    if not COUNT_ONLY:
        pytest.fail(f'cartpole {" ".join(argv)}: {problem}')


# -- generated values --------------------------------------------------------------------------
NOT_NUMBERS = st.sampled_from(['nan', 'NaN', 'inf', '-inf', 'Infinity', '1e999', '-1e999',
                               'abc', '', ' ', '1,5', '0x10', '--', '1e', 'None'])


def bad_number(low=None, high=None, low_open=False, high_open=False, integer=False):
    """Strings of numbers outside [low, high] (or not numbers at all)."""
    options = [NOT_NUMBERS]
    if integer:
        if low is not None:
            options.append(st.integers(max_value=int(low) - 1, min_value=-10**30).map(str))
        if high is not None:
            options.append(st.integers(min_value=int(high) + 1, max_value=10**30).map(str))
        options.append(st.floats(allow_nan=False, allow_infinity=False).filter(
            lambda f: f != int(f) if abs(f) < 1e15 else True).map(repr))
        return st.one_of(*options)
    if low is not None:
        options.append(st.floats(max_value=low, exclude_max=not low_open, min_value=-1e308)
                       .map(repr))
    if high is not None:
        options.append(st.floats(min_value=high, exclude_min=not high_open, max_value=1e308)
                       .map(repr))
    return st.one_of(*options)


TRAVEL = 0.769
SCENARIO = {  # option: (low, high, low_open, high_open); the physical ranges
    '--x0': (0.0, TRAVEL, False, False),
    '--theta0': (-100.0, 100.0, False, False),
    '--tip-mass': (0.0, 1000.0, True, False),
    '--cart-mass': (0.0, 1000.0, True, False),
    '--friction-scale': (0.0, 1000.0, False, False),
    '--encoder-offset': (-100.0, 100.0, False, False),
    '--delay': (0.0, 0.04, False, False),
    '--jitter': (0.0, 0.04, False, False),
    '--drop': (0.0, 0.99, False, False),
    '--force-noise': (0.0, 1e4, False, False),
    '--actuator-gain': (0.0, 1000.0, True, False),
    '--actuator-tau': (0.0, 1.0, False, False),
}
DURATION = (0.0, 3600.0, True, False)


def option_values(table: dict[str, tuple]):
    return st.sampled_from(sorted(table)).flatmap(
        lambda opt: st.tuples(st.just(opt), bad_number(*table[opt])))


def bad_push(duration: float):
    """Pushes with a malformed part, a bad number, or a start after the end of the run."""
    good = st.floats(0.0, duration * 0.9).map(repr)
    late = st.floats(duration, 1e6).map(repr)
    number = bad_number(-1e4, 1e4)
    target = st.sampled_from(['cart', 'pendulum'])
    return st.one_of(
        st.tuples(late, target, st.just('5'), st.just('0.1')).map(':'.join),
        st.tuples(bad_number(0.0, 1e6), target, st.just('5'), st.just('0.1')).map(':'.join),
        st.tuples(good, st.text('abcxyz', min_size=0, max_size=6).filter(
            lambda t: t not in ('cart', 'pendulum')), st.just('5'), st.just('0.1')).map(':'.join),
        st.tuples(good, target, number, st.just('0.1')).map(':'.join),
        st.tuples(good, target, st.just('5'), bad_number(0.0, 1e6, True)).map(':'.join),
        st.text(':0123456789.abc', max_size=12).filter(lambda t: t.count(':') != 3),
    )


def file_option(files, option: str, kinds: list[str]):
    return st.sampled_from(kinds).flatmap(lambda k: st.sampled_from(files[k])).map(
        lambda path: (option, str(path)))


PLANT_DEFECTS = ['directory', 'missing', 'not_yaml', 'binary', 'list', 'scalar',
                 'negative_mass', 'nan_mass', 'mixed_keys', 'unknown_key', 'string_value']
PARAMS_DEFECTS = ['directory', 'missing', 'not_yaml', 'binary', 'list', 'scalar', 'params_only']


def figure_path(files):
    """--plot targets that cannot be written: a directory, a missing parent, no matplotlib
    format."""
    root = files['root']
    return st.one_of(
        st.just(str(files['root'] / 'a_directory.png')),
        st.text('abcdefghij', min_size=1, max_size=6).map(lambda s: str(root / 'nope' / f'{s}.png')),
        st.text('qwxyz', min_size=1, max_size=4).map(lambda s: str(root / f'plot.{s}k')),
        st.just(str(files['a_file'][0] / 'x.png')),
    )


# -- the subcommands ---------------------------------------------------------------------------
@SETTINGS
@given(data=st.data())
def test_offline_refuses_bad_numbers(data):
    opt, value = data.draw(st.one_of(
        option_values(SCENARIO),
        option_values({'--duration': DURATION, '--speed': (0.0, 1000.0, True, False)}),
        st.tuples(st.just('--seed'), bad_number(0, None, integer=True)),
        st.tuples(st.just('--push'), bad_push(1.0))))
    argv = ['offline', '--duration', '1', f'{opt}={value}']
    if opt == '--duration':
        argv = ['offline', f'{opt}={value}']
    check('offline numbers', argv, [opt])


@SETTINGS
@given(data=st.data())
def test_offline_refuses_bad_files_and_outputs(data, files):
    opt, value = data.draw(st.one_of(
        file_option(files, '--plant-params', PLANT_DEFECTS),
        file_option(files, '--params', PARAMS_DEFECTS),
        figure_path(files).map(lambda p: ('--plot', p))))
    check('offline files', ['offline', '--duration', '1', opt, value],
          [opt, value, str(Path(value).parent)])


@SETTINGS
@given(data=st.data())
def test_offline_refuses_a_run_that_loses_every_sample(data):
    seed = data.draw(st.integers(0, 50))
    drop = data.draw(st.floats(0.5, 0.99))
    # a run of one or two samples: lost entirely with a probability of drop^2
    from cartpole_core.model import CartPoleParameters
    from cartpole_sim.plant import Plant
    from cartpole_sim.scenario import Scenario
    plant = Plant(CartPoleParameters(), Scenario(drop=drop, seed=seed))
    if not (plant.sample_lost() and plant.sample_lost()):
        return  # some sample arrives: a valid run (and not this test's business)
    check('offline all samples lost',
          ['offline', '--duration', '0.005', '--drop', repr(drop), '--seed', str(seed)],
          ['--drop'])


@SETTINGS
@given(data=st.data())
def test_run_refuses_bad_numbers_files_and_outputs(data, files):
    opt, value = data.draw(st.one_of(
        option_values(SCENARIO),
        option_values({'--duration': DURATION}),
        st.tuples(st.just('--push'), bad_push(1.0)),
        st.tuples(st.just('--domain-id'), bad_number(0, 232, integer=True)),
        file_option(files, '--plant-params', PLANT_DEFECTS),
        file_option(files, '--params', PARAMS_DEFECTS),
        st.tuples(st.sampled_from(['--record', '--plots']),
                  st.sampled_from([str(files['a_file'][0]),
                                   str(files['a_file'][0] / 'below')]))))
    argv = ['run', '--sim', '--duration', '1', f'{opt}={value}']
    if opt == '--duration':
        argv = ['run', '--sim', f'{opt}={value}']
    check('run', argv, [opt, value])


def _damaged_bag(kind: str, good: Path, root: Path, cut: float, junk: bytes) -> Path:
    """A copy of ``good`` damaged as ``kind``."""
    import tempfile
    bag = Path(tempfile.mkdtemp(dir=root)) / 'bag'
    shutil.copytree(good, bag)
    mcap = next(bag.glob('*.mcap'))
    meta = bag / 'metadata.yaml'
    if kind == 'truncated':
        data = mcap.read_bytes()
        mcap.write_bytes(data[:int(len(data) * cut)])
    elif kind == 'empty_file':
        mcap.write_bytes(b'')
    elif kind == 'random_file':
        mcap.write_bytes(junk or b'\x00')
    elif kind == 'no_file':
        mcap.unlink()
    elif kind == 'garbage_metadata':
        meta.write_bytes(junk or b'\x00')
    elif kind == 'no_metadata':
        meta.unlink()
    elif kind == 'wrong_counts':
        text = meta.read_text()
        meta.write_text(text.replace('message_count: ', 'message_count: 1', 1))
    elif kind == 'empty_dir':
        shutil.rmtree(bag)
        bag.mkdir()
    return bag


BAG_DAMAGE = ['truncated', 'empty_file', 'random_file', 'no_file', 'garbage_metadata',
              'no_metadata', 'wrong_counts']


def damaged_bags(good_bag, files, kinds=BAG_DAMAGE):
    return st.builds(_damaged_bag, st.sampled_from(kinds), st.just(good_bag),
                     st.just(files['root']), st.floats(0.0, 0.999),
                     st.binary(min_size=0, max_size=200))


@SETTINGS
@given(data=st.data())
def test_analyze_refuses_damaged_bags_and_bad_options(data, good_bag, files):
    if data.draw(st.booleans()):
        bag = data.draw(damaged_bags(good_bag, files, BAG_DAMAGE + ['empty_dir']))
        check('analyze damaged bag', ['analyze', str(bag)], [str(bag)])
        return
    opt, value = data.draw(st.one_of(
        st.tuples(st.just('--x-ref'), bad_number(0.0, TRAVEL)),
        file_option(files, '--plant-params', PLANT_DEFECTS),
        st.tuples(st.just('--plots'), st.just(str(files['a_file'][0]))),
        st.tuples(st.just('--animate'), st.text('abcdef', min_size=1, max_size=4).map(
            lambda s: str(files['root'] / f'anim.{s}x'))),
        st.tuples(st.just('--animate'), st.just(str(files['directory'][0] / 'x.gif'))
                  .map(lambda p: str(Path(p).parent))),
    ))
    check('analyze options', ['analyze', str(good_bag), f'{opt}={value}'], [opt, value])


@settings(SETTINGS, max_examples=40)  # each example copies, damages and repairs a bag: ~0.2 s
@given(data=st.data())
def test_bag_info_says_damaged_and_repair_says_what_it_cannot(data, good_bag, files):
    bag = data.draw(damaged_bags(good_bag, files))
    check('bag info damaged', ['bag', 'info', str(bag)], [str(bag)], codes=(1,))
    code, out, err, error = invoke(['bag', 'repair', str(bag)])
    TRIED['bag repair'] = TRIED.get('bag repair', 0) + 1
    problem = None
    if error is not None:
        problem = f'traceback: {type(error).__name__}: {error}'
    elif code == 0:
        if invoke(['bag', 'info', str(bag)])[0] != 0:
            problem = 'repair said done, but bag info still finds it damaged'
    elif code != 1 or len(err.strip().splitlines()) != 1 or str(bag) not in err:
        problem = f'exit {code}, stderr {err.strip()[:160]!r}'
    if problem:
        FAILED.setdefault('bag repair', []).append(f'{bag}: {problem}')
        if not COUNT_ONLY:
            pytest.fail(f'cartpole bag repair {bag}: {problem}')


@SETTINGS
@given(data=st.data())
def test_identify_refuses_bad_bounds_numbers_files_and_damaged_bags(data, good_bag, files):
    if data.draw(st.integers(0, 3)) == 0:
        bag = data.draw(damaged_bags(good_bag, files, [k for k in BAG_DAMAGE]))
        check('identify damaged bag', ['identify', str(bag)], [str(bag)])
        return
    name = data.draw(st.sampled_from(['m_c', 'c_c_right', 'c_c_left']))
    opt, value = data.draw(st.one_of(
        st.tuples(st.just('--bound'), st.one_of(
            st.tuples(bad_number(0.0, None), st.floats(0.5, 5).map(repr)),
            st.tuples(st.floats(-10, -0.01).map(repr), st.floats(-0.01, 5).map(repr)),
            st.tuples(st.floats(1, 5).map(repr), st.floats(0.01, 1).map(repr)),
        ).map(lambda lh: f'{name}={lh[0]}:{lh[1]}')),
        option_values({'--weight-cart': (0.0, 1e6, True, False),
                       '--weight-pendulum': (0.0, 1e6, True, False),
                       '--integration-step': (1e-4, 0.005, False, False),
                       '--t-start': (0.0, 3600.0, False, False)}),
        st.tuples(st.just('--max-nfev'), bad_number(1, 100_000, integer=True)),
        file_option(files, '--plant-params', PLANT_DEFECTS),
        st.tuples(st.just('--output'), st.sampled_from([
            str(files['directory'][0]), str(files['root'] / 'nope' / 'p.yaml'),
            str(files['root'] / 'p.txt')])),
        figure_path(files).map(lambda p: ('--plot', p)),
    ))
    free = 'm_c,c_c_right,c_c_left'
    check('identify', ['identify', str(good_bag), '--free', free, f'{opt}={value}'],
          [opt, value, str(Path(value).parent)])


@SETTINGS
@given(data=st.data())
def test_bound_and_plan_refuse_bad_numbers_and_files(data, files):
    if data.draw(st.booleans()):
        opt, value = data.draw(st.one_of(
            st.tuples(st.just('--intervals'), bad_number(5, 2000, integer=True)),
            st.tuples(st.just('--refine'), bad_number(0, 4000, integer=True)),
            file_option(files, '--plant-params', PLANT_DEFECTS)))
        check('bound', ['bound', f'{opt}={value}'], [opt, value])
        return
    opt, value = data.draw(st.one_of(
        st.tuples(st.just('--x0'), bad_number(0.0, TRAVEL)),
        file_option(files, '--plant-params', PLANT_DEFECTS),
        file_option(files, '--params', PARAMS_DEFECTS[:-1] + ['params_manager'])))
    check('plan', ['plan', '--no-bound', f'{opt}={value}'], [opt, value])


def test_the_fuzz_tried_enough_inputs():
    """The examples above ran (each test adds to the count) and none failed."""
    assert sum(TRIED.values()) >= 400, TRIED
    if not COUNT_ONLY:
        assert not FAILED, FAILED
