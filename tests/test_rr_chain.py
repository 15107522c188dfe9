"""The Resource Registrar across processes: chains, sharing, failures, cascades."""
import pytest

from temoto_core.errors import ErrorCode
from temoto_testing import wait_for
from rr_helpers import RegistrarNode, registry_empty


@pytest.fixture(scope='module')
def chain_nodes(rospy_client, module_procs):
    """A (the action) -> B (a sensor manager) -> C (the process manager), one process each."""
    return [RegistrarNode(module_procs, n) for n in ('rr_a', 'rr_b', 'rr_c')]


@pytest.fixture
def chain(chain_nodes):
    """The shared chain, reset: every test starts from empty registries and counters."""
    for node in chain_nodes:
        node.command(op='reset')
    yield chain_nodes
    for node in chain_nodes:
        assert registry_empty(node) or node.command(op='release_all') is not None


def test_failure_at_the_bottom_reaches_the_top_under_its_own_id(chain):
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('nested', 'rr_c/load_test/driver')])
    assert 'error' not in res, res
    assert res['payload'].startswith('payload of cam from /rr_b')
    c.fail('driver', 'cable pulled')
    events = a.wait_events(1)
    assert events[0]['id'] == res['id']          # A's own id, not B's or C's
    assert events[0]['code'] == 1
    assert any('cable pulled' in m for m in events[0]['stack'])   # where it started
    assert any('sub-resource' in m for m in events[0]['stack'])   # the hop through B
    # B's owner callback ran for the failed process it held
    wait_for(lambda: b.owner_events(), 10, "B's owner status callback")
    assert b.owner_events()[0]['code'] == 1
    # each registry says why its entry failed (it said '' for a resource that failed after its load)
    for node in (c, b):
        [entry] = [q for q in node.registry()['server_queries']]
        assert entry['state'] == 'failed' and 'cable pulled' in entry['failure'], (node.name, entry)


def test_cascade_unload_and_empty_registries(chain):
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('nested', 'rr_c/load_test/driver')])
    reg_b = b.registry()
    assert len(reg_b['server_queries']) == 1 and len(reg_b['client_queries']) == 1
    assert reg_b['server_queries'][0]['links'] == reg_b['client_queries'][0]['local_ids']
    assert a.unload(res['id']) == {}
    assert c.counts()['unloads'] == {'driver': 1}
    assert b.counts()['unloads'] == {'cam': 1}
    for node in chain:
        assert registry_empty(node), node.registry()


def test_failed_load_rolls_back_sub_resources(chain):
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('nested', 'rr_c/load_test/driver'), ('fail', 'raise')])
    assert res['code'] == ErrorCode.RESOURCE_FAILED
    assert 'refused cam on purpose' in res['error']
    assert c.counts() == {'loads': {'driver': 1}, 'unloads': {'driver': 1}}
    for node in chain:
        assert registry_empty(node)


def test_a_call_made_with_link_false_inside_a_load_is_held_but_not_linked(chain):
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('held', 'rr_c/load_test/driver')])
    assert 'error' not in res, res
    reg_b = b.registry()
    assert reg_b['server_queries'][0]['links'] == []
    assert reg_b['client_queries'][0]['linked_to'] == []
    c.fail('driver', 'cable pulled')
    wait_for(lambda: b.events(), 10, "B's own callback for the driver it holds")
    # B forwards through links before it runs its callbacks: nothing was forwarded, so cam is still active
    assert [q['state'] for q in b.registry()['server_queries']] == ['active']
    assert a.unload(res['id']) == {}
    assert c.counts()['unloads'] == {}                      # not released in cascade
    assert b.command(op='release_all') == {}
    assert c.counts()['unloads'] == {'driver': 1}


def test_a_resource_linked_after_the_call_goes_with_its_parent_and_its_failure_goes_up(chain):
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('adopt', 'rr_c/load_test/driver')])
    assert 'error' not in res, res
    reg_b = b.registry()
    assert reg_b['server_queries'][0]['links'] == reg_b['client_queries'][0]['local_ids']
    c.fail('driver', 'cable pulled')
    events = a.wait_events(1)
    assert events[0]['id'] == res['id'] and any('cable pulled' in m for m in events[0]['stack'])
    assert a.unload(res['id']) == {}
    assert c.counts()['unloads'] == {'driver': 1}


def test_linking_a_resource_that_failed_meanwhile_is_refused_and_fails_the_load(chain):
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('adopt', 'rr_c/load_test/doomed_driver')])
    assert res.get('code') == ErrorCode.RESOURCE_FAILED, res
    assert 'is failed' in res['error'], res['error']
    for node in chain:
        wait_for(lambda: registry_empty(node), 10, 'nothing left at %s' % node.name)
    assert c.counts()['unloads'] == {'doomed_driver': 1}


def test_a_failure_is_said_once_then_its_chain(chain):
    """The error text names where the failure started exactly once (each hop used to repeat the whole
    text of the hop below it), then the hops it took, newest first."""
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('nested', 'rr_c/load_test/driver'), ('fail', 'raise')])
    text = res['error']
    assert text.count('refused cam on purpose') == 1, text
    assert text.startswith('/temoto/rr_b/load_test refused the request: refused cam on purpose'), text
    assert 'loading load_test failed' in text
    assert len(res['stack']) >= 3


def test_failed_status_during_a_load_fails_that_load(chain):
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('nested', 'rr_c/load_test/driver'), ('fail_during_load', '1')])
    assert 'error' in res and 'failed while loading' in res['error']
    for node in chain:
        wait_for(lambda: registry_empty(node), 10, 'rollback at %s' % node.name)
    assert c.counts()['unloads'] == {'driver': 1}


def test_status_reaches_every_holder_of_a_shared_sub_resource(chain):
    a, b, c = chain
    direct = b.call('rr_c', 'driver')                                      # B holds driver itself
    via_a = a.call('rr_b', 'cam', [('nested', 'rr_c/load_test/driver')])  # and on behalf of A's cam
    assert c.counts()['loads'] == {'driver': 1}
    c.fail('driver')
    wait_for(lambda: any(e['id'] == direct['id'] for e in b.events()), 10, "B's direct holder")
    wait_for(lambda: any(e['id'] == via_a['id'] for e in a.events()), 10, 'A through the link')


def test_two_consumers_share_one_resource_and_it_goes_with_the_last(chain):
    a, b, c = chain
    r1 = a.call('rr_c', 'shared')
    r2 = b.call('rr_c', 'shared')
    assert r1['payload'] == r2['payload']
    assert c.counts()['loads'] == {'shared': 1}
    reg = c.registry()['server_queries']
    assert len(reg) == 1 and len(reg[0]['consumers']) == 2
    a.unload(r1['id'])
    assert c.counts()['unloads'] == {}
    b.unload(r2['id'])
    assert c.counts()['unloads'] == {'shared': 1}
    assert registry_empty(c)


def test_equal_calls_in_one_client_share_a_query_with_two_local_ids(chain):
    a, _, c = chain
    r1 = a.call('rr_c', 'x')
    r2 = a.call('rr_c', 'x')
    assert r1['id'] != r2['id']
    assert len(c.registry()['server_queries'][0]['consumers']) == 1   # one remote reference
    a.unload(r1['id'])
    assert c.counts()['unloads'] == {}
    a.unload(r2['id'])
    assert c.counts()['unloads'] == {'x': 1}


def test_a_failed_resource_is_not_shared_again(chain):
    a, b, c = chain
    r1 = a.call('rr_c', 'dev')
    c.fail('dev')
    a.wait_events(1)
    r2 = b.call('rr_c', 'dev')          # equal request after the failure: a fresh load
    assert c.counts()['loads'] == {'dev': 2}
    r3 = a.call('rr_c', 'dev')          # A's failed query is not reused either
    assert r3['id'] != r1['id']
    for node, rid in ((a, r1['id']), (b, r2['id']), (a, r3['id'])):
        assert node.unload(rid) == {}
    assert c.counts()['unloads'] == {'dev': 2}
    assert registry_empty(c) and registry_empty(a)


def test_status_right_after_load_is_not_lost(chain):
    a, _, c = chain
    # a fresh consumer/server pair each round; the failure is sent the instant the load returns
    for i in range(5):
        res = a.call('rr_c', 'quick%d' % i)
        c.fail('quick%d' % i)
        wait_for(lambda: any(e['id'] == res['id'] for e in a.events()), 10, 'status %d' % i)


def test_a_sub_resource_released_after_it_failed_does_not_fail_the_load(chain):
    """A load callback may try a candidate, see it fail, release it and go on with another."""
    a, b, c = chain
    res = a.call('rr_b', 'cam', [('try', 'rr_c/load_test/doomed_first'), ('nested', 'rr_c/load_test/second')])
    assert 'error' not in res, res
    assert c.counts()['unloads'] == {'doomed_first': 1}
    links = b.registry()['server_queries'][0]['links']
    assert len(links) == 1                                   # only the candidate it kept
    a.unload(res['id'])
    assert c.counts()['unloads'] == {'doomed_first': 1, 'second': 1}
