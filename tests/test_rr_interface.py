"""Registrar bad input, introspection, ids, lifetime, and the `temoto registry` command."""
import json
import os
import signal
import subprocess

import pytest
import rospy

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.ids import IdGenerator
from temoto_core.msg import ResourceStatus
from temoto_core.rr import RegistrySnapshot, ResourceRegistrar
from temoto_core.rr.keys import request_key
from temoto_core.rr.messages import clone
from temoto_core.srv import LoadTestResource, UnloadResource
from temoto_testing import wait_for
from diagnostic_msgs.msg import KeyValue
from rr_helpers import RegistrarNode, registry_empty

Req = LoadTestResource._request_class


@pytest.fixture(scope='module')
def owner(rospy_client, module_procs):
    return RegistrarNode(module_procs, 'rr_owner', check_period=0.5)


@pytest.fixture(scope='module')
def local_rr(rospy_client):
    rr = ResourceRegistrar('rr_local')
    yield rr
    rr.shutdown()


def test_equality_ignores_the_header_and_treats_keyvalues_as_multisets():
    a = Req(name='x', params=[KeyValue('a', '1'), KeyValue('b', '2')])
    b = Req(name='x', params=[KeyValue('b', '2'), KeyValue('a', '1')])
    b.trr.status_topic = '/elsewhere/status'
    assert request_key(a) == request_key(b)
    assert request_key(a) != request_key(Req(name='x', params=[KeyValue('a', '1')]))
    assert request_key(a) != request_key(Req(name='x', params=[KeyValue('a', '1'), KeyValue('a', '1'),
                                                               KeyValue('b', '2')]))


def test_a_consumer_s_copy_of_a_response_shares_nothing_it_could_change():
    """Each consumer gets its own copy of a shared response (messages.clone): changing one, lists,
    nested messages and times included, must not change the registrar's or another consumer's."""
    from temoto_core.msg import Error
    original = LoadTestResource._response_class(payload='p')
    original.trr.error_stack = [Error(code=1, message='m', stamp=rospy.Time(5, 6))]
    copy = clone(original)
    assert copy == original
    copy.trr.resource_id = 9
    copy.trr.error_stack[0].message = 'changed'
    copy.trr.error_stack[0].stamp.secs = 7
    copy.trr.error_stack.append(Error())
    assert original.trr.resource_id == 0 and len(original.trr.error_stack) == 1
    assert original.trr.error_stack[0].message == 'm' and original.trr.error_stack[0].stamp == rospy.Time(5, 6)


def test_ids_are_unique_and_increase_across_restarts():
    first = IdGenerator()
    ids = [first.next() for _ in range(10000)]
    assert len(set(ids)) == len(ids) and ids == sorted(ids)
    restarted = IdGenerator()        # a new incarnation of the node
    assert restarted.next() > ids[-1]


def test_unknown_server_name(local_rr, owner):
    with pytest.raises(TemotoError) as err:
        local_rr.call('rr_owner', 'no_such_server', Req(name='x'))
    assert err.value.code == ErrorCode.SERVICE_REQ_FAIL
    assert '/temoto/rr_owner/no_such_server does not exist' in str(err.value)
    assert local_rr.registry().is_empty()


def test_unknown_or_already_unloaded_id(local_rr, owner):
    with pytest.raises(TemotoError) as err:
        local_rr.unload(12345)
    assert err.value.code == ErrorCode.RESOURCE_NOT_FOUND and '12345' in str(err.value)
    res = local_rr.call('rr_owner', 'load_test', Req(name='once'))
    local_rr.unload(res.trr.resource_id)
    with pytest.raises(TemotoError) as err:
        local_rr.unload(res.trr.resource_id)
    assert 'already unloaded' in str(err.value)
    # the server side says the same for a raw unload of an unknown id, naming the server
    out = rospy.ServiceProxy('/temoto/rr_owner/unload', UnloadResource)(server_name='load_test', resource_id=999)
    assert out.code == 1 and 'no resource 999' in out.message
    out = rospy.ServiceProxy('/temoto/rr_owner/unload', UnloadResource)(server_name='nope', resource_id=1)
    assert out.code == 1 and "no server 'nope'" in out.message and 'load_test' in out.message
    assert registry_empty(owner)


@pytest.mark.parametrize('how,expected', [('raise', 'refused bad on purpose'), ('crash', 'RuntimeError')])
def test_load_callback_that_raises(local_rr, owner, how, expected):
    with pytest.raises(TemotoError) as err:
        local_rr.call('rr_owner', 'load_test', Req(name='bad', params=[KeyValue('fail', how)]))
    assert expected in str(err.value)
    assert len(err.value.stack) >= 2          # the owner's frame plus the hops back to us
    assert registry_empty(owner) and local_rr.registry().is_empty()


def test_call_to_a_server_that_died(local_rr, procs):
    victim = RegistrarNode(procs, 'rr_victim')
    res = local_rr.call('rr_victim', 'load_test', Req(name='v'))
    os.killpg(victim.process.pid, signal.SIGKILL)
    victim.process.proc.wait(10)
    with pytest.raises(TemotoError) as err:
        local_rr.call('rr_victim', 'load_test', Req(name='other'))
    assert err.value.code == ErrorCode.SERVICE_REQ_FAIL
    with pytest.raises(TemotoError) as err:
        local_rr.unload(res.trr.resource_id)      # the reference is dropped locally even so
    assert 'could not unload' in str(err.value)
    assert local_rr.registry().is_empty()


def test_malformed_status_is_ignored_and_changes_nothing(local_rr, owner):
    res = local_rr.call('rr_owner', 'load_test', Req(name='m'))
    pub = rospy.Publisher(local_rr.status_topic, ResourceStatus, queue_size=10)
    wait_for(lambda: pub.get_num_connections() > 0, 10, 'status publisher connection')
    before = local_rr.registry()
    for bad in (ResourceStatus(manager_name='rr_owner', server_name='load_test', resource_id=1, status_code=7),
                ResourceStatus(manager_name='', server_name='load_test', resource_id=1, status_code=1),
                ResourceStatus(manager_name='rr_owner', server_name='load_test', resource_id=-4, status_code=1)):
        pub.publish(bad)
    owner.fail('m')        # a good one after the bad ones still arrives
    wait_for(lambda: local_rr.registry().client_queries[0].state == 'failed', 10, 'the genuine FAILED')
    assert before.client_queries[0].state == 'active'
    pub.unregister()
    local_rr.unload(res.trr.resource_id)


def test_nested_call_to_the_same_registrar_is_refused(local_rr):
    with pytest.raises(TemotoError) as err:
        local_rr.call('rr_local', 'anything', Req(name='x'))
    assert err.value.code == ErrorCode.NESTED_CALL and 'cannot request a resource from itself' in str(err.value)


def test_bad_names_are_refused(local_rr):
    for rr_name, server in (('', 'x'), ('has space', 'x'), ('ok', '')):
        with pytest.raises(TemotoError) as err:
            local_rr.call(rr_name, server, Req(name='x'))
        assert err.value.code == ErrorCode.BAD_REQUEST
    with pytest.raises(TemotoError):
        local_rr.add_server('unload', LoadTestResource, lambda q, s: None, lambda q, s: None)


def test_bad_trr_header_is_refused_by_the_server(owner):
    req = Req(name='h')
    req.trr.status_topic = 'not a topic!'
    res = rospy.ServiceProxy('/temoto/rr_owner/load_test', LoadTestResource)(req)
    assert res.trr.code == 1 and 'status_topic' in res.trr.message
    assert registry_empty(owner)


def test_registry_round_trips_through_json(local_rr, owner):
    res = local_rr.call('rr_owner', 'load_test', Req(name='j', params=[KeyValue('k', 'v')]))
    snap = RegistrySnapshot.from_json(json.dumps(owner.registry()))
    assert RegistrySnapshot.from_json(snap.to_json()) == snap
    assert snap.server_queries[0].summary['name'] == 'j'
    from temoto_core.rr.registry import decode_message
    assert decode_message(snap.server_queries[0].request, Req).params == [KeyValue('k', 'v')]
    local_rr.unload(res.trr.resource_id)


def test_temoto_registry_command_prints_a_table_and_json(local_rr, owner, ros_master):
    res = local_rr.call('rr_owner', 'load_test', Req(name='shown'))
    table = subprocess.run(['temoto', 'registry', 'rr_owner'], env=ros_master.env, capture_output=True, text=True,
                           timeout=30)
    assert table.returncode == 0, table.stderr
    assert 'registrar rr_owner' in table.stdout and 'load_test' in table.stdout and 'name=shown' in table.stdout
    js = subprocess.run(['temoto', 'registry', '--json'], env=ros_master.env, capture_output=True, text=True,
                        timeout=30)
    names = {r['name'] for r in json.loads(js.stdout)}
    assert {'rr_owner', 'rr_local'} <= names
    missing = subprocess.run(['temoto', 'registry', 'nobody'], env=ros_master.env, capture_output=True, text=True,
                             timeout=30)
    assert missing.returncode == 1 and "registrar 'nobody' is not running" in missing.stderr
    # Debian's rosservice calls the same service with the project's type
    raw = subprocess.run(['rosservice', 'call', '/temoto/rr_owner/registry'], env=ros_master.env,
                         capture_output=True, text=True, timeout=30)
    assert raw.returncode == 0 and 'shown' in raw.stdout
    local_rr.unload(res.trr.resource_id)


def test_shutdown_releases_everything_it_holds(rospy_client, owner):
    rr = ResourceRegistrar('rr_shortlived')
    rr.call('rr_owner', 'load_test', Req(name='s1'))
    rr.call('rr_owner', 'load_test', Req(name='s2'))
    rr.shutdown()
    assert owner.counts()['unloads'].get('s1') == 1 and owner.counts()['unloads'].get('s2') == 1
    assert registry_empty(owner)
    with pytest.raises(TemotoError):
        rr.call('rr_owner', 'load_test', Req(name='s3'))


def test_references_of_a_consumer_that_died_are_released(owner, procs):
    doomed = RegistrarNode(procs, 'rr_dead_consumer')
    doomed.call('rr_owner', 'held_by_dead')
    os.killpg(doomed.process.pid, signal.SIGKILL)
    # owner runs with consumer_check_period 0.5 s: bound 0.5 s + 1 s ping timeout
    wait_for(lambda: owner.counts()['unloads'].get('held_by_dead') == 1, 5, 'release of the dead consumer')
    assert registry_empty(owner)
