"""stop_process_group: a process that does not stop on SIGINT or SIGTERM writes where it hung before it is
killed, also when it is not the group's leader (the node a warm-respawn parent forked, temoto_core/warm_respawn.py).
The chaos history of seed 17 had a wedged ER Manager whose log ended with its parent's stack alone."""
import os
import subprocess
import sys
import textwrap

from temoto_core.process_group import group_members
from temoto_core.processes import dump_stacks, stop_process_group
from temoto_testing import wait_for

# a leader that forks a child and waits for it, as warm_respawn.py does; both ignore SIGINT and SIGTERM, and the
# child registers its stack dump on SIGUSR1, as temoto_core.node.init_node does
WEDGED_PAIR = textwrap.dedent('''
    import faulthandler, os, signal, sys, threading
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    child = os.fork()
    if child == 0:
        faulthandler.register(signal.SIGUSR1, all_threads=True)
        def wedged_in_here():
            print('child ready', flush=True)
            threading.Event().wait()
        wedged_in_here()
    os.waitpid(child, 0)
''')


def start_wedged_pair(log_path):
    """The pair, started in a session of its own; returns once the child runs."""
    with open(log_path, 'wb') as log:
        proc = subprocess.Popen([sys.executable, '-c', WEDGED_PAIR], stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
    try:
        wait_for(lambda: b'child ready' in log_path.read_bytes(), 20, 'the child to start')
    except TimeoutError:
        os.killpg(proc.pid, 9)
        proc.wait(10)
        raise
    return proc


def test_a_wedged_child_of_the_group_leader_writes_its_stack_before_it_is_killed(tmp_path):
    log_path = tmp_path / 'pair.log'
    proc = start_wedged_pair(log_path)
    try:
        stop_process_group(proc, sigint_grace=0.2, sigterm_grace=0.2)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 9)
            proc.wait(10)
    assert proc.returncode is not None
    wait_for(lambda: not group_members(proc.pid), 10, 'no member of the group left')
    text = log_path.read_text(errors='replace')
    assert 'in wedged_in_here' in text, text


def test_stacks_are_asked_only_of_the_processes_that_catch_the_signal(tmp_path):
    """``dump_stacks`` (a chaos run that found a violation, before it stops anything): the wedged child
    writes its stack and keeps running; the leader, which does not catch SIGUSR1, is not killed by it."""
    log_path = tmp_path / 'pair.log'
    proc = start_wedged_pair(log_path)
    try:
        [child] = group_members(proc.pid, exclude=proc.pid)
        assert dump_stacks([proc.pid]) == [child]
        wait_for(lambda: 'in wedged_in_here' in log_path.read_text(errors='replace'), 20, 'the child\'s stack')
        assert proc.poll() is None and group_members(proc.pid, exclude=proc.pid) == [child]
    finally:
        os.killpg(proc.pid, 9)
        proc.wait(10)
    wait_for(lambda: not group_members(proc.pid), 10, 'no member of the group left')
