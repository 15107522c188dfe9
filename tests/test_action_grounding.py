"""Grounding instructions to UMRF graphs (pure: no ROS, no model)."""
import pytest

from temoto_action_engine.grounding import Grounder, inflections
from temoto_action_engine.umrf import parse_graph


def shape(graph):
    """[(name, instance_id, inputs, [parent keys])] of a grounded graph."""
    return [(a['name'], a['instance_id'], {k: v['pvf_value'] for k, v in a['input_parameters'].items()},
             ['%s_%d' % (p['name'], p['instance_id']) for p in a['parents']]) for a in graph['actions']]


def ok(grounder, index, text):
    r = grounder.ground(text)
    assert r.ok, r.message
    parse_graph(r.graph, index)         # every grounded graph is a valid UMRF graph
    return r


def test_single_clause(grounder, index):
    r = ok(grounder, index, 'show the environment')
    assert shape(r.graph) == [('show_environment', 0, {}, [])]
    assert r.graph['graph_description'] == 'show the environment'


def test_it_makes_a_child_that_receives_the_parent_outputs(grounder, index):
    r = ok(grounder, index, 'track the hand and show it on the screen')
    assert shape(r.graph) == [('track_object', 0, {'object': 'hand'}, []),
                              ('show', 1, {}, ['track_object_0'])]
    assert r.graph['actions'][0]['children'] == [{'name': 'show', 'instance_id': 1}]
    assert r.clauses[1].from_parent == ['topic']
    spec = parse_graph(r.graph, index)
    assert spec.nodes['show_1'].parents == {'track_object_0': True}
    assert 'track_object(object=hand); track_object -> show(topic from track_object)' in r.message


def test_there_also_makes_a_child(grounder, index):
    r = ok(grounder, index, 'find the ball, display there')
    assert shape(r.graph) == [('track_object', 0, {'object': 'ball'}, []), ('show', 1, {}, ['track_object_0'])]


def test_independent_clauses_become_parallel_branches(grounder, index):
    r = ok(grounder, index, 'track the hand and show the environment')
    assert shape(r.graph) == [('track_object', 0, {'object': 'hand'}, []), ('show_environment', 1, {}, [])]
    assert all(a['children'] == [] for a in r.graph['actions'])


def test_same_action_twice_in_parallel_with_different_subjects(grounder, index):
    r = ok(grounder, index, 'track the hand and then track the ball')
    assert shape(r.graph) == [('track_object', 0, {'object': 'hand'}, []),
                              ('track_object', 1, {'object': 'ball'}, [])]


def test_it_attaches_to_the_previous_clause_only(grounder, index):
    r = ok(grounder, index, 'show the environment and track the cup and show it in rviz')
    assert shape(r.graph) == [('show_environment', 0, {}, []), ('track_object', 1, {'object': 'cup'}, []),
                              ('show', 2, {}, ['track_object_1'])]


def test_subject_words_choose_between_actions_sharing_a_verb(grounder, index):
    assert shape(ok(grounder, index, 'display the surroundings').graph)[0][0] == 'show_environment'
    assert shape(ok(grounder, index, 'show /camera/Depth/points').graph) == \
        [('show', 0, {'topic': '/camera/Depth/points'}, [])]        # topic keeps its case


def test_wildcard_parameter_takes_unknown_objects(grounder, index):
    assert shape(ok(grounder, index, 'follow the red ball').graph) == [('track_object', 0, {'object': 'ball'}, [])]
    assert shape(ok(grounder, index, 'track the giraffe').graph) == [('track_object', 0, {'object': 'giraffe'}, [])]


def test_inflected_verbs_and_stop_with_the_rest_of_the_clause(grounder, index):
    assert {'stop', 'stops', 'stopping', 'stopped'} <= inflections('stop')
    assert {'tracking', 'tracked'} <= inflections('track')
    assert 'displaying' in inflections('display') and 'visualizing' in inflections('visualize')
    r = ok(grounder, index, 'please stop showing the environment')
    assert shape(r.graph) == [('stop', 0, {'action': 'showing environment'}, [])]


def test_ungroundable_input_names_the_words_and_the_actions(grounder):
    r = grounder.ground('fly to the moon')
    assert not r.ok and r.graph is None and r.addressed
    assert r.unmatched == ['fly', 'moon']
    for w in ("'fly'", "'moon'", 'show_environment', 'track_object', 'show (', 'stop ('):
        assert w in r.message, r.message


def test_one_bad_clause_rejects_the_whole_instruction(grounder):
    r = grounder.ground('show the environment and juggle the plates')
    assert not r.ok and r.graph is None
    assert "'juggle'" in r.message and "'plates'" in r.message


def test_verb_without_the_needed_words_says_what_is_missing(grounder):
    r = grounder.ground('show')
    assert not r.ok
    assert 'show needs topic' in r.message
    assert 'show_environment needs one of the words environment' in r.message


def test_it_with_nothing_before_is_rejected(grounder):
    r = grounder.ground('show it on the screen')
    assert not r.ok and 'refers to nothing' in r.message


@pytest.mark.parametrize('text', ['', '   ', 'and and', ', ;'])
def test_empty_instructions(grounder, text):
    r = grounder.ground(text)
    assert not r.ok and 'empty' in r.message


def test_wake_word(index):
    g = Grounder(index.descriptors(), wake_words=['temoto', 'everybody'])
    r = g.ground('show the environment')
    assert not r.ok and not r.addressed
    r = g.ground('Temoto, show the environment')
    assert r.ok and shape(r.graph) == [('show_environment', 0, {}, [])]
    assert g.ground('everybody track the hand').ok


def test_graph_name_comes_from_the_actions(grounder, index):
    assert ok(grounder, index, 'track the hand and show it').graph['graph_name'] == 'track_object_show'


def test_a_robots_name_picks_whose_environment_is_shown(grounder, index):
    r = ok(grounder, index, 'show the environment of vaultbot_2 and show the surroundings of vaultbot_1')
    assert shape(r.graph) == [('show_environment', 0, {'robot': 'vaultbot_2'}, []),
                              ('show_environment', 1, {'robot': 'vaultbot_1'}, [])]
