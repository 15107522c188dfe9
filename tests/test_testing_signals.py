"""temoto_testing/signals.py: a stopped process is stopped in every thread when ``stop`` returns."""
import os
import signal
import subprocess
import sys

from temoto_testing import signals, wait_for

# a process whose threads all burn CPU: each must be stopped, not only the one that took the signal
SPINNERS = '''
import threading
def spin():
    while True:
        pass
for _ in range(3):
    threading.Thread(target=spin, daemon=True).start()
print('spinning', flush=True)
spin()
'''


def _states(pid):
    states = []
    for tid in os.listdir('/proc/%d/task' % pid):
        with open('/proc/%d/task/%s/stat' % (pid, tid)) as f:
            stat = f.read()
        states.append(stat[stat.rindex(')') + 2])
    return states


def _spinners(new_group):
    proc = subprocess.Popen([sys.executable, '-c', SPINNERS], stdout=subprocess.PIPE, text=True,
                            start_new_session=new_group)
    assert proc.stdout.readline().strip() == 'spinning'
    return proc


def test_stop_returns_once_every_thread_is_stopped_and_the_process_runs_again_on_sigcont():
    proc = _spinners(new_group=False)
    try:
        signals.stop(proc.pid)
        states = _states(proc.pid)
        assert len(states) == 4 and set(states) == {'T'}, states
        os.kill(proc.pid, signal.SIGCONT)
        wait_for(lambda: 'T' not in _states(proc.pid), 10, 'every thread to run again')
    finally:
        proc.kill()
        proc.wait(timeout=10)


def test_stop_of_a_group_stops_every_process_of_it():
    leader = _spinners(new_group=True)
    try:
        signals.stop(leader.pid, group=True)
        assert signals.group_members(leader.pid) == [leader.pid]
        assert set(_states(leader.pid)) == {'T'}
        os.killpg(leader.pid, signal.SIGCONT)
    finally:
        os.killpg(leader.pid, signal.SIGKILL)
        leader.wait(timeout=10)
