"""A driver that is silent from its start costs its first-data limit, derived from its catalogue rate
(a few seconds), not the manager's cap (it cost the whole 20 s cap per candidate, so "every sensor
failed" came 42 s late with all three VaultBot sensors unplugged); once the driver has been seen to
start, its own start time (learnt); and nothing at all when the driver reports its device missing on
/diagnostics (12 s for three unplugged devices, before)."""
import re
import time

import pytest

from temoto_core.errors import TemotoError
from temoto_testing import made_interfaces
from temoto_sensor_manager.interface import SensorManagerInterface

NS = 'first_data'
CATALOGUE = '''
sensors:
  - name: rated_silent
    type: rated silent
    package: temoto_sensor_manager
    executable: fake_sensor
    args: _device:=rated_silent _start_mode:=silent
    rate: 30
    output_topics:
      data: {topic: /first_data/silent/data, remap: data}

  - name: missing_device
    type: missing device
    package: temoto_sensor_manager
    executable: fake_sensor
    args: _device:=missing_device _start_mode:=missing
    rate: 30
    output_topics:
      data: {topic: /first_data/missing/data, remap: data}

  - name: learnt_device
    type: learnt device
    package: temoto_sensor_manager
    executable: fake_sensor
    args: _device:=learnt_device _rate:=30 _silent_if:=%s
    rate: 30
    output_topics:
      data: {topic: /first_data/learnt/data, remap: data}
'''


@pytest.fixture(scope='module')
def managers(rospy_client, module_procs, tmp_path_factory):
    work = tmp_path_factory.mktemp('first_data')
    catalogue = work / 'rated_silent.yaml'
    catalogue.write_text(CATALOGUE % (work / 'unplugged'))
    module_procs.unplugged_flag = work / 'unplugged'
    module_procs.node('temoto_er_manager', 'temoto_er_manager', name='first_data_er', namespace=NS,
                      params={'temoto_namespace': NS, 'log_dir': str(work), 'registration_timeout': 20.0})
    module_procs.node('temoto_sensor_manager', 'temoto_sensor_manager', name='first_data_sm', namespace=NS,
                      params={'temoto_namespace': NS, 'extra_catalogues': str(catalogue), 'first_data_timeout': 20.0})
    rospy_client.wait_for_service('/%s/temoto_sensor_manager/start_sensor' % NS, timeout=20)
    return module_procs


def test_a_silent_driver_costs_its_rate_derived_limit_not_the_cap(managers):
    with made_interfaces(lambda: SensorManagerInterface(namespace=NS)) as make:
        sm = make()
        started = time.monotonic()
        with pytest.raises(TemotoError) as err:
            sm.start_sensor('rated silent', ['data'])
        took = time.monotonic() - started
    # 4 s of allowance + 10 periods at 30 Hz; the cap is 20 s
    assert 'within 4.3 s' in str(err.value), str(err.value)
    assert took < 15.0, took


def test_a_driver_that_reports_its_device_missing_fails_at_once(managers):
    """The fake driver never publishes data and says why on /diagnostics: the candidate fails on that
    report, long before its 4.3 s of first-data allowance."""
    with made_interfaces(lambda: SensorManagerInterface(namespace=NS)) as make:
        sm = make()
        with pytest.raises(TemotoError) as err:
            sm.start_sensor('missing device', ['data'])
    assert 'reported an error' in str(err.value) and 'device not found' in str(err.value), str(err.value)
    assert 'within' not in str(err.value), str(err.value)


def test_a_silent_start_of_a_driver_seen_before_costs_its_learnt_start_time(managers):
    with made_interfaces(lambda: SensorManagerInterface(namespace=NS)) as make:
        sm = make()
        for _ in range(3):      # three starts seen: its start time is learnt
            sm.stop_sensor(sm.start_sensor('learnt device', ['data']).resource_id)
        managers.unplugged_flag.write_text('')
        try:
            with pytest.raises(TemotoError) as err:
                sm.start_sensor('learnt device', ['data'])
        finally:
            managers.unplugged_flag.unlink()
    message = str(err.value)
    assert 'learnt from its last 3 starts' in message, message
    limit = float(re.search(r'within ([0-9.]+) s', message).group(1))
    assert limit < 4.3, message    # below the default allowance + 10 periods
