"""What words may move the robot, without ROS: the grounder's new rules, the engine's halt and its motion
wake phrase, and the speech grammar's. A sentence said to someone else must never start a motion; "stop"
must always halt."""
import pytest

from temoto_action_engine.engine import ActionEngine
from temoto_action_engine.grounding import Grounder
from temoto_action_engine.indexer import ActionIndex
from temoto_action_engine.umrf import UmrfError, parse_descriptor, parse_graph
from temoto_core.wait import wait_for
from temoto_speech import grammar
from temoto_speech.confirmation import ANSWERS, Decision, MotionConfirmation
from temoto_testing.action_engine import FakeRegistrarFactory, write_plugin

HOLD = '''
from temoto_action_engine.action_base import ActionBase

class Hold(ActionBase):
    pass
'''
STR = {'pvf_type': 'string'}
OPT = {'pvf_type': 'string', 'pvf_required': False}


def grounded(grounder, index, text):
    r = grounder.ground(text)
    assert r.ok, r.message
    parse_graph(r.graph, index)
    return [(c.action, c.inputs) for c in r.clauses]


@pytest.mark.parametrize('text, expected', [
    ('go', [('navigate', {})]),                                 # bare: the pointed goal
    ('go there', [('navigate', {'place': 'there'})]),           # "there" with nothing before it: the pointed goal
    ('go home', [('navigate', {'place': 'home'})]),
    ('drive to the shelf', [('navigate', {'place': 'shelf'})]),
    ('open the gripper', [('gripper', {'command': 'open'})]),   # the verb fills the command
    ('close the gripper', [('gripper', {'command': 'close'})]),
    ('follow my hand', [('follow_hand', {})]),                 # the operator's own hand
    ('follow the hand', [('track_object', {'object': 'hand'})]),   # a tie: the action that does not move
    ('move the arm with my hand', [('follow_hand', {})]),
    ('follow my hand with the right arm', [('follow_hand', {'arm': 'right'})]),
    ('follow my hand at 0.1', [('follow_hand', {'scale': '0.1'})]),
    ('drive with my hand', [('follow_hand', {'mode': 'drive'})]),        # navigation mode: the verb says it
    ('follow my hand with the base', [('follow_hand', {'mode': 'base'})]),
    ('move the base with my hand', [('follow_hand', {'mode': 'base'})]),
    ('drive home', [('navigate', {'place': 'home'})]),
    ('stop', [('stop', {})]),
    ('stop stop', [('stop', {'action': 'stop'})]),
])
def test_motion_instructions_ground(grounder, index, text, expected):
    assert grounded(grounder, index, text) == expected


@pytest.mark.parametrize('text, words', [
    ('close the door', 'gripper needs one of the words'),      # the verb alone points at no gripper
    ('open', 'gripper needs one of the words'),
    ('show it', 'refers to nothing said before'),              # "it" still needs a clause before it
])
def test_words_that_name_no_motion_start_none(grounder, text, words):
    r = grounder.ground(text)
    assert not r.ok and words in r.message, r.message


def test_a_tie_goes_to_the_action_that_does_not_move(tmp_path):
    for name, motion in (('watch', False), ('wave', True)):
        write_plugin(str(tmp_path), name, HOLD, effect='asynchronous', grounding={'verbs': ['greet'],
                                                                                  'subjects': ['hand']},
                     motion=motion)
    idx = ActionIndex([str(tmp_path)], include_bundled=False).reindex()
    assert idx.problems == []
    r = Grounder(idx.descriptors()).ground('greet the hand')
    assert r.ok, r.message
    assert r.clauses[0].action == 'watch'


@pytest.mark.parametrize('field, value, words', [
    ('motion', 'yes', '"motion" must be true or false'),
    ('grounding', {'verbs': ['go'], 'bare': 1}, 'grounding.bare must be true or false'),
])
def test_bad_motion_fields_are_refused_naming_them(field, value, words):
    data = {'name': 'x', 'description': 'd', 'effect': 'synchronous', 'grounding': {'verbs': ['go']}, field: value}
    with pytest.raises(UmrfError, match=words):
        parse_descriptor(data)


@pytest.mark.parametrize('text, halts', [
    ('stop', True), ('stop stop', True), ('stop the robot', True), ('stop everything', True),
    ('halt', True), ('stop moving', True), ('stop right now', True),
    ('stop showing the environment', False), ('stop tracking the ball', False),
    ('go home', False), ('show the environment', False),
])
def test_which_instructions_halt_the_robot(grounder, text, halts):
    r = grounder.ground(text)
    assert r.ok, r.message
    assert ActionEngine.is_halt(r.clauses) is halts


@pytest.fixture
def engine(tmp_path):
    write_plugin(str(tmp_path), 'roll', HOLD, effect='asynchronous', grounding={'verbs': ['roll'], 'bare': True},
                 motion=True)
    write_plugin(str(tmp_path), 'look', HOLD, effect='asynchronous', grounding={'verbs': ['look']})
    idx = ActionIndex([str(tmp_path)]).reindex()          # bundled (stop) + these
    halts, feedback = [], []
    engine = ActionEngine(idx, rr_factory=FakeRegistrarFactory(), publish_halt=halts.append,
                          publish_feedback=feedback.append)
    yield engine, halts, feedback
    engine.shutdown(10)


def test_a_motion_heard_without_the_wake_phrase_is_not_started(engine):
    engine, halts, feedback = engine
    result, run = engine.say('roll', require_motion_wake=True)
    assert run is None and not result.ok
    assert 'not started: roll moves the robot, so say "robot please" first' in feedback[-1]
    assert engine.list_graphs() == []
    _, run = engine.say('look', require_motion_wake=True)        # no motion: no wake phrase needed
    assert run is not None
    _, run = engine.say('Robot, please roll', require_motion_wake=True)
    assert run is not None and list(run.nodes) == ['roll_0']
    assert halts == []


def test_stop_halts_first_then_stops_only_the_motions(engine):
    engine, halts, _ = engine
    _, looking = engine.say('look')
    _, rolling = engine.say('robot please roll')
    wait_for(lambda: len(engine.running_actions()) == 2, 10, 'both running')
    _, stopper = engine.say('stop')
    assert halts and 'stop' in halts[0]                  # before the stop's graph ran
    assert stopper.wait(15) == []
    assert stopper.nodes['stop_0'].action.outputs == {'stopped': ['%s/roll_0' % rolling.name]}
    assert rolling.nodes['roll_0'].state == 'FINISHED'
    assert engine.running_actions() == ['%s/look_0' % looking.name]      # the view goes on
    halted = len(halts)               # the engine's, and the stop action's own (for a graph sent as JSON)
    _, stopper = engine.say('stop looking')               # names an action: it halts nothing
    assert stopper.wait(15) == [] and len(halts) == halted
    assert engine.running_actions() == []


@pytest.mark.parametrize('text, stripped, woke', [
    ('robot please go', 'go', True), ('Robot, please go home', 'go home', True), ('go', 'go', False),
    ('please robot go', 'please robot go', False),
])
def test_the_motion_wake_phrase_is_taken_off_before_grounding(engine, text, stripped, woke):
    assert engine[0].strip_motion_wake(text) == (stripped, woke)


def test_the_grammar_says_a_motion_only_after_the_wake_phrase(index):
    actions = index.to_json()['actions']
    g = grammar.build(actions)
    top = g.jsgf.splitlines()[2]
    assert top.startswith('public <utterance> = ([please] <clause>')
    # one motion an utterance, and only after the wake phrase
    assert 'robot please (<motion> [(and | then) <clause>] | <clause> [(and | then) (<motion> | <clause>)])' in top
    assert '<motion> = <a_follow_hand> | <a_gripper> | <a_navigate>;' in g.jsgf
    assert '<a_follow_hand> = (drive | follow | mirror | move) [me] [(the | a | my)] (hand) [((at | with) ' \
        '[(the | a)] (left | right) [arm] | (at | with) [(the | a)] (base | driving | navigation) [mode] | ' \
        '(at | with) [(the | a)] (fifth | half | hundredth | tenth) [scale])];' in g.jsgf, g.jsgf
    clause = next(line for line in g.jsgf.splitlines() if line.startswith('<clause> ='))
    assert 'navigate' not in clause and 'gripper' not in clause
    said = grammar.phrases(actions)
    assert 'robot please close the gripper' in said and 'stop' in said
    assert 'robot please go to the shelf' in said and 'robot please go home' in said and 'finer' in said
    assert not [p for p in said if ' the home' in p or ' the there' in p or p.startswith('finer the')]
    assert not [p for p in said if p.split()[0] in ('go', 'open', 'close', 'follow') and 'gripper' in p]


def test_a_motion_waits_for_its_yes_within_the_window_and_anything_else_drops_it():
    c = MotionConfirmation(('robot', 'please'), ('stop', 'halt'), window=5.0, wake_words=('temoto',))
    asked = c.heard('robot please go to the shelf', 0.0)
    assert asked == Decision(say='go to the shelf? yes or no')
    assert c.heard('yes', 1.0) == Decision(send='robot please go to the shelf')
    assert c.heard('yes', 1.5) == Decision(say='nothing to confirm: no motion is waiting for an answer')
    c.heard('robot please go home', 2.0)
    assert c.heard('no', 3.0) == Decision(say='cancelled')
    c.heard('temoto robot please go home', 4.0)                    # after the node's own wake word
    assert c.heard('confirm', 9.5) == Decision(say='too late: no motion is waiting for an answer')
    c.heard('robot please go home', 10.0)
    assert c.expire(14.0) is None and c.expire(15.5) == 'robot please go home'
    c.heard('robot please go home', 20.0)
    assert c.heard('show the environment', 21.0) == Decision(send='show the environment',
                                                             say='not confirmed: robot please go home')
    c.heard('robot please go home', 22.0)
    assert c.heard('stop', 22.5) == Decision(send='stop'), 'a stop is never held'
    assert c.pending is None
    with pytest.raises(ValueError, match='window'):
        MotionConfirmation(('robot', 'please'), ('stop',), window=0.0)


def test_with_confirmation_the_grammar_takes_yes_and_no_alone(index):
    g = grammar.build(index.to_json()['actions'], answers=ANSWERS)
    top = g.jsgf.splitlines()[2]
    assert top.endswith('| (cancel | confirm | no | yes);'), top
    assert {'yes', 'no'} <= g.words
