"""Graph execution in-process: order, parallel siblings, data passing, stopping, failures.

Registrars are fakes here (the lifetime is what matters); test_action_resources.py does the
same against real registrars across processes.
"""
import threading

import pytest

from temoto_action_engine.engine import ActionEngine
from temoto_action_engine.indexer import ActionIndex
from temoto_testing.action_engine import FakeRegistrarFactory, write_plugin
from temoto_action_engine.umrf import UmrfError
from temoto_core.wait import wait_for

EMIT = '''
from temoto_action_engine.action_base import ActionBase

class Emit(ActionBase):
    def execute(self):
        value = (self.input('value') or '') + self.input('tag')
        self.config['log'].append(('emit', self.input('tag'), self.input('value')))
        self.set_output('value', value)
'''
MEET = '''
from temoto_action_engine.action_base import ActionBase

class Meet(ActionBase):
    def execute(self):
        self.config['barrier'].wait()          # raises BrokenBarrierError unless siblings overlap
        self.config['log'].append(('meet', self.input('tag')))
'''
HOLD = '''
from temoto_action_engine.action_base import ActionBase

class Hold(ActionBase):
    def on_start(self):
        self.rr.held.append('resource of ' + self.rr_name)
        self.set_output('value', 'held')
        self.config['log'].append(('hold', 'started'))

    def on_stop(self):
        self.config['log'].append(('hold', 'stopped', len(self.rr.held)))
'''
FAIL = '''
from temoto_action_engine.action_base import ActionBase, ActionError

class Fail(ActionBase):
    def execute(self):
        self.rr.held.append('x')
        raise ActionError('boom: the device is gone')
'''
SLOW = '''
from temoto_action_engine.action_base import ActionBase

class Slow(ActionBase):
    def on_start(self):
        self.config['log'].append(('slow', 'entered'))
        self.wait(60.0)                      # woken by the stop request
        self.set_output('value', 'late')
'''
STR = {'pvf_type': 'string'}
OPT = {'pvf_type': 'string', 'pvf_required': False}


@pytest.fixture
def plugins(tmp_path):
    write_plugin(str(tmp_path), 'emit', EMIT, inputs={'tag': STR, 'value': OPT}, outputs={'value': STR},
                 grounding={'verbs': ['emit'], 'parameters': {'tag': {'any': True}}})
    write_plugin(str(tmp_path), 'meet', MEET, inputs={'tag': STR})
    write_plugin(str(tmp_path), 'hold', HOLD, effect='asynchronous', outputs={'value': STR},
                 grounding={'verbs': ['hold']})
    write_plugin(str(tmp_path), 'fail', FAIL, outputs={'value': STR})
    write_plugin(str(tmp_path), 'slow', SLOW, effect='asynchronous', outputs={'value': STR})
    return str(tmp_path)


@pytest.fixture
def env(plugins):
    log = []
    rrs = FakeRegistrarFactory()
    feedback = []
    events = []
    cfg = {name: {'log': log, 'barrier': threading.Barrier(2, timeout=10)} for name in ('emit', 'meet', 'hold', 'fail', 'slow')}
    idx = ActionIndex([plugins]).reindex()
    assert idx.problems == []
    engine = ActionEngine(idx, action_config=cfg, rr_factory=rrs, publish_feedback=feedback.append,
                          publish_event=events.append)
    yield engine, log, rrs, feedback, events
    engine.shutdown(10)


def node(name, iid, inputs=None, parents=(), children=()):
    return {'name': name, 'instance_id': iid,
            'input_parameters': {k: {'pvf_type': 'string', 'pvf_value': v} for k, v in (inputs or {}).items()},
            'parents': [{'name': p[0], 'instance_id': p[1], **({'required': p[2]} if len(p) > 2 else {})}
                        for p in parents],
            'children': [{'name': c[0], 'instance_id': c[1]} for c in children]}


def states(run):
    return {k: n.state for k, n in run.nodes.items()}


def test_chain_runs_in_order_and_passes_data(env):
    engine, log, rrs, _, _ = env
    run = engine.start_graph({'graph_name': 'chain', 'actions': [
        node('emit', 0, {'tag': 'a'}, children=[('emit', 1)]),
        node('emit', 1, {'tag': 'b'}, children=[('emit', 2)]),
        node('emit', 2, {'tag': 'c'})]})
    assert run.wait(10) == []
    assert log == [('emit', 'a', None), ('emit', 'b', 'a'), ('emit', 'c', 'ab')]
    assert run.nodes['emit_2'].action.outputs == {'value': 'abc'}
    assert set(states(run).values()) == {'FINISHED'} and run.state == 'FINISHED'
    assert rrs.made == []          # nobody touched self.rr, so no registrar was created


def test_explicit_inputs_win_over_parent_outputs(env):
    engine, log, _, _, _ = env
    run = engine.start_graph({'actions': [node('emit', 0, {'tag': 'a'}),
                                          node('emit', 1, {'tag': 'b', 'value': 'mine'}, parents=[('emit', 0)])]})
    assert run.wait(10) == []
    assert log[1] == ('emit', 'b', 'mine')


def test_siblings_run_in_parallel_after_their_parent(env):
    engine, log, _, _, _ = env
    run = engine.start_graph({'actions': [
        node('emit', 0, {'tag': 'root'}, children=[('meet', 1), ('meet', 2)]),
        node('meet', 1, {'tag': 'left'}), node('meet', 2, {'tag': 'right'})]})
    assert run.wait(20) == []
    assert states(run) == {'emit_0': 'FINISHED', 'meet_1': 'FINISHED', 'meet_2': 'FINISHED'}, \
        [n.message for n in run.nodes.values()]
    assert log[0] == ('emit', 'root', None)
    assert sorted(log[1:]) == [('meet', 'left'), ('meet', 'right')]


def test_async_parent_releases_children_after_on_start_and_stop_releases_its_registrar(env):
    engine, log, rrs, _, events = env
    run = engine.start_graph({'graph_name': 'keep', 'actions': [
        node('hold', 0, children=[('emit', 1)]), node('emit', 1, {'tag': '!'})]})
    wait_for(lambda: run.nodes['emit_1'].state == 'FINISHED', 10, 'child of the async action to finish')
    assert log[:2] == [('hold', 'started'), ('emit', '!', 'held')]
    assert run.nodes['hold_0'].state == 'RUNNING' and run.state == 'RUNNING'
    assert [g['graph_name'] for g in engine.list_graphs()] == ['keep']
    (rr,) = rrs.made
    assert rr.name.startswith('action_hold_') and rr.held and not rr.shut_down
    ok, msg = engine.stop_graph('keep')
    assert ok, msg
    assert log[-1] == ('hold', 'stopped', 1)          # on_stop ran before the release
    assert rr.shut_down and rr.held == []
    assert run.nodes['hold_0'].state == 'FINISHED' and run.nodes['hold_0'].message == 'stopped'
    wait_for(lambda: engine.list_graphs()[0]['state'] == 'FINISHED', 5, 'graph moved to history')
    assert ('STOP_REQUESTED' in [e.get('state') for e in events])


def test_each_instance_owns_a_distinct_registrar(env):
    engine, _, rrs, _, _ = env
    a = engine.start_graph({'graph_name': 'a', 'actions': [node('hold', 0), node('hold', 1)]})
    wait_for(lambda: len(rrs.made) == 2, 10, 'two registrars')
    assert len({r.name for r in rrs.made}) == 2
    a.stop(10)
    assert all(r.shut_down for r in rrs.made)


def test_failure_cancels_required_children_only(env):
    engine, log, rrs, feedback, _ = env
    run = engine.start_graph({'actions': [
        node('fail', 0, children=[('emit', 1)]),
        node('emit', 1, {'tag': 'needs'}, children=[('emit', 3)]),
        node('emit', 2, {'tag': 'optional'}, parents=[('fail', 0, False)]),
        node('emit', 3, {'tag': 'grandchild'})]})
    assert run.wait(10) == []
    assert states(run) == {'fail_0': 'FAILED', 'emit_1': 'CANCELLED', 'emit_2': 'FINISHED', 'emit_3': 'CANCELLED'}
    assert run.nodes['fail_0'].message == 'boom: the device is gone'
    assert 'fail_0' in run.nodes['emit_1'].message
    assert run.state == 'FAILED'
    assert rrs.made[0].shut_down             # a failed action's resources are released too
    assert any('fail failed: boom' in f for f in feedback)
    assert [t for _, t, _ in log] == ['optional']


def test_missing_input_cancels_with_the_parameter_name(env):
    engine, _, _, feedback, _ = env
    run = engine.start_graph({'actions': [node('fail', 0, children=[('emit', 1)]),
                                          node('emit', 1, parents=[('fail', 0, False)])]})
    assert run.wait(10) == []
    assert run.nodes['emit_1'].state == 'CANCELLED' and 'tag' in run.nodes['emit_1'].message


@pytest.mark.parametrize('graph, words', [
    ({'actions': [{'name': 'nope'}]}, ['unknown action', 'nope']),
    ({'actions': [node('emit', 0, {'tag': 'a', 'colour': 'red'})]}, ['no input parameter', 'colour']),
    ({'actions': [{'name': 'emit', 'input_parameters': {'tag': {'pvf_value': 3}}}]}, ['expects string']),
    ({'actions': [node('emit', 0, {'tag': 'a'}, parents=[('emit', 1)]),
                  node('emit', 1, {'tag': 'b'}, parents=[('emit', 0)])]}, ['cycle']),
    ({'actions': [node('emit', 0, {'tag': 'a'}, parents=[('meet', 7)])]}, ['meet_7', 'not a node']),
    ({'actions': [node('emit', 0, {'tag': 'a'}), node('emit', 0, {'tag': 'b'})]}, ['duplicate']),
    ({'actions': []}, ['non-empty']),
    ('{"actions": [', ['not valid JSON']),
])
def test_bad_graphs_are_rejected_and_change_nothing(env, graph, words):
    engine, log, rrs, _, _ = env
    with pytest.raises(UmrfError) as e:
        engine.start_graph(graph)
    for w in words:
        assert w in str(e.value), str(e.value)
    assert engine.list_graphs() == [] and log == [] and rrs.made == []


def test_graph_names_are_made_unique_while_running(env):
    engine, _, _, _, _ = env
    a = engine.start_graph({'graph_name': 'g', 'actions': [node('hold', 0)]})
    b = engine.start_graph({'graph_name': 'g', 'actions': [node('hold', 0)]})
    assert (a.name, b.name) == ('g', 'g_2')
    assert engine.stop_graph('nope')[0] is False and 'g, g_2' in engine.stop_graph('nope')[1]


def test_say_grounds_and_runs_and_stop_action_stops_by_words(env, plugins):
    engine, log, rrs, feedback, _ = env
    result, run = engine.say('hold and emit bang with it')
    assert result.ok and run is not None, result.message
    wait_for(lambda: run.nodes['emit_1'].state == 'FINISHED', 10, 'emit after hold')
    assert log[1] == ('emit', 'bang', 'held')
    assert engine.running_actions() == ['%s/hold_0' % run.name]
    assert engine.stop_actions('holding') == ['%s/hold_0' % run.name]
    assert run.nodes['hold_0'].state == 'FINISHED' and rrs.made[0].shut_down
    result, run2 = engine.say('dance with me')
    assert run2 is None and "'dance'" in feedback[-1]


def test_stop_action_from_the_bundled_plugins(tmp_path, plugins):
    log = []
    idx = ActionIndex([plugins]).reindex()                 # bundled + test plugins
    rrs = FakeRegistrarFactory()
    engine = ActionEngine(idx, action_config={'hold': {'log': log}}, rr_factory=rrs)
    try:
        holder = engine.start_graph({'graph_name': 'holder', 'actions': [node('hold', 0)]})
        wait_for(lambda: log, 10, 'hold started')
        _, stopper = engine.say('stop hold')
        assert stopper.wait(15) == []
        assert stopper.nodes['stop_0'].state == 'FINISHED'
        assert stopper.nodes['stop_0'].action.outputs == {'stopped': ['holder/hold_0']}
        assert holder.nodes['hold_0'].state == 'FINISHED' and rrs.made[0].shut_down
        _, again = engine.say('stop hold')
        assert again.wait(15) == [] and again.nodes['stop_0'].state == 'FAILED'
        assert 'nothing running matches' in again.nodes['stop_0'].message
    finally:
        engine.shutdown(10)


def test_stop_during_on_start_ends_the_node_and_cancels_its_children(env):
    engine, log, _, _, _ = env
    run = engine.start_graph({'graph_name': 'slow', 'actions': [node('slow', 0, children=[('emit', 1)]),
                                                                node('emit', 1, {'tag': 'never'})]})
    wait_for(lambda: log == [('slow', 'entered')], 10, 'on_start entered')
    ok, msg = engine.stop_graph('slow', timeout=10)
    assert ok, msg
    assert states(run) == {'slow_0': 'FINISHED', 'emit_1': 'CANCELLED'}
    assert log == [('slow', 'entered')]
