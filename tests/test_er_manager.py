"""The ER Manager node end to end: a real roscore, a real manager process, real children.

Consumers are Resource Registrars in this test process (one hop away from the manager).
"""
import glob
import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
import xmlrpc.client

import pytest
import rosgraph
import rospy

from temoto_core import master_lookup as er_master
from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_core.rr import ResourceRegistrar
from temoto_core.srv import GetRegistry
from temoto_er_manager.cli import ps_main
from temoto_er_manager.interface import ERManagerInterface
from temoto_er_manager.srv import LoadProcess
from temoto_testing import ProcessGroupLauncher, wait_for

SRV = 'load_process'
MGR = 'temoto_er_manager'
_names = itertools.count(1)


def pid_gone(pid):
    """Not running and reaped (a zombie still has a /proc entry)."""
    return not os.path.exists('/proc/%d' % pid)


def start_manager(launcher, tmp, name=MGR, **params):
    base = {'sys_allowlist': '[echo]', 'registration_timeout': 8.0, 'sigint_grace': 2.0, 'sigterm_grace': 1.0,
            'log_dir': str(tmp)}
    base.update(params)
    return launcher.node(MGR, MGR, name=name, params=base)


# every test runs against a manager that starts Python nodes plainly and one that forks them from its zygote
MODES = {'plain': {}, 'preload': {'preload_python': 'true'}}


@pytest.fixture(scope='module', params=sorted(MODES))
def manager(request, ros_master, tmp_path_factory):
    launcher = ProcessGroupLauncher(ros_master.env, str(tmp_path_factory.mktemp('er_manager')))
    proc = start_manager(launcher, tmp_path_factory.mktemp('er_logs'), **MODES[request.param])
    proc.mode = request.param
    yield proc
    launcher.stop_all()


class Consumer:
    """A registrar in this process, with the status events it received."""

    def __init__(self, namespace='temoto'):
        self.rr = ResourceRegistrar('er_test_consumer_%d' % next(_names), namespace=namespace)
        self.events = []

    def load(self, executable, args='', package='temoto_er_manager', action='ros_execute', ns=''):
        req = LoadProcess._request_class(action=action, package_name=package, executable=executable, args=args,
                                         ros_namespace=ns)
        return self.rr.call(MGR, SRV, req, status_cb=lambda ev: self.events.append((time.monotonic(), ev)))

    def failed(self):
        return [ev for _, ev in self.events if ev.code == ResourceStatus.FAILED]


@pytest.fixture
def consumers(rospy_client, manager):
    made = []

    def make():
        c = Consumer()
        made.append(c)
        return c
    yield make
    for c in made:
        c.rr.shutdown()


def registry():
    return json.loads(rospy.ServiceProxy('/temoto/%s/registry' % MGR, GetRegistry)().json)


def processes():
    return json.loads(rospy.ServiceProxy('/temoto/%s/processes' % MGR, GetRegistry)().json)['processes']


def master_uri():
    return os.environ['ROS_MASTER_URI']


def node_pid(name):
    uri = er_master.lookup_node(master_uri(), name)
    return er_master.node_pid(uri) if uri else None


# ---------------------------------------------------------------------------------------------------

def test_two_consumers_share_one_process_and_unload_reaps_it(consumers):
    a, b = consumers(), consumers()
    ra = a.load('er_test_node', '__name:=shared_node')
    rb = b.load('er_test_node', '__name:=shared_node')
    assert ra.pid == rb.pid > 0
    assert node_pid('/shared_node') == ra.pid, 'the response comes after the node registered'
    assert os.path.isfile(ra.log_path)
    query = [q for q in registry()['server_queries'] if q['details'].get('pid') == ra.pid]
    assert len(query) == 1 and len(query[0]['consumers']) == 2
    a.rr.unload(ra.trr.resource_id)
    assert not pid_gone(ra.pid), 'still held by the second consumer'
    b.rr.unload(rb.trr.resource_id)
    assert pid_gone(ra.pid), 'unload returns once the process is stopped and reaped'
    assert not a.failed() and not b.failed(), 'an unload is never reported as a failure'


@pytest.mark.parametrize('how, reason', [
    ('sigkill', 'SIGKILL'), ('segv', 'SIGSEGV'), ('exit0', 'exited with code 0')])
def test_death_while_held_is_failed_to_every_consumer(consumers, how, reason):
    a, b = consumers(), consumers()
    args = '__name:=victim_%s _on_usr1:=%s' % (how, 'exit0' if how == 'exit0' else 'segv')
    ra, rb = a.load('er_test_node', args), b.load('er_test_node', args)
    os.kill(ra.pid, signal.SIGKILL if how == 'sigkill' else signal.SIGUSR1)
    wait_for(lambda: a.failed() and b.failed(), 10, 'FAILED at both consumers')
    for c, r in ((a, ra), (b, rb)):
        ev = c.failed()[0]
        assert ev.resource_id == r.trr.resource_id
        assert reason in ev.message and 'er_test_node' in ev.message, ev.message
    # a preloaded node's zygote reaps it just after the supervisor has recorded its exit, which the FAILED
    # may overtake (temoto_er_manager/supervisor.py): dead at once, gone from the process table a moment later
    wait_for(lambda: pid_gone(ra.pid), 10, 'the dead node reaped')
    a.rr.unload(ra.trr.resource_id)
    b.rr.unload(rb.trr.resource_id)


def test_launch_file_with_a_dying_node_is_detected(consumers):
    c = consumers()
    r = c.load('er_two_nodes.launch', ns='/launched')
    first, second = node_pid('/launched/first'), node_pid('/launched/inner/second')
    assert first and second, 'both nodes registered before the response'
    assert r.pid == first, 'a launch resource answers with its first node'
    t0 = time.monotonic()
    os.kill(second, signal.SIGKILL)
    wait_for(c.failed, 10, 'FAILED for the launch file')
    took = c.events[0][0] - t0
    assert took < 2.0, 'generous bound (the bench measures ~ms): %.3f s' % took
    msg = c.failed()[0].message
    assert 'node /launched/inner/second' in msg and 'SIGKILL' in msg and 'er_two_nodes.launch' in msg, msg
    assert '/launched/first' in msg, 'the message says which other nodes are stopped'
    wait_for(lambda: pid_gone(first) and pid_gone(second), 10, 'the rest of the launch stopped')
    c.rr.unload(r.trr.resource_id)


def test_launch_file_unload_stops_its_nodes(consumers):
    c = consumers()
    r = c.load('er_two_nodes.launch', ns='/launched2')
    nodes = [node_pid('/launched2/first'), node_pid('/launched2/inner/second')]
    c.rr.unload(r.trr.resource_id)
    assert all(pid_gone(p) for p in nodes), 'unload returns once every node is stopped and reaped'
    assert not c.failed()


def test_launch_file_load_returns_once_every_node_is_registered(consumers):
    c = consumers()
    t0 = time.monotonic()
    r = c.load('er_two_nodes.launch', 'delay:=1.5', ns='/slowlaunch')
    assert time.monotonic() - t0 >= 1.5
    [row] = [p for p in processes() if p['pid'] == r.pid]
    assert row['state'] == 'running' and row['label'] == 'temoto_er_manager/er_two_nodes.launch'
    assert row['node_names'] == ['/slowlaunch/first', '/slowlaunch/inner/second']
    assert [node_pid(n) for n in row['node_names']] == row['pids'] and row['pids'][0] == r.pid
    c.rr.unload(r.trr.resource_id)


def test_launch_file_node_failing_at_start_fails_the_load_and_stops_the_others(consumers):
    c = consumers()
    with pytest.raises(TemotoError) as err:
        c.load('er_two_nodes.launch', 'exit_second:=4', ns='/badlaunch')
    msg = str(err.value)
    assert 'node /badlaunch/inner/second' in msg and 'exited with code 4' in msg, msg
    wait_for(lambda: not [p for p in processes() if p['label'].endswith('er_two_nodes.launch') and
                          p['node_names'][0].startswith('/badlaunch/')], 5, 'resource gone')
    assert node_pid('/badlaunch/first') is None, 'the first node was stopped with the failed load'


def test_launch_file_params_names_remaps_env(consumers, rospy_client):
    rospy.set_param('/lp/grp/stale', 'old')
    c = consumers()
    r = c.load('er_features.launch', 'prefix:=xy topic:=renamed', ns='/lp')
    assert rospy.get_param('/lp/top_value') == 'xy_top' and rospy.get_param('/lp/loaded') == {'a': 1, 'b': ['x', 'y']}
    assert rospy.get_param('/lp/grp/inner_value') == 42 and rospy.get_param('/lp/grp/talker/private_value') == 'xy'
    assert rospy.get_param('/lp/grp/inc/included_by') == 'xy'
    assert not rospy.has_param('/lp/grp/stale'), 'clear_params of the group'
    [row] = [p for p in processes() if p['pid'] == r.pid]
    talker, listener = row['node_names']
    assert talker == '/lp/grp/talker' and listener.startswith('/lp/grp/inc/listener_')
    assert [node_pid(talker), node_pid(listener)] == row['pids'], 'the anonymous node was checked too'
    pubs = dict(rospy.get_master().getSystemState()[2][0])
    assert '/lp/grp/talker' in pubs.get('/lp/grp/renamed', []), 'remap chatter:=$(arg topic) in the group ns'
    assert 'er_test_node: ER_TEST_ENV=from_launch_xy' in open(r.log_path).read()
    c.rr.unload(r.trr.resource_id)


def test_python_nodes_come_from_the_zygote_only_with_preload(consumers, manager):
    c = consumers()
    r = c.load('er_test_node', '__name:=which_start')
    lr = c.load('er_two_nodes.launch', ns='/which_launch')
    rows = {row['pid']: row for row in processes()}
    preloaded = [p['preloaded'] for row in (rows[r.pid], rows[lr.pid]) for p in row['processes']]
    assert preloaded == [manager.mode == 'preload'] * 3, preloaded
    comm = open('/proc/%d/comm' % r.pid).read().strip()
    assert comm == ('er_test_node' if manager.mode == 'preload' else 'python'), 'ps shows the node by its script'
    c.rr.unload(r.trr.resource_id)
    c.rr.unload(lr.trr.resource_id)
    assert pid_gone(r.pid)


@pytest.mark.parametrize('executable, args, words', [
    ('no_such_node', '', 'no executable'),
    ('er_not_executable', '', 'not an executable file'),
    ('er_test_node', '_exit_at_start:=7', 'exited with code 7'),
])
def test_bad_loads_fail_clearly(consumers, executable, args, words):
    with pytest.raises(TemotoError) as err:
        consumers().load(executable, args)
    assert words in str(err.value)


def test_unknown_package(consumers):
    with pytest.raises(TemotoError, match="package 'nope_pkg' not found"):
        consumers().load('x', package='nope_pkg')


def test_shell_injection_does_nothing(consumers, tmp_path):
    c = consumers()
    marks = [tmp_path / n for n in ('semi', 'dollar', 'tick')]
    args = "__name:=inj ; touch %s $(touch %s) `touch %s`" % tuple(marks)
    r = c.load('er_test_node', args)
    assert node_pid('/inj') == r.pid
    c.rr.unload(r.trr.resource_id)
    # echo prints its arguments literally and exits at once, so this load fails as "exited before ready"
    with pytest.raises(TemotoError) as err:
        c.load('echo', args, package='', action='sys_execute')
    assert 'exited with code 0' in str(err.value) and '\n__name:=inj ; touch' in str(err.value)
    assert not any(m.exists() for m in marks)


def test_sys_execute_refused_unless_allowlisted(consumers, tmp_path):
    with pytest.raises(TemotoError, match='sys_allowlist'):
        consumers().load('touch', str(tmp_path / 'x'), package='', action='sys_execute')
    assert not (tmp_path / 'x').exists()


def test_a_process_being_stopped_is_listed_until_it_is_gone(consumers):
    """An unload stops a process in steps (SIGINT, SIGTERM, SIGKILL, each with its grace): until it is reaped
    it is still listed, as stopping. (It used to leave the list at once and run on for the graces: a live
    process in no entry, which the chaos checker saw after unloads.)"""
    c = consumers()
    r = c.load('er_test_node', '__name:=slow_stop_%d _ignore_sigint:=true' % next(_names))
    unload = threading.Thread(target=c.rr.unload, args=(r.trr.resource_id,), daemon=True)
    unload.start()
    looks = 0
    deadline = time.monotonic() + 30
    while unload.is_alive() and time.monotonic() < deadline:
        listed = [row for row in processes() if r.pid in row['pids']]
        if pid_gone(r.pid):
            break
        # alive after the list was read, so alive while it was read: it must have been in it
        assert listed, 'pid %d runs, but the ER Manager does not list it' % r.pid
        if listed[0]['state'] == 'stopping':
            looks += 1
        time.sleep(0.05)
    unload.join(30)
    assert not unload.is_alive() and pid_gone(r.pid)
    assert looks > 0, 'never seen while it was being stopped'
    assert not [row for row in processes() if r.pid in row['pids']]


def test_ps_lists_running_processes(consumers, capsys):
    c = consumers()
    r = c.load('er_test_node', '__name:=ps_node')
    lr = c.load('er_two_nodes.launch', ns='/ps_launch')
    assert ps_main([]) == 0
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if str(r.pid) in ln]
    assert line and 'er_test_node' in line[0] and '1' in line[0]
    assert r.log_path in out
    pids = '%d,%d' % (node_pid('/ps_launch/first'), node_pid('/ps_launch/inner/second'))
    rows = [ln for ln in out.splitlines() if 'er_two_nodes.launch' in ln]
    assert len(rows) == 1 and rows[0].startswith(pids) and lr.log_path in rows[0], out
    c.rr.unload(r.trr.resource_id)
    c.rr.unload(lr.trr.resource_id)


# -- manager lifetime: each test has its own manager -------------------------------------------------

@pytest.fixture(params=sorted(MODES))
def own_manager(request, ros_master, rospy_client, tmp_path):
    launcher = ProcessGroupLauncher(ros_master.env, str(tmp_path))
    started = []

    def start(**params):
        # its own node name and TeMoto namespace: it must not collide with the module's manager
        n = next(_names)
        proc = start_manager(launcher, tmp_path / 'logs', name='er_manager_%d' % n, temoto_namespace='own%d' % n,
                             **dict(MODES[request.param], **params))
        proc.mode = request.param
        started.append(proc)
        return proc, Consumer('own%d' % n)
    yield start
    launcher.stop_all()


def test_manager_sigint_leaves_no_process(own_manager, tmp_path):
    mgr, c = own_manager()
    try:
        node = c.load('er_test_node', '__name:=stay_a')
        launch = c.load('er_two_nodes.launch', ns='/stay_b')
        nodes = [node.pid, launch.pid, node_pid('/stay_b/inner/second')]
        everything = descendants(mgr.pid)     # with preload: the zygote too
        assert set(nodes) <= set(everything) and len(everything) == len(nodes) + (mgr.mode == 'preload')
        os.killpg(mgr.pid, signal.SIGINT)
        mgr.proc.wait(20)
        wait_for(lambda: all(pid_gone(p) for p in everything), 10, 'children gone after SIGINT')
    finally:
        c.rr.shutdown()


def test_manager_sigkill_leaves_no_process(own_manager):
    mgr, c = own_manager()
    try:
        node = c.load('er_test_node', '__name:=orphan_a')
        launch = c.load('er_two_nodes.launch', ns='/orphan_b')
        nodes = [node.pid, launch.pid, node_pid('/orphan_b/inner/second')]
        everything = descendants(mgr.pid)     # with preload: the zygote too
        assert set(nodes) <= set(everything) and len(everything) == len(nodes) + (mgr.mode == 'preload')
        os.kill(mgr.pid, signal.SIGKILL)      # the manager only, not its group: PDEATHSIG must do it
        mgr.proc.wait(5)
        wait_for(lambda: all(pid_gone(p) or _state(p) == 'Z' for p in everything),
                 10, 'children gone after SIGKILL of the manager')
    finally:
        c.rr.shutdown()


def test_stop_while_a_load_is_starting_leaks_nothing(own_manager, tmp_path):
    """The manager is stopped while a load waits for a node that never registers: nothing survives."""
    mgr, c = own_manager(registration_timeout=30.0)
    result = []
    try:
        t = threading.Thread(target=lambda: result.append(_try(lambda: c.load('er_test_node', '_register:=false'))))
        t.start()
        log_dir = tmp_path / 'logs'
        log = wait_for(lambda: [p for p in log_dir.glob('*er_test_node.log') if 'not registering' in p.read_text()],
                       15, 'child started')[0]
        assert log
        [pid] = [p for p in descendants(mgr.pid) if _is_test_node(p)]
        os.killpg(mgr.pid, signal.SIGINT)
        t.join(20)
        assert not t.is_alive() and isinstance(result[0], TemotoError)
        mgr.proc.wait(20)
        wait_for(lambda: pid_gone(pid), 5, 'starting child gone')
    finally:
        c.rr.shutdown()


def _try(fn):
    try:
        return fn()
    except Exception as e:
        return e


def descendants(root):
    """Live processes below ``root`` (children, and the zygote's children)."""
    parents = {}
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            parents[int(entry)] = er_master.parent_pid(int(entry))
    found, frontier = [], [root]
    while frontier:
        kids = [p for p, pp in parents.items() if pp in frontier and _state(p) not in ('Z', '')]
        found += kids
        frontier = kids
    return found


def _state(pid):
    try:
        return open('/proc/%d/stat' % pid).read().rsplit(')', 1)[1].split()[0]
    except OSError:
        return ''


def _is_test_node(pid):
    """Plain start: the script is in the command line; from the zygote: the process name is the script's."""
    try:
        return (open('/proc/%d/comm' % pid).read().strip() == 'er_test_node' or
                b'er_test_node' in open('/proc/%d/cmdline' % pid, 'rb').read())
    except OSError:
        return False


def test_interface_load_unload_and_update_callback(rospy_client, manager):
    er = ERManagerInterface()
    events = []
    er.register_update_callback(events.append)
    try:
        r = er.load('temoto_er_manager', 'er_test_node', args='__name:=iface_node')
        assert node_pid('/iface_node') == r.pid
        os.kill(r.pid, signal.SIGKILL)
        wait_for(lambda: events, 10, 'update callback')
        assert events[0].code == ResourceStatus.FAILED and 'SIGKILL' in events[0].message
        er.unload(r.trr.resource_id)
        with pytest.raises(TemotoError):
            er.unload(r.trr.resource_id)
    finally:
        er.shutdown()


def test_interface_default_policy_restarts_the_process(rospy_client, manager):
    er = ERManagerInterface()
    try:
        r = er.load('temoto_er_manager', 'er_test_node', args='__name:=restarted_node')
        os.kill(r.pid, signal.SIGKILL)
        new_id = wait_for(lambda: er.replacement_of(r.trr.resource_id), 15, 'reload')
        new_pid = wait_for(lambda: node_pid('/restarted_node') if node_pid('/restarted_node') != r.pid else None,
                           10, 'restarted node')
        assert new_pid != r.pid and er.holds(new_id)
    finally:
        er.shutdown()


CONSUMER_SCRIPT = '''
import sys, rospy
from temoto_core.rr import ResourceRegistrar
from temoto_er_manager.srv import LoadProcess
rospy.init_node("dying_consumer")
rr = ResourceRegistrar("dying_consumer")
print("calling", flush=True)
rr.call("temoto_er_manager", "load_process", LoadProcess._request_class(
    action="ros_execute", package_name="temoto_er_manager", executable="er_test_node",
    args="__name:=slow_node _start_delay:=1.5"))
print("loaded", flush=True)
rospy.spin()
'''


def test_consumer_dying_while_its_load_starts_leaks_nothing(manager, ros_master, tmp_path):
    """The consumer is SIGKILLed while the manager still waits for the node: once the load completes,
    the registrar finds the consumer dead and releases it, and the process is stopped."""
    log = open(tmp_path / 'consumer.log', 'wb')
    consumer = subprocess.Popen([sys.executable, '-c', CONSUMER_SCRIPT], env=ros_master.env, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        wait_for(lambda: any('__name:=slow_node' in t and 'er_test_node: starting' in t
                             for t in (p.read_text() for p in _er_logs(manager))), 20, 'slow node spawned')
        assert node_pid('/slow_node') is None, 'the consumer dies while the load is still starting'
        os.killpg(consumer.pid, signal.SIGKILL)
        consumer.wait(5)
        # The node's own log says when it is up (init_node done); polling the master instead could miss it,
        # since the registrar may release the dead consumer's reference a few ms after the load completes.
        pid = wait_for(lambda: _up_pid('/slow_node', manager), 10, 'slow node up')
        wait_for(lambda: pid_gone(pid), 20, 'process of the dead consumer stopped')
    finally:
        if consumer.poll() is None:
            os.killpg(consumer.pid, signal.SIGKILL)
            consumer.wait(5)
        log.close()


def _up_pid(node_name, manager_proc):
    """The pid er_test_node printed once ``node_name`` was up, from the ER Manager's per-process logs."""
    marker = 'er_test_node %s: up, pid ' % node_name
    for path in _er_logs(manager_proc):
        for line in path.read_text().splitlines():
            if line.startswith(marker):
                return int(line[len(marker):])
    return None


def _er_logs(manager_proc):
    argv = manager_proc.argv
    log_dir = [a.split(':=', 1)[1] for a in argv if a.startswith('_log_dir:=')][0]
    return [__import__('pathlib').Path(p) for p in glob.glob(os.path.join(log_dir, '*er_test_node.log'))]


def test_a_node_name_in_use_by_a_live_node_is_refused_and_that_node_lives_on(consumers, rospy_client):
    c = consumers()
    own = rospy.get_name()            # this test process is a live node the request tries to take over
    with pytest.raises(TemotoError) as err:
        c.load('er_test_node', '__name:=%s' % own.lstrip('/'))
    assert err.value.origin.code == ErrorCode.NAME_TAKEN and own in str(err.value)
    # a namespace that makes the full name collide is caught the same way
    held = c.load('er_test_node', '__name:=collide_me', ns='/tenant')
    with pytest.raises(TemotoError, match='/tenant/collide_me is already in use'):
        c.load('er_test_node', '__name:=collide_me _v:=2', ns='tenant')
    # nothing changed: the first holder's node is registered by the same pid, and this process still is
    assert node_pid('/tenant/collide_me') == held.pid and node_pid(own) == os.getpid()
    assert registry()['server_queries'][0]['consumers'] and len(registry()['server_queries']) == 1
    c.rr.unload(held.trr.resource_id)


def test_a_name_left_by_a_dead_node_whose_port_another_node_has_now_is_free(consumers, rospy_client):
    """A SIGKILLed node never unregisters. When its port goes to another node, that node answers at the dead one's
    URI: the name must still count as free (CI once refused a test's own restart so), and starting it must not
    shut down the node that has the port now."""

    master = xmlrpc.client.ServerProxy(rosgraph.get_master_uri())
    # the dead /ghost's registration, at the URI this process (a live node) has now
    code, _msg, _ = master.registerPublisher('/ghost', '/ghost/chatter', 'std_msgs/String', rospy.get_node_uri())
    assert code == 1
    c = consumers()
    node = c.load('er_test_node', '__name:=ghost')
    assert node_pid('/ghost') == node.pid and node_pid(rospy.get_name()) == os.getpid()
    c.rr.unload(node.trr.resource_id)
    wait_for(lambda: pid_gone(node.pid), 10, 'the ghost to stop')


def test_two_different_requests_for_one_explicit_name_cannot_kill_each_other(consumers):
    """``__name:=d _v:=1`` and ``__name:=d _v:=2`` at once: one starts, the other is refused (the master
    used to shut the first down when the second registered)."""
    c = consumers()
    results = {}

    def load(v):
        try:
            results[v] = c.load('er_test_node', '__name:=twin _v:=%d' % v)
        except TemotoError as e:
            results[v] = e
    threads = [threading.Thread(target=load, args=(v,)) for v in (1, 2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    loaded = [r for r in results.values() if not isinstance(r, TemotoError)]
    refused = [r for r in results.values() if isinstance(r, TemotoError)]
    assert len(loaded) == 1 and len(refused) == 1, results
    assert 'already in use' in str(refused[0])
    assert node_pid('/twin') == loaded[0].pid and not c.failed()
    c.rr.unload(loaded[0].trr.resource_id)
    wait_for(lambda: pid_gone(loaded[0].pid), 10, 'the twin to stop')


def test_a_crashed_node_is_removed_from_the_master(consumers):
    """`rosnode list` must not show a driver that died: its registrations are cleaned up (a SIGKILLed node
    never unregisters itself)."""
    c = consumers()
    r = c.load('er_test_node', '__name:=crash_and_vanish')
    assert '/crash_and_vanish' in er_master.registered_nodes(master_uri())
    os.kill(r.pid, signal.SIGKILL)
    wait_for(lambda: c.failed(), 10, 'FAILED at the consumer')
    wait_for(lambda: '/crash_and_vanish' not in er_master.registered_nodes(master_uri()), 10,
             'the dead node to leave the master')
    assert er_master.lookup_node(master_uri(), '/crash_and_vanish') is None
    c.rr.unload(r.trr.resource_id)
