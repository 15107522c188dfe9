"""temoto_core.warm_respawn: a node with a journal runs under a warm-respawn parent that forks it again at once
when it is killed, passes a stop on, and never leaves it behind. Real roscore, real processes."""
import os
import signal
import sys

from temoto_core import master_lookup
from temoto_core.master import RosMaster, free_port, master_proxy
from temoto_core.process_group import start_ticks
from temoto_core.processes import ProcessGroupLauncher
from temoto_testing import wait_for

PROBE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'temoto_test_nodes', 'nodes', 'respawn_probe')


def registered_pid(ros_master, name):
    uri = master_lookup.lookup_node(ros_master.uri, '/' + name)
    return master_lookup.node_pid(uri) if uri else None


def start(procs, tmp_path, name, *args, wait=True):
    """The probe as node ``name`` (each test its own: private parameters outlive a node on the master)."""
    proc = procs.command([sys.executable, PROBE, '__name:=' + name] + list(args), name)
    if wait:
        procs.wait_registered(proc, ['/' + name], 20)
    return proc


def test_a_killed_node_is_forked_again_by_its_parent_and_a_stop_ends_both(procs, ros_master, tmp_path):
    parent = start(procs, tmp_path, 'respawn_respawn', '_journal:=%s' % (tmp_path / 'j.sqlite'))
    first = wait_for(lambda: registered_pid(ros_master, 'respawn_respawn'), 20, 'the node to answer')
    assert first != parent.pid, 'the node runs in a child of the parent the launcher started'
    os.kill(first, signal.SIGKILL)
    second = wait_for(lambda: (lambda p: p not in (None, first) and p)(registered_pid(ros_master, 'respawn_respawn')),
                      20,
                      'the node forked again')
    assert parent.alive() and start_ticks(first) is None
    assert parent.stop() == 0, 'SIGINT is passed on; the node stops cleanly and the parent with it'
    assert start_ticks(second) is None


def test_a_node_that_exits_by_itself_is_not_forked_again(procs, ros_master, tmp_path):
    parent = start(procs, tmp_path, 'respawn_exit', '_journal:=%s' % (tmp_path / 'j.sqlite'), '_exit_with:=3',
                   wait=False)
    wait_for(lambda: not parent.alive(), 20, 'the parent to end with its node')
    assert parent.returncode == 3


def test_a_killed_parent_takes_its_node_with_it(procs, ros_master, tmp_path):
    parent = start(procs, tmp_path, 'respawn_orphan', '_journal:=%s' % (tmp_path / 'j.sqlite'))
    node = wait_for(lambda: registered_pid(ros_master, 'respawn_orphan'), 20, 'the node to answer')
    os.kill(parent.pid, signal.SIGKILL)
    wait_for(lambda: start_ticks(node) is None, 10, 'the node to die with its parent')


def test_without_a_journal_the_node_is_the_process_itself(procs, ros_master, tmp_path):
    proc = start(procs, tmp_path, 'respawn_plain')
    assert wait_for(lambda: registered_pid(ros_master, 'respawn_plain'), 20, 'the node to answer') == proc.pid


def test_a_node_that_crashes_as_it_starts_is_forked_again_ever_later(procs, ros_master, tmp_path):
    """A crash loop backs off (0.5 s, then 1 s, ...); a SIGKILL from outside does not (the first test)."""
    parent = start(procs, tmp_path, 'respawn_crash', '_journal:=%s' % (tmp_path / 'j.sqlite'), '_crash:=true',
                   wait=False)
    def log():
        with open(parent.log_path) as f:       # all of it: each crash writes a long stack dump
            return f.read()
    wait_for(lambda: 'killed by SIGSEGV; forking it again in 1.0 s' in log(), 30, 'the second back-off')
    assert 'killed by SIGSEGV; forking it again in 0.5 s' in log()
    assert parent.stop() is not None


def test_a_node_forked_again_after_its_master_started_again_has_the_parameters_it_started_with(tmp_path):
    """A new master has no parameters; without them the node would start as another node (its defaults)."""
    (tmp_path / 'ros').mkdir()
    master = RosMaster(str(tmp_path / 'ros'), port=free_port()).start()
    (tmp_path / 'logs').mkdir()
    launcher = ProcessGroupLauncher(master.env, str(tmp_path / 'logs'))
    echo = tmp_path / 'greeting.txt'
    try:
        # as a launch file puts them: on the master, before the node starts
        master_proxy(master.uri).setParam('/test', '/respawn_params', {
            'journal': str(tmp_path / 'j.sqlite'), 'greeting': 'hello', 'echo_to': str(echo)})
        parent = launcher.command([sys.executable, PROBE, '__name:=respawn_params'], 'respawn_params')

        def node_pid():
            uri = master_lookup.lookup_node(master.uri, '/respawn_params')
            return master_lookup.node_pid(uri) if uri else None
        first = wait_for(node_pid, 20, 'the node to answer')
        # it registers (init_node) before it writes what it read: the file comes a moment later
        wait_for(lambda: echo.exists() and echo.read_text(), 20, 'the node to write what it read')
        assert echo.read_text() == 'hello'
        echo.unlink()
        master.stop()
        master.start()                       # the same address, no parameters
        os.kill(first, signal.SIGKILL)
        wait_for(echo.exists, 20, 'the node forked again to write what it read (without its parameters it writes nothing)')
        wait_for(lambda: echo.read_text(), 5, 'the node to write what it read')
        assert echo.read_text() == 'hello', 'the respawned node started without its parameters'
        assert parent.alive()
    finally:
        launcher.stop_all()
        master.stop()


def test_a_wedged_node_writes_its_stacks_kills_itself_and_is_forked_again(procs, ros_master, tmp_path):
    """Its watchdog (temoto_core/watchdog.py) finds a lock every thread needs held for good: the node says so
    with every thread's stack, and SIGKILLs itself; its warm-respawn parent forks it again at once."""
    marker = tmp_path / 'wedged'
    parent = start(procs, tmp_path, 'respawn_wedge', '_journal:=%s' % (tmp_path / 'j.sqlite'),
                   '_wedge_once:=%s' % marker, '_watchdog_bound:=1.0')
    # the wedged incarnation may be killed and forked again before its registration is read: it names itself
    first = int(wait_for(lambda: marker.exists() and marker.read_text(), 20, 'the node to wedge'))
    second = wait_for(lambda: (lambda p: p not in (None, first) and p)(registered_pid(ros_master, 'respawn_wedge')),
                      30, 'the wedged node killed and forked again')
    assert start_ticks(first) is None and parent.alive()
    with open(parent.log_path) as f:
        log = f.read()
    assert '[temoto watchdog] pid %d is wedged: the logging module lock was not free' % first in log, log
    assert 'in hold_the_logging_lock_for_good' in log, 'the stacks say where it hung'
    assert 'the node (pid %d) was killed by SIGKILL; forking it again' % first in log
    assert parent.stop() == 0
    assert start_ticks(second) is None
