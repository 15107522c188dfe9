"""The engine node across processes: chatter is grounded and runs; services and the CLI work."""
import json
import os
import threading

import pytest
import rospy

from temoto_action_engine import cli
from temoto_testing.action_engine import write_plugin
from temoto_core.master import connected
from temoto_core.wait import wait_for

NS = 'aetest'
HOLD = '''
from temoto_action_engine.action_base import ActionBase

class Hold(ActionBase):
    def on_start(self):
        self.set_output('value', 'held')
'''
EMIT = '''
from temoto_action_engine.action_base import ActionBase

class Emit(ActionBase):
    def execute(self):
        self.set_output('value', (self.input('value') or '') + '+' + self.input('tag'))
'''
STR = {'pvf_type': 'string'}


class Listener:
    """Collects the engine's feedback and events."""

    def __init__(self, rospy):
        from std_msgs.msg import String
        self.lock = threading.Lock()
        self.feedback, self.events = [], []
        self.subs = [rospy.Subscriber('/%s/action_engine/feedback' % NS, String, self._fb),
                     rospy.Subscriber('/%s/action_engine/events' % NS, String, self._ev)]
        self.chatter = rospy.Publisher('/%s/human_chatter' % NS, String, queue_size=10)
        self.String = String

    def _fb(self, msg):
        with self.lock:
            self.feedback.append(msg.data)

    def _ev(self, msg):
        with self.lock:
            self.events.append(json.loads(msg.data))

    def connected(self):
        """The engine's feedback and events publishers have this process connected, and the engine's chatter
        subscriber is connected here. A subscriber counts a connection as soon as it *starts* connecting
        (rospy), so its own count let the test speak while the engine's publisher had no connection yet,
        and the engine's answer was dropped (outside check: 1 failed run in 3)."""
        me = rospy.get_name()
        return self.chatter.get_num_connections() > 0 and all(
            connected(os.environ['ROS_MASTER_URI'], '/ae_node_engine', me, '/%s/action_engine/%s' % (NS, topic))
            for topic in ('feedback', 'events'))

    def say(self, text):
        self.chatter.publish(self.String(data=text))

    def feedback_with(self, *words):
        with self.lock:
            return [f for f in self.feedback if all(w in f for w in words)]

    def node_state(self, graph, key):
        with self.lock:
            states = [e['state'] for e in self.events if e.get('event') == 'state' and e['graph'] == graph
                      and '%s_%s' % (e['action'], e['instance_id']) == key]
        return states[-1] if states else None

    def close(self):
        for s in self.subs:
            s.unregister()
        self.chatter.unregister()


@pytest.fixture
def engine(procs, rospy_client, tmp_path):
    plugins = tmp_path / 'plugins'
    write_plugin(str(plugins), 'hold', HOLD, effect='asynchronous', outputs={'value': STR},
                 grounding={'verbs': ['hold'], 'subjects': ['breath']})
    write_plugin(str(plugins), 'emit', EMIT, inputs={'tag': STR, 'value': {'pvf_type': 'string', 'pvf_required': False}},
                 outputs={'value': STR}, grounding={'verbs': ['emit'], 'parameters': {'tag': {'any': True}}})
    write_plugin(str(plugins), 'broken', 'import does_not_exist\n')
    listener = Listener(rospy_client)
    if rospy_client.has_param('/ae_node_engine'):
        rospy_client.delete_param('/ae_node_engine')   # private params outlive a node on the shared master
    procs.node('temoto_action_engine', 'temoto_action_engine', name='ae_node_engine',
               params={'temoto_namespace': NS, 'action_paths': str(plugins), 'wake_words': 'robot'})
    rospy_client.wait_for_service('/%s/action_engine/start_graph' % NS, timeout=20)
    wait_for(listener.connected, 20, 'engine topics connected')
    yield listener
    listener.close()


def services(rospy):
    from temoto_action_engine.srv import ListActions, ListGraphs, StartGraph, StopGraph
    base = '/%s/action_engine/' % NS
    return (rospy.ServiceProxy(base + 'start_graph', StartGraph), rospy.ServiceProxy(base + 'stop_graph', StopGraph),
            rospy.ServiceProxy(base + 'list_graphs', ListGraphs), rospy.ServiceProxy(base + 'list_actions', ListActions))


def graph_names(list_graphs):
    return {g['graph_name']: g for g in json.loads(list_graphs().json)}


def test_chatter_with_wake_word_runs_a_graph_and_stop_graph_ends_it(engine, rospy_client):
    start, stop, list_graphs, _ = services(rospy_client)
    engine.say('hold your breath and emit it')              # no wake word: ignored
    engine.say('robot, hold your breath and then emit bang with it')
    wait_for(lambda: engine.node_state('hold_emit', 'emit_1') == 'FINISHED', 20, 'emit finished after hold')
    graphs = graph_names(list_graphs)
    assert list(graphs) == ['hold_emit'], graphs           # the first sentence started nothing
    nodes = {'%s_%d' % (n['name'], n['instance_id']): n for n in graphs['hold_emit']['nodes']}
    assert nodes['hold_0']['state'] == 'RUNNING'
    assert nodes['emit_1']['outputs'] == {'value': 'held+bang'}  # data passed across the edge
    wait_for(lambda: engine.feedback_with('grounded', 'hold()', 'hold -> emit(tag=bang, value from hold)',
                                          'hold_emit'), 10, 'the grounding on the feedback topic')
    resp = stop(graph_name='hold_emit')
    assert resp.code == 0, resp.message
    assert graph_names(list_graphs)['hold_emit']['state'] == 'FINISHED'
    # the events topic delivers the node's last state after the service answered: wait for it
    wait_for(lambda: engine.node_state('hold_emit', 'hold_0') == 'FINISHED', 10,
             'hold_0 FINISHED on the events topic')
    resp = stop(graph_name='hold_emit')
    assert resp.code == 1 and 'no running graph' in resp.message


def test_ungroundable_chatter_gets_a_clear_answer(engine):
    engine.say('robot fly to the moon')
    fb = wait_for(lambda: engine.feedback_with('could not ground'), 20, 'feedback about the failed grounding')
    for w in ("'fly'", "'moon'", 'hold (hold)', 'emit (emit)', 'show_environment'):
        assert w in fb[0], fb[0]


def test_start_graph_service_validates_and_runs_json(engine, rospy_client):
    start, stop, list_graphs, _ = services(rospy_client)
    bad = start(graph_json='{"actions": [{"name": "emit", "input_parameters": {"tag": {"pvf_value": 5}}}]}', text='')
    assert bad.code == 1 and 'expects string' in bad.message
    assert start(graph_json='', text='').code == 1
    assert start(graph_json='{}', text='emit x').code == 1
    assert graph_names(list_graphs) == {}
    ok = start(graph_json=json.dumps({'graph_name': 'direct', 'actions': [
        {'name': 'emit', 'input_parameters': {'tag': {'pvf_type': 'string', 'pvf_value': 'json'}}}]}), text='')
    assert ok.code == 0 and ok.graph_name == 'direct', ok.message
    wait_for(lambda: graph_names(list_graphs)['direct']['state'] == 'FINISHED', 20, 'sync graph finished by itself')
    text = start(graph_json='', text='emit words')           # the service needs no wake word
    assert text.code == 0 and text.graph_name == 'emit', text.message
    assert json.loads(text.graph_json)['actions'][0]['input_parameters']['tag']['pvf_value'] == 'words'


def test_cli_lists_actions_with_broken_plugins_and_graphs(engine, rospy_client, capsys):
    assert cli.actions(['--ns', NS]) == 1                    # 1: a plugin is broken
    out = capsys.readouterr().out
    assert 'hold ' in out and 'show_environment' in out and 'BROKEN' in out and 'does_not_exist' in out
    assert cli.main(['actions', '--ns', NS, '--reindex', '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    assert {a['name'] for a in data['actions']} == {'hold', 'emit', 'show', 'show_environment', 'stop',
                                                    'track_object', 'navigate', 'gripper', 'follow_hand', 'dial'}
    assert [e['kind'] for e in data['errors']] == ['import_error']
    assert cli.say(['--ns', NS, 'hold', 'your', 'breath']) == 0
    assert 'graph: hold' in capsys.readouterr().out
    assert cli.graphs(['--ns', NS]) == 0
    assert 'hold_0  RUNNING' in capsys.readouterr().out
    assert cli.say(['--ns', NS, 'juggle']) == 1
    assert "'juggle'" in capsys.readouterr().out
    assert cli.graphs(['--ns', NS, 'stop', 'hold']) == 0
    assert 'graph hold stopped' in capsys.readouterr().out


def test_launch_file_loads_the_config(procs, rospy_client):
    from temoto_action_engine.srv import ListActions
    procs.launch('temoto_action_engine', 'action_engine.launch', args=['temoto_namespace:=aelaunch'])
    rospy_client.wait_for_service('/aelaunch/action_engine/list_actions', timeout=20)
    data = json.loads(rospy_client.ServiceProxy('/aelaunch/action_engine/list_actions', ListActions)(reindex=False).json)
    assert sorted(a['name'] for a in data['actions']) == ['dial', 'follow_hand', 'gripper', 'navigate', 'show',
                                                          'show_environment', 'stop', 'track_object']
    assert data['errors'] == []
    priority = rospy_client.get_param('/temoto_action_engine/actions/show_environment/sensor_priority')
    assert [p['sensor_type'] for p in priority] == ['depth camera', 'lidar', 'lidar']
    assert [p['display_key'] for p in priority] == ['camera_data', 'cloud_data', 'lidar_data']


def test_cli_says_in_one_line_when_the_engine_fails_a_call(rospy_client, capsys):
    """An engine that dies or errs during a call gives one line and exit status, never a traceback."""
    from temoto_action_engine.srv import StartGraph

    def broken(req):
        raise RuntimeError('the engine fell over')
    service = rospy_client.Service('/aecli/action_engine/start_graph', StartGraph, broken)
    try:
        with pytest.raises(SystemExit) as stop:
            cli.say(['--ns', 'aecli', 'hold', 'your', 'breath'])
    finally:
        service.shutdown()
    message = str(stop.value.code)
    assert message.startswith('error: /aecli/action_engine/start_graph failed:') and '\n' not in message, message
    assert 'Traceback' not in capsys.readouterr().err
