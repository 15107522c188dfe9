"""The teleoperation dial (temoto_operator/dial.py): logarithmic steps, bounds, bad values refused."""
import math

import numpy as np

import pytest

from temoto_operator.dial import MAXIMUM, MINIMUM, STEPS, Dial


def test_the_steps_run_the_1_2_5_series_from_a_hundredth_to_ten():
    assert STEPS == (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
    ratios = [b / a for a, b in zip(STEPS, STEPS[1:])]
    assert all(2.0 - 1e-9 <= r <= 2.5 + 1e-9 for r in ratios), ratios     # each click about the same ratio


def test_a_click_moves_one_step_and_the_ends_hold():
    dial = Dial()
    assert dial.finer() == 0.5 and dial.finer() == 0.2 and dial.coarser() == 0.5
    assert dial.step(-20) == MINIMUM and dial.finer() == MINIMUM
    assert dial.step(20) == MAXIMUM and dial.coarser() == MAXIMUM


def test_a_scale_set_between_steps_moves_to_the_next_step_turned_to():
    dial = Dial(0.3)
    assert dial.coarser() == 0.5
    dial.set(0.3)
    assert dial.finer() == 0.2


@pytest.mark.parametrize('bad', [0.0, 0.009, 10.5, -1.0, float('nan'), math.inf, 'tenth', None])
def test_a_bad_scale_is_refused_naming_the_range_and_changes_nothing(bad):
    dial = Dial(0.1)
    with pytest.raises(ValueError) as err:
        dial.set(bad)
    assert '0.01' in str(err.value) and '10' in str(err.value)
    assert dial.scale == 0.1


@pytest.mark.parametrize('step', [0.01, 0.05, 0.2, 10.0])
def test_a_scale_that_came_as_a_float32_is_the_step_it_means(step):
    sent = float(np.float32(step))              # std_msgs/Float32 on the dial topic
    dial = Dial(sent)
    assert dial.scale == step
    if step > 0.01:
        assert dial.finer() < step and dial.scale == STEPS[STEPS.index(step) - 1]
