"""show_environment's failover policy against stand-in sensor and output managers (in-process).

The managers here follow the interface contract the action is written against:
SensorManagerInterface(rr).start_sensor(type, output_topics={key: ''}, on_status=cb) -> .sensor_name/
.output_topics/.resource_id, .stop_sensor(id); OutputManagerInterface(rr).show_in_rviz(type, topic, name='',
config='', on_status=cb) -> id, .hide(id). Statuses are typed StatusEvents, given to each request's own cb. The end-to-end run against the real managers and simulation
belongs to the integration suite.
"""
import itertools
import time
import threading
from types import SimpleNamespace

import pytest

from temoto_action_engine.action_base import ActionError
from temoto_action_engine.view_sources import DEFAULT_PRIORITY, parse_priority
from temoto_action_engine.engine import ActionEngine
from temoto_action_engine.indexer import ActionIndex
from temoto_testing.action_engine import FakeRegistrarFactory
from temoto_core.rr.status import Status, StatusEvent
from temoto_core.wait import wait_for

VAULTBOT = [  # name, type, topics
    ('d435', 'depth camera', {'camera_data': '/d435/points', 'camera_info': '/d435/info'}),
    ('hokuyo', 'lidar', {'lidar_data': '/hokuyo/scan', 'cloud_data': '/stitcher/cloud'}),
    ('sick', 'lidar', {'lidar_data': '/sick/scan'}),
]


# the operator's station's own sensor (its Sensor Manager, reachable when the robot's link is down)
STATION = [('site_lidar', 'lidar', {'lidar_data': '/site_lidar/scan'})]
SITE_ENTRY = {'label': 'site LIDAR scan', 'sensor_type': 'lidar', 'output_topics': ['lidar_data'],
              'display_type': 'laser scan', 'sensor_manager': 'station'}


class Devices:
    """The 'cables' and what both fake managers did."""

    def __init__(self):
        self.lock = threading.Lock()
        self.plugged = {name for name, _, _ in VAULTBOT + STATION}
        self.active = {}             # resource id -> sensor name
        self.shown = {}              # display id -> (type, topic)
        self.hidden = {}             # display id -> (type, topic): subscribed, drawn transparent
        self.configs = {}            # display id -> the RViz properties it was shown with
        self.names = {}              # display id -> the name it was shown under
        self.log = []
        self.ids = itertools.count(1)
        self.policies = {}           # resource or display id -> the request's on_status
        self.stop_gate = threading.Event()   # cleared: stop_sensor blocks (a slow driver unload)
        self.stop_gate.set()
        self.start_gate = threading.Event()  # cleared: start_sensor blocks (a driver starting)
        self.start_gate.set()
        self.failed_before = set()           # ranked last by the fake's likely_topics (as reliability does)
        self.guess_override = None           # likely_topics answers this instead
        self.flap_after = {}                 # name -> seconds: the device starts, then fails this long after
        self.robot_cut = False               # the robot's link is down: its manager cannot be reached

    def unplug(self, name):
        with self.lock:
            self.plugged.discard(name)
            self.failed_before.add(name)
            victims = [(rid, self.policies[rid]) for rid, n in self.active.items() if n == name]
        for rid, cb in victims:
            cb(status(rid, Status.FAILED, '%s unplugged' % name))

    def fail(self, rid, why):
        with self.lock:
            cb = self.policies[rid] if rid in self.active else None
        if cb is not None:
            cb(status(rid, Status.FAILED, why))

    def crash_display(self, did):
        """The RViz host of a display dies: FAILED to that display's holder."""
        with self.lock:
            cb = self.policies[did]
        cb(status(did, Status.FAILED, 'rviz host crashed'))

    def plug(self, name):
        with self.lock:
            self.plugged.add(name)

    def cut_robot_link(self):
        """What a partition does: every robot sensor held FAILED (its owner lost), the manager out of reach."""
        with self.lock:
            self.robot_cut = True
            robot = {name for name, _, _ in VAULTBOT}
            victims = [(rid, self.policies[rid]) for rid, n in self.active.items() if n in robot]
        for rid, cb in victims:
            cb(status(rid, Status.FAILED, 'owner /vaultbot/temoto_sensor_manager unreachable'))


class FakeSensorManager:
    def __init__(self, devices, rr, catalogue=None, on_robot=True):
        self.d = devices
        self.catalogue = VAULTBOT if catalogue is None else catalogue
        self.on_robot = on_robot       # cut off with the robot's link (Devices.robot_cut)

    def _reach(self):
        if self.on_robot and self.d.robot_cut:
            raise RuntimeError('service /vaultbot/temoto_sensor_manager/start_sensor is not tried: its owner is '
                               'unreachable')

    def start_sensor(self, sensor_type, output_topics, package_name='', executable='', on_status=None):
        assert self.d.start_gate.wait(10), 'start_sensor gate never opened'
        self._reach()
        with self.d.lock:
            for name, stype, topics in self.catalogue:
                if executable and executable != name:
                    continue
                if stype == sensor_type and name in self.d.plugged and set(output_topics) <= set(topics):
                    rid = next(self.d.ids)
                    self.d.active[rid] = name
                    self.d.policies[rid] = on_status
                    self.d.log.append(('start', name))
                    if name in self.d.flap_after:
                        threading.Timer(self.d.flap_after[name], self.d.fail, (rid, '%s flapped' % name)).start()
                    return SimpleNamespace(sensor_name=name, resource_id=rid,
                                           output_topics={k: topics[k] for k in output_topics})
        raise RuntimeError('no %s with %s available' % (sensor_type, sorted(output_topics)))

    def ranked_sensors(self, sensor_type, keys, timeout=1.0):
        """The real manager's ranking: matches in VAULTBOT's order, a device that failed before last."""
        self._reach()
        with self.d.lock:
            rows = [{'name': name, 'package': 'fake', 'executable': name, 'type': stype}
                    for name, stype, topics in self.catalogue if stype == sensor_type and set(keys) <= set(topics)]
            return sorted(rows, key=lambda r: r['name'] in self.d.failed_before)

    def likely_topics(self, sensor_type, keys, timeout=1.0):
        """What the real manager's catalogue ranking gives: the first plugged-or-not match in VAULTBOT."""
        with self.d.lock:
            self.d.log.append(('guess', sensor_type))
            if self.d.guess_override is not None:
                return self.d.guess_override
        self._reach()
        for name, stype, topics in self.catalogue:
            if stype == sensor_type and set(keys) <= set(topics) and name not in self.d.failed_before:
                return {k: topics[k] for k in keys}
        return None

    def stop_sensor(self, rid):
        assert self.d.stop_gate.wait(10), 'stop_sensor gate never opened'
        with self.d.lock:
            self.d.log.append(('stop', self.d.active.pop(rid)))

    def shutdown(self):
        with self.d.lock:
            for rid in list(self.d.active):
                self.d.log.append(('stop at shutdown', self.d.active.pop(rid)))


class FakeOutputManager:
    def __init__(self, devices, rr):
        self.d = devices

    def show_in_rviz(self, display_type, topic, name='', config='', on_status=None, hidden=False):
        with self.d.lock:
            did = 1000 + next(self.d.ids)
            self.d.policies[did] = on_status
            (self.d.hidden if hidden else self.d.shown)[did] = (display_type, topic)
            self.d.configs[did] = config
            self.d.names[did] = name
            self.d.log.append(('show hidden' if hidden else 'show', display_type, topic))
            return did

    def set_visible(self, did, visible):
        with self.d.lock:
            src, dst = (self.d.hidden, self.d.shown) if visible else (self.d.shown, self.d.hidden)
            if did not in src:
                raise RuntimeError('display %d is not %s' % (did, 'hidden' if visible else 'shown'))
            dst[did] = src.pop(did)
            self.d.log.append(('reveal' if visible else 'conceal',) + dst[did])

    def hide(self, did):
        with self.d.lock:
            self.d.log.append(('hide',) + (self.d.shown.pop(did, None) or self.d.hidden.pop(did)))


@pytest.fixture
def setup():
    devices = Devices()
    events, feedback = [], []
    idx = ActionIndex([]).reindex()
    engine = ActionEngine(
        idx, rr_factory=FakeRegistrarFactory(), publish_event=events.append, publish_feedback=feedback.append,
        action_config={'show_environment': {'retry_initial_s': 0.05, 'retry_max_s': 0.2}},
        interface_factories={'sensor_manager': lambda rr, namespace=None: FakeSensorManager(devices, rr),
                             'station_sensor_manager': lambda rr: FakeSensorManager(devices, rr, STATION, False),
                             'output_manager': lambda rr: FakeOutputManager(devices, rr)})
    yield engine, devices, events, feedback
    engine.shutdown(10)


def status(rid, code, message):
    return StatusEvent(resource_id=rid, code=code, message=message, error_stack=[], rr_name='fake',
                       server_name='fake', namespace='temoto', stamp=0.0)


def of(events, kind):
    return [e for e in events if e.get('event') == kind]


def displayed(devices):
    with devices.lock:
        return sorted(devices.shown.values())


def test_fails_over_down_the_priority_list_and_waits_for_a_device_to_return(setup):
    engine, devices, events, feedback = setup
    result, run = engine.say('show the environment')
    assert run is not None, result.message
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    assert displayed(devices) == [('point cloud', '/d435/points')]
    assert run.nodes['show_environment_0'].action.outputs == {'topic': '/d435/points'}

    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    wait_for(lambda: displayed(devices) == [('point cloud', '/stitcher/cloud')], 10, 'the failed display hidden')
    assert run.nodes['show_environment_0'].action.outputs == {'topic': '/stitcher/cloud'}
    failed = of(events, 'sensor_failed')[0]
    assert failed['sensor_name'] == 'd435' and failed['message'] == 'd435 unplugged'
    assert of(events, 'sensor_active')[1]['sensor_name'] == 'hokuyo'

    devices.unplug('hokuyo')
    wait_for(lambda: len(of(events, 'sensor_active')) == 3, 10, 'sick active')
    wait_for(lambda: displayed(devices) == [('laser scan', '/sick/scan')], 10, 'the failed display hidden')

    devices.unplug('sick')
    wait_for(lambda: len(of(events, 'retry')) >= 3, 10, 'retries while everything is unplugged')
    wait_for(lambda: displayed(devices) == [], 10, 'the last display hidden')
    assert any('every sensor failed' in f for f in feedback)
    # the fourth all_failed follows the third retry: wait for it rather than read it as the retry lands
    backoffs = [e['retry_in_s'] for e in wait_for(lambda: len(of(events, 'all_failed')) >= 4 and
                                                  of(events, 'all_failed'), 10, 'four rounds of all_failed')]
    assert backoffs[:4] == [0.05, 0.1, 0.2, 0.2]                     # bounded exponential backoff

    devices.plug('hokuyo')
    wait_for(lambda: len(of(events, 'sensor_active')) == 4, 10, 'a sensor back after retry')
    assert of(events, 'sensor_active')[3]['sensor_name'] == 'hokuyo'
    assert displayed(devices) == [('point cloud', '/stitcher/cloud')]
    # the feedback sentence follows the event that the wait above saw
    wait_for(lambda: any('a sensor is back' in f for f in feedback), 10, 'the feedback that a sensor is back')

    # every failed sensor and its display were released, and each only once
    log = devices.log
    assert log.count(('stop', 'd435')) == 1 and log.count(('hide', 'point cloud', '/d435/points')) == 1
    assert log.count(('stop', 'sick')) == 1 and log.count(('hide', 'laser scan', '/sick/scan')) == 1
    assert run.nodes['show_environment_0'].state == 'RUNNING'

    ok, msg = engine.stop_graph(run.name)
    assert ok, msg
    assert displayed(devices) == [] and devices.active == {}
    assert log[-2:] == [('hide', 'point cloud', '/stitcher/cloud'), ('stop', 'hokuyo')]


def test_the_substitute_is_shown_before_the_failed_sensor_is_released(setup):
    """A slow unload of the failed driver (a stalled one takes seconds) must not delay the new view."""
    engine, devices, events, _ = setup
    _, run = engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    devices.stop_gate.clear()                     # stopping a sensor now blocks until the gate opens
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active while d435 is still stopping')
    with devices.lock:
        log = list(devices.log)
    assert ('start', 'hokuyo') in log and ('show', 'point cloud', '/stitcher/cloud') in log
    assert ('stop', 'd435') not in log            # the failed sensor is still being released
    # its frozen view went off screen at once, without waiting for the substitute
    assert log.index(('hide', 'point cloud', '/d435/points')) < log.index(('show', 'point cloud', '/stitcher/cloud'))
    devices.stop_gate.set()
    wait_for(lambda: ('stop', 'd435') in devices.log, 10, 'the failed sensor released')
    assert devices.log.count(('stop', 'd435')) == 1 and devices.log.count(('hide', 'point cloud', '/d435/points')) == 1


def test_stopping_during_a_background_release_releases_everything_once(setup):
    engine, devices, events, _ = setup
    _, run = engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    devices.stop_gate.clear()
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    stopper = threading.Thread(target=engine.stop_graph, args=(run.name,))
    stopper.start()
    wait_for(lambda: run.nodes['show_environment_0'].state != 'RUNNING', 10, 'the stop to begin')
    devices.stop_gate.set()
    stopper.join(10)
    assert not stopper.is_alive()
    wait_for(lambda: devices.active == {} and displayed(devices) == [], 10, 'everything released')
    log = devices.log
    assert log.count(('stop', 'd435')) == 1 and log.count(('stop', 'hokuyo')) == 1
    assert not [e for e in log if e[0] == 'stop at shutdown']   # the action released them, not the shutdown


def test_starts_lower_in_the_list_when_the_best_sensor_is_already_gone(setup):
    engine, devices, events, _ = setup
    devices.plugged.discard('d435')
    _, run = engine.say('show me the surroundings')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'a sensor active')
    assert [e['sensor_type'] for e in of(events, 'sensor_unavailable')] == ['depth camera']
    assert of(events, 'sensor_active')[0]['sensor_name'] == 'hokuyo'
    # the display guessed on the camera's likely topic is gone: never asked for (the camera failed first),
    # or asked for and hidden exactly once (the guess runs on its own thread: wait for it to settle)
    def guess_settled():
        with devices.lock:
            shown = devices.log.count(('show', 'point cloud', '/d435/points'))
            hidden = devices.log.count(('hide', 'point cloud', '/d435/points'))
        return shown == hidden and (shown, hidden)
    shown, hidden = wait_for(guess_settled, 10, 'the camera guess to be hidden')
    assert hidden <= 1
    assert displayed(devices) == [('point cloud', '/stitcher/cloud')]


def test_the_display_is_asked_for_while_the_sensor_starts(setup):
    engine, devices, events, _ = setup
    _, run = engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    devices.start_gate.clear()                    # the next driver takes its time to start
    devices.unplug('d435')
    wait_for(lambda: ('show', 'point cloud', '/stitcher/cloud') in devices.log, 10, 'the display on the likely topic')
    assert ('start', 'hokuyo') not in devices.log and len(of(events, 'sensor_active')) == 1
    devices.start_gate.set()
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    wait_for(lambda: displayed(devices) == [('point cloud', '/stitcher/cloud')], 10, 'the failed display hidden')
    assert devices.log.count(('show', 'point cloud', '/stitcher/cloud')) == 1     # the early display was kept


def test_a_wrong_guess_is_hidden_once_and_the_right_topic_shown(setup):
    engine, devices, events, _ = setup
    _, run = engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    devices.guess_override = {'lidar_data': '/elsewhere/scan', 'cloud_data': '/elsewhere/cloud'}
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    wait_for(lambda: displayed(devices) == [('point cloud', '/stitcher/cloud')], 10, 'only the right display left')
    log = devices.log
    assert log.count(('show', 'point cloud', '/elsewhere/cloud')) == 1
    assert log.count(('hide', 'point cloud', '/elsewhere/cloud')) == 1
    assert log.index(('hide', 'point cloud', '/elsewhere/cloud')) < log.index(('show', 'point cloud', '/stitcher/cloud'))
    assert of(events, 'sensor_active')[1]['topic'] == '/stitcher/cloud'
    ok, msg = engine.stop_graph(run.name)
    assert ok, msg
    assert displayed(devices) == [] and devices.active == {}


def test_without_speculative_display_the_display_follows_the_sensor(setup):
    engine, devices, events, _ = setup
    engine.action_config['show_environment'] = {'speculative_display': False}
    _, run = engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    log = devices.log
    assert not [e for e in log if e[0] == 'guess']
    assert log.index(('start', 'd435')) < log.index(('show', 'point cloud', '/d435/points'))


def test_a_status_for_a_released_resource_is_ignored(setup):
    engine, devices, events, _ = setup
    _, run = engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    action = run.nodes['show_environment_0'].action
    action.post(status(424242, Status.FAILED, 'stale'))
    action.post(status(action.view.shown.resource_id, Status.UPDATE, 'just an update'))
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    assert len(of(events, 'sensor_failed')) == 1


def test_bad_priority_parameter_fails_the_action_clearly(setup):
    engine, devices, events, feedback = setup
    engine.action_config['show_environment'] = {'sensor_priority': [{'sensor_type': 'lidar',
                                                                     'output_topics': ['lidar_data'],
                                                                     'display_type': 'laser scan',
                                                                     'display_key': 'cloud_data'}]}
    _, run = engine.say('show the environment')
    assert run.wait(10) == []
    node = run.nodes['show_environment_0']
    assert node.state == 'FAILED' and "display_key 'cloud_data'" in node.message
    assert devices.log == []


def test_display_config_reaches_the_output_manager_as_yaml():
    import yaml
    entry = {'sensor_type': 'lidar', 'output_topics': ['lidar_data'], 'display_type': 'laser scan',
             'display_config': {'Size (m)': 0.05, 'Color': '255; 120; 0'}}
    choice = parse_priority([entry])[0]
    assert yaml.safe_load(choice.display_config) == {'Size (m)': 0.05, 'Color': '255; 120; 0'}
    with pytest.raises(ActionError, match='display_config'):
        parse_priority([dict(entry, display_config=[1, 2])])


def test_a_failed_view_is_hidden_before_the_substitute_is_asked_for(setup):
    """A frozen last frame must not look live: the failed display goes off screen first."""
    engine, devices, events, _ = setup
    engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    devices.start_gate.clear()          # the substitute's driver is slow to start
    devices.unplug('d435')
    wait_for(lambda: ('hide', 'point cloud', '/d435/points') in devices.log, 10, 'the failed view hidden')
    assert not any(e[0] == 'start' and e[1] == 'hokuyo' for e in devices.log), 'hidden before the substitute'
    devices.start_gate.set()
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')


def test_a_display_failure_reaches_the_action_and_the_same_sensor_is_shown_again(setup):
    engine, devices, events, _ = setup
    _, run = engine.say('show the environment')
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    action = run.nodes['show_environment_0'].action
    failed_display = action.view.shown.display_id
    devices.crash_display(failed_display)
    restored = wait_for(lambda: of(events, 'display_restored'), 10, 'the display shown again')
    assert restored[0]['sensor_name'] == 'd435' and action.view.shown.display_id != failed_display
    assert of(events, 'sensor_failed')[0]['failed_part'] == 'display'
    wait_for(lambda: failed_display not in devices.shown, 10, 'the failed display released')
    assert list(devices.shown.values()) == [('point cloud', '/d435/points')]
    assert [e for e in devices.log if e[0] == 'start'] == [('start', 'd435')], 'no failover for a display crash'
    run.stop(10)
    assert devices.shown == {} and devices.active == {}, 'nothing held after the stop'


# ---------------------------------------------------------------------------- standby, fail-back, flapping
FAST = {'retry_initial_s': 0.05, 'retry_max_s': 0.2, 'failback_check_s': 0.05, 'failback_max_s': 0.4,
        'failback_hold_s': 0.2}


def started(devices, name):
    with devices.lock:
        return [e for e in devices.log if e[0] == 'start' and e[1] == name]


def hidden(devices):
    with devices.lock:
        return sorted(devices.hidden.values())


def run_with(engine, events, say='show the environment', **config):
    engine.action_config['show_environment'] = dict(FAST, **config)
    result, run = engine.say(say)
    assert run is not None, result.message
    wait_for(lambda: of(events, 'sensor_active'), 10, 'first sensor active')
    return run


def test_warm_standby_runs_the_next_driver_and_a_failover_only_adds_its_display(setup):
    engine, devices, events, _ = setup
    run = run_with(engine, events, standby='warm', failback=False)
    ready = wait_for(lambda: of(events, 'standby_ready'), 10, 'the spare running')[0]
    assert ready['sensor_name'] == 'hokuyo' and ready['display'] == 'none'
    assert displayed(devices) == [('point cloud', '/d435/points')] and hidden(devices) == []
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    active = of(events, 'sensor_active')[1]
    assert active['sensor_name'] == 'hokuyo' and active['via'] == 'standby' and active['standby'] == 'warm'
    assert len(started(devices, 'hokuyo')) == 1, 'the running spare is used, not started again'
    wait_for(lambda: displayed(devices) == [('point cloud', '/stitcher/cloud')], 10, 'the spare shown')
    wait_for(lambda: len(of(events, 'standby_ready')) == 2, 10, 'the next spare running')
    assert of(events, 'standby_ready')[1]['sensor_name'] == 'sick'
    run.stop(10)
    assert devices.shown == {} and devices.hidden == {} and devices.active == {}, 'nothing held after the stop'


def test_hot_standby_fails_over_by_showing_a_display_that_was_already_subscribed(setup):
    engine, devices, events, _ = setup
    run = run_with(engine, events, say='show the environment with a hot standby', failback=False)
    wait_for(lambda: of(events, 'standby_ready'), 10, 'the spare streaming into its hidden display')
    assert hidden(devices) == [('point cloud', '/stitcher/cloud')]
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    assert of(events, 'sensor_active')[1]['via'] == 'standby'
    assert ('reveal', 'point cloud', '/stitcher/cloud') in devices.log
    assert devices.log.count(('show hidden', 'point cloud', '/stitcher/cloud')) == 1
    assert not [e for e in devices.log if e[0] == 'show' and e[2] == '/stitcher/cloud'], 'no new display'
    wait_for(lambda: hidden(devices) == [('laser scan', '/sick/scan')], 10, 'the next spare hidden and streaming')
    assert displayed(devices) == [('point cloud', '/stitcher/cloud')]
    run.stop(10)
    assert devices.shown == {} and devices.hidden == {} and devices.active == {}, 'nothing held after the stop'


def test_a_failed_standby_is_reported_and_replaced(setup):
    engine, devices, events, _ = setup
    run_with(engine, events, standby='hot', failback=False)
    wait_for(lambda: of(events, 'standby_ready'), 10, 'the spare ready')
    devices.unplug('hokuyo')
    failed = wait_for(lambda: of(events, 'standby_failed'), 10, 'the spare failure reported')[0]
    assert failed['sensor_name'] == 'hokuyo' and failed['message'] == 'hokuyo unplugged'
    replaced = wait_for(lambda: len(of(events, 'standby_ready')) == 2 and of(events, 'standby_ready')[1],
                        10, 'a new spare')
    assert replaced['sensor_name'] == 'sick'
    wait_for(lambda: hidden(devices) == [('laser scan', '/sick/scan')], 10, 'the failed spare released')
    assert started(devices, 'hokuyo') == [('start', 'hokuyo')] and ('stop', 'hokuyo') in devices.log
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'the new spare active')
    assert of(events, 'sensor_active')[1]['sensor_name'] == 'sick'
    assert displayed(devices) == [('laser scan', '/sick/scan')]


@pytest.mark.parametrize('standby', ['cold', 'hot'])
def test_the_view_fails_back_to_a_replugged_better_sensor_after_a_hold(setup, standby):
    engine, devices, events, feedback = setup
    run = run_with(engine, events, standby=standby)
    if standby != 'cold':     # the spare must be up before the failure, or the failover starts it a second time
        wait_for(lambda: of(events, 'standby_ready'), 10, 'the spare running')
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    devices.plug('d435')
    back = wait_for(lambda: of(events, 'failback'), 10, 'the fail-back')[0]
    candidate = of(events, 'failback_candidate')[0]
    assert back['label'] == 'RGB-D camera cloud' and back['from_sensor'] == 'hokuyo'
    assert candidate['sensor_name'] == 'd435' and candidate['hold_s'] == FAST['failback_hold_s']
    active = of(events, 'sensor_active')[2]
    assert active['sensor_name'] == 'd435' and active['via'] == 'failback'
    # shown by a visibility change, with no blank frame: the candidate's display was already subscribed
    assert ('reveal', 'point cloud', '/d435/points') in devices.log
    wait_for(lambda: displayed(devices) == [('point cloud', '/d435/points')], 10, 'the better view alone on screen')
    if standby == 'hot':
        assert back['kept_as_standby'] is True
        assert hidden(devices) == [('point cloud', '/stitcher/cloud')], 'the old view is now the hidden spare'
        assert len(started(devices, 'hokuyo')) == 1
    else:
        assert back['kept_as_standby'] is False
        wait_for(lambda: ('stop', 'hokuyo') in devices.log, 10, 'the worse sensor released under cold')
    wait_for(lambda: any('a better sensor is back' in f for f in feedback), 10, 'the operator told')
    assert run.nodes['show_environment_0'].state == 'RUNNING'


def test_each_fail_back_try_that_does_not_start_is_reported_with_its_doubling_wait(setup):
    engine, devices, events, _ = setup
    run_with(engine, events)
    devices.unplug('d435')
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    tries = wait_for(lambda: len(of(events, 'failback_unavailable')) >= 3 and of(events, 'failback_unavailable'),
                     10, 'three fail-back tries while the camera is unplugged')[:3]
    assert all(t['priority_indexes'] == [0] and 'RGB-D camera cloud' in t['message'] for t in tries), tries
    waits = [t['retry_in_s'] for t in tries]
    assert waits[0] < waits[1] < waits[2] <= FAST['failback_max_s'], waits
    assert of(events, 'failback_abandoned') == [], 'a try that never started is not a flap'


def test_a_flapping_sensor_costs_at_most_one_switch_per_backoff_window(setup):
    """A camera that fails again 20 ms after each start (a loose cable) is tried with a doubling wait, then
    quarantined: the view never switches back to it, and each try is reported."""
    engine, devices, events, _ = setup
    run_with(engine, events, failback_hold_s=30.0, quarantine_after=3, quarantine_s=60.0)
    devices.flap_after['d435'] = 0.02
    devices.unplug('d435')          # shown for less than a hold: the first flap
    wait_for(lambda: len(of(events, 'sensor_active')) == 2, 10, 'hokuyo active')
    devices.plug('d435')
    abandoned = wait_for(lambda: len(of(events, 'failback_abandoned')) >= 2 and of(events, 'failback_abandoned'),
                         10, 'two fail-back tries abandoned')
    assert [a['retry_in_s'] for a in abandoned] == [0.1, 60.0]
    assert [a['quarantined'] for a in abandoned] == [False, True]
    assert all(a['message'] == 'd435 flapped' for a in abandoned)
    assert [a['sensor_name'] for a in of(events, 'sensor_active')] == ['d435', 'hokuyo']
    assert of(events, 'failback') == []
    wait_for(lambda: devices.log.count(('stop', 'd435')) == 3, 10, 'the camera and both tries released')
    assert len(started(devices, 'd435')) == 3, 'quarantined: not tried again'


def test_a_cut_robot_link_fails_over_to_the_hot_station_sensor_and_fails_back_after_the_heal(setup):
    """The entry after the view is served by the station's own Sensor Manager: under hot standby it streams into
    a hidden display before the cut, so the failover needs nothing from the robot's side (nor its master)."""
    engine, devices, events, _ = setup
    priority = [DEFAULT_PRIORITY[0], SITE_ENTRY]
    run_with(engine, events, standby='hot', sensor_priority=priority)
    ready = wait_for(lambda: of(events, 'standby_ready'), 10, 'the station sensor ready as the hot spare')[0]
    assert ready['sensor_name'] == 'site_lidar' and ready['display'] == 'hidden'
    devices.cut_robot_link()
    active = wait_for(lambda: len(of(events, 'sensor_active')) == 2 and of(events, 'sensor_active')[1], 10,
                      'the station sensor on screen')
    assert active['sensor_name'] == 'site_lidar' and active['via'] == 'standby'
    assert ('reveal', 'laser scan', '/site_lidar/scan') in devices.log
    wait_for(lambda: displayed(devices) == [('laser scan', '/site_lidar/scan')], 10, 'the station view alone')
    # while the link is down, the robot's camera is tried with a doubling wait, and each try is reported
    tries = wait_for(lambda: len(of(events, 'failback_unavailable')) >= 2 and of(events, 'failback_unavailable'),
                     10, 'fail-back tries while the robot is out of reach')
    assert all('unreachable' in t['message'] for t in tries), [t['message'] for t in tries]
    devices.robot_cut = False             # the link heals; the camera's driver is started afresh
    back = wait_for(lambda: of(events, 'failback'), 10, 'the fail-back to the robot\'s camera')[0]
    assert back['sensor_name'] == 'd435' and back['from_sensor'] == 'site_lidar'
    wait_for(lambda: displayed(devices) == [('point cloud', '/d435/points')], 10, 'the robot\'s view back')
    assert hidden(devices) == [('laser scan', '/site_lidar/scan')], 'the station sensor is the spare again'


def test_a_view_of_a_named_robot_names_its_displays_after_the_robot(setup):
    """One station shows several robots: two views' displays of the same entry must not share a name."""
    engine, devices, events, _ = setup
    run_with(engine, events, say='show the environment of vaultbot_2')
    wait_for(lambda: devices.names, 10, 'a display shown')
    assert set(devices.names.values()) == {'RGB-D camera cloud (vaultbot_2)'}, devices.names


def test_a_bad_sensor_manager_in_the_priority_list_is_refused_by_name():
    with pytest.raises(ActionError, match=r"sensor_priority\[1\]\.sensor_manager must be one of robot, station, "
                                          r"got 'operator'"):
        parse_priority([DEFAULT_PRIORITY[0], dict(SITE_ENTRY, sensor_manager='operator')])
    assert [c.station for c in parse_priority([DEFAULT_PRIORITY[0], SITE_ENTRY])] == [False, True]


def test_the_failover_configuration_is_checked_and_names_what_is_wrong():
    from temoto_action_engine.failover_policy import FailoverConfig, Standby
    assert FailoverConfig.from_config({}).standby is Standby.COLD
    assert FailoverConfig.from_config({'standby': 'warm'}, 'HOT').standby is Standby.HOT
    for config, override, words in [({'standby': 'lukewarm'}, None, 'standby must be one of cold, warm, hot'),
                                    ({}, 'tepid', "the request's standby must be one of"),
                                    ({'failback': 'yes'}, None, 'failback must be true or false'),
                                    ({'failback_hold_s': -1}, None, 'failback_hold_s must be a number'),
                                    ({'quarantine_after': True}, None, 'quarantine_after must be a number'),
                                    ({'failback_check_s': 5, 'failback_max_s': 1}, None, 'failback_max_s (1)')]:
        with pytest.raises(ValueError, match=words.replace('(', r'\(').replace(')', r'\)')):
            FailoverConfig.from_config(config, override)


def test_backoff_doubles_quarantines_only_a_flapping_source_and_forgives_a_whole_hold():
    from temoto_core.backoff import Backoff
    b = Backoff(initial=1.0, maximum=8.0, quarantine_after=3, quarantine_s=60.0)
    assert [b.failed(0.0, flapped=False) for _ in range(5)] == [1.0, 2.0, 4.0, 8.0, 8.0]
    assert not b.quarantined and not b.ready(7.9) and b.ready(8.0)
    b.succeeded()
    assert [b.failed(0.0, flapped=True) for _ in range(3)] == [1.0, 2.0, 60.0] and b.quarantined
    b.succeeded()
    assert b.ready(0.0) and b.failed(0.0, flapped=True) == 1.0


def test_a_bad_standby_fails_the_action_before_it_holds_anything(setup):
    engine, devices, events, _ = setup
    engine.action_config['show_environment'] = {'standby': 'lukewarm'}
    _, run = engine.say('show the environment')
    assert run.wait(10) == []
    node = run.nodes['show_environment_0']
    assert node.state == 'FAILED' and 'standby must be one of cold, warm, hot' in node.message
    assert devices.log == []
