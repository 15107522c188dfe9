"""The node watchdog (temoto_core/watchdog.py): a lock every thread of a node needs, held for good, makes the
node write every thread's stack and kill itself, instead of answering nothing for ever (the chaos history of
seed 17 twice had a robot ER Manager wedged like this, with no trace of where)."""
import signal
import threading

import pytest

from temoto_core import watchdog
from temoto_testing import wait_for
from rr_helpers import RegistrarNode

HANG = 20.0


def held_for_good_by_a_thread(lock, release):
    lock.acquire()
    release.wait(HANG)
    lock.release()


def test_a_lock_held_past_the_bound_wedges_the_node_with_every_stack_written(capfd):
    lock, release, why = threading.Lock(), threading.Event(), []
    holder = threading.Thread(target=held_for_good_by_a_thread, args=(lock, release), daemon=True)
    holder.start()
    wait_for(lock.locked, HANG, 'the holder to take the lock')
    dog = watchdog.Watchdog(bound=0.3, period=0.1, on_wedged=why.append)
    dog.watch('the test lock', lock)
    dog.start()
    try:
        wait_for(lambda: why, HANG, 'the watchdog to find the node wedged')
    finally:
        dog.stop()
        release.set()
        holder.join(HANG)
    assert why[0].startswith('the test lock was not free for 0.'), why
    err = capfd.readouterr().err
    assert 'is wedged: the test lock was not free' in err
    assert 'in held_for_good_by_a_thread' in err, 'the stacks say which thread holds it'


def test_locks_that_are_only_busy_and_unwatched_locks_do_not_wedge_the_node():
    busy, dropped, why = threading.Lock(), threading.Lock(), []
    dog = watchdog.Watchdog(bound=0.5, period=0.05, on_wedged=why.append)
    dog.watch('a busy lock', busy)
    dog.watch('a lock no longer watched', dropped)
    dog.unwatch('a lock no longer watched')
    dropped.acquire()                          # held for good, but nobody watches it any more
    dog.start()
    try:
        for _ in range(20):                    # held for a tenth of the bound each time, 20 times
            with busy:
                threading.Event().wait(0.05)
        assert dog.check() == ''
    finally:
        dog.stop()
        dropped.release()
    assert why == []


def test_an_old_lock_unwatched_under_a_name_a_new_lock_has_taken_leaves_the_new_one_watched():
    """A registrar made again under the same name before the old one shut down: the old one's shutdown must
    not end the new one's watch."""
    old, new = threading.Lock(), threading.Lock()
    dog = watchdog.Watchdog(bound=0.2, period=0.1, on_wedged=lambda why: None)
    dog.watch('the lock of registrar r', old)
    dog.watch('the lock of registrar r', new)
    dog.unwatch('the lock of registrar r', old)
    new.acquire()
    try:
        assert dog.check().startswith('the lock of registrar r was not free')
    finally:
        new.release()


def test_a_bound_shorter_than_the_period_is_refused():
    with pytest.raises(ValueError, match='period'):
        watchdog.Watchdog(bound=0.5, period=1.0)


def test_a_wedged_registrar_node_kills_itself_naming_its_registrar(rospy_client, procs):
    """Across processes: the registrar's lock is watched in a real node."""
    node = RegistrarNode(procs, 'rr_wedged', watchdog_bound=1.0)
    assert node.command(op='wedge') == {}
    wait_for(lambda: not node.process.alive(), HANG, 'the wedged node to kill itself')
    assert node.process.returncode == -signal.SIGKILL
    with open(node.process.log_path) as f:
        log = f.read()
    assert 'is wedged: the lock of registrar' in log and 'rr_wedged' in log, log[-3000:]
    assert 'in hold_for_good' in log


class ResumedFromAStop:
    """A lock as the watchdog sees it in a process SIGSTOPped longer than the bound: the first wait times
    out as the process resumes, and the holder releases it a moment later."""

    def __init__(self):
        self.tries = 0

    def acquire(self, timeout):
        self.tries += 1
        return self.tries > 1

    def release(self):
        pass


def test_a_process_resumed_after_a_long_stop_is_not_taken_for_wedged():
    lock, why = ResumedFromAStop(), []
    dog = watchdog.Watchdog(bound=0.3, period=0.1, on_wedged=why.append)
    dog.watch('a lock held as the process was stopped', lock)
    assert dog.check() == '' and lock.tries == 2


# the nodes that handle their signals themselves, and so call rospy.init_node, then node.after_init_node
OWN_INIT = {
    'rviz_host': ('temoto_output_manager', 'rviz_host', {'show_robot': 'false', 'show_grid': 'false'}),
    'action_engine': ('temoto_action_engine', 'temoto_action_engine', {'temoto_namespace': 'temoto'}),
}


@pytest.mark.parametrize('which', sorted(OWN_INIT))
def test_a_node_with_its_own_init_reads_its_watchdog_bound_and_refuses_a_bad_one(rospy_client, procs, which):
    """The RViz host and the action engine get the watchdog too: a bound that is not a number of seconds
    stops them, naming the parameter, as it stops any other node."""
    package, script, params = OWN_INIT[which]
    proc = procs.node(package, script, name=which + '_bad_bound', namespace='temoto',
                      params=dict(params, watchdog_bound='soon'), wait=False)   # it stops at once
    wait_for(lambda: not proc.alive(), HANG, '%s to stop' % which)
    assert proc.returncode != 0
    assert "parameter ~watchdog_bound: 'soon' is not a number of seconds" in proc.log(60), proc.log(60)
