"""Each action instance owns a real Resource Registrar: what it loads is released when it ends.

Processes: a test RR server (LoadTestResource), the engine node, and this test (chatter, services).
"""
import json
import sys
import threading

import pytest

from temoto_action_engine.testing import write_plugin
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


@pytest.fixture
def world(procs, rospy_client, tmp_path):
    from std_msgs.msg import String
    plugins = tmp_path / 'plugins'
    write_plugin(str(plugins), 'grab', GRAB, effect='asynchronous',
                 inputs={'name': {'pvf_type': 'string'}}, outputs={'payload': {'pvf_type': 'string'}},
                 grounding={'verbs': ['grab', 'hold'], 'parameters': {'name': {'any': True}}})
    server = tmp_path / 'rr_test_server.py'
    server.write_text(SERVER)
    srv_proc = procs.command([sys.executable, str(server), NS], 'rr_test_server')
    procs.wait_registered(srv_proc, ['/rr_test_server'], 20)
    if rospy_client.has_param('/' + ENGINE):
        rospy_client.delete_param('/' + ENGINE)      # private params outlive a node on the shared master
    engine = procs.node('temoto_action_engine', 'temoto_action_engine', name=ENGINE,
                        params={'temoto_namespace': NS, 'action_paths': str(plugins)})
    rospy_client.wait_for_service('/%s/test_server/load_test' % NS, timeout=20)
    rospy_client.wait_for_service('/%s/action_engine/start_graph' % NS, timeout=20)
    events, lock = [], threading.Lock()

    def on_event(msg):
        with lock:
            events.append(json.loads(msg.data))

    sub = rospy_client.Subscriber('/%s/action_engine/events' % NS, String, on_event)
    chatter = rospy_client.Publisher('/%s/human_chatter' % NS, String, queue_size=10)
    fail = rospy_client.Publisher('/%s/test_server/fail' % NS, String, queue_size=10)
    wait_for(lambda: sub.get_num_connections() and chatter.get_num_connections() and fail.get_num_connections(),
             20, 'topics connected')

    class World:
        def say(self, text):
            chatter.publish(String(data=text))

        def unplug(self, name):
            fail.publish(String(data=name))

        def events(self, kind):
            with lock:
                return [e for e in events if e.get('event') == kind]

        engine_proc = engine

    yield World()
    for x in (sub, chatter, fail):
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
    assert consumers == ['/' + ENGINE, '/' + ENGINE]
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
