"""temoto_core.node: SIGINT and SIGTERM stop a node cleanly whatever its main thread was doing.

rospy's own handler shuts down inside the signal handler and deadlocked a driver
that was publishing (see temoto_core/node.py). The first test pins the mechanism
without ROS: the callback must run while the main thread still holds a lock the
callback needs, which a handler-based design cannot do. The others stop real
nodes, in their own processes, many times over.
"""
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from temoto_testing import wait_for

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

HOLDS_A_LOCK = textwrap.dedent('''
    import os, signal, threading
    from temoto_core.node import on_signals
    lock = threading.Lock()
    seen = []
    def callback(signum):
        with lock:          # held by the main thread when the signal arrived
            seen.append((signum, threading.current_thread() is threading.main_thread()))
    on_signals(callback)
    with lock:
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGTERM)
        total = 0
        for i in range(200000):     # bytecodes: a Python-level handler would run here, lock held
            total += i
    for _ in range(1000):           # bounded: the relay thread needs the lock first
        if len(seen) == 2:
            break
        threading.Event().wait(0.01)
    print(sorted(seen), flush=True)
''')


def test_the_callback_runs_in_a_thread_after_the_main_thread_lets_go_of_its_lock():
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get('PYTHONPATH', ''))
    out = subprocess.run([sys.executable, '-c', HOLDS_A_LOCK], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(sorted([(int(signal.SIGINT), False), (int(signal.SIGTERM), False)]))


OK_FROM_A_SIDE_THREAD = textwrap.dedent('''
    import threading
    import rospy
    from temoto_core import node
    node._stop_signal.set()                  # as the relay does when SIGINT arrives
    seen = []
    side = threading.Thread(target=lambda: seen.append((node.ok(), rospy.core.is_shutdown_requested())))
    side.start()
    side.join(30)
    seen.append((node.ok(), rospy.core.is_shutdown_requested()))
    print(seen, flush=True)
''')


def test_only_the_main_thread_runs_the_shutdown_that_ok_starts():
    """A side thread's ok() that ran rospy's shutdown closed the topics between the main loop's ok() and its
    publish(): the SICK driver, its diagnostics thread polling ok(), exited 1 on SIGINT in CI."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get('PYTHONPATH', ''))
    out = subprocess.run([sys.executable, '-c', OK_FROM_A_SIDE_THREAD], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    # the side thread sees the stop and leaves rospy alone; the main thread then shuts it down
    assert out.stdout.strip().splitlines()[-1] == str([(False, False), (False, True)])


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_node_publishing_flat_out_from_its_main_thread_always_exits_cleanly(procs, rospy_client, sig):
    from std_msgs.msg import UInt8MultiArray
    received = []
    sub = rospy_client.Subscriber('/busy', UInt8MultiArray, lambda m: received.append(1), queue_size=10)
    try:
        for attempt in range(6):
            node = procs.node('temoto_test_nodes', 'busy_publisher', name='busy_publisher')
            before = len(received)
            # one message proves the publishing loop runs (what the signal must interrupt); beside two CPU
            # hogs its GIL-competing thread once kept the 21 this used to wait for from going out in 20 s
            wait_for(lambda: len(received) > before, 30, 'a message from busy_publisher')
            os.killpg(node.pid, sig)
            deadline = time.monotonic() + 15      # generous: a deadlock never ends, a clean stop takes < 1 s
            wait_for(lambda: node.returncode is not None or time.monotonic() > deadline, 16, 'the node to exit')
            assert node.returncode == 0, 'attempt %d: exit %r\n%s' % (attempt, node.returncode, node.log())
            assert node.stop() == 0
    finally:
        sub.unregister()


def test_a_spinning_node_stops_on_sigterm_and_runs_its_shutdown_hooks(procs, ros_master):
    """rr_node spins in temoto_core.node.spin(); SIGTERM must end it through rospy's shutdown."""
    from temoto_core.master import master_proxy
    node = procs.node('temoto_test_nodes', 'rr_node', name='spinner')
    master = master_proxy(ros_master.uri)
    assert '/spinner' in _node_names(master)
    os.killpg(node.pid, signal.SIGTERM)
    wait_for(lambda: node.returncode is not None, 15, 'rr_node to exit on SIGTERM')
    assert node.returncode == 0, node.log()
    # a clean rospy shutdown unregisters the node from the master
    wait_for(lambda: '/spinner' not in _node_names(master), 10, 'the node to leave the master')


def _node_names(master):
    code, _, state = master.getSystemState('/test')
    assert code == 1
    names = set()
    for group in state:
        for _, nodes in group:
            names.update(nodes)
    return names


def test_a_spinning_node_also_ends_when_rospy_is_shut_down_from_outside(procs, ros_master):
    """`rosnode kill` calls the node's slave API: spin() must return then too, with no signal at all."""
    import xmlrpc.client
    from temoto_core.master import master_proxy
    node = procs.node('temoto_test_nodes', 'rr_node', name='killed_remotely')
    code, _, uri = master_proxy(ros_master.uri).lookupNode('/test', '/killed_remotely')
    assert code == 1
    try:
        xmlrpc.client.ServerProxy(uri).shutdown('/test', 'asked by the test')
    except ConnectionError:
        pass        # rospy closes its XML-RPC server before replying, as rosnode kill knows
    wait_for(lambda: node.returncode is not None, 15, 'rr_node to exit after a remote shutdown')
    assert node.returncode == 0, node.log()


def test_a_node_stopped_the_moment_it_registers_exits_cleanly(procs):
    """Supervisors may stop a node as soon as the master knows it, before init_node has returned."""
    for attempt in range(5):
        node = procs.node('temoto_er_manager', 'er_minimal_node', args=['_spin:=temoto'], name='early_%d' % attempt)
        os.killpg(node.pid, signal.SIGINT)
        wait_for(lambda: node.returncode is not None, 15, 'the node to exit')
        assert node.returncode == 0, 'attempt %d: exit %r\n%s' % (attempt, node.returncode, node.log())


PORTLY = textwrap.dedent('''
    import rospy
    from std_msgs.msg import String
    from temoto_core.node import init_node, spin
    init_node('portly')
    rospy.Subscriber('/portly/only_mine', String, lambda msg: None)
    spin()
''')

STRANGER = textwrap.dedent('''
    import sys
    import rospy
    rospy.init_node('stranger', xmlrpc_port=int(sys.argv[1]))
    rospy.spin()
''')


def test_a_node_restarted_after_a_sigkill_does_not_shut_down_whoever_got_the_dead_ones_port(procs, ros_master,
                                                                                          tmp_path):
    """The master sends ``shutdown`` to the old URI of a name that registers again. If the killed node's port
    went to another node meanwhile, that node was shut down: init_node removes the stale registration first."""
    import xmlrpc.client
    from temoto_core import master_lookup
    master = xmlrpc.client.ServerProxy(ros_master.env['ROS_MASTER_URI'])
    (tmp_path / 'portly.py').write_text(PORTLY)
    (tmp_path / 'stranger.py').write_text(STRANGER)

    def subscribed():
        return any(t == '/portly/only_mine' and '/portly' in n for t, n in master.getSystemState('/t')[2][1])
    first = procs.command([sys.executable, str(tmp_path / 'portly.py')], 'portly')
    procs.wait_registered(first, ['/portly'], 20)
    wait_for(subscribed, 20, 'the subscription of the first portly')
    port = int(master.lookupNode('/t', '/portly')[2].rstrip('/').rsplit(':', 1)[1])
    os.killpg(first.pid, signal.SIGKILL)
    wait_for(lambda: not first.alive(), 10, 'the first portly to die')
    stranger = procs.command([sys.executable, str(tmp_path / 'stranger.py'), str(port)], 'stranger')
    procs.wait_registered(stranger, ['/stranger'], 20)
    assert master.lookupNode('/t', '/stranger')[2].rstrip('/').endswith(':%d' % port), 'the stranger has the port'
    assert master_lookup.node_pid(master.lookupNode('/t', '/portly')[2]) == stranger.pid, \
        'the stale registration of portly now answers with the stranger'
    second = procs.command([sys.executable, str(tmp_path / 'portly.py')], 'portly')
    # (the stale name is registered all along: wait for the new process behind it)
    wait_for(lambda: master_lookup.node_pid(master.lookupNode('/t', '/portly')[2]) == second.pid, 20,
             'the second portly to register')
    assert 'registration(s) a dead earlier /portly left' in second.log(), second.log()
    assert stranger.alive() and 'shutdown request' not in stranger.log(), stranger.log()
