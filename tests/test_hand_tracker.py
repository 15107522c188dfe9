"""The operator's hand as a sensor: the simulated hand tracker replays a hand path at 100 Hz, is served by the
Sensor Manager as a `hand` catalogue entry (temoto_sensor_manager/config/hands.yaml), and fails its holder
when its cable is pulled. Real roscore, sim, ER and Sensor Managers across processes."""
import threading

import pytest

from temoto_core.msg import HandSample, ResourceStatus
from temoto_sensor_manager.interface import SensorManagerInterface
from temoto_testing import made_interfaces, wait_for
from temoto_testing.sensor_manager import (GENEROUS_ALLOWANCE, HAND_CATALOGUE as HANDS, er_processes, managers_idle, set_cable,
                                           start_er_manager, start_sensor_manager, start_sim)
from vaultbot_sim.hand_path import DEFAULT, HandPath

HANG = 60.0


@pytest.fixture(scope='module')
def stack(rospy_client, module_procs, tmp_path_factory):
    start_sim(module_procs, hand_motion=False)
    start_er_manager(module_procs, tmp_path_factory.mktemp('er_logs'))
    start_sensor_manager(module_procs, extra=HANDS, first_data_allowance=GENEROUS_ALLOWANCE)
    return module_procs


@pytest.fixture
def smi(stack):
    with made_interfaces(SensorManagerInterface) as make:
        yield make
    set_cable('hand_tracker', 'plugged')
    managers_idle(timeout=20)


def test_the_hand_path_interpolates_loops_and_refuses_a_bad_keyframe(tmp_path):
    path = HandPath()
    assert path.at(0.6)[4] == pytest.approx(0.5)                    # half way into the grab
    assert path.at(1.7)[2] == pytest.approx(0.05)                   # half way along its 10 cm
    assert path.at(1.7 + path.period)[1:] == pytest.approx(path.at(1.7)[1:])
    bad = tmp_path / 'hand.txt'
    bad.write_text('# t x y z grab\n0 0 0 0.2 0\n1 0 0 0.2 1.5\n')
    with pytest.raises(ValueError, match='keyframe 1: grab 1.5 must be from 0 to 1'):
        HandPath.read(str(bad))
    bad.write_text('0 0 0 0.2 0\n1 0 0 0.2\n')
    with pytest.raises(ValueError, match=r'hand.txt:2: 4 numbers, want 5'):
        HandPath.read(str(bad))
    assert len(DEFAULT) >= 2


def test_a_hand_source_is_served_as_a_sensor_at_100_hz_and_fails_its_holder_when_unplugged(smi, collect):
    heard, lock = [], threading.Lock()

    def on_status(event):
        with lock:
            heard.append(event)
    sm = smi()
    res = sm.start_sensor('hand', ['hand_data'], on_status=on_status)
    assert (res.sensor_name, res.executable) == ('sim_hand_tracker', 'hand_tracker_driver')
    samples = collect(res.output_topics['hand_data'], HandSample)
    # the path: a fist at 0.7 s, an open hand from 3.4 s to 5.7 s; 6 s of it holds both
    wait_for(lambda: len(samples.msgs) >= 600, HANG, '600 hand samples')
    stamps = [m.header.stamp.to_sec() for m in samples.msgs[-100:]]
    assert 0.7 <= (stamps[-1] - stamps[0]) / 99 / 0.01 <= 1.5, 'about 100 Hz'
    grabs = [m.grab_strength for m in samples.msgs]
    assert min(grabs) == 0.0 and max(grabs) == 1.0 and all(m.tracked for m in samples.msgs)
    set_cable('hand_tracker', 'unplugged', 'crash')
    failed = wait_for(lambda: next((e for e in heard if e.code == ResourceStatus.FAILED), None), HANG,
                      'FAILED at the holder')
    assert 'hand_tracker_driver' in failed.message or 'sim_hand_tracker' in failed.message, failed.message
    wait_for(lambda: not er_processes(), HANG, 'the driver gone')


def test_the_tracker_on_the_station_needs_no_joint_states_of_the_robot(stack, collect):
    """On the operator's station (two hosts) the robot's joint states are under its namespace; a tracker that
    waited for them as the robot's sensors do never gave a sample, and the Sensor Manager failed it."""
    samples = collect('/station_hand/sample', HandSample)
    stack.node('vaultbot_sim', 'hand_tracker_driver', name='station_hand_tracker',
               args=['joint_states:=/nobody/joint_states', 'hand/sample:=/station_hand/sample'])
    wait_for(lambda: len(samples.msgs) >= 100, HANG, '100 samples with no joint states anywhere')
