"""The combined benchmark's range table, its draws and the scenario file round trip.

Pure tests: no rclpy.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant
from cartpole_sim.scenario import Push, Scenario
from cartpole_sim.scenario_ranges import FACTORS, RangeTable, dump_ranges, factors, load_ranges, \
    sample

PUBLISHED = Path(__file__).resolve().parents[1] / 'config' / 'combined_ranges.yaml'
NOMINAL = CartPoleParameters()


def test_the_published_yaml_is_the_default_table():
    table = load_ranges(PUBLISHED)
    assert table == RangeTable()
    assert table.push_share == 2 / 3
    assert table.cart_mass == (0.8, 1.25) and table.delay == (0.0, 0.025)


def test_a_dumped_table_loads_back_equal(tmp_path):
    table = RangeTable(delay=(0.001, 0.0123456789), push_share=0.3, noise=False)
    path = tmp_path / 'r.yaml'
    path.write_text(dump_ranges(table))
    assert load_ranges(path) == table


def test_a_users_partial_table_keeps_the_other_defaults(tmp_path):
    path = tmp_path / 'mine.yaml'
    path.write_text('delay: [0.0, 0.01]\npush_share: 0\n')
    table = load_ranges(path)
    assert table.delay == (0.0, 0.01) and table.push_share == 0.0
    assert table.cart_mass == RangeTable().cart_mass


@pytest.mark.parametrize('text, words', [
    ('delays: [0, 0.01]', ['unknown factor', "'delays'", 'delay']),
    ('delay: [0.02, 0.01]', ['delay', 'low <= high']),
    ('delay: [0, 0.5]', ['delay', '[0, 0.04]']),
    ('delay: 0.01', ['delay', '[low, high]']),
    ('cart_mass: [0, 1.2]', ['cart_mass', '> 0']),
    ('force_noise: [0, .nan]', ['force_noise', 'number']),
    ('push_share: 3/2', ['push_share', '[0, 1]']),
    ('push_share: two', ['push_share', 'fraction']),
    ('noise: 1', ['noise', 'true or false']),
    ('- 1\n- 2', ['mapping']),
    ('delay: [0, 0.01', ['not valid YAML']),
])
def test_a_bad_table_is_refused_naming_the_file_and_the_key(tmp_path, text, words):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ValueError) as error:
        load_ranges(path)
    assert str(path) in str(error.value)
    for word in words:
        assert word in str(error.value)


def test_a_missing_file_is_refused_with_its_name(tmp_path):
    with pytest.raises(ValueError, match='cannot read'):
        load_ranges(tmp_path / 'nope.yaml')


def test_every_factor_is_drawn_inside_its_interval_and_the_pushes_as_published():
    table = RangeTable()
    drawn = [sample(table, seed) for seed in range(600)]
    values = {name: np.array([factors(s)[name] for s in drawn]) for name in FACTORS}
    for name in ('cart_mass', 'tip_mass', 'pendulum_length', 'friction', 'delay', 'jitter',
                 'actuator_gain', 'actuator_lag', 'encoder_offset', 'lost_samples',
                 'force_noise'):
        low, high = getattr(table, name)
        assert low <= values[name].min() and values[name].max() <= high, name
        # Spread over the interval, not stuck at one value.
        assert values[name].max() - values[name].min() > 0.9 * (high - low), name
    pushed = [s for s in drawn if s.pushes]
    # Two runs of three: 400 expected, binomial std 11.5; 4.5 std either way.
    assert 348 <= len(pushed) <= 452
    cart = [s.pushes[0] for s in pushed if s.pushes[0].target == 'cart']
    pend = [s.pushes[0] for s in pushed if s.pushes[0].target == 'pendulum']
    assert 150 <= len(cart) <= 250 and len(cart) + len(pend) == len(pushed)
    assert all(abs(p.impulse) <= 3.0 + 1e-12 and p.width == 0.1 for p in cart)
    assert all(abs(p.impulse) <= 0.025 + 1e-15 and p.width == 0.05 for p in pend)
    assert any(p.impulse < 0 for p in cart) and any(p.impulse > 0 for p in cart)
    assert all(10.0 <= s.pushes[0].t <= 15.0 for s in pushed)
    assert all(s.noise and s.theta0 == math.pi + s.encoder_offset for s in drawn)
    assert len({s.seed for s in drawn}) == len(drawn)


def test_a_draw_depends_only_on_the_seed_or_the_generator_state():
    assert sample(RangeTable(), 7) == sample(RangeTable(), 7)
    assert sample(RangeTable(), 7) != sample(RangeTable(), 8)
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    assert [sample(RangeTable(), a) for _ in range(3)] == [sample(RangeTable(), b) for _ in
                                                           range(3)]


def test_a_degenerate_table_gives_the_nominal_plant_with_noise():
    table = RangeTable(**{n: (1.0, 1.0) for n in ('cart_mass', 'tip_mass', 'pendulum_length',
                                                  'friction', 'actuator_gain')},
                       **{n: (0.0, 0.0) for n in ('delay', 'jitter', 'actuator_lag',
                                                  'encoder_offset', 'lost_samples',
                                                  'force_noise')}, push_share=0.0)
    s = sample(table, 1)
    assert s.replace(seed=0) == Scenario(noise=True)


def test_the_drawn_scales_reach_the_plants_true_parameters():
    s = sample(RangeTable(), 11)
    f = factors(s)
    p = Plant(NOMINAL, s).true_params
    assert p.m_c == NOMINAL.m_c * f['cart_mass'] and p.m_p == NOMINAL.m_p * f['tip_mass']
    assert p.l == NOMINAL.l * f['pendulum_length']
    assert p.c_c_right == NOMINAL.c_c_right * f['friction']


def test_a_scenario_round_trips_through_json_and_yaml_exactly():
    s = Scenario(x0=0.1, theta0=3.0000000000000004, tip_mass=0.3, cart_mass=5.1,
                 friction_scale=1.1, encoder_offset=-0.013, noise=True,
                 noise_std_cart=1.23e-4, noise_std_pendulum=1 / 3 * 1e-2, seed=12345,
                 parameter_scales=(('l', 1.0 + 1e-15), ('c_p', 2.0)), delay=0.0123,
                 jitter=0.001, drop=0.02, force_noise=2.5, actuator_gain=0.7,
                 actuator_tau=0.013, pushes=(Push(12.5, 'cart', -21.7, 0.1),
                                             Push(3.0, 'pendulum', 0.1, 0.05)))
    assert Scenario.from_dict(json.loads(json.dumps(s.to_dict()))) == s
    assert Scenario.from_dict(yaml.safe_load(yaml.safe_dump(s.to_dict()))) == s
    drawn = sample(RangeTable(), 5)
    assert Scenario.from_dict(json.loads(json.dumps(drawn.to_dict()))) == drawn


@pytest.mark.parametrize('data, word', [
    ({'delays': 0.1}, 'unknown scenario field'),
    ({'delay': 1.0}, 'delay'),
    ({'pushes': [{'t': 1, 'target': 'cart'}]}, 'push'),
    ({'pushes': [{'t': 1, 'target': 'roof', 'amplitude': 1, 'width': 0.1}]}, 'target'),
    ({'parameter_scales': [['mass', 2.0]]}, 'parameter_scales'),
    ({'parameter_scales': [1.0]}, 'pairs'),
    ([], 'mapping'),
])
def test_a_bad_scenario_mapping_is_refused_with_its_field(data, word):
    with pytest.raises(ValueError, match=word):
        Scenario.from_dict(data)
