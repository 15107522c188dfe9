"""A node outlives its master: the new master at the same address gets the node's registrations back
(temoto_core/master_rejoin.py), and what needs the master while it is away says so. Real roscore, stopped
and restarted on its port; real registrar nodes.

Across two hosts, with the robot's return, in test_two_hosts.py.
"""
import json
import os
import subprocess

import pytest

from temoto_core import control_socket

from temoto_core.master import RosMaster, free_port
from temoto_core.processes import ProcessGroupLauncher
from temoto_testing import wait_for
from temoto_core.xmlrpc_util import proxy
from rr_helpers import RegistrarNode

HANG = 10.0


@pytest.fixture
def own_master(tmp_path, session_token):
    master = RosMaster(str(tmp_path / 'master'), session_token, port=free_port())
    (tmp_path / 'master').mkdir()
    master.start()
    procs = ProcessGroupLauncher(master.env, str(tmp_path))
    yield master, procs
    procs.stop_all()
    master.stop()


def system_state(master):
    code, _, state = proxy(master.uri, 2.0).getSystemState('/test_master_rejoin')
    assert code == 1
    return state


def run_id(master):
    code, _, value = proxy(master.uri, 2.0).getParam('/test_master_rejoin', '/run_id')
    assert code == 1
    return value


def registered(master, node):
    publishers, subscribers, services = system_state(master)
    return ({t for t, nodes in publishers if node in nodes}, {t for t, nodes in subscribers if node in nodes},
            {s for s, nodes in services if node in nodes})


def test_a_restarted_master_gets_every_registration_of_a_node_back(own_master):
    master, procs = own_master
    RegistrarNode(procs, 'rr_rejoin', control_socket=str(procs.workdir) + '/rr_rejoin.sock')
    before = registered(master, '/rr_rejoin')
    assert '/rr_rejoin/control' in before[2] and '/temoto/rr_rejoin/status' in before[1], before
    old_run = run_id(master)
    master.stop()
    master.start()                       # the same address and port: a new roscore, which knows nothing
    # (asking it at once whether it knows the node races the node's rejoin, which may already have happened)
    assert run_id(master) != old_run
    wait_for(lambda: registered(master, '/rr_rejoin') == before, HANG, 'every registration of /rr_rejoin back')


# nodes with no registrar of their own, which must rejoin too: (package, script, params, the service that
# registers last, relative to the node or to the namespace 'temoto')
NO_REGISTRAR = {
    'rviz_host': ('temoto_output_manager', 'rviz_host', {'show_robot': 'false', 'show_grid': 'false'},
                  '{node}/list_displays'),
    'action_engine': ('temoto_action_engine', 'temoto_action_engine', {'temoto_namespace': 'temoto'},
                      '/temoto/action_engine/list_actions'),
}


@pytest.mark.parametrize('which', sorted(NO_REGISTRAR))
def test_a_node_with_no_registrar_outlives_its_master_and_registers_again(own_master, which):
    """The station's RViz host and action engine, when the robot (and the master on it) lost power. Without
    it, every display was refused until the host itself was restarted (chaos, seed 17), and no instruction
    reached the engine again."""
    master, procs = own_master
    package, script, params, last_service = NO_REGISTRAR[which]
    proc = procs.node(package, script, name=which + '_rejoin', namespace='temoto', params=params)
    node = '/temoto/%s_rejoin' % which
    last_service = last_service.format(node=node)
    wait_for(lambda: last_service in registered(master, node)[2] or not proc.alive(), 30,
             '%s to offer its services' % which)
    assert proc.alive(), proc.log(40)
    before = registered(master, node)
    master.stop()
    master.start()
    # every registration seen before is back; the node may have made more since the snapshot (the service
    # taken for its last is not always so: a CI run waited 10 s for an equality the node had outgrown)
    wait_for(lambda: all(was <= now for was, now in zip(before, registered(master, node))), HANG,
             'every registration of %s back' % which)


def librviz_node(master, host_proc):
    """The roscpp node librviz started inside the host's process, as the master knows it now."""
    publishers, subscribers, services = system_state(master)
    names = {n for _, nodes in publishers + subscribers + services for n in nodes if '/rviz_' in n
             and not n.endswith('/rviz_host_rejoin')}
    found = []
    for name in names:
        code, _, uri = proxy(master.uri, 2.0).lookupNode('/test_master_rejoin', name)
        if code == 1 and proxy(uri, 2.0).getPid('/test_master_rejoin')[2] == host_proc.pid:
            found.append((name, uri))
    return found


def connected_publishers(node_uri, topic):
    """The nodes a node receives ``topic`` from, by its own bus information: connections, not registrations."""
    code, _, bus = proxy(node_uri, 2.0).getBusInfo('/test_master_rejoin')
    assert code == 1
    # roscpp's rows: (id, destination URI or node, direction, transport, topic, connected, ...)
    return {row[1] for row in bus if row[4] == topic and row[2] == 'i' and row[5]}


def test_the_rviz_hosts_own_roscpp_node_hears_the_returned_robots_transforms(own_master):
    """librviz runs a roscpp node of its own in the host, and roscpp never registers again: after the robot
    (and the master on it) rebooted, RViz never heard the new robot's /tf, and every display in its frames
    lost its transform while the host still listed it as shown. The host adopts that node, and its master
    check registers it again: the transforms published after the return reach it."""
    master, procs = own_master
    package, script, params, last_service = NO_REGISTRAR['rviz_host']
    proc = procs.node(package, script, name='rviz_host_rejoin', namespace='temoto', params=params)
    wait_for(lambda: '/temoto/rviz_host_rejoin/list_displays' in registered(master, '/temoto/rviz_host_rejoin')[2]
             or not proc.alive(), 30, 'the RViz host to offer its services')
    assert proc.alive(), proc.log(40)
    [(name, uri)] = librviz_node(master, proc)
    before = registered(master, name)
    assert {'/tf', '/tf_static'} <= before[1], before
    master.stop()
    master.start()
    wait_for(lambda: registered(master, name) == before, HANG, 'every registration of %s back' % name)
    procs.node('temoto_test_nodes', 'tf_talker', name='robot_tf_after_reboot')
    talker_uri = lambda: proxy(master.uri, 2.0).lookupNode('/test_master_rejoin', '/robot_tf_after_reboot')[2]
    wait_for(lambda: talker_uri() in connected_publishers(uri, '/tf'), HANG,
             "librviz's node to receive /tf from a publisher that started after the master's restart")
    assert 'registered 0 publisher' not in proc.log(200)
    assert "librviz runs roscpp node %s" % name in proc.log(200), proc.log(40)


def nodes_of_pid(master, pid):
    """(name, URI) of the nodes process ``pid`` serves, as the master knows them."""
    publishers, subscribers, services = system_state(master)
    found = []
    for name in {n for _, nodes in publishers + subscribers + services for n in nodes}:
        code, _, uri = proxy(master.uri, 2.0).lookupNode('/test_master_rejoin', name)
        try:
            if code == 1 and proxy(uri, 2.0).getPid('/test_master_rejoin')[2] == pid:
                found.append((name, uri))
        except OSError:
            continue                   # a node that died: not ours
    return found


def er_nodes(master, pid):
    """The nodes `temoto ps` says process ``pid`` serves (the ER Manager's own account, through the CLI)."""
    out = subprocess.run(['temoto', 'ps', '--json'], env=master.env, capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    return [n for row in json.loads(out.stdout) if pid in row['pids'] for n in row['nodes']]


def test_a_roscpp_program_the_er_manager_runs_hears_a_topic_published_after_the_masters_restart(own_master):
    """A throttle on the station of a robot's topic (topic_tools, roscpp: its node is anonymous and never
    registers again). After the robot's reboot it heard nothing more, with no error anywhere. The ER
    Manager finds the nodes of what it runs by the ports they listen on, and its master check registers them
    again."""
    master, procs = own_master
    procs.node('temoto_er_manager', 'temoto_er_manager', namespace='temoto',
               params={'sys_allowlist': '[/usr/lib/topic_tools/throttle]', 'log_dir': str(procs.workdir)})
    sock = str(procs.workdir) + '/client.sock'
    procs.node('temoto_chaos', 'chaos_client', name='rejoin_client',
               params={'control_socket': sock, 'temoto_namespace': 'temoto'})
    wait_for(lambda: os.path.exists(sock), HANG, "the client's control socket")
    loaded = control_socket.ask(sock, {'op': 'load_process', 'topic': '/rejoin/status_out', 'rate': 5}, 30)
    assert loaded['ok'], loaded
    [(name, uri)] = wait_for(lambda: nodes_of_pid(master, loaded['pid']), HANG, "the throttle's node")
    before = registered(master, name)
    assert '/rejoin/status_out' in before[1], before    # its output is advertised at its first message
    wait_for(lambda: name in er_nodes(master, loaded['pid']), HANG, 'the ER Manager to find the node of its child')
    master.stop()
    master.start()
    wait_for(lambda: registered(master, name) == before, HANG, 'every registration of %s back' % name)
    procs.node('temoto_test_nodes', 'talker', name='talker_after_reboot', namespace='rejoin')
    talker_uri = lambda: proxy(master.uri, 2.0).lookupNode('/test_master_rejoin', '/rejoin/talker_after_reboot')[2]
    wait_for(lambda: talker_uri() in connected_publishers(uri, '/rejoin/status_out'), HANG,
             'the throttle to receive a topic whose publisher started after the master restarted')
    wait_for(lambda: '/rejoin/status_out_throttled' in registered(master, name)[0], HANG,
             'the throttle to pass on what it receives')


def test_a_bad_master_check_period_stops_the_node_naming_it(own_master):
    _, procs = own_master
    # no registration wait: it stops as soon as it has read the parameter, maybe before the wait sees it
    proc = procs.node('temoto_test_nodes', 'rr_node', name='rr_bad_period', params={'master_check_period': -1},
                      wait=False)
    wait_for(lambda: not proc.alive(), HANG, 'the node to stop')
    assert proc.returncode != 0
    assert 'parameter ~master_check_period: -1 is not a number of seconds' in proc.log(40), proc.log(40)


def test_a_new_master_that_learnt_one_registration_first_gets_all_the_others(own_master):
    """rospy registers a publisher made while the master is down the moment a new master answers. That
    master then knows the node, with one registration of many; the node's services could not be looked up,
    and the unloads owed to it were never delivered (chaos seed 17, step 4669). The periodic check is
    turned off here and run once by hand, after rospy's registration: the order the chaos history met."""
    master, procs = own_master
    sock = str(procs.workdir) + '/rr_partial.sock'
    node = RegistrarNode(procs, 'rr_partial', control_socket=sock, master_check_period=1e6)
    before = registered(master, '/rr_partial')
    master.stop()
    node.command(op='advertise', topic='/rr_partial/late')
    master.start()
    wait_for(lambda: '/rr_partial/late' in registered(master, '/rr_partial')[0], HANG,
             "rospy's own registration of the publisher made while the master was down")
    assert '/rr_partial/control' not in registered(master, '/rr_partial')[2]    # what the check must repair
    assert node.command(op='rejoin') == {'registered': True}
    publishers, subscribers, services = registered(master, '/rr_partial')
    assert (publishers, subscribers, services) == (before[0] | {'/rr_partial/late'}, before[1], before[2])
    assert node.command(op='rejoin') == {'registered': False}         # once is enough


def test_a_load_that_needs_a_new_status_channel_while_the_master_is_away_is_refused_at_once_naming_it(own_master):
    """rospy registers a new publisher in a loop that lasts until the master answers: a consumer's first
    load while the master was away (the robot rebooting) held the owner until the caller's deadline, and the
    caller heard of a deadline, not of the master. The load is refused at once, naming the master, and
    changes nothing; once the master is back the same load is served."""
    master, procs = own_master
    owner = RegistrarNode(procs, 'rr_owner', control_socket=str(procs.workdir) + '/owner.sock')
    consumer = RegistrarNode(procs, 'rr_consumer', control_socket=str(procs.workdir) + '/consumer.sock')
    first = consumer.call('rr_owner', 'warm')          # the consumer learns where the owner's services are
    assert 'id' in first, first
    assert consumer.unload(first['id']) == {}
    # the owner closes the consumer's unused status channel after its grace
    wait_for(lambda: '/temoto/rr_consumer/status' not in registered(master, '/rr_owner')[0], 30,
             "the owner to close the consumer's idle status channel")
    owner_before = registered(master, '/rr_owner')
    master.stop()
    refused = consumer.command(op='call', rr='rr_owner', name='while_away', deadline=20.0)
    assert 'does not answer' in refused.get('error', '') and master.uri.split('//')[1].rstrip('/') in \
        refused['error'], refused
    assert owner.registry()['server_queries'] == []
    assert 'while_away' not in owner.counts()['loads']
    master.start()
    wait_for(lambda: registered(master, '/rr_owner') == owner_before, HANG, 'the owner to register again')
    served = consumer.call('rr_owner', 'while_away')
    assert 'id' in served and owner.counts()['loads'].get('while_away') == 1, served


def test_a_display_shown_while_the_master_is_away_is_refused_at_once_naming_it(own_master):
    """RViz subscribes through roscpp, which waits for the master on the thread that renders: a display shown
    while the master was away (the robot rebooting) froze the operator's whole view until it came back, and
    the request ran out its deadline. The host refuses it at once, naming the master; what it shows stays."""
    master, procs = own_master
    procs.node('temoto_er_manager', 'temoto_er_manager', namespace='st',
               params={'temoto_namespace': 'st', 'log_dir': str(procs.workdir)})
    procs.node('temoto_output_manager', 'temoto_output_manager', namespace='st',
               params={'temoto_namespace': 'st', 'host/show_robot': 'false', 'host/show_grid': 'false'})
    sock = str(procs.workdir) + '/viewer.sock'
    procs.node('temoto_chaos', 'chaos_client', name='viewer',
               params={'control_socket': sock, 'temoto_namespace': 'rb', 'station_namespace': 'st'})
    wait_for(lambda: os.path.exists(sock), HANG, "the client's control socket")
    shown = control_socket.ask(sock, {'op': 'show_display', 'type': 'laser scan', 'topic': 'scan'}, 60)
    assert shown['ok'], shown
    master.stop()
    refused = control_socket.ask(sock, {'op': 'show_display', 'type': 'laser scan', 'topic': 'other_scan'}, 60)
    assert not refused['ok'] and 'does not answer' in refused['error'] and 'freeze' in refused['error'], refused
    held = control_socket.ask(sock, {'op': 'state'}, 10)['held']
    assert [info['failed'] for info in held.values()] == [''], held     # the first display is still shown
