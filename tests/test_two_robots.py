"""Two VaultBots on one master, each started by robot.launch with its name: its own ROS and TeMoto
namespace, its own simulation, drivers and managers, its TF frames prefixed in the one shared tree.

Each robot's sensors fail over on their own, and nothing of one robot reaches the other: its topics, its
statuses, its processes.
"""
import json

import pytest
import rosgraph
from sensor_msgs.msg import LaserScan
from tf2_msgs.msg import TFMessage

from temoto_core.msg import ResourceStatus
from temoto_testing import made_interfaces, wait_for
from temoto_sensor_manager.interface import SensorManagerInterface
from vaultbot_sim.srv import SetDeviceState

ROBOTS = {'vaultbot_1': '[0, 0, 0]', 'vaultbot_2': '[0, 8, 0]'}

# Two whole robots (two simulations, two D435s rendering at 30 Hz) and, last, an operator's station with RViz
# take the machine: alone, its idle time fell to 0-16 % for the last test. Beside the other worker, a clean
# clone's suite once saw robot 1's view not fail over within 30 s; the demo's tests, starved the same way, saw
# their LIDARs stall (no scan for 0.3 s, the stall limit) and every candidate fail in turn. The module runs
# alone, as test_chaos does.
pytestmark = pytest.mark.alone


@pytest.fixture(scope='module')
def robots(rospy_client, module_procs):
    for robot, origin in ROBOTS.items():
        # the launch file takes the name; no <group ns> around it
        # two simulations render on 2 cores beside the other worker: a driver's start-up may take longer than
        # the default 4 s allowance (robot 2's camera once did, and its view began on the lidar); these tests
        # are about the robots' independence, not start-up speed (bench_sim.py measures that)
        module_procs.launch('temoto_bringup', 'robot.launch',
                            ['robot:=' + robot, 'frame_prefix:=%s/' % robot, 'origin:=' + origin, 'world:=lab',
                             'first_data_allowance:=15.0'])
    for robot in ROBOTS:
        rospy_client.wait_for_service('/%s/temoto_sensor_manager/start_sensor' % robot, timeout=30)
        rospy_client.wait_for_service('/%s/vaultbot_sim/set_device_state' % robot, timeout=30)
    return module_procs


@pytest.fixture
def make(robots):
    with made_interfaces(lambda robot: SensorManagerInterface(namespace=robot)) as make:
        yield make
    for robot in ROBOTS:
        for device, _ in DEVICES.values():
            set_cable(robot, device, 'plugged')


def set_cable(robot, device, state, mode=''):
    resp = rospy_proxy('/%s/vaultbot_sim/set_device_state' % robot, SetDeviceState)(device, state, mode)
    assert resp.success, resp.message


def rospy_proxy(name, kind):
    import rospy
    return rospy.ServiceProxy(name, kind)


class Scans:
    """Every scan heard on one topic: its frame, and how many."""

    def __init__(self, topic):
        import rospy
        self.frames, self.count = set(), 0
        self._sub = rospy.Subscriber(topic, LaserScan, self._on, queue_size=10)

    def _on(self, msg):
        self.frames.add(msg.header.frame_id)
        self.count += 1

    def close(self):
        self._sub.unregister()


def publishers(topic):
    state = rosgraph.Master('/test_two_robots').getSystemState()
    return sorted(node for name, nodes in state[0] if name == topic for node in nodes)


def failed(events):
    return [e for e in events if e.code == ResourceStatus.FAILED]


def test_each_robot_serves_its_own_sensors_in_its_own_names(make):
    one, two = make('vaultbot_1'), make('vaultbot_2')
    first = one.start_sensor('lidar', ['lidar_data'], executable='sick_driver')
    second = two.start_sensor('lidar', ['lidar_data'], executable='sick_driver')
    assert first.output_topics == {'lidar_data': '/vaultbot_1/sick/scan'}
    assert second.output_topics == {'lidar_data': '/vaultbot_2/sick/scan'}
    for robot, result in (('vaultbot_1', first), ('vaultbot_2', second)):
        topic = result.output_topics['lidar_data']
        scans = Scans(topic)
        wait_for(lambda: scans.count >= 3, 15, 'scans on %s' % topic)
        scans.close()
        assert scans.frames == {'%s/sick_link' % robot}, scans.frames
        # the driver runs in its robot's namespace, started by that robot's own ER Manager
        assert publishers(topic) == ['/%s/sick_driver' % robot], publishers(topic)


def test_the_shared_tf_tree_holds_both_robots_apart_at_their_origins(robots):
    import rospy
    static = rospy.wait_for_message('/tf_static', TFMessage, timeout=10)
    heard = {}
    sub = None

    def on(msg):
        for t in msg.transforms:
            heard[t.child_frame_id] = (t.header.frame_id, t.transform.translation.y)
    sub = rospy.Subscriber('/tf_static', TFMessage, on, queue_size=10)
    try:
        on(static)
        wait_for(lambda: {'vaultbot_1/world', 'vaultbot_2/world'} <= set(heard), 10,
                 'both robots\' worlds on /tf_static (latched, one message per robot)')
    finally:
        sub.unregister()
    assert heard['vaultbot_1/world'] == ('world', 0.0)
    assert heard['vaultbot_2/world'] == ('world', 8.0)
    assert heard['vaultbot_2/odom'][0] == 'vaultbot_2/world'          # odom -> base_link: its base controller
    for frame, (parent, _) in heard.items():       # no frame of one robot hangs off the other's
        if frame.startswith('vaultbot_1/'):
            assert not parent.startswith('vaultbot_2/'), (frame, parent)


DEVICES = {'hokuyo_utm30lx': ('hokuyo', 'hokuyo_link'), 'sick_lms511': ('sick', 'sick_link')}


def test_a_robot_fails_over_on_its_own_and_the_other_hears_nothing(make):
    one, two = make('vaultbot_1'), make('vaultbot_2')
    events_one, events_two = [], []
    one.rr.register_status_callback(events_one.append)
    two.rr.register_status_callback(events_two.append)
    first = one.start_sensor('lidar', ['lidar_data'])
    second = two.start_sensor('lidar', ['lidar_data'], executable=first.executable)     # the same device
    topic_one, topic_two = first.output_topics['lidar_data'], second.output_topics['lidar_data']
    assert topic_one.startswith('/vaultbot_1/') and topic_two.startswith('/vaultbot_2/'), (topic_one, topic_two)
    device, _ = DEVICES[first.sensor_name]
    other = next(name for name in DEVICES if name != first.sensor_name)
    set_cable('vaultbot_1', device, 'unplugged', 'crash')
    wait_for(lambda: failed(events_one), 15, 'FAILED at robot 1\'s client')
    # robot 1's default policy reloads with the topic pinned: its unplugged device still ranks first and
    # fails, and its other lidar serves the same topic
    new_id = wait_for(lambda: one.replacement_of(first.resource_id) or one.reload_errors.get(first.resource_id),
                      60, 'robot 1\'s reload')
    assert isinstance(new_id, int), new_id
    assert one.result_of(new_id).sensor_name == other
    scans = Scans(topic_one)
    wait_for(lambda: scans.count >= 3, 15, 'robot 1\'s substitute on its pinned topic')
    scans.close()
    assert scans.frames == {'vaultbot_1/' + DEVICES[other][1]}, scans.frames
    # robot 2 heard nothing and still streams from its own device, the one robot 1 lost
    still = Scans(topic_two)
    wait_for(lambda: still.count >= 3, 15, 'robot 2\'s lidar still streaming')
    still.close()
    assert still.frames == {'vaultbot_2/' + DEVICES[second.sensor_name][1]}, still.frames
    assert not failed(events_two), events_two
    assert two.result_of(second.resource_id).sensor_name == second.sensor_name


class ActionEvents:
    """The action engine's events (JSON on ``/temoto/action_engine/events``), as they arrive."""

    def __init__(self):
        import rospy
        from std_msgs.msg import String
        self.events = []
        self._sub = rospy.Subscriber('/temoto/action_engine/events', String,
                                     lambda msg: self.events.append(json.loads(msg.data)), queue_size=100)

    def of(self, kind, graph=None):
        return [e for e in list(self.events) if e.get('event') == kind and graph in (None, e.get('graph'))]

    def story(self, graph=None):
        """What happened, for a failure's message: every event but the state ticks, briefly."""
        return [(e.get('event'), e.get('graph'), e.get('message') or e.get('topic')) for e in list(self.events)
                if e.get('event') != 'state' and graph in (None, e.get('graph'))]

    def close(self):
        self._sub.unregister()


def test_one_station_shows_both_robots_and_each_view_fails_over_on_its_own(robots, procs, rospy_client):
    """Two "show the environment of <robot>" graphs on one operator's station: robot 1's camera crashes, and
    only robot 1's view fails over, to robot 1's own next sensor; robot 2's view stays on its camera."""
    from std_msgs.msg import String
    from temoto_action_engine.srv import StopGraph
    procs.launch('temoto_bringup', 'operator.launch',
                 ['robot:=vaultbot_1', 'robots:=vaultbot_1,vaultbot_2', 'fixed_frame:=world'])
    rospy_client.wait_for_service('/temoto/action_engine/list_actions', timeout=30)
    events = ActionEvents()
    chatter = rospy_client.Publisher('/temoto/human_chatter', String, queue_size=5)
    wait_for(lambda: chatter.get_num_connections() > 0, 15, 'the engine to hear the chatter')
    try:
        chatter.publish(String(data='show the environment of vaultbot_1'))
        first = wait_for(lambda: events.of('sensor_active'), 60, 'robot 1\'s view')[0]
        chatter.publish(String(data='show the environment of vaultbot_2'))
        second = wait_for(lambda: len(events.of('sensor_active')) >= 2 and events.of('sensor_active')[1], 60,
                          'robot 2\'s view')
        assert first['topic'] == '/vaultbot_1/d435/depth_registered/points', first
        assert second['topic'] == '/vaultbot_2/d435/depth_registered/points', events.story()[-4:]
        assert first['graph'] != second['graph']
        set_cable('vaultbot_1', 'd435', 'unplugged', 'crash')
        try:
            moved = wait_for(lambda: len(events.of('sensor_active', first['graph'])) >= 2
                             and events.of('sensor_active', first['graph'])[1], 30, 'robot 1\'s view failing over')
        except TimeoutError as err:
            raise AssertionError('%s; robot 1\'s graph told: %s' % (err, events.story(first['graph']))) from err
        assert moved['topic'].startswith('/vaultbot_1/') and moved['priority_index'] == 1, moved
        [failed_event] = events.of('sensor_failed')
        assert failed_event['graph'] == first['graph'] and 'd435_driver' in failed_event['message'], failed_event
        assert events.of('sensor_active', second['graph']) == [second], 'robot 2\'s view must not move'
    finally:
        set_cable('vaultbot_1', 'd435', 'plugged')
        stop = rospy_client.ServiceProxy('/temoto/action_engine/stop_graph', StopGraph)
        for graph in {e['graph'] for e in events.of('sensor_active')}:
            stop(graph_name=graph)
        events.close()
