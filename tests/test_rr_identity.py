"""Consumer identity and status delivery at the edges (docs/architecture.md: identity, status channels).

A consumer is a node *incarnation* (its name and its XML-RPC URI), never only a
name; a status raised at any moment after a load is answered reaches the
consumer, even on its very first request; and a manager does not keep a status
publisher for every consumer it ever served.
"""
import os
import signal
import threading

import pytest
import rosgraph
import rospy

from temoto_core.msg import ResourceStatus
from temoto_core.rr import ResourceRegistrar
from temoto_core.srv import LoadTestResource, UnloadResource
from temoto_testing import wait_for, wait_receiving
from rr_helpers import RegistrarNode

Req = LoadTestResource._request_class


@pytest.fixture(scope='module')
def owner(rospy_client, module_procs):
    return RegistrarNode(module_procs, 'rr_id_owner', check_period=0.5)


def _released(owner, name: str) -> bool:
    return owner.counts()['unloads'].get(name, 0) >= 1


def _one_watch_pass_later(owner, procs, label: str) -> None:
    """Returns right after the owner's consumer watch has run a pass that began after this call: a
    sentinel consumer loads, dies, and is released (the watch checks every holder on each pass)."""
    sentinel = RegistrarNode(procs, 'rr_sentinel_%s' % label)
    sentinel.call(owner.name, 'sentinel_%s' % label)
    os.killpg(sentinel.process.pid, signal.SIGKILL)
    wait_for(lambda: _released(owner, 'sentinel_%s' % label), 15, 'release of the sentinel consumer %s' % label)


def _consumers_of(owner, name: str) -> list:
    for q in owner.registry()['server_queries']:
        if q['summary'].get('name') == name:
            return q['consumers']
    return []


def test_a_restarted_consumer_keeps_what_it_loads_and_its_dead_incarnation_is_released(rospy_client, procs):
    """The restart lands between two passes of the owner's watch (a pass has just run, the next is 3 s
    away), which is where a name-keyed liveness check released the new incarnation's references along
    with the dead one's, or kept the dead one's forever."""
    owner = RegistrarNode(procs, 'rr_id_slow_owner', check_period=3.0)
    old = RegistrarNode(procs, 'rr_reborn')
    old.call(owner.name, 'held_by_old_incarnation')
    old_uri = _consumers_of(owner, 'held_by_old_incarnation')[0]['client_uri']
    assert old_uri.startswith('http://'), 'the consumer is recorded with its incarnation URI'
    _one_watch_pass_later(owner, procs, 'before')

    os.killpg(old.process.pid, signal.SIGKILL)
    new = RegistrarNode(procs, 'rr_reborn')              # at once, under the same name
    new.call(owner.name, 'held_by_new_incarnation')
    new_uri = _consumers_of(owner, 'held_by_new_incarnation')[0]['client_uri']
    assert new_uri != old_uri

    # the dead incarnation's reference goes ...
    wait_for(lambda: _released(owner, 'held_by_old_incarnation'), 15, 'release of the dead incarnation')
    _one_watch_pass_later(owner, procs, 'after')
    # ... and the live one keeps its own, and hears nothing about it
    assert not _released(owner, 'held_by_new_incarnation')
    assert [c['client_uri'] for c in _consumers_of(owner, 'held_by_new_incarnation')] == [new_uri]
    assert new.events() == []
    new.unload(new.registry()['client_queries'][0]['local_ids'][0])


def test_a_release_the_holder_did_not_ask_for_is_announced_to_it(owner, procs, rospy_client):
    heard = []
    doomed = RegistrarNode(procs, 'rr_announced')
    doomed.call(owner.name, 'held_until_death')
    ext = _consumers_of(owner, 'held_until_death')[0]['resource_id']
    # listen on the dead consumer's status topic, as a new incarnation of it would
    sub = rospy.Subscriber('/temoto/rr_announced/status', ResourceStatus, heard.append)
    try:
        wait_receiving(sub, 10, 'a connection from the owner')
        os.killpg(doomed.process.pid, signal.SIGKILL)
        wait_for(lambda: _released(owner, 'held_until_death'), 10, 'release of the dead consumer')
        msg = wait_for(lambda: next((m for m in heard if m.resource_id == ext), None), 10, 'the announcement')
    finally:
        sub.unregister()
    assert msg.status_code == ResourceStatus.FAILED
    assert 'is gone' in msg.message and msg.manager_name == 'rr_id_owner'


def test_failed_reaches_a_consumer_on_its_first_request_whenever_it_is_raised(owner, rospy_client):
    """An equal request from a consumer never served before, with FAILED raised 0 to 45 ms after it
    goes out: the consumer either hears FAILED for what it got, or got a fresh resource that is live."""
    holder = ResourceRegistrar('rr_first_holder')
    lost = []
    try:
        for trial, delay in enumerate([i * 0.003 for i in range(16)]):
            name = 'first_request_%d' % trial
            holder.call('rr_id_owner', 'load_test', Req(name=name))
            fresh = ResourceRegistrar('rr_first_%d' % trial)
            failed = threading.Event()
            failer = threading.Timer(delay, lambda: owner.fail(name, 'killed during the request'))
            try:
                failer.start()
                res = fresh.call('rr_id_owner', 'load_test', Req(name=name),
                                 status_cb=lambda ev: ev.code == ResourceStatus.FAILED and failed.set())
                failer.join(10)
                ext = fresh.registry().client_queries[0].external_id

                def settled():
                    if failed.is_set():
                        return 'failed'
                    for q in owner.registry()['server_queries']:
                        if any(c['resource_id'] == ext for c in q['consumers']) and q['state'] == 'active':
                            return 'live'
                    return None
                try:
                    wait_for(settled, 5, 'FAILED or a live resource for trial %d' % trial)
                except TimeoutError:
                    lost.append((trial, delay, res.trr.resource_id))
            finally:
                fresh.shutdown()
    finally:
        holder.shutdown()
    assert lost == [], 'FAILED lost for a first request (trial, delay, id): %s' % lost


def test_a_manager_drops_the_status_channel_of_a_consumer_that_left(owner, rospy_client):
    master = rosgraph.Master('/test_rr_identity')

    def published_by_owner(topic):
        publishers = dict(master.getSystemState()[0])
        return '/rr_id_owner' in publishers.get(topic, [])

    client = ResourceRegistrar('rr_short_lived_client')
    client.call('rr_id_owner', 'load_test', Req(name='briefly_held'))
    assert published_by_owner(client.status_topic)
    client.shutdown()
    wait_for(lambda: not published_by_owner(client.status_topic), 30,
             'the owner to unregister its publisher of %s' % client.status_topic)


def _raw_consumer(procs, owner, resource: str):
    """A plain-rospy consumer named ``raw_lazarus`` that holds ``resource`` at ``owner``."""
    proc = procs.node('temoto_test_nodes', 'raw_consumer', name='raw_lazarus',
                      params={'owner': owner.name, 'resource': resource})
    wait_for(lambda: rospy.get_param('/raw_lazarus/loaded', None) is True and _consumers_of(owner, resource),
             20, 'the load of %s by the raw consumer' % resource)
    rospy.delete_param('/raw_lazarus/loaded')
    return proc


def test_a_dead_raw_consumer_is_released_though_its_name_came_back_before_the_check(procs, rospy_client):
    """A consumer that sends no URI (plain rospy) is known by the incarnation that called. Resolved by name at
    the owner's next check, both references were charged to the new incarnation started under the name
    before that check, and the dead one's was never released (outside check, 3 of 3)."""
    owner = RegistrarNode(procs, 'rr_id_raw_owner', check_period=5.0)
    _one_watch_pass_later(owner, procs, 'raw')       # the next pass is 5 s away: the restart lands before it
    old = _raw_consumer(procs, owner, 'held_by_dead_raw')
    os.killpg(old.pid, signal.SIGKILL)
    wait_for(lambda: not old.alive(), 10, 'the end of the first raw consumer')
    new = _raw_consumer(procs, owner, 'held_by_live_raw')
    new_uri = _consumers_of(owner, 'held_by_live_raw')[0]['client_uri']

    wait_for(lambda: _released(owner, 'held_by_dead_raw'), 30, 'release of the dead raw consumer')
    assert new_uri.startswith('http://'), 'the live consumer is known by its incarnation from its load on'
    _one_watch_pass_later(owner, procs, 'raw_after')
    assert not _released(owner, 'held_by_live_raw')
    assert [c['client_uri'] for c in _consumers_of(owner, 'held_by_live_raw')] == [new_uri]
    os.killpg(new.pid, signal.SIGKILL)


def test_unloading_what_the_owner_let_go_already_succeeds(owner, procs, rospy_client):
    """A resource the owner released behind the holder's back (a FAILED cleaned up, or a consumer it could
    not reach, during a partition) is gone everywhere: the holder's unload answers so, not "unloading failed"
    with the owner's "no resource" (outside check)."""
    holder = RegistrarNode(procs, 'rr_let_go')
    holder.call(owner.name, 'let_go_behind_its_back')
    ext = _consumers_of(owner, 'let_go_behind_its_back')[0]['resource_id']
    local = holder.registry()['client_queries'][0]['local_ids'][0]
    # the owner drops it, as its consumer watch or a cleanup does while the holder is cut off
    gone = rospy.ServiceProxy('/temoto/%s/unload' % owner.name, UnloadResource)(server_name='load_test',
                                                                                resource_id=ext)
    assert gone.code == 0, gone.message
    out = holder.unload(local)
    assert 'error' not in out, out
    assert holder.registry()['client_queries'] == []
