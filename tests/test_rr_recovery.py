"""A registrar that is killed and restarted with its journal gets its registry back, keeps carrying status,
and hears of what died while it was down (docs/recovery.md).

A (the action) -> B (a manager, with a journal) -> C (the process manager). B is
killed with SIGKILL and started again under the same name.
"""
import concurrent.futures
import os
import signal
import sqlite3
import time

import pytest
import rosgraph
import rospy

from temoto_core.errors import ErrorCode
from temoto_core.msg import ResourceStatus
from temoto_core.srv import Reclaim
from temoto_testing import signals, wait_for
from rr_helpers import RegistrarNode, registry_empty

# A clean clone's suite (fifth session, 1 run in 4) saw the first load of a chain, A -> B (journaled) -> C,
# get no answer within its 30 s beside the other worker; alone it takes milliseconds, and 6 runs alone
# passed. Its cause is not found yet: these tests run alone until it is.
pytestmark = pytest.mark.alone

STATUS_CONNECT_TIMEOUT = 2.0     # the registrar's default wait for a consumer's status channel to connect


def _kill(node: RegistrarNode) -> None:
    os.killpg(node.process.pid, signal.SIGKILL)
    node.process.proc.wait(10)


def _shape(registry: dict) -> dict:
    """What a registry holds, without what differs by incarnation (node URIs, status topics stay)."""
    return {
        'served': sorted((q['server'], q['internal_id'], q['state'], tuple(q['links']),
                          tuple((c['resource_id'], c['client_name'], c['status_topic']) for c in q['consumers']))
                         for q in registry['server_queries']),
        'held': sorted((q['target'], q['external_id'], q['state'], tuple(q['local_ids']), tuple(q['linked_to']))
                       for q in registry['client_queries']),
    }


@pytest.fixture
def chain(rospy_client, procs, tmp_path):
    journal = str(tmp_path / 'rr_rb.sqlite3')
    a = RegistrarNode(procs, 'rr_ra')
    c = RegistrarNode(procs, 'rr_rc', check_period=0.5, recovery_grace=30.0)
    b = RegistrarNode(procs, 'rr_rb', journal=journal)
    return a, b, c, (lambda: RegistrarNode(procs, 'rr_rb', journal=journal))


def _journal_has(path: str, query: str, arg) -> bool:
    """Whether the committed journal has a row for ``query`` (a ``SELECT count(*) ... ?``) with ``arg``."""
    db = sqlite3.connect('file:%s?mode=ro' % path, uri=True)
    try:
        return db.execute(query, (arg,)).fetchone()[0] > 0
    finally:
        db.close()


def _in_journal(path: str, internal_id: int) -> bool:
    """Whether the journal has committed the served resource ``internal_id`` with a consumer."""
    return _journal_has(path, 'SELECT count(*) FROM consumers WHERE internal_id = ?', internal_id)


def _journaled_state(path: str, state: str) -> bool:
    """Whether the journal has committed a served resource in ``state``."""
    return _journal_has(path, 'SELECT count(*) FROM served WHERE state = ?', state)


def _forget_in_journal(path: str, internal_id: int) -> None:
    """What a SIGKILL between a change and its commit loses: a served resource, its consumer and its hold."""
    db = sqlite3.connect(path)
    with db:
        held = db.execute('SELECT namespace, rr, server, external_id FROM holds WHERE parent = ?',
                          (internal_id,)).fetchall()
        db.execute('DELETE FROM served WHERE internal_id = ?', (internal_id,))
        db.execute('DELETE FROM consumers WHERE internal_id = ?', (internal_id,))
        db.execute('DELETE FROM holds WHERE parent = ?', (internal_id,))
        for row in held:
            db.execute('DELETE FROM held WHERE namespace = ? AND rr = ? AND server = ? AND external_id = ?', row)
    db.close()


def test_a_killed_registrar_gets_its_registry_back_and_carries_status_and_cascade(chain):
    a, b, c, restart = chain
    res = a.call('rr_rb', 'cam', [('nested', 'rr_rc/load_test/driver')])
    assert 'error' not in res, res
    before = _shape(b.registry())
    assert before['served'] and before['held']
    _kill(b)
    b = restart()
    assert _shape(b.registry()) == before
    assert b.counts()['loads'] == {}                       # nothing was loaded again
    assert c.counts()['loads'] == {'driver': 1}
    holder = [q for q in c.registry()['server_queries'] if q['summary']['name'] == 'driver'][0]['consumers'][0]
    assert holder['client_uri'] == b.registry_uri()        # C now tells the new incarnation
    c.fail('driver', 'cable pulled')
    events = a.wait_events(1)
    assert events[0]['id'] == res['id'] and any('cable pulled' in m for m in events[0]['stack'])
    assert a.unload(res['id']) == {}
    wait_for(lambda: c.counts()['unloads'] == {'driver': 1}, 10, 'the cascade through the recovered registrar')
    for node in (a, b, c):
        wait_for(lambda: registry_empty(node), 10, 'an empty registry at %s' % node.name)


def test_a_failure_while_the_registrar_is_down_reaches_the_action_after_recovery(chain):
    a, b, c, restart = chain
    res = a.call('rr_rb', 'cam', [('nested', 'rr_rc/load_test/driver')])
    _kill(b)
    c.fail('driver', 'unplugged while its manager was down')
    b = restart()
    events = a.wait_events(1)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED
    assert any('was failed when' in m for m in events[0]['stack']), events[0]['stack']
    assert a.unload(res['id']) == {}
    wait_for(lambda: c.counts()['unloads'] == {'driver': 1}, 10, 'the failed driver released')


def test_a_failed_status_lost_while_the_holder_could_not_connect_is_found_in_the_owner_s_registry(chain, procs,
                                                                                                   tmp_path):
    """The chaos history of seed 17 (two hosts, step 543): the robot lost power and booted again; its Sensor
    Manager rebuilt its registry and sent the FAILED of a camera whose driver had died, before the clients had
    joined the new master, so the status went nowhere and the clients held a dead camera as healthy. Here the
    holder is stopped while the owner comes back, so it cannot connect to the new incarnation in time."""
    a, b, c, _restart = chain
    res = a.call('rr_rb', 'mortal_cam')
    assert 'error' not in res, res
    # committed before the kill: the neighbour that would give back an uncommitted change (A) is stopped below,
    # and without it a kill inside the commit pause loses the load (then nothing is there to fail)
    [served] = b.registry()['server_queries']
    wait_for(lambda: _in_journal(str(tmp_path / 'rr_rb.sqlite3'), served['internal_id']), 10,
             "mortal_cam and its consumer committed to B's journal")
    _kill(b)
    signals.stop(a.process.pid)
    try:
        # a stopped consumer does not answer the owner's check: the new incarnation keeps it as a consumer for
        # a minute (its recovery grace) rather than dropping it while the test holds it stopped
        b = RegistrarNode(procs, 'rr_rb', journal=str(tmp_path / 'rr_rb.sqlite3'), recovery_grace=60.0)
        wait_for(lambda: [q['state'] for q in b.registry()['server_queries']] == ['failed'], 20,
                 'the new incarnation to find mortal_cam dead')
        [entry] = b.registry()['server_queries']
        assert entry['failure'], 'the registry says why mortal_cam failed: %r' % entry       # it said ''
        # the fault: the holder stays stopped while the FAILED goes out (after the status channel's 2 s wait for a
        # connection), so nobody is connected to hear it
        time.sleep(STATUS_CONNECT_TIMEOUT + 1.0)
    finally:
        os.kill(a.process.pid, signal.SIGCONT)
    events = a.wait_events(1, timeout=20)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED, events
    assert 'its status never reached this node' in events[0]['message'], events[0]
    assert a.unload(res['id']) == {}
    wait_for(lambda: registry_empty(b), 10, 'an empty registry at B')


def test_a_resource_found_dead_on_recovery_is_reported_failed_to_its_consumer(chain):
    a, b, c, restart = chain
    res = a.call('rr_rb', 'mortal_cam')
    _kill(b)
    b = restart()
    events = a.wait_events(1)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED
    assert 'mortal_cam died while its owner was down' in events[0]['message']
    assert a.unload(res['id']) == {}
    assert b.counts()['unloads'] == {'mortal_cam': 1}


def test_a_stale_incarnation_is_fenced_out(chain):
    a, b, c, restart = chain
    res = a.call('rr_rb', 'cam', [('nested', 'rr_rc/load_test/driver')])
    driver_id = b.registry()['client_queries'][0]['external_id']
    _kill(b)
    b = restart()
    wait_for(lambda: c.registry()['server_queries'][0]['consumers'][0]['client_uri'] == b.registry_uri(), 10,
             'the new incarnation to reclaim the driver')
    # the old incarnation (1) claims the driver back: refused, and nothing changes hands
    reclaim = rospy.ServiceProxy('/temoto/rr_rc/reclaim', Reclaim)
    answer = reclaim(client_name='/rr_rb', client_uri='http://stale:1/', status_topic='/temoto/rr_rb/status',
                     incarnation=1, server_name='load_test', resource_ids=[driver_id])
    assert answer.code == 1 and 'stale incarnation 1' in answer.message
    assert c.registry()['server_queries'][0]['consumers'][0]['client_uri'] == b.registry_uri()
    # once A has heard B's new incarnation, a status from the old one is dropped
    external = a.registry()['client_queries'][0]['external_id']
    pub = rospy.Publisher('/temoto/rr_ra/status', ResourceStatus, queue_size=10)
    wait_for(lambda: pub.get_num_connections() > 0, 10, 'a connection to A')
    for incarnation, code, text in ((2, ResourceStatus.UPDATE, 'live'), (1, ResourceStatus.FAILED, 'from the dead'),
                                    (2, ResourceStatus.UPDATE, 'live again')):
        pub.publish(ResourceStatus(temoto_namespace='temoto', manager_name='rr_rb', server_name='load_test',
                                   resource_id=external, status_code=code, message=text, incarnation=incarnation))
    events = a.wait_events(2)
    assert [e['message'] for e in events] == ['live', 'live again']
    pub.unregister()
    assert a.unload(res['id']) == {}


def test_a_load_whose_commit_the_kill_lost_comes_back_from_its_consumers_copy(chain, tmp_path):
    a, b, c, restart = chain
    first = a.call('rr_rb', 'cam', [('nested', 'rr_rc/load_test/driver')])
    second = a.call('rr_rb', 'cam2', [('nested', 'rr_rc/load_test/driver2')])
    assert 'error' not in first and 'error' not in second, (first, second)
    before = _shape(b.registry())
    lost = [q['internal_id'] for q in b.registry()['server_queries'] if q['summary']['name'] == 'cam2'][0]
    _kill(b)
    _forget_in_journal(str(tmp_path / 'rr_rb.sqlite3'), lost)
    b = restart()
    wait_for(lambda: not b.registry()['recovering'], 20, 'rr_rb to finish recovering')
    assert _shape(b.registry()) == before
    assert b.counts()['loads'] == {} and c.counts()['loads'] == {'driver': 1, 'driver2': 1}
    c.fail('driver2', 'cable pulled')
    events = a.wait_events(1)
    assert events[0]['id'] == second['id'] and any('cable pulled' in m for m in events[0]['stack'])
    assert a.unload(second['id']) == {} and a.unload(first['id']) == {}
    wait_for(lambda: c.counts()['unloads'] == {'driver': 1, 'driver2': 1}, 10, 'both drivers unloaded')
    for node in (a, b, c):
        wait_for(lambda: registry_empty(node), 10, 'an empty registry at %s' % node.name)


def _journaled(path: str, server: str) -> bool:
    """Whether the journal at ``path`` has committed a resource of ``server`` (it is written behind the answer)."""
    db = sqlite3.connect(path)
    try:
        return db.execute('SELECT COUNT(*) FROM served WHERE server = ?', (server,)).fetchone()[0] > 0
    except sqlite3.OperationalError:          # not created yet
        return False
    finally:
        db.close()


def test_a_resource_released_while_its_owner_was_down_is_unloaded_when_the_owner_returns(chain, tmp_path):
    a, b, c, restart = chain
    res = a.call('rr_rb', 'cam', [('nested', 'rr_rc/load_test/driver')])
    assert 'error' not in res, res
    # the journal knows cam (without it, only C's record of the driver is left, which the restart releases)
    wait_for(lambda: _journaled(str(tmp_path / 'rr_rb.sqlite3'), 'load_test'), 10, 'cam in the journal')
    _kill(b)
    # A lets go while B is dead: its own registry forgets the resource, the unload cannot reach B
    assert 'could not unload' in a.unload(res['id']).get('error', '')
    assert registry_empty(a)
    b = restart()
    wait_for(lambda: c.counts()['unloads'] == {'driver': 1}, 20, 'the driver unloaded in cascade')
    assert b.counts()['unloads'] == {'cam': 1}
    for node in (b, c):
        wait_for(lambda: registry_empty(node), 10, 'an empty registry at %s' % node.name)


def test_a_sub_resource_neither_the_journal_nor_its_owner_gives_back_fails_what_links_it(chain, tmp_path):
    """B's journal is lost and C, which served B's driver, died with B: A's copy of B's record names the driver,
    but nobody can give it back, so nobody can vouch for the camera that uses it."""
    a, b, c, restart = chain
    res = a.call('rr_rb', 'cam', [('nested', 'rr_rc/load_test/driver')])
    assert 'error' not in res, res
    _kill(b)
    _kill(c)
    for suffix in ('', '-wal', '-shm'):
        path = str(tmp_path / 'rr_rb.sqlite3') + suffix
        if os.path.exists(path):
            os.remove(path)
    b = restart()
    events = a.wait_events(1)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED
    text = ' '.join([events[0]['message']] + events[0]['stack'])
    assert '/temoto/rr_rc/load_test' in text and 'could not be recovered' in text, text
    assert [q['summary']['name'] for q in b.registry()['server_queries']] == ['cam']
    assert a.unload(res['id']) == {}
    for node in (a, b):
        wait_for(lambda: registry_empty(node), 10, 'an empty registry at %s' % node.name)


def test_a_call_after_the_owner_restarted_connects_afresh_whatever_the_pool_holds(chain):
    """A's pool holds two idle connections to B's server (two loads overlapped). B is killed and restarted:
    both connections are dead. The next call finds the first one stale, and its one retry must not take the
    second: it connects to the new incarnation."""
    a, b, c, restart = chain
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        first, second = pool.map(lambda name: a.call('rr_rb', name, [('delay', '0.3')]), ('slow1', 'slow2'))
    assert 'error' not in first and 'error' not in second, (first, second)
    _kill(b)
    b = restart()
    wait_for(lambda: not b.registry()['recovering'], 20, 'rr_rb to finish recovering')
    third = a.call('rr_rb', 'after_restart')
    assert 'error' not in third, third
    for res in (first, second, third):
        assert a.unload(res['id']) == {}


def test_a_load_given_up_on_before_any_answer_is_released_after_its_journaled_owner_restarts(chain, procs,
                                                                                              tmp_path):
    """Chaos seed 17, two hosts, step 6429: a client's first call to the Context Manager since its watch began
    was cut, the manager was killed and came back, and what it had served for that call stayed counted for
    the client. The client had had no answer from it, so its watch did not know the owner kept a journal, took
    the new incarnation for one that lost everything, and stopped watching: nothing ever read the registry
    that the journal had rebuilt. Here A gives up on its first load from B, and is stopped while B finishes it,
    commits it, and is killed and started again."""
    a, b, _c, _restart = chain
    journal = str(tmp_path / 'rr_rb.sqlite3')
    out = a.command(op='call', rr='rr_rb', name='given_up', params=[['delay', '1.0']], deadline=0.3)
    assert out.get('code') == ErrorCode.TIMEOUT, out
    signals.stop(a.process.pid)
    try:
        wait_for(lambda: _journaled(journal, 'load_test'), 10, 'the given-up load committed to B\'s journal')
        _kill(b)
        b = RegistrarNode(procs, 'rr_rb', journal=journal, recovery_grace=60.0)
        wait_for(lambda: not b.registry()['recovering'], 20, 'rr_rb to finish recovering')
        [entry] = b.registry()['server_queries']
        assert [c['client_name'] for c in entry['consumers']] == ['/rr_ra'], entry
    finally:
        os.kill(a.process.pid, signal.SIGCONT)
    wait_for(lambda: b.counts()['unloads'] == {'given_up': 1}, 20, 'the given-up load released at B')
    wait_for(lambda: registry_empty(b), 10, 'an empty registry at B')
    assert registry_empty(a)


def test_an_unload_sent_to_a_restarted_owner_waits_until_its_registry_is_back(chain, procs, tmp_path):
    """Chaos seed 17, two hosts, step 1098: a client unloaded a tracked object (failed, so its watch of the
    Context Manager had ended) while the manager's new incarnation was starting. It had added its first
    server (load_tracker), and with it its unload service, but not yet track_object: the unload was answered
    "no server 'track_object'", which settled it, and the tracked object came back from the journal a moment
    later, held for nobody. A registrar now refuses an unload until its registry is back (RECOVERING), and the
    consumer keeps it owed until then."""
    a, b, _c, _restart = chain
    journal = str(tmp_path / 'rr_rb.sqlite3')
    res = a.call('rr_rb', 'cam')
    assert 'error' not in res, res
    assert 'sent' in b.fail('cam')
    a.wait_events(1)
    wait_for(lambda: _journaled(journal, 'load_test'), 10, 'cam in the journal')
    _kill(b)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        started = pool.submit(RegistrarNode, procs, 'rr_rb', journal=journal, late_server_s=4.0)
        # its first server is up, and with it its unload service; load_test, and cam with it, are not yet
        wait_for(lambda: _service_known('/temoto/rr_rb/early_test'), 20, 'the first server of the new incarnation')
        out = a.unload(res['id'])
        b = started.result(30)
    wait_for(lambda: b.counts()['unloads'] == {'cam': 1}, 20, 'the unload of cam taken at B')
    assert 'taking its registry back' in out.get('error', '') and 'the unload is sent again when its owner ' \
        'answers' in out['error'], out
    wait_for(lambda: registry_empty(b), 10, 'an empty registry at B')
    assert registry_empty(a)


def _service_known(service: str) -> bool:
    try:
        rosgraph.Master('/test_rr_recovery').lookupService(service)
        return True
    except rosgraph.MasterError:
        return False


def test_a_failed_resource_keeps_its_reason_across_its_owner_s_restart(chain, tmp_path):
    """The journal keeps why a served resource failed: after the owner's restart its registry says why,
    not "the journal keeps no reason" (outside check)."""
    a, b, c, restart = chain
    a.call('rr_rb', 'cam_with_reason', [('nested', 'rr_rc/load_test/driver_with_reason')])
    c.fail('driver_with_reason', 'cable pulled for the reason test')
    a.wait_events(1)

    def failed_with(reg: dict):
        return [q['failure'] for q in reg['server_queries'] if q['state'] == 'failed' and q.get('failure')]
    wait_for(lambda: failed_with(b.registry()), 10, 'the failure at the owner')
    # the journal commits within its pause: the kill comes after the FAILED state is on disk
    wait_for(lambda: _journaled_state(str(tmp_path / 'rr_rb.sqlite3'), 'failed'), 10, 'the failure journaled')
    _kill(b)
    b = restart()
    reasons = wait_for(lambda: failed_with(b.registry()), 20, 'the failed resource back in the registry')
    assert any('cable pulled for the reason test' in r for r in reasons), reasons
    assert not any('keeps no reason' in r for r in reasons), reasons
