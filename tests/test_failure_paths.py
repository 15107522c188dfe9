"""No failure is silent off the demo's path: every kind of resource tells the action that holds it.

The whole stack in real processes: roscore, the simulated VaultBot, the ER, Sensor, Context and
Output Managers (a real RViz under Xvfb), and the action engine. Each test speaks to the engine as
an operator does (start_graph with text) and reads what an operator reads: list_graphs, the
feedback topic, the events topic, RViz screenshots.
"""
import json
import os
import signal

import numpy as np
import pytest
import rospy
from PIL import Image

from temoto_testing import wait_for, wait_receiving
from temoto_testing.operator import Operator
from temoto_core import master_lookup as er_master
from temoto_output_manager.host_client import RvizHostClient, host_node_name
from temoto_testing.sensor_manager import (NS, managers_idle, set_cable, start_context_manager, start_er_manager,
                                           start_sensor_manager, start_sim)

ALL_RRS = ('temoto_context_manager', 'temoto_context_manager_trackers', 'temoto_sensor_manager',
           'temoto_er_manager', 'temoto_output_manager')


@pytest.fixture(scope='module')
def operator(rospy_client, module_procs, tmp_path_factory):
    start_sim(module_procs)
    start_er_manager(module_procs, tmp_path_factory.mktemp('er_logs'))
    start_sensor_manager(module_procs, first_data_timeout=20.0, extra='')     # the VaultBot's sensors only
    start_context_manager(module_procs)
    module_procs.node('temoto_output_manager', 'temoto_output_manager', name='temoto_output_manager',
                      params={'host_ready_timeout': 20.0})
    if rospy_client.has_param('/temoto_action_engine'):
        rospy_client.delete_param('/temoto_action_engine')
    module_procs.node('temoto_action_engine', 'temoto_action_engine', name='temoto_action_engine',
                      params={'temoto_namespace': NS})
    rospy.wait_for_service('/%s/action_engine/start_graph' % NS, timeout=20)
    op = Operator()
    wait_receiving(op.subs, 20, 'the engine topics connected')
    yield op
    op.close()


@pytest.fixture
def clean(operator):
    yield operator
    for g in json.loads(operator.list().json):
        if g['state'] in ('RUNNING', 'STOPPING'):
            operator.stop(graph_name=g['graph_name'])
    set_cable('d435', 'plugged')
    managers_idle(ALL_RRS, timeout=30)
    wait_for(lambda: host_pid() is None, 20, 'the RViz host to stop')


def host_pid():
    uri = er_master.lookup_node(os.environ['ROS_MASTER_URI'], host_node_name(NS))
    return er_master.node_pid(uri) if uri else None


def red_pixels(path: str) -> int:
    """Pixels of RViz's default Pose arrow colour (255, 25, 0)."""
    rgb = np.asarray(Image.open(path).convert('RGB')).astype(int)
    return int(((rgb[..., 0] > 180) & (rgb[..., 1] < 90) & (rgb[..., 2] < 70)).sum())


def test_track_the_hand_and_show_it_on_the_screen_draws_the_hand_pose(clean, tmp_path):
    """The README's example: the pose display exists, and the hand's pose arrow is on screen."""
    op = clean
    graph = op.say('track the hand and show it on the screen')
    showing = op.wait_event('showing', graph, 60, 'the show action to put the pose on screen')
    assert showing[0]['display_type'] == 'pose'
    tracking = op.of('tracking', graph)[0]
    assert showing[0]['topic'] == tracking['topic']
    host = RvizHostClient(host_node_name(NS))

    path = str(tmp_path / 'pose.png')

    def drawn():
        assert host.screenshot(path=path).ok
        return red_pixels(path) > 50
    wait_for(drawn, 30, "the hand's pose arrow drawn in RViz")
    assert op.graph(graph)['state'] == 'RUNNING'
    assert op.stop(graph_name=graph).code == 0
    assert op.graph(graph)['state'] == 'FINISHED'


def test_a_camera_crash_under_track_object_ends_the_graph_failed_with_the_reason(clean):
    """The tracker's client hears FAILED; nothing else can track the hand, so the graph ends FAILED (it
    used to stay RUNNING after the interface's reload gave up in a log line)."""
    op = clean
    graph = op.say('track the hand')
    op.wait_event('tracking', graph, 60, 'tracking')
    set_cable('d435', 'unplugged', 'crash')
    finished = wait_for(lambda: (lambda g: g['state'] != 'RUNNING' and g)(op.graph(graph)), 60,
                        'the graph to end')
    assert finished['state'] == 'FAILED', finished
    assert 'hand' in finished['reason'] and 'd435' in finished['reason'], finished['reason']
    node = finished['nodes'][0]
    assert node['state'] == 'FAILED' and node['message'] in finished['reason']
    wait_for(lambda: op.of('tracker_failed', graph), 10, 'the failure to reach the action')
    wait_for(lambda: any('track_object failed' in f and 'hand' in f for f in op.feedback), 10,
             'the failure said on the feedback topic')
    # the event is published as the graph ends; the state read above may come before it arrives
    done = wait_for(lambda: op.of('graph_finished', graph), 10, 'the graph_finished event')
    assert done and done[-1]['state'] == 'FAILED' and done[-1]['reason'] == finished['reason']


def test_an_rviz_host_crash_reaches_show_environment_which_shows_the_same_sensor_again(clean):
    """A display failure goes to the action's own policy (not the interface's silent reload), and the
    action holds nothing stale afterwards."""
    op = clean
    graph = op.say('show the environment')
    active = op.wait_event('sensor_active', graph, 60, 'the first view')
    pid = wait_for(host_pid, 30, 'the RViz host')
    os.kill(pid, signal.SIGKILL)
    restored = op.wait_event('display_restored', graph, 60, 'the display shown again')
    assert restored[0]['sensor_name'] == active[0]['sensor_name']
    failed = op.of('sensor_failed', graph)
    assert failed and failed[0]['failed_part'] == 'display'
    new_pid = wait_for(host_pid, 30, 'a new RViz host')
    assert new_pid != pid
    assert len(op.of('sensor_active', graph)) == 1, 'no failover for a healthy sensor'
    assert op.graph(graph)['state'] == 'RUNNING'
    assert op.stop(graph_name=graph).code == 0
