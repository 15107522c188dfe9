"""``process_group.ended``: a process has ended only once every thread has, not when its leader reads as a
zombie (its other threads still hold its sockets). Against a real process whose leader exits first."""
import os
import signal
import subprocess
import sys
import textwrap

from temoto_core.process_group import ended
from temoto_core.wait import wait_for

HANG = 20.0
SYS_EXIT = {'x86_64': 60, 'aarch64': 93}    # exit(2) of one thread, not exit_group(2): the leader alone goes


def _leader_state(pid: int) -> str:
    with open('/proc/%d/stat' % pid) as f:
        return f.read().rsplit(')', 1)[1].split()[0]


def test_a_process_whose_leader_exited_has_not_ended_while_another_thread_runs():
    code = textwrap.dedent('''
        import ctypes, socket, sys, threading, time
        held = socket.socket()                       # what a killed manager's last threads still hold
        threading.Thread(target=time.sleep, args=(%r,)).start()
        print('ready', flush=True)
        ctypes.CDLL(None).syscall(%d, 0)
    ''' % (HANG * 3, SYS_EXIT[os.uname().machine]))
    child = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == 'ready'
        wait_for(lambda: _leader_state(child.pid) == 'Z', HANG, 'the leader thread to exit')
        assert not ended(child.pid), 'a thread still runs and holds the process\'s files'
        child.send_signal(signal.SIGKILL)
        wait_for(lambda: ended(child.pid), HANG, 'every thread gone')
    finally:
        child.kill()
        child.wait(HANG)
    assert ended(child.pid)
