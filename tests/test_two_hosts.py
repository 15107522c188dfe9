"""A registrar on the operator's host holds resources from one on the robot's host, and the link between the
hosts fails (docs/two_hosts.md).

The hosts are two network namespaces joined by a veth pair (``temoto_core/hosts.py``):
the robot host runs the master and owner C; the operator host runs consumer A. ROS 1's
own transport joins them. The test drives both nodes through Unix sockets, which
reach into every namespace, so it still sees both sides while the link is cut.
"""
import os
import threading
import time

import pytest

from temoto_core.errors import ErrorCode
from temoto_core.msg import ResourceStatus
from temoto_testing import wait_for
from rr_helpers import RegistrarNode, registry_empty

HANG = 5.0           # generous: catches a call or a detection that hangs, not a slow machine


class Pair:
    """Owner C and the master on the robot, consumer A on the operator's station."""

    def __init__(self, hosts, tmp_path, session_token, journal: bool = False) -> None:
        self.hosts, self.tmp_path = hosts, tmp_path
        self.params = {'journal': str(tmp_path / 'rr_hc.sqlite')} if journal else {}
        self.master = hosts.master(str(tmp_path / 'master'), session_token)
        os.makedirs(self.master.workdir)
        self.robot = hosts.launcher(hosts.robot, self.master, str(tmp_path))
        self.operator = hosts.launcher(hosts.operator, self.master, str(tmp_path))

    def start_robot(self) -> RegistrarNode:
        """C on the robot, against the master (started by the caller)."""
        self.c = RegistrarNode(self.robot, 'rr_hc', control_socket=str(self.tmp_path / 'rr_hc.sock'), **self.params)
        return self.c

    def stop(self) -> None:
        self.hosts.link(True)
        self.operator.stop_all()
        self.robot.stop_all()
        self.master.stop()
        for host in self.hosts.hosts:
            assert self.hosts.pids(host) == [], 'processes left on %s' % host.name


@pytest.fixture
def robot_and_operator(two_hosts, tmp_path, session_token, request):
    """A :class:`Pair` with the link up; an indirect parameter True gives C a journal."""
    two_hosts.link(True)
    pair = Pair(two_hosts, tmp_path, session_token, journal=getattr(request, 'param', False))
    try:
        pair.master.start()
        pair.start_robot()
        pair.a = RegistrarNode(pair.operator, 'rr_ha', control_socket=str(tmp_path / 'rr_ha.sock'))
        yield pair
    finally:
        pair.stop()


@pytest.fixture
def pair(robot_and_operator):
    return robot_and_operator.a, robot_and_operator.c, robot_and_operator.hosts


def timed(fn, *args, **kwargs):
    t0 = time.monotonic()
    out = fn(*args, **kwargs)
    return out, time.monotonic() - t0


def test_a_remote_load_crosses_the_hosts(pair):
    a, c, _ = pair
    res = a.call('rr_hc', 'cam')
    assert res['payload'] == 'payload of cam from /rr_hc', res
    assert a.unload(res['id']) == {}
    wait_for(lambda: c.counts()['unloads'] == {'cam': 1}, 10, 'the unload at C')
    wait_for(lambda: registry_empty(c), 10, 'an empty registry at C')


def test_a_partition_while_idle_fails_what_crosses_it_and_the_heal_leaks_nothing(pair):
    a, c, hosts = pair
    res = a.call('rr_hc', 'cam')
    hosts.link(False)
    events, heard = timed(a.wait_events, 1, timeout=HANG)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED, events
    assert 'no answer from /rr_hc' in events[0]['message'], events[0]
    # C keeps its consumer's reference through the partition (no answer is no verdict)...
    assert c.counts()['unloads'] == {}
    # ...and a call across the cut fails within its deadline, naming why
    out, took = timed(a.command, op='call', rr='rr_hc', name='lidar', deadline=1.0)
    assert out.get('code') in (ErrorCode.SERVICE_REQ_FAIL, ErrorCode.TIMEOUT), out
    assert took < HANG
    hosts.link(True)
    # requested again at once, it is served: the owner is asked rather than taken as still lost, and C
    # shares the resource it kept through the cut (no second driver)
    again = a.call('rr_hc', 'cam')
    assert again.get('payload') == 'payload of cam from /rr_hc', again
    assert c.counts()['loads'].get('cam') == 1
    # the failed one stays failed (one event); releasing both reaches C
    for resource_id in (res['id'], again['id']):
        out = a.unload(resource_id)
        assert out == {} or 'the unload is sent again when its owner answers' in out['error'], out
    # the request written to the cut connection may reach C once the link is back: C loads it for a
    # caller that gave up, and A releases it; either way every load at C is released, once
    wait_for(lambda: c.counts()['unloads'] == c.counts()['loads'], 10, 'every load at C released after the heal')
    assert c.counts()['unloads'].get('cam') == 1 and c.counts()['loads'].get('lidar', 0) <= 1
    for node in (a, c):
        wait_for(lambda: registry_empty(node), 10, 'an empty registry at %s' % node.name)
    assert len(a.events()) == 1


def test_a_partition_during_a_load_cuts_the_call_and_the_late_resource_is_released(pair):
    a, c, hosts = pair
    result = {}
    caller = threading.Thread(target=lambda: result.update(out=timed(
        a.command, op='call', rr='rr_hc', name='slow', params=[['delay', '2.0']])))
    caller.start()
    wait_for(lambda: c.counts()['loads'] == {'slow': 1}, 10, 'the load to start at C')
    hosts.link(False)
    caller.join(HANG + 5)
    assert not caller.is_alive(), 'the call hangs across a cut link'
    out, took = result['out']
    assert 'cut short' in out.get('error', '') and 'no answer from /rr_hc' in out['error'], out
    assert took < HANG
    assert registry_empty(a)
    hosts.link(True)
    # C finished the load for a caller that had given up: A finds the stray reference and releases it
    wait_for(lambda: c.counts()['unloads'] == {'slow': 1}, 15, 'the late resource released at C')
    wait_for(lambda: registry_empty(c), 10, 'an empty registry at C')
    assert c.counts()['loads'] == {'slow': 1}


def test_a_status_sent_during_a_partition_is_not_lost(pair):
    a, c, hosts = pair
    res = a.call('rr_hc', 'cam')
    hosts.link(False)
    c.fail('cam', 'the camera died during the partition')
    events = a.wait_events(1, timeout=HANG)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED, events
    hosts.link(True)
    assert a.unload(res['id']).get('code', 0) in (0, ErrorCode.RESOURCE_UNLOAD_FAIL)
    wait_for(lambda: registry_empty(c), 10, 'an empty registry at C')


def test_a_robot_host_that_dies_fails_what_is_held_from_it(pair):
    a, c, hosts = pair
    res = a.call('rr_hc', 'cam')
    hosts.kill_all(hosts.robot)            # the master goes with it, as on a real robot
    events, heard = timed(a.wait_events, 1, timeout=HANG)
    assert events[0]['id'] == res['id'] and events[0]['code'] == ResourceStatus.FAILED, events
    assert '/rr_hc' in events[0]['message'], events[0]
    assert heard < HANG
    out = a.unload(res['id'])              # the owner is gone: the release is local
    assert registry_empty(a), out


def master_knows(pair, node: str) -> bool:
    return pair.hosts.run_in(pair.hosts.robot, lambda: pair.master.is_registered(node))


@pytest.mark.parametrize('robot_and_operator', [True], indirect=True)
def test_a_robot_host_that_returns_is_joined_again_and_rebuilds_its_registry_from_the_operator(robot_and_operator):
    """The master runs on the robot: a new master knows nothing of the operator's nodes, which rospy registers
    once. They register again (temoto_core/master_rejoin.py), so the returned robot's registrar finds the
    operator's copy of its registry, and its statuses reach the operator."""
    pair = robot_and_operator
    a, hosts = pair.a, pair.hosts
    res = a.call('rr_hc', 'cam')
    [held] = a.registry()['client_queries']
    # the robot host dies: its processes, and its answers on the network (a host whose kernel still refuses
    # connections looks like a respawning owner, given its grace)
    hosts.kill_all(hosts.robot)
    hosts.link(False)
    a.wait_events(1, timeout=HANG)
    pair.master.stop()
    hosts.link(True)
    pair.master.start()                    # the robot boots: a new master at the same address
    wait_for(lambda: master_knows(pair, '/rr_ha'), HANG, 'the operator registered again with the new master')
    c = pair.start_robot()
    # the journal is of the old master's run: the operator's copy alone gives the resource back, failed (its
    # process died with the host), with A as its consumer
    served = c.registry()['server_queries']
    assert [(q['state'], [x['resource_id'] for x in q['consumers']]) for q in served] == \
        [('failed', [held['external_id']])], served
    assert len(a.events()) == 1, 'the failed resource is not announced twice'
    assert a.unload(res['id']) == {}
    for node in (a, c):
        wait_for(lambda node=node: registry_empty(node), HANG, 'an empty registry at %s' % node.name)
    # a new load, and its FAILED reaches the operator from the new robot
    again = a.call('rr_hc', 'cam')
    c.fail('cam', 'the camera died after the reboot')
    events = a.wait_events(2, timeout=HANG)
    assert events[1]['id'] == again['id'] and events[1]['code'] == ResourceStatus.FAILED, events
    assert a.unload(again['id']).get('code', 0) in (0, ErrorCode.RESOURCE_UNLOAD_FAIL)
