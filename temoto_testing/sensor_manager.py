"""Helpers for tests of the sensor and context managers: managers as processes, introspection, fake cables."""
import json
import os
import time

import rospy
from std_msgs.msg import String

from temoto_core.rr.deadlines import call_once
from temoto_core.srv import GetRegistry
from temoto_testing import wait_for

NS = 'temoto'
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FAKE_CATALOGUE = os.path.join(ROOT, 'temoto_sensor_manager', 'test_nodes', 'fake_sensors.yaml')
ER_PARAMS = {'registration_timeout': 15.0, 'sigint_grace': 2.0, 'sigterm_grace': 1.0}
CALL_BOUND = 30.0     # generous: a helper's call that hangs fails its test, not the whole run


def start_er_manager(launcher, log_dir):
    return launcher.node('temoto_er_manager', 'temoto_er_manager', params=dict(ER_PARAMS, log_dir=str(log_dir)))


# A driver's start-up allowance for the stacks whose tests are not about start-up speed: the product's 4 s
# (temoto_sensor_manager DEFAULT_FIRST_DATA_ALLOWANCE) covers a loaded robot, not a CI machine running two
# workers' simulations on 2 cores, where a healthy driver's first message once came later (a SICK, a fake
# camera) and a test failed on a start-up it was not about. bench_sensor.py and bench_sim.py measure start-ups.
GENEROUS_ALLOWANCE = 10.0
# the operator's hand sources (the simulated Leap Motion), for a Sensor Manager's ~extra_catalogues
HAND_CATALOGUE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'temoto_sensor_manager',
                              'config', 'hands.yaml')


def start_sensor_manager(launcher, first_data_timeout=20.0, extra=FAKE_CATALOGUE, name='temoto_sensor_manager',
                         first_data_allowance=None):
    params = {'extra_catalogues': extra, 'first_data_timeout': first_data_timeout}
    if first_data_allowance is not None:
        params['first_data_allowance'] = first_data_allowance
    proc = launcher.node('temoto_sensor_manager', 'temoto_sensor_manager', name=name, params=params)
    rospy.wait_for_service('/%s/temoto_sensor_manager/start_sensor' % NS, timeout=20)
    return proc


def _json(service):
    return json.loads(call_once(service, GetRegistry, GetRegistry._request_class(), CALL_BOUND).json)


def er_processes(alive_only=True):
    rows = _json('/%s/temoto_er_manager/processes' % NS)['processes']
    return [r for r in rows if not alive_only or r['state'] != 'exited']


def catalogue():
    return {s['name']: s for s in _json('/%s/temoto_sensor_manager/catalogue' % NS)['sensors']}


def catalogue_problems():
    return _json('/%s/temoto_sensor_manager/catalogue' % NS)['problems']


def registry(rr='temoto_sensor_manager'):
    return _json('/%s/%s/registry' % (NS, rr))


def pid_gone(pid):
    return not os.path.exists('/proc/%d' % pid)


def managers_idle(rrs=('temoto_sensor_manager', 'temoto_er_manager'), timeout=15.0):
    def idle():
        return all(not registry(rr)['server_queries'] and not registry(rr)['client_queries'] for rr in rrs)
    wait_for(idle, timeout, 'empty registries at %s' % ', '.join(rrs))
    wait_for(lambda: not er_processes(), timeout, 'every driver process to be stopped')


class FakeCables:
    """Pull the cable of a fake_sensor driver (test_nodes/fake_sensor)."""

    def __init__(self):
        self.pub = rospy.Publisher('/fake_sensors/control', String, queue_size=10, latch=False)

    def send(self, command, device):
        # wait until every fake driver currently running is connected, so the command is not lost
        wait_for(lambda: self.pub.get_num_connections() >= 1, 10, 'a fake driver listening for cable commands')
        self.pub.publish(String('%s %s' % (command, device)))
        return time.monotonic()


class TopicWatch:
    """Counts messages on a topic (any type) in this process."""

    def __init__(self, topic):
        self.count = 0
        self.last = 0.0
        self.sub = rospy.Subscriber(topic, rospy.AnyMsg, self._cb, queue_size=5)

    def _cb(self, _msg):
        self.count += 1
        self.last = time.monotonic()

    def close(self):
        self.sub.unregister()


def start_robot(launcher, work: str, first_data_timeout: float = 30.0) -> None:
    """The simulated VaultBot with its ER Manager (logs under ``work``) and Sensor Manager, as the benchmarks
    run them."""
    start_sim(launcher)
    start_er_manager(launcher, os.path.join(work, 'er_logs'))
    start_sensor_manager(launcher, first_data_timeout=first_data_timeout)


def start_sim(launcher, **params):
    """The simulated VaultBot (world, joint states, cables); the hand waves, the wrist does not sweep."""
    base = {'world': 'lab', 'sweep': False, 'hand_motion': True}
    base.update(params)
    proc = launcher.node('vaultbot_sim', 'vaultbot_sim', params=base)
    rospy.wait_for_service('/vaultbot_sim/set_device_state', timeout=20)
    return proc


def set_cable(device, state, mode=''):
    """Plug or unplug a simulated device (what `temoto sim unplug DEVICE --mode MODE` does)."""
    from vaultbot_sim.srv import SetDeviceState
    resp = call_once('/vaultbot_sim/set_device_state', SetDeviceState,
                     SetDeviceState._request_class(device=device, state=state, mode=mode), CALL_BOUND)
    if not resp.success:
        raise RuntimeError('set_device_state %s %s %s: %s' % (device, state, mode, resp.message))
    return time.monotonic()


def start_robot_manager(launcher, descriptions='', journal=''):
    """The Robot Manager, with the VaultBot's description unless ``descriptions`` names others; with a
    ``journal`` path it runs under its warm-respawn parent (``proc``) and recovers after a crash."""
    params = {'descriptions': descriptions} if descriptions else {}
    if journal:
        params['journal'] = journal
    proc = launcher.node('temoto_robot_manager', 'temoto_robot_manager', params=params)
    # the master may still list a SIGKILLed manager's services: wait for this one's registry to answer
    wait_for(lambda: _answers('temoto_robot_manager'), 30, 'the Robot Manager to serve')
    return proc


def recovered_registry(rr):
    """``rr``'s registry once it has recovered, without what a restart changes by design (its node, its
    incarnation, the calls in flight); None while it does not answer or still recovers."""
    try:
        raw = registry(rr)
    except (OSError, rospy.ServiceException, rospy.ROSException):       # the new incarnation is not serving yet
        return None
    if raw['recovering']:
        return None
    for key in ('node', 'incarnation', 'calls_in_flight'):
        raw.pop(key)
    return raw


def _answers(rr):
    try:
        return not registry(rr)['recovering']
    except (OSError, rospy.ServiceException, rospy.ROSException):
        return False


def start_robot_stack(launcher, er_logs, extra='', descriptions='', **sim):
    """The sim (``sim`` overrides its parameters) with its base controller, and the ER, Sensor and Robot
    Managers, as a module of tests shares them; returns the Robot Manager's process. The Sensor Manager has
    the VaultBot's sensors and the catalogues in ``extra`` (``HAND_CATALOGUE``, say); the Robot Manager the
    VaultBot's description unless ``descriptions`` names others."""
    start_sim(launcher, **sim)
    launcher.node('vaultbot_sim', 'base_controller')
    start_er_manager(launcher, er_logs)
    start_sensor_manager(launcher, first_data_timeout=20.0, extra=extra,
                         first_data_allowance=GENEROUS_ALLOWANCE)
    return start_robot_manager(launcher, descriptions)


def robot_info():
    return _json('/%s/temoto_robot_manager/robots' % NS)


def start_context_manager(launcher, trackers=''):
    params = {'trackers': trackers} if trackers else {}
    proc = launcher.node('temoto_context_manager', 'temoto_context_manager', params=params)
    rospy.wait_for_service('/%s/temoto_context_manager/track_object' % NS, timeout=20)
    return proc


def tracker_info():
    return _json('/%s/temoto_context_manager/trackers' % NS)
