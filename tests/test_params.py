"""temoto_core.params: every node reads its parameters through one typed reader, and a bad value stops the
node at start, naming the parameter, the value and what was expected."""
import math

import pytest

from temoto_core.params import (ParamError, flag_param, list_param, number_param, seconds_param, text_param)
from temoto_testing import wait_for

HANG = 60.0     # generous: a node that refuses its parameters stops in about a second


@pytest.mark.parametrize('value, kwargs, words', [
    ('fast', {}, "parameter ~rate: 'fast' is not a number"),
    (True, {}, 'parameter ~rate: True is not a number'),
    (math.nan, {}, 'parameter ~rate: nan is not a number'),
    (-5, {'above': 0}, 'parameter ~rate: -5 is not a number > 0'),
    (2000, {'above': 0, 'maximum': 1000}, 'parameter ~rate: 2000 is not a number > 0 and <= 1000'),
    (2.5, {'integer': True}, 'parameter ~rate: 2.5 is not a whole number'),
])
def test_a_number_out_of_its_kind_or_bounds_is_refused_naming_it(value, kwargs, words):
    with pytest.raises(ParamError) as caught:
        number_param(value, 'rate', **kwargs)
    assert str(caught.value).startswith(words), str(caught.value)


def test_good_values_come_back_typed():
    assert number_param(3, 'rate', above=0) == 3.0 and isinstance(number_param(3, 'rate'), float)
    assert number_param(4, 'n', minimum=1, integer=True) == 4 and isinstance(number_param(4, 'n', integer=True), int)
    assert seconds_param(0, 'bound') == 0.0 and flag_param(False, 'sweep') is False
    assert text_param('sweep', 'mode', choices=('rolling', 'sweep')) == 'sweep'
    assert list_param('a, b,', 'words') == ['a', 'b'] and list_param(['a'], 'words') == ['a']


@pytest.mark.parametrize('check, value, words', [
    (lambda v: seconds_param(v, 'bound'), -1, 'parameter ~bound: -1 is not a number of seconds'),
    (lambda v: flag_param(v, 'sweep'), 'yes', "parameter ~sweep: 'yes' is not true or false"),
    (lambda v: text_param(v, 'mode', choices=('rolling', 'sweep')), 'spin',
     "parameter ~mode: 'spin' is not one of 'rolling', 'sweep'"),
    (lambda v: text_param(v, 'world', empty=False), '', "parameter ~world: '' is not a string, not empty"),
    (lambda v: list_param(v, 'words'), 5, 'parameter ~words: 5 is not a list of strings'),
    (lambda v: seconds_param(v, '/global_bound'), 'x', "parameter /global_bound: 'x' is not a number"),
])
def test_every_kind_names_the_parameter_the_value_and_the_expectation(check, value, words):
    with pytest.raises(ParamError) as caught:
        check(value)
    assert str(caught.value).startswith(words), str(caught.value)


@pytest.mark.parametrize('package, executable, params, words', [
    ('vaultbot_sim', 'vaultbot_sim', {'rate': 'fast'}, "parameter ~rate: 'fast' is not a number > 0 and <= 1000"),
    ('vaultbot_sim', 'vaultbot_sim', {'sweep': 'maybe'}, "parameter ~sweep: 'maybe' is not true or false"),
    ('vaultbot_sim', 'laser_stitcher', {'min_scans': 0}, 'parameter ~min_scans: 0 is not a whole number >= 1'),
    ('vaultbot_sim', 'sick_driver', {'rate': -5}, 'parameter ~rate: -5 is not a number > 0 and <= 1000'),
    ('temoto_sensor_manager', 'temoto_sensor_manager', {'first_data_timeout': 'soon'},
     "parameter ~first_data_timeout: 'soon' is not a number > 0"),
])
def test_a_node_given_a_bad_value_stops_at_start_naming_it(rospy_client, procs, package, executable, params, words):
    proc = procs.node(package, executable, name='bad_' + executable, params=params, wait=False)  # it stops at once
    wait_for(lambda: not proc.alive(), HANG, '%s to stop on its bad parameter' % executable)
    assert proc.returncode != 0
    assert words in proc.log(60), proc.log(60)
