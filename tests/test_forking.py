"""The fork rules both fork servers follow (temoto_core/forking.py), in processes of their own: pytest's
process has threads, and a fork from it is exactly what the rules forbid."""
import os
import signal
import subprocess
import sys
import textwrap

from temoto_core.process_group import ended
from temoto_core.wait import wait_for

HANG = 30.0


def run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-c', textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=HANG)


def test_a_process_with_threads_is_refused_and_a_single_threaded_one_forks():
    out = run('''
        import os, threading, time
        from temoto_core.forking import ForkRefused, fork, finish, thread_count
        release = threading.Event()
        t = threading.Thread(target=release.wait)
        t.start()
        try:
            fork(0)
            print('forked with a thread')
        except ForkRefused as e:
            print('refused:', e)
        release.set()
        t.join()
        # join returns once the thread's Python part is done; the kernel's thread goes a moment later
        for _ in range(1000):
            if thread_count() == 1:
                break
            time.sleep(0.001)
        pid = fork(0)
        if pid == 0:
            finish(7)
        print('child', os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]))
    ''')
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ['refused: the process has 2 threads; it forks only single-threaded',
                                       'child 7']


def test_a_child_ends_as_an_interpreter_would():
    """atexit runs, a SystemExit's code is kept, and an uncaught KeyboardInterrupt is a death by SIGINT."""
    out = run('''
        import atexit, os, sys
        from temoto_core.forking import fork, finish, run_main

        def child(body):
            pid = fork(0)
            if pid == 0:
                atexit.register(lambda: print('atexit ran', flush=True))
                finish(run_main(body, lambda e: print('printed', type(e).__name__, flush=True)))
            return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])

        def interrupted():
            raise KeyboardInterrupt

        print('exit', child(lambda: sys.exit(3)), flush=True)
        print('returned', child(lambda: 4), flush=True)
        print('interrupt', child(interrupted), flush=True)
        print('error', child(lambda: 1 / 0), flush=True)
    ''')
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ['atexit ran', 'exit 3', 'atexit ran', 'returned 4',
                                       'printed KeyboardInterrupt', 'atexit ran', 'interrupt %d' % -signal.SIGINT,
                                       'printed ZeroDivisionError', 'atexit ran', 'error 1']




def test_a_child_dies_with_the_parent_that_forked_it():
    parent = subprocess.Popen([sys.executable, '-c', textwrap.dedent('''
        import os, signal, time
        from temoto_core.forking import fork
        pid = fork(signal.SIGKILL)
        if pid == 0:
            signal.pause()
        print(pid, flush=True)
        signal.pause()
    ''')], stdout=subprocess.PIPE, text=True)
    child = 0
    try:
        child = int(parent.stdout.readline())
        assert os.path.exists('/proc/%d' % child)
        parent.kill()
        parent.wait(HANG)
        wait_for(lambda: ended(child), HANG, 'the child to die with its parent')
    finally:
        if child and not ended(child):
            os.kill(child, signal.SIGKILL)
        parent.kill()
        parent.wait(HANG)
        parent.stdout.close()
