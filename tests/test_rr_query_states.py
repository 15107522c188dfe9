"""The registrar's query state machine: only its own edges, and a wrong move is a loud bug."""
import pytest

from temoto_core.rr.query import (ACTIVE, FAILED, GONE, LOADING, TRANSITIONS, UNLOADING, ClientQuery,
                                  IllegalTransition, QueryState)


def test_every_state_has_its_edges_and_gone_is_final():
    assert set(TRANSITIONS) == set(QueryState)
    assert TRANSITIONS[GONE] == frozenset()
    assert all(LOADING not in targets for targets in TRANSITIONS.values())    # nothing goes back to loading


def test_a_query_follows_its_edges():
    query = ClientQuery(('temoto', 'rr', 'srv'), ('k',), None)
    for to in (ACTIVE, FAILED, UNLOADING, GONE):
        query.move(to)
        assert query.state is to


@pytest.mark.parametrize('path', [(ACTIVE, LOADING), (UNLOADING,), (ACTIVE, GONE, ACTIVE), (FAILED, ACTIVE)])
def test_a_move_off_the_edges_raises_and_leaves_the_state(path):
    query = ClientQuery(('temoto', 'rr', 'srv'), ('k',), None)
    *allowed, wrong = path
    for to in allowed:
        query.move(to)
    before = query.state
    with pytest.raises(IllegalTransition, match='%s -> %s' % (before, wrong)):
        query.move(wrong)
    assert query.state is before


def test_states_serialise_as_their_plain_names():
    assert [str(s) for s in QueryState] == ['loading', 'active', 'failed', 'unloading', 'gone']
