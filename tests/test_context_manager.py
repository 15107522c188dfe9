"""The Context Manager end to end: track the person's green hand in the simulated D435's cloud.

The four-level chain of the paper's Figures 4-5: a client -> track_object (Context Manager)
-> load_tracker (its tracker registrar) -> start_sensor (Sensor Manager) -> load_process (ER Manager).
Shared by the module: roscore, vaultbot_sim, and the three managers.
"""
import os
import time

import pytest

from temoto_testing import made_interfaces
import rospy
from geometry_msgs.msg import PoseStamped

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_testing import wait_for
from temoto_context_manager.interface import ContextManagerInterface
from temoto_testing.sensor_manager import (ROOT, catalogue, er_processes, managers_idle, set_cable,
                                           start_context_manager, start_er_manager, start_sensor_manager, start_sim,
                                           tracker_info)

DEFAULT_TRACKERS = os.path.join(ROOT, 'temoto_context_manager', 'config', 'trackers.yaml')
BAD_TRACKERS = os.path.join(ROOT, 'temoto_context_manager', 'test_config', 'bad_trackers.yaml')
ALL_RRS = ('temoto_context_manager', 'temoto_context_manager_trackers', 'temoto_sensor_manager', 'temoto_er_manager')


@pytest.fixture(scope='module')
def stack(rospy_client, module_procs, tmp_path_factory):
    start_sim(module_procs)
    start_er_manager(module_procs, tmp_path_factory.mktemp('er_logs'))
    start_sensor_manager(module_procs, first_data_timeout=20.0, extra='')      # the VaultBot's sensors only
    start_context_manager(module_procs, trackers='%s,%s' % (DEFAULT_TRACKERS, BAD_TRACKERS))
    return module_procs


@pytest.fixture
def cmi(stack):
    with made_interfaces(ContextManagerInterface) as make:
        yield make
    set_cable('d435', 'plugged')
    managers_idle(ALL_RRS, timeout=20)


class Poses:
    def __init__(self, topic):
        self.poses = []
        self.sub = rospy.Subscriber(topic, PoseStamped, lambda m: self.poses.append((time.monotonic(), m)))

    def close(self):
        self.sub.unregister()


def test_tracking_the_hand_gives_moving_3d_positions_at_the_camera_rate(cmi):
    cm = cmi()
    obj = cm.track_object('hand')
    assert (obj.object_name, obj.detection_method, obj.tracker_name) == ('hand', 'hand', 'green_hand_rgbd')
    assert obj.topic == '/temoto/%s/filter_1/pose' % obj.pipe_id
    poses = Poses(obj.topic)
    wait_for(lambda: len(poses.poses) >= 2, 5, 'poses flowing right after the response')
    start = time.monotonic()
    wait_for(lambda: time.monotonic() - start > 3.0 and len(poses.poses) > 10, 10, 'three seconds of poses')
    poses.close()
    msgs = [m for _, m in poses.poses]
    assert all(m.header.frame_id == 'd435_optical_frame' for m in msgs)
    zs = [m.pose.position.z for m in msgs]
    assert 0.5 < min(zs) and max(zs) < 4.0                    # in front of the camera, at the person
    xs = [m.pose.position.x for m in msgs]
    assert max(xs) - min(xs) > 0.03, 'the hand waves, so its estimate moves: %r' % xs[:: max(1, len(xs) // 10)]
    span = poses.poses[-1][0] - poses.poses[0][0]
    assert len(msgs) / span > 3.0                             # one pose per cloud; the camera runs at ~25 Hz


def test_killing_the_camera_driver_fails_track_object_through_every_level(cmi):
    cm = cmi()
    events = []
    cm.register_update_callback(events.append)
    obj = cm.track_object('hand')
    info = tracker_info()
    tracker_before = info['trackers']['green_hand_rgbd']['reliability']
    log_before = len(info['status_log'])
    set_cable('d435', 'unplugged', 'crash')
    wait_for(lambda: [e for e in events if e.code == ResourceStatus.FAILED], 15, 'FAILED at the track_object client')
    event = events[0]
    assert event.resource_id == obj.resource_id and event.rr_name == 'temoto_context_manager'
    stack = [f.message for f in event.error_stack]
    assert any('d435' in m and 'exit' in m for m in stack), stack             # where it started: the ER Manager
    assert sum('sub-resource' in m for m in stack) >= 3, stack                # one hop each: SM, trackers, CM
    # every intermediate owner callback ran
    info = wait_for(lambda: (lambda i: len(i['status_log']) >= log_before + 2 and i)(tracker_info()), 10,
                    'the Context Manager owner callbacks')
    owners = {entry['owner'] for entry in info['status_log'][log_before:]}
    assert owners == {'tracker', 'object'}
    assert info['trackers']['green_hand_rgbd']['reliability'] < tracker_before
    assert info['methods']['hand/hand'] < 0.81
    assert catalogue()['realsense_d435']['reliability'] < 0.8                  # the Sensor Manager's callback
    cm.stop(obj.resource_id)
    managers_idle(ALL_RRS, timeout=20)


def raw(server, **fields):
    from temoto_core.rr import ResourceRegistrar
    from temoto_context_manager.srv import LoadTracker, TrackObject
    srv = {'load_tracker': LoadTracker, 'track_object': TrackObject}[server]
    rr = ResourceRegistrar('context_bad_input_client')
    try:
        return rr.call('temoto_context_manager', server, srv._request_class(**fields))
    finally:
        rr.shutdown()


@pytest.mark.parametrize('server, fields, code, words', [
    ('track_object', dict(object_name='unicorn'), ErrorCode.BAD_REQUEST, ["unknown object 'unicorn'", 'hand']),
    ('load_tracker', dict(tracker_category='sonar'), ErrorCode.NO_TRACKERS_FOUND,
     ["no tracker of category 'sonar'", 'hand']),
    ('load_tracker', dict(tracker_category=''), ErrorCode.BAD_REQUEST, ['tracker_category is empty']),
    ('load_tracker', dict(tracker_category='hand', output_topics=[('velocity', '')]), ErrorCode.NO_TRACKERS_FOUND,
     ["no 'hand' tracker gives velocity", 'green_hand_rgbd: pose']),
    ('load_tracker', dict(tracker_category='hand', output_topics=[('pose', '/mine')]), ErrorCode.BAD_REQUEST,
     ['cannot be chosen']),
])
def test_bad_input_gets_a_clear_error_and_leaves_nothing_loaded(cmi, server, fields, code, words):
    from diagnostic_msgs.msg import KeyValue
    fields = dict(fields)
    if 'output_topics' in fields:
        fields['output_topics'] = [KeyValue(k, v) for k, v in fields['output_topics']]
    with pytest.raises(TemotoError) as info:
        raw(server, **fields)
    for word in words:
        assert word in str(info.value), str(info.value)
    assert any(f.code == code for f in info.value.stack)
    assert not er_processes()


def test_malformed_tracker_entries_are_reported_with_file_and_line(stack):
    problems = tracker_info()['problems']
    assert any('bad_trackers.yaml:3:' in p and 'filters must be a non-empty list' in p for p in problems), problems
    assert any('bad_trackers.yaml:7:' in p and "input type 'camera_data' is produced by no earlier filter" in p
               for p in problems), problems
    assert any('bad_trackers.yaml:17:' in p and 'detection_methods' in p for p in problems), problems
    assert set(tracker_info()['trackers']) == {'green_hand_rgbd'}
