"""No registrar call outlives its deadline, and an owner that stops answering is found out within the
liveness bound (docs/failures.md, "Deadlines and owner liveness").

A holds resources from C, or calls it. C is slowed down (``delay``), SIGSTOPped
(the process is there and says nothing: what a partition looks like from A) or
SIGKILLed (it keeps no journal, so what it served is gone).
"""
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
import rospy

from temoto_core.errors import ErrorCode
from temoto_core.msg import ResourceStatus
from temoto_core.rr import ResourceRegistrar, owners
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.deadlines import call_once
from temoto_core.srv import GetRegistry, LoadTestResource
from temoto_testing import signals, wait_for
from rr_helpers import RegistrarNode, registry_empty

BOUND = 0.7          # owners.DEFAULT_BOUND: a stopped owner is lost after this much silence
HANG = 5.0           # generous: catches a call that hangs, not a slow machine


@pytest.fixture
def pair(rospy_client, procs):
    c = RegistrarNode(procs, 'rr_dc')
    # a stopped owner still accepts connections: it is lost after the busy bound (3 s by default)
    a = RegistrarNode(procs, 'rr_da', owner_busy_bound=1.5)
    return a, c


@contextlib.contextmanager
def stopped(node: RegistrarNode):
    signals.stop(node.process.pid, group=True)
    try:
        yield
    finally:
        os.killpg(node.process.pid, signal.SIGCONT)


def timed(fn, *args, **kwargs):
    t0 = time.monotonic()
    out = fn(*args, **kwargs)
    return out, time.monotonic() - t0


def test_a_call_past_its_deadline_fails_with_timeout_and_the_late_resource_is_released(pair):
    a, c = pair
    out, took = timed(a.command, op='call', rr='rr_dc', name='slow', params=[['delay', '2.0']], deadline=0.5)
    assert out.get('code') == ErrorCode.TIMEOUT and 'within its deadline of 0.50 s' in out['error'], out
    assert 0.5 <= took < HANG
    assert registry_empty(a)
    # C finished the load after A gave up on it: A finds the stray reference and releases it
    wait_for(lambda: c.counts()['unloads'] == {'slow': 1}, 15, 'the late resource released at C')
    wait_for(lambda: registry_empty(c), 10, 'an empty registry at C')


def test_a_late_resource_is_released_while_its_owner_is_busy_with_another_consumers_load(pair, procs):
    """The owner is read for what this node gave up on as soon as none of *this node's* loads are still being
    served there. (It waited for every load there to end: in the chaos history of seed 17, step 1228, a
    display answered after its caller gave up stayed counted at the Output Manager for 20 s, while other
    clients' displays waited there for a first frame from a dead driver.)"""
    a, c = pair
    b = RegistrarNode(procs, 'rr_db')
    answers = []         # B's call ends when the test stops the nodes: its error is not this test's business
    busy = threading.Thread(target=lambda: answers.append(_answer_or_error(
        b.command, op='call', rr='rr_dc', name='busy', params=[['delay', '30.0']])), daemon=True)
    busy.start()
    wait_for(lambda: [q for q in c.registry()['server_queries'] if q['state'] == 'loading'], HANG,
             "B's load under way at C")
    out = a.command(op='call', rr='rr_dc', name='slow', params=[['delay', '2.0']], deadline=0.5)
    assert out.get('code') == ErrorCode.TIMEOUT, out
    wait_for(lambda: c.counts()['unloads'].get('slow') == 1, 15, "A's late resource released at C")
    assert [q['state'] for q in c.registry()['server_queries'] if q['summary'].get('name') == 'busy'] == \
        ['loading'], "B's load was still under way: A did not wait for it"


def _answer_or_error(fn, **kwargs):
    try:
        return fn(**kwargs)
    except Exception as err:
        return err


def test_a_load_answered_after_its_registrar_shut_down_is_released_at_its_owner(pair):
    """An action's registrar shuts down when the action ends, and a load that a side thread of the plugin
    started (follow_hand's failover to another hand source) may still be on its way: its answer came to a
    registrar that had already released everything, so nothing released it until the worker's process went."""
    a, c = pair
    answers = []
    call = threading.Thread(target=lambda: answers.append(_answer_or_error(
        a.command, op='call', rr='rr_dc', name='late', params=[['delay', '1.5']])), daemon=True)
    call.start()
    wait_for(lambda: [q for q in c.registry()['server_queries'] if q['state'] == 'loading'], HANG,
             "A's load under way at C")
    a.command(op='shutdown')
    call.join(HANG)
    assert answers and answers[0].get('code') == ErrorCode.SHUTDOWN, answers
    assert 'shut down while' in answers[0]['error'], answers
    wait_for(lambda: c.counts()['unloads'] == {'late': 1}, HANG, 'the late resource released at C')
    wait_for(lambda: registry_empty(c), HANG, 'an empty registry at C')


def test_a_bad_deadline_is_refused_and_changes_nothing(pair):
    a, c = pair
    out = a.command(op='call', rr='rr_dc', name='cam', deadline=-1)
    assert out.get('code') == ErrorCode.BAD_REQUEST and 'deadline -1' in out['error'], out
    assert c.counts()['loads'] == {} and registry_empty(a)


def test_a_stopped_owner_fails_what_is_held_from_it_within_the_bound(pair):
    a, c = pair
    res = a.call('rr_dc', 'cam')
    assert 'error' not in res, res
    with stopped(c):
        t0 = time.monotonic()
        events = a.wait_events(1, timeout=HANG)
        heard = time.monotonic() - t0
        assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED
        assert 'no answer from /rr_dc' in events[0]['message'], events[0]
        assert 'the process is stopped or wedged' in events[0]['message'], events[0]
        # it still takes connections: busy or stopped, given the busy bound (1.5 s), counted from the last
        # answer, which came up to one owner check period (0.15 s) before the stop
        assert 1.5 - owners.DEFAULT_PERIOD - 0.05 <= heard < HANG
    # the failed resource stays failed; releasing it reaches C once C answers again (at once if A has
    # already heard C again, else as an owed unload)
    out = a.unload(res['id'])
    assert out == {} or 'the unload is sent again when its owner answers' in out['error'], out
    assert registry_empty(a)
    wait_for(lambda: c.counts()['unloads'] == {'cam': 1}, 10, 'the unload at C')
    for node in (a, c):
        wait_for(lambda: registry_empty(node), 10, 'an empty registry at %s' % node.name)


def test_a_call_in_flight_to_an_owner_that_stops_answering_is_cut(pair):
    a, c = pair
    result = {}
    caller = threading.Thread(target=lambda: result.update(out=timed(
        a.command, op='call', rr='rr_dc', name='slow', params=[['delay', '2.0']])))
    caller.start()
    wait_for(lambda: c.counts()['loads'] == {'slow': 1}, 10, 'the load to start at C')
    with stopped(c):
        caller.join(HANG + 5)
        assert not caller.is_alive(), 'the call hangs on a stopped owner'
    out, took = result['out']
    assert 'cut short' in out.get('error', '') and 'no answer from /rr_dc' in out['error'], out
    assert took < HANG
    # the load completed at C once it ran again: A releases what it never got
    wait_for(lambda: c.counts()['unloads'] == {'slow': 1}, 15, 'the late resource released at C')


def test_an_unload_that_cannot_reach_its_owner_is_sent_again_when_it_answers(pair):
    a, c = pair
    res = a.call('rr_dc', 'cam')
    with stopped(c):
        out, took = timed(a.unload, res['id'])
        assert 'could not unload' in out.get('error', ''), out
        assert took < HANG
        assert registry_empty(a)
    wait_for(lambda: c.counts()['unloads'] == {'cam': 1}, 10, 'the owed unload delivered')
    wait_for(lambda: registry_empty(c), 10, 'an empty registry at C')


def test_an_owner_without_journal_that_dies_fails_what_is_held_from_it_at_once(pair):
    a, c = pair
    res = a.call('rr_dc', 'cam')
    os.killpg(c.process.pid, signal.SIGKILL)
    c.process.proc.wait(10)
    events = a.wait_events(1, timeout=HANG)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED
    assert '/rr_dc died (it keeps no journal' in events[0]['message'], events[0]
    out = a.unload(res['id'])         # its owner is gone: the release is local, and says so
    assert registry_empty(a), out


def test_a_request_type_gets_its_managers_deadline_without_the_contract_imported():
    # a client that imports only the message type (a process load would otherwise get the 1 s default)
    code = ('import sys; from temoto_er_manager.srv import LoadProcess; '
            'from temoto_core.rr.deadlines import load_deadline, unload_deadline; '
            'assert "temoto_er_manager.contract" not in sys.modules; '
            'print(load_deadline(LoadProcess._request_class(), 1.0), unload_deadline(LoadProcess._request_class(), 1.0))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ['15.0', '10.0']


def test_a_one_off_read_of_a_stopped_server_fails_within_its_deadline(pair):
    # a manager's catalogue and a neighbour's registry are read with call_once, not a registrar call: a
    # plain rospy call would hang on a stopped server for as long as it stays stopped
    _, c = pair
    service = '/temoto/rr_dc/registry'
    assert json.loads(call_once(service, GetRegistry, GetRegistry._request_class(), 2.0).json)['name'] == 'rr_dc'
    with stopped(c):
        t0 = time.monotonic()
        with pytest.raises(rospy.ServiceException, match='rr_dc/registry'):
            call_once(service, GetRegistry, GetRegistry._request_class(), 0.5)
        assert time.monotonic() - t0 < HANG
    with pytest.raises(rospy.ServiceException, match='not known to the master'):
        call_once('/temoto/nobody/registry', GetRegistry, GetRegistry._request_class(), 0.5)


def test_an_owner_answering_a_load_while_its_watch_reads_the_holds_stays_watched(rospy_client):
    """The race the chaos history of seed 17 found (two hosts, step 132): the watch read "nothing held" just
    before a load from the owner was answered, then ended; the new resource was held with no watch, and a
    partition never failed it."""
    core = RegistrarCore('rr_race', 'temoto', 0)
    loaded = threading.Event()
    holding = []

    def holds_from(node):
        if not loaded.is_set():         # read just before a load from the owner is answered...
            loaded.set()
            holding.append(node)        # ...which is held from now on, and noticed after this read
            watch.notice('/owner', 'http://127.0.0.1:9/', 0)
            return False
        return bool(holding)

    watch = owners.OwnerWatch(core, holds_from, lambda node: [], lambda *a: None, lambda *a: True,
                              lambda *a: True, period=0.05, bound=0.2, busy_bound=0.3)
    try:
        watch.notice('/owner', 'http://127.0.0.1:9/', 0)     # the first answer starts the watch
        wait_for(loaded.is_set, HANG, 'the watch to read the holds')
        deadline = time.monotonic() + 0.5                    # several periods: the watch had its chance to end
        while time.monotonic() < deadline:
            assert '/owner' in watch._owners, 'the watch ended while a resource was held from the owner'
            time.sleep(0.05)
    finally:
        watch.stop()


def test_an_owner_a_call_was_given_up_on_is_read_again_until_a_late_request_can_no_longer_arrive(
        rospy_client, monkeypatch):
    """A request caught in a cut link reaches its owner when TCP sends it again, after the caller gave up and
    possibly after the one read of the owner's registry that found nothing (chaos seed 17, step 2437: a
    tracker loaded after that read leaked). The registry is read again until LATE_REQUEST_S has passed."""
    monkeypatch.setattr(owners, 'LATE_REQUEST_S', 1.5, raising=False)   # (absent before the fix)
    core = RegistrarCore('rr_late', 'temoto', 0)
    reads = []

    def reconcile(registrar, quiet):
        reads.append(time.monotonic())
        return True
    # the owner is this test's own node: its URI answers every ping
    watch = owners.OwnerWatch(core, lambda node: False, lambda node: [], lambda *a: None, lambda *a: True,
                              reconcile, period=0.05, bound=2.0, busy_bound=3.0)
    try:
        # in a registrar's order: the call is counted before its owner is known. Noticed first, with nothing
        # held and no call, the owner's watch could end at once (a loaded machine let it run first); the call
        # then made a new record with no URI, which a name no master knows never gets, and it never ended
        owner = watch.calling('/late_owner', ('temoto', 'rr_owner'))
        watch.notice('/late_owner', rospy.get_node_uri(), 0)
        gave_up = time.monotonic()
        watch.done_calling(owner, answered=False)
        wait_for(lambda: '/late_owner' not in watch._owners, 15, 'the watch to end once no late request can come')
        assert len(reads) >= 2 and reads[-1] - gave_up >= 1.0, \
            'read %d time(s), the last %.2f s after the call was given up' % (len(reads), reads[-1] - gave_up)
    finally:
        watch.stop()


def test_an_owner_uri_noticed_while_the_master_is_asked_is_not_overwritten_by_its_answer(rospy_client, monkeypatch):
    """A call counts its owner before any response names its URI, so the watch asks the master; a response
    that names the URI while the master is being asked must not be overwritten by the master's answer (CI
    failure of the test above: the master knew no such node and said '', the watch then pinged nothing, and
    a suspect owner was never read, so its watch never ended)."""
    monkeypatch.setattr(owners, 'LATE_REQUEST_S', 0.3, raising=False)
    core = RegistrarCore('rr_lookup_race', 'temoto', 0)
    noticed, asked = threading.Event(), threading.Event()

    def lookup(self, node):
        asked.set()
        noticed.wait(HANG)             # the response arrives while the master is asked...
        return ''                      # ...which knows no such node
    monkeypatch.setattr(owners.OwnerWatch, '_lookup', lookup)
    reads = []
    watch = owners.OwnerWatch(core, lambda node: False, lambda node: [], lambda *a: None, lambda *a: True,
                              lambda registrar, quiet: reads.append(registrar) or True,
                              period=0.05, bound=2.0, busy_bound=3.0)
    try:
        owner = watch.calling('/raced_owner', ('temoto', 'rr_owner'))
        wait_for(asked.is_set, HANG, 'the watch to ask the master for the owner')
        watch.notice('/raced_owner', rospy.get_node_uri(), 0)
        noticed.set()
        watch.done_calling(owner, answered=False)
        wait_for(lambda: '/raced_owner' not in watch._owners, 15, 'the watch to read the owner and end')
        assert reads, 'the suspect owner was never read'
    finally:
        watch.stop()


def test_a_watch_that_starts_while_the_master_is_away_reaches_an_owner_it_has_met(rospy_client, monkeypatch):
    """A consumer's watch of an owner ends when nothing is held from it. A call to that owner while the master
    is away (the robot rebooting) started a new watch, which asked the master for the owner's address, got
    none, pinged nothing, and lost the owner after the bound as "its host is cut off or down": the call was
    cut though the owner was up (found with a stopped master, test_master_rejoin.py). The watch uses the
    address it last met the owner at; an owner it never met is lost naming the master."""
    core = RegistrarCore('rr_met', 'temoto', 0)
    monkeypatch.setattr(owners.OwnerWatch, '_lookup', lambda self, node: '')     # the master does not answer
    watch = owners.OwnerWatch(core, lambda node: False, lambda node: [], lambda *a: None, lambda *a: True,
                              lambda registrar, quiet: True, period=0.05, bound=0.3, busy_bound=0.5)
    try:
        watch.notice('/met_owner', rospy.get_node_uri(), 0)      # a response named it (the owner: this node)
        wait_for(lambda: '/met_owner' not in watch._owners, HANG, 'the watch to end: nothing is held')
        owner = watch.calling('/met_owner', ('temoto', 'rr_owner'))
        started = owner.last_ok
        wait_for(lambda: owner.lost or owner.last_ok - started > 2 * watch.bound, HANG,
                 'the owner to answer past the bound, or to be lost')
        assert not owner.lost, owner.lost
        stranger = watch.calling('/never_met', ('temoto', 'rr_stranger'))
        wait_for(lambda: stranger.lost, HANG, 'an owner never met to be lost')
        assert 'the master' in stranger.lost and 'does not name it' in stranger.lost, stranger.lost
        watch.done_calling(owner, answered=True)
        watch.done_calling(stranger, answered=True)
    finally:
        watch.stop()


def test_a_consumer_whose_status_channel_was_never_connected_hears_the_failed_anyway(rospy_client, procs):
    """A status channel is connected when the master tells the consumer of the owner's new publisher. That
    update can be lost (sent across a link that went down a moment later), and then nothing the owner says
    arrives: a display's FAILED never reached its client (chaos seed 17, step 3914). The consumer's owner
    watch finds the owner answering but unheard, asks the master for the publishers again, and reads the
    owner's registry."""
    owner = RegistrarNode(procs, 'rr_unheard_owner')
    consumer = RegistrarNode(procs, 'rr_unheard_consumer')
    held = consumer.call('rr_unheard_owner', 'cam')
    assert 'id' in held, held
    assert consumer.command(op='deafen', node='/rr_unheard_owner') == {'dropped': 1}
    owner.fail('cam', 'broke while nobody could hear it')
    [event] = consumer.wait_events(1, timeout=HANG)
    assert event['id'] == held['id'] and event['code'] == ResourceStatus.FAILED, event
    consumer.unload(held['id'])


def test_a_pooled_connection_broken_while_sending_is_retried_not_raised(rospy_client, procs):
    """rospy raises TransportTerminated, which is not a ROSException, when the socket fails while a request is
    sent: a pooled connection to an owner that had died broke a chaos client's load with an exception that
    was not a TemotoError (seed 17, two hosts, step 1506). The call is retried on a new connection."""
    RegistrarNode(procs, 'rr_dp')
    rr = ResourceRegistrar('rr_pool_test', namespace='temoto')
    try:
        first = rr.call('rr_dp', 'load_test', LoadTestResource._request_class(name='cam'))
        [service] = [s for s in rr._client._proxies if s.endswith('/rr_dp/load_test')]
        [pooled] = rr._client._proxies[service]
        pooled.transport.socket.shutdown(socket.SHUT_WR)      # the next request cannot be sent on it
        second = rr.call('rr_dp', 'load_test', LoadTestResource._request_class(name='cam_2'))
        assert second.trr.code == 0 and second.trr.resource_id != first.trr.resource_id
        for response in (first, second):
            rr.unload(response.trr.resource_id)
    finally:
        rr.shutdown()
