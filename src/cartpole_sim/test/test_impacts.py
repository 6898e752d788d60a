"""End-stop impacts: a cart resting against a stop is not a crash; hitting or pressing it is.

Pure tests: no rclpy.
"""
import pytest

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import IMPACT_PRESS_FORCE, IMPACT_SPEED, Plant, Scenario

NOMINAL = CartPoleParameters()
FRICTIONLESS = NOMINAL.replace(c_c_right=0.0, c_c_left=0.0, v_c=0.0)


def run(plant, command, samples):
    for _ in range(samples):
        plant.step(command)
    return plant


def test_a_cart_resting_on_the_left_stop_under_force_noise_is_no_impact():
    # 3 N of force noise presses the resting cart micrometres into the stop again and again.
    plant = run(Plant(NOMINAL, Scenario(force_noise=3.0, seed=4)), 0.0, 200)
    assert plant._in_stop or plant.state[0] > 0.0
    touched = Plant(NOMINAL, Scenario(force_noise=3.0, seed=4))
    pressed_in = 0
    for _ in range(200):
        touched.step(0.0)
        pressed_in += touched.in_end_stop()
    assert pressed_in > 10  # it was in contact (the old rule's failure) ...
    assert plant.impacts == [] and not plant.end_stop_contact  # ... but never hit it


@pytest.mark.parametrize('command, impact', [(-0.8 * IMPACT_PRESS_FORCE, False),
                                             (-1.5 * IMPACT_PRESS_FORCE, True)])
def test_our_force_pressing_the_resting_cart_into_the_stop_is_an_impact_beyond_the_bound(
        command, impact):
    plant = run(Plant(NOMINAL, Scenario()), command, 100)
    assert plant.end_stop_contact is impact
    if impact:
        (hit,) = plant.impacts  # one contact, one impact however long it presses
        assert (hit.side, hit.kind) == ('left', 'press')
        assert hit.force == pytest.approx(-command, rel=0.01)
        assert hit.t <= 0.005


@pytest.mark.parametrize('speed', [0.5 * IMPACT_SPEED, 2.0 * IMPACT_SPEED, 1.0])
def test_arriving_at_the_right_stop_faster_than_the_bound_is_an_impact(speed):
    # Coasting with no force and no friction: the arrival speed is the initial one.
    start = NOMINAL.travel - 0.002
    plant = run(Plant(FRICTIONLESS, Scenario(x0=start, x_dot0=speed)), 0.0, 40)
    if speed < IMPACT_SPEED:
        assert plant.impacts == []
        return
    hit = plant.impacts[0]
    assert (hit.side, hit.kind) == ('right', 'arrival')
    assert hit.speed == pytest.approx(speed, rel=0.01)
    assert hit.t == pytest.approx(0.002 / speed, abs=0.0015)


def test_full_force_across_the_rail_hits_the_far_stop_and_each_bounce_is_an_impact():
    plant = run(Plant(NOMINAL, Scenario()), 1000.0, 400)
    first, *bounces = plant.impacts
    assert (first.side, first.kind) == ('right', 'arrival') and first.speed > 1.0
    # The damped stop throws the cart back; each return faster than the bound hits again,
    # slower each time, until full force presses the cart in.
    assert len(bounces) >= 3 and all(b.side == 'right' for b in bounces)
    arrivals = [b for b in bounces if b.kind == 'arrival']
    assert all(a.speed > b.speed > IMPACT_SPEED for a, b in zip(plant.impacts, arrivals))
    assert bounces[-1].kind == 'press' and bounces[-1].force > IMPACT_PRESS_FORCE
    # The disturbed hold (a delay) judges contacts the same way, at the same time.
    delayed = run(Plant(NOMINAL, Scenario(delay=0.0025)), 1000.0, 400)
    assert len(delayed.impacts) == len(plant.impacts)
    assert delayed.impacts[0].t == pytest.approx(first.t + 0.0025, abs=0.0011)


def test_a_push_into_the_stop_is_not_our_force():
    # A 10 N push on the resting cart for 0.1 s presses it into the stop, but it is not ours.
    from cartpole_sim.plant import Push
    plant = run(Plant(NOMINAL, Scenario(pushes=(Push(0.0, 'cart', -10.0, 0.1),))), 0.0, 40)
    assert plant.impacts == []
    assert run(Plant(NOMINAL, Scenario()), -10.0, 40).impacts != []


def test_reset_forgets_the_impacts():
    plant = run(Plant(NOMINAL, Scenario()), 1000.0, 400)
    plant.reset()
    assert plant.impacts == [] and not plant.end_stop_contact and not plant._in_stop
