"""Each action instance owns a real Resource Registrar: what it loads is released when it ends.

Processes: a test RR server (LoadTestResource), the engine node, its graph workers (one process
per graph), and this test (chatter, services). Plugins that crash their worker or ignore a stop
show what isolation guarantees: the engine lives on, the graph ends FAILED with the reason, and
what the graph held is released.
"""
import json
import os
import signal
import sys
import threading

import pytest

from temoto_testing import wait_receiving
from temoto_testing.action_engine import write_plugin
from temoto_core.wait import wait_for

NS = 'aeres'
ENGINE = 'ae_resources_engine'
SERVER = '''
import sys
import rospy
from std_msgs.msg import String
from temoto_core.msg import ResourceStatus
from temoto_core.rr import ResourceRegistrar
from temoto_core.srv import LoadTestResource

ns = sys.argv[1]
rospy.init_node('rr_test_server', disable_signals=False)
rr = ResourceRegistrar('test_server', namespace=ns)
loaded = {}

def load(req, resp):
    loaded[resp.trr.resource_id] = req.name
    resp.payload = 'payload of ' + req.name

def unload(req, resp):
    loaded.pop(resp.trr.resource_id, None)

def fail(msg):
    for iid, name in list(loaded.items()):
        if name == msg.data:
            rr.send_status(iid, ResourceStatus.FAILED, 'unplugged ' + name)

rr.add_server('load_test', LoadTestResource, load, unload)
rospy.Subscriber('/%s/test_server/fail' % ns, String, fail)
rospy.on_shutdown(rr.shutdown)
rospy.spin()
'''
GRAB = '''
from temoto_action_engine.action_base import ActionBase
from temoto_core.srv import LoadTestResourceRequest

class Grab(ActionBase):
    def on_start(self):
        name = self.input('name')
        resp = self.rr.call('test_server', 'load_test', LoadTestResourceRequest(name=name), status_cb=self.post)
        self.rr.call('test_server', 'load_test', LoadTestResourceRequest(name=name + '_extra'))
        self.set_output('payload', resp.payload)
        self.event('grabbed', name=name, registrar=self.rr_name)

    def execute(self):
        while self.action_ok():
            ev = self.next_item(3600.0)
            if ev is not None:
                self.event('resource_status', code=ev.code, message=ev.message, resource_id=ev.resource_id)
'''
CRASH = '''
import ctypes
import os
from temoto_action_engine.action_base import ActionBase
from temoto_core.srv import LoadTestResourceRequest

class Crash(ActionBase):
    def execute(self):
        self.rr.call('test_server', 'load_test', LoadTestResourceRequest(name=self.input('name')))
        self.event('holding', name=self.input('name'), pid=os.getpid())
        if self.input('how') == 'exit':
            os._exit(3)
        ctypes.string_at(0)      # a crash in C: SIGSEGV
'''
WEDGE = '''
import time
from temoto_action_engine.action_base import ActionBase
from temoto_core.srv import LoadTestResourceRequest

class Wedge(ActionBase):
    def on_start(self):
        self.rr.call('test_server', 'load_test', LoadTestResourceRequest(name=self.input('name')))
        self.event('holding', name=self.input('name'))

    def execute(self):
        print('a plugin printing to stdout does not disturb its worker')
        while True:              # ignores every stop
            time.sleep(0.05)
'''
STOP_TIMEOUT_S = 3.0
# a killed worker's references are released by the server's consumer watch: 2 x (check period + 1 s)
CONSUMER_DEATH_BOUND_S = 2 * (2.0 + 1.0)


@pytest.fixture
def world(procs, rospy_client, tmp_path):
    from std_msgs.msg import String
    plugins = tmp_path / 'plugins'
    write_plugin(str(plugins), 'grab', GRAB, effect='asynchronous',
                 inputs={'name': {'pvf_type': 'string'}}, outputs={'payload': {'pvf_type': 'string'}},
                 grounding={'verbs': ['grab', 'hold'], 'parameters': {'name': {'any': True}}})
    write_plugin(str(plugins), 'crash', CRASH, inputs={'name': {'pvf_type': 'string'}, 'how': {'pvf_type': 'string'}})
    write_plugin(str(plugins), 'wedge', WEDGE, effect='asynchronous', inputs={'name': {'pvf_type': 'string'}})
    server = tmp_path / 'rr_test_server.py'
    server.write_text(SERVER)
    srv_proc = procs.command([sys.executable, str(server), NS], 'rr_test_server')
    procs.wait_registered(srv_proc, ['/rr_test_server'], 20)
    engine_params = {'temoto_namespace': NS, 'action_paths': str(plugins), 'stop_timeout_s': STOP_TIMEOUT_S,
                     'journal': str(tmp_path / 'engine.sqlite')}
    if rospy_client.has_param('/' + ENGINE):
        rospy_client.delete_param('/' + ENGINE)      # private params outlive a node on the shared master
    engine = procs.node('temoto_action_engine', 'temoto_action_engine', name=ENGINE,
                        params=engine_params)
    rospy_client.wait_for_service('/%s/test_server/load_test' % NS, timeout=20)
    rospy_client.wait_for_service('/%s/action_engine/start_graph' % NS, timeout=20)
    events, lock = [], threading.Lock()

    def on_event(msg):
        with lock:
            events.append(json.loads(msg.data))

    feedback = []

    def on_feedback(msg):
        with lock:
            feedback.append(msg.data)

    sub = rospy_client.Subscriber('/%s/action_engine/events' % NS, String, on_event)
    fb_sub = rospy_client.Subscriber('/%s/action_engine/feedback' % NS, String, on_feedback)
    chatter = rospy_client.Publisher('/%s/human_chatter' % NS, String, queue_size=10)
    fail = rospy_client.Publisher('/%s/test_server/fail' % NS, String, queue_size=10)
    wait_receiving([sub, fb_sub], 20, 'the engine\'s events and feedback connected')
    wait_for(lambda: chatter.get_num_connections() and fail.get_num_connections(), 20, 'topics connected')

    class World:
        def say(self, text):
            chatter.publish(String(data=text))

        def unplug(self, name):
            fail.publish(String(data=name))

        def events(self, kind):
            with lock:
                return [e for e in events if e.get('event') == kind]

        def feedback_with(self, *words):
            with lock:
                return [f for f in feedback if all(w in f for w in words)]

        engine_proc = engine

        def restart_engine(self):
            """SIGKILL the engine alone (its workers live on) and start it again, as a respawn would."""
            os.kill(self.engine_proc.pid, signal.SIGKILL)
            wait_for(lambda: not self.engine_proc.alive(), 10, 'the engine to die')
            self.engine_proc = procs.node('temoto_action_engine', 'temoto_action_engine', name=ENGINE,
                                          params=engine_params)
            rospy_client.wait_for_service('/%s/action_engine/list_graphs' % NS, timeout=20)

    yield World()
    for x in (sub, fb_sub, chatter, fail):
        x.unregister()


def registry(rospy, rr_name):
    from temoto_core.srv import GetRegistry
    return json.loads(rospy.ServiceProxy('/%s/%s/registry' % (NS, rr_name), GetRegistry)().json)


def served(rospy):
    return sorted(q['summary']['name'] for q in registry(rospy, 'test_server')['server_queries'])


def action_registrars(rospy):
    import rosservice
    return sorted({s.split('/')[2] for s in rosservice.get_service_list() if s.startswith('/%s/action_grab_' % NS)})


def grab_and_check(rospy, world, text='grab the cake', thing='cake'):
    world.say(text)
    wait_for(lambda: served(rospy) == [thing, thing + '_extra'], 20, 'the action to load two resources')
    (rr_name,) = action_registrars(rospy)
    assert rr_name.startswith('action_grab_')
    held = registry(rospy, rr_name)['client_queries']
    assert sorted(q['summary']['name'] for q in held) == [thing, thing + '_extra']
    consumers = [c['client_name'] for q in registry(rospy, 'test_server')['server_queries'] for c in q['consumers']]
    # the graph runs in a worker process of the engine's, a node of its own: that node holds them
    assert len(set(consumers)) == 1 and len(consumers) == 2, consumers
    assert consumers[0].startswith('/%s_worker_' % ENGINE), consumers
    return rr_name


def test_stopping_the_graph_releases_everything_the_action_loaded(world, rospy_client):
    from temoto_action_engine.srv import StopGraph
    grab_and_check(rospy_client, world)
    resp = rospy_client.ServiceProxy('/%s/action_engine/stop_graph' % NS, StopGraph)(graph_name='grab')
    assert resp.code == 0, resp.message
    assert served(rospy_client) == []                   # released by the time stop_graph answered
    wait_for(lambda: action_registrars(rospy_client) == [], 10, "the action's registrar to unregister")


def test_status_reaches_the_action_and_stop_by_words_releases(world, rospy_client):
    grab_and_check(rospy_client, world)
    world.unplug('cake')
    (ev,) = wait_for(lambda: world.events('resource_status'), 20, 'FAILED to reach the action')
    assert ev['code'] == 1 and 'unplugged cake' in ev['message']
    world.say('stop grabbing the cake')
    wait_for(lambda: served(rospy_client) == [], 20, 'resources released after "stop grabbing the cake"')
    wait_for(lambda: action_registrars(rospy_client) == [], 10, "the action's registrar to unregister")


def test_engine_shutdown_releases_the_resources_of_running_actions(world, rospy_client):
    grab_and_check(rospy_client, world, 'hold the pie', 'pie')
    assert world.engine_proc.stop() is not None           # SIGINT: the node stops its graphs first
    assert served(rospy_client) == []


def start_graph(rospy, action, **inputs):
    from temoto_action_engine.srv import StartGraph
    graph = {'graph_name': action, 'actions': [{'name': action, 'input_parameters': {
        k: {'pvf_type': 'string', 'pvf_value': v} for k, v in inputs.items()}}]}
    resp = rospy.ServiceProxy('/%s/action_engine/start_graph' % NS, StartGraph)(graph_json=json.dumps(graph), text='')
    assert resp.code == 0, resp.message
    return resp.graph_name


def graphs(rospy):
    from temoto_action_engine.srv import ListGraphs
    return {g['graph_name']: g for g in json.loads(
        rospy.ServiceProxy('/%s/action_engine/list_graphs' % NS, ListGraphs)().json)}


def pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.parametrize('how, reason', [('exit', 'exited with code 3'), ('segv', 'killed by SIGSEGV')])
def test_a_plugin_that_kills_its_process_fails_its_graph_and_the_engine_lives_on(world, rospy_client, how, reason):
    from temoto_core import master_lookup
    name = start_graph(rospy_client, 'crash', name='cake', how=how)
    (held,) = wait_for(lambda: world.events('holding'), 20, 'the plugin to hold its resource')
    worker = graphs(rospy_client)[name]['worker_pid']
    assert held['pid'] == worker != world.engine_proc.pid
    (query,) = registry(rospy_client, 'test_server')['server_queries']
    (worker_node,) = [c['client_name'] for c in query['consumers']]
    wait_for(lambda: graphs(rospy_client)[name]['state'] == 'FAILED', 20, 'the graph to end FAILED')
    g = graphs(rospy_client)[name]
    assert reason in g['reason'] and 'worker process died' in g['reason'], g
    assert [n['state'] for n in g['nodes']] == ['FAILED']
    # the feedback topic is asynchronous to the graph listing: the message may still be on its way
    wait_for(lambda: world.feedback_with('crash failed', reason), 10, 'the failure on the feedback topic')
    assert world.engine_proc.alive()
    wait_for(lambda: served(rospy_client) == [], CONSUMER_DEATH_BOUND_S + 10, 'the dead graph\'s resource released')
    consumers_left = [q for q in registry(rospy_client, 'test_server')['server_queries']]
    assert consumers_left == []
    # the dead worker's node is gone from the master, and the engine still runs graphs
    master = os.environ['ROS_MASTER_URI']
    wait_for(lambda: master_lookup.lookup_node(master, worker_node) is None, 20, 'the dead worker to leave the master')
    grab_and_check(rospy_client, world, 'grab the pie', 'pie')


def test_an_action_that_ignores_stop_is_ended_after_the_grace_and_its_resource_released(world, rospy_client):
    from temoto_action_engine.srv import StopGraph
    name = start_graph(rospy_client, 'wedge', name='cake')
    wait_for(lambda: world.events('holding'), 20, 'the plugin to hold its resource')
    worker = graphs(rospy_client)[name]['worker_pid']
    assert served(rospy_client) == ['cake']
    resp = rospy_client.ServiceProxy('/%s/action_engine/stop_graph' % NS, StopGraph)(graph_name=name)
    assert resp.code == 1, resp.message
    assert 'wedge_0 did not stop within 3 s' in resp.message and 'ended' in resp.message, resp.message
    g = graphs(rospy_client)[name]
    assert g['state'] == 'FAILED' and 'did not stop within 3 s' in g['reason'], g
    assert not pid_alive(worker)
    # SIGTERM lets the worker release what it holds before it goes; the consumer watch is the backstop
    wait_for(lambda: served(rospy_client) == [], CONSUMER_DEATH_BOUND_S + 10, 'the wedged graph\'s resource released')
    assert world.engine_proc.alive()


def test_the_stop_action_ends_an_action_that_ignores_it(world, rospy_client):
    start_graph(rospy_client, 'wedge', name='cake')
    wait_for(lambda: world.events('holding'), 20, 'the plugin to hold its resource')
    world.say('stop the wedge')
    wait_for(lambda: world.feedback_with('stop: stopped', 'wedge_0', 'did not stop within 3 s'), 30,
             'the stop action to say it ended the wedged action')
    wait_for(lambda: served(rospy_client) == [], CONSUMER_DEATH_BOUND_S + 10, 'the wedged graph\'s resource released')


def test_graphs_running_when_the_engine_is_killed_are_reported_failed_by_its_next_start(world, rospy_client):
    name = start_graph(rospy_client, 'grab', name='cup')
    wait_for(lambda: world.events('grabbed'), 20, 'the graph to hold its resource')
    worker = graphs(rospy_client)[name]['worker_pid']
    assert len(served(rospy_client)) == 2
    world.restart_engine()
    g = graphs(rospy_client)[name]
    assert g['state'] == 'FAILED' and 'the action engine died while this graph ran' in g['reason'], g
    assert all(n['state'] == 'FAILED' for n in g['nodes']), g['nodes']
    wait_for(lambda: [e for e in world.events('graph_finished') if e['graph'] == name and e['state'] == 'FAILED'],
             10, 'the FAILED on the events topic')
    wait_for(lambda: world.feedback_with(name, 'engine died'), 10, 'the FAILED on the feedback topic')
    # what the graph held is released: its worker stopped it when the engine's pipe closed
    wait_for(lambda: served(rospy_client) == [], CONSUMER_DEATH_BOUND_S + 10, 'the graph\'s resources released')
    wait_for(lambda: not pid_alive(worker), STOP_TIMEOUT_S + 10, 'the worker to be gone')
