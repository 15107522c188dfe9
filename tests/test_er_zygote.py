"""The preload zygote: a Python script forked from it behaves like one started plainly.

Supervisor level (no ROS master) except the last test, which kills the zygote of a real ER Manager.
"""
import json
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from temoto_testing import ProcessGroupLauncher, wait_for
from temoto_er_manager.supervisor import ProcessExitedEarly, ProcessSpec, ProcessSupervisor

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

PROBE = '''#!/usr/bin/env python3
import sys
PRELOADED = 'rospy' in sys.modules          # before this script imports anything
import os, signal, time
mode = sys.argv[1]
if mode == 'report':
    import json, rospy, rospy.names, numpy
    print(json.dumps({'argv': sys.argv, 'cwd': os.getcwd(), 'foo': os.environ.get('ZY_FOO'),
                      'secret': os.environ.get('ZY_ONLY_IN_MANAGER'), 'main': __name__, 'path0': sys.path[0],
                      'preloaded': PRELOADED, 'ns': rospy.get_namespace(), 'mappings': rospy.names.get_mappings(),
                      'random': int(numpy.random.randint(1 << 30)), 'stdin': sys.stdin.read(),
                      'comm': open('/proc/self/comm').read().strip(), 'sid': os.getsid(0) == os.getpid()}))
    print('to stderr', file=sys.stderr)
elif mode.startswith('exit:'):
    sys.exit(int(mode[5:]))
elif mode == 'exitmsg':
    sys.exit('bad configuration')
elif mode == 'raise':
    raise ValueError('probe failure')
elif mode == 'kbint':
    raise KeyboardInterrupt
elif mode == 'unflushed':
    sys.stdout.write('unflushed line\\n')
    os.kill(os.getpid(), signal.SIGKILL)
elif mode == 'finish':
    import atexit, threading
    atexit.register(lambda: print('atexit ran', flush=True))
    threading.Thread(target=lambda: (time.sleep(0.3), print('thread done', flush=True))).start()
elif mode == 'group':
    import subprocess
    print('grandchild', subprocess.Popen(['sleep', '60']).pid, flush=True)
    time.sleep(60)
else:
    print('up', flush=True)
    time.sleep(60)
'''

THREADED_MODULE = 'import threading, time\nthreading.Thread(target=time.sleep, args=(60,), daemon=True).start()\n'


def gone(pid):
    return not os.path.exists('/proc/%d' % pid)


@pytest.fixture(scope='module')
def probe(tmp_path_factory):
    d = tmp_path_factory.mktemp('probe')
    path = d / 'zy_probe'
    path.write_text(PROBE)
    path.chmod(0o755)
    return str(path)


@pytest.fixture(scope='module')
def zsup():
    exits = []
    s = ProcessSupervisor(lambda p, info: exits.append(info), sigint_grace=1.0, sigterm_grace=1.0,
                          preload_modules=['rospy', 'numpy', 'std_msgs.msg'], preload_log='/dev/null')
    s.exits = exits
    yield s
    zygote = s._zygote
    s.shutdown()
    assert zygote is not None and gone(zygote.pid), 'the zygote was used throughout, and shutdown ends it'


def pspec(tmp_path, probe, mode, name='p', preloadable=True, **env):
    e = dict(os.environ, ZY_FOO='bar', **env)
    return ProcessSpec(argv=[sys.executable, probe, mode], env=e, log_path=str(tmp_path / ('%s.log' % name)),
                       cwd=str(tmp_path), label=name, preloadable=preloadable)


def run_to_exit(sup, s):
    proc = sup.start(s)
    with proc.cond:
        assert proc.cond.wait_for(lambda: proc.exit_info is not None, 20), 'exit within 20 s'
    return proc


def test_argv_env_cwd_stdio_namespace_and_remaps(zsup, tmp_path, probe):
    env = dict(os.environ, ZY_FOO='bar', ROS_NAMESPACE='/zns')
    os.environ['ZY_ONLY_IN_MANAGER'] = 'x'    # in the zygote's environment (it started earlier), not in the request
    try:
        reports = []
        for i in range(2):
            s = ProcessSpec(argv=[sys.executable, probe, 'report', 'chatter:=talk', '__name:=probe', '__ns:=/zns'],
                            env=env, log_path=str(tmp_path / ('r%d.log' % i)), cwd=str(tmp_path), preloadable=True)
            proc = run_to_exit(zsup, s)
            assert proc.zygote is not None and proc.exit_info.returncode == 0
            text = open(s.log_path).read()
            reports.append(json.loads(text.splitlines()[1]))
            assert 'to stderr' in text, 'stderr goes to the log too'
    finally:
        del os.environ['ZY_ONLY_IN_MANAGER']
    r = reports[0]
    assert r['preloaded'], 'rospy was imported before the script ran'
    assert r['argv'] == [probe, 'report', 'chatter:=talk', '__name:=probe', '__ns:=/zns']
    assert r['cwd'] == str(tmp_path) and r['foo'] == 'bar' and r['secret'] is None
    assert r['main'] == '__main__' and r['path0'] == os.path.dirname(probe)
    assert r['ns'] == '/zns/', "rospy.names re-read ROS_NAMESPACE/__ns in the child"
    assert r['mappings'].get('chatter') == 'talk' and r['mappings'].get('__name') == 'probe'
    assert r['stdin'] == '' and r['comm'] == 'zy_probe' and r['sid']
    assert reports[0]['random'] != reports[1]['random'], 'numpy.random reseeded per child'


# mode -> returncode, words in the reason, words in the log tail (plain and zygote starts must agree)
EXITS = [
    ('exit:3', 3, 'exited with code 3', ''),
    ('exitmsg', 1, 'exited with code 1', 'bad configuration'),
    ('raise', 1, 'exited with code 1', 'ValueError: probe failure'),
    ('kbint', -signal.SIGINT, 'SIGINT', 'KeyboardInterrupt'),
    ('unflushed', -signal.SIGKILL, 'SIGKILL', 'unflushed line'),
    ('finish', 0, 'exited with code 0', 'thread done\natexit ran'),
]


@pytest.mark.parametrize('mode, rc, reason, tail', EXITS, ids=[e[0] for e in EXITS])
def test_exit_status_and_log_like_a_plain_start(zsup, tmp_path, probe, mode, rc, reason, tail):
    infos = {}
    for preloadable in (False, True):
        s = pspec(tmp_path, probe, mode, name='%s-%s' % (mode, preloadable), preloadable=preloadable)
        proc = run_to_exit(zsup, s)
        assert (proc.zygote is not None) == preloadable
        infos[preloadable] = proc.exit_info
    for info in infos.values():
        assert info.returncode == rc and reason in info.reason and tail in info.log_tail, info.message()
        assert not info.intentional and info.command.endswith('zy_probe ' + mode)
    assert infos[True].log_tail.splitlines()[1:] == infos[False].log_tail.splitlines()[1:], \
        'same output, tracebacks included (the zygote frames are not shown)'
    wait_for(lambda: infos[True] in zsup.exits, 5, 'reported through on_exit like any child')


def test_signal_death_and_stop_of_the_group(zsup, tmp_path, probe):
    proc = zsup.start(pspec(tmp_path, probe, 'sleep', 'segv'))
    wait_for(lambda: 'up' in open(proc.spec.log_path).read(), 10, 'probe up')
    os.kill(proc.pid, signal.SIGSEGV)
    with proc.cond:
        proc.cond.wait_for(lambda: proc.exit_info is not None, 10)
    assert proc.exit_info.returncode == -signal.SIGSEGV and 'SIGSEGV' in proc.exit_info.message()
    wait_for(lambda: gone(proc.pid), 5, 'reaped by the zygote after the exit was recorded')

    proc = zsup.start(pspec(tmp_path, probe, 'group', 'group'))
    line = wait_for(lambda: [ln for ln in open(proc.spec.log_path) if ln.startswith('grandchild')], 10, 'up')[0]
    grandchild = int(line.split()[1])
    assert os.getpgid(grandchild) == proc.pid, 'the child leads its own group'
    info = zsup.stop(proc)
    assert info.intentional and info.returncode == -signal.SIGINT
    assert gone(proc.pid), 'stop returns once the zygote reaped it'
    wait_for(lambda: gone(grandchild) or open('/proc/%d/stat' % grandchild).read().split()[2] == 'Z', 5,
             'the whole group stopped')


def test_exit_while_starting_fails_the_wait(zsup, tmp_path, probe):
    proc = zsup.start(pspec(tmp_path, probe, 'exit:4', 'early'))
    with pytest.raises(ProcessExitedEarly, match='exited with code 4'):
        zsup.wait_ready(proc, lambda p: False, 10)


def test_incompatible_environment_starts_plainly(zsup, tmp_path, probe):
    proc = zsup.start(pspec(tmp_path, probe, 'sleep', 'pp', PYTHONPATH='/nonexistent'))
    assert proc.zygote is None and proc.popen is not None
    zsup.stop(proc)


def test_zygote_death_falls_back_and_reports_its_children(tmp_path, probe, caplog):
    exits = []
    sup = ProcessSupervisor(lambda p, info: exits.append(info), sigint_grace=1.0, sigterm_grace=1.0,
                            preload_modules=['rospy'], preload_log=str(tmp_path / 'z.log'))
    try:
        proc = sup.start(pspec(tmp_path, probe, 'sleep', 'victim'))
        zygote = proc.zygote
        assert zygote is not None
        with caplog.at_level(logging.WARNING, logger='temoto_er_manager.supervisor'):
            os.kill(zygote.pid, signal.SIGKILL)
            wait_for(lambda: exits, 10, 'the child died with the zygote and was reported')
        assert exits[0].pid == proc.pid and 'preload zygote died' in exits[0].reason
        assert 'Python nodes start plainly from now on' in caplog.text
        wait_for(lambda: gone(zygote.pid), 5, 'the zygote reaped')
        after = sup.start(pspec(tmp_path, probe, 'exit:5', 'after'))
        assert after.zygote is None
        with after.cond:
            after.cond.wait_for(lambda: after.exit_info is not None, 10)
        assert after.exit_info.returncode == 5
    finally:
        sup.shutdown()


def test_a_threaded_zygote_refuses_to_fork_and_the_node_starts_plainly(tmp_path, probe, caplog):
    (tmp_path / 'zy_threaded.py').write_text(THREADED_MODULE)
    env = dict(os.environ, PYTHONPATH=str(tmp_path) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    sup = ProcessSupervisor(preload_modules=['zy_threaded'], preload_log=str(tmp_path / 'z.log'), preload_env=env)
    try:
        with caplog.at_level(logging.WARNING, logger='temoto_er_manager.supervisor'):
            proc = sup.start(pspec(tmp_path, probe, 'exit:6', 'threaded', PYTHONPATH=env['PYTHONPATH']))
        assert proc.zygote is None and 'it forks only single-threaded' in caplog.text
        with proc.cond:
            proc.cond.wait_for(lambda: proc.exit_info is not None, 10)
        assert proc.exit_info.returncode == 6
    finally:
        sup.shutdown()


def test_children_and_zygote_die_with_a_sigkilled_supervisor(tmp_path, probe):
    script = textwrap.dedent('''
        import os, sys, time
        sys.path.insert(0, %r)
        from temoto_er_manager.supervisor import ProcessSpec, ProcessSupervisor
        s = ProcessSupervisor(preload_modules=[], preload_log=%r)
        p = s.start(ProcessSpec([sys.executable, %r, 'sleep'], dict(os.environ), %r, preloadable=True))
        print(p.pid, p.zygote.pid, flush=True)
        time.sleep(60)
    ''' % (ROOT, str(tmp_path / 'z.log'), probe, str(tmp_path / 'c.log')))
    host = subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE, start_new_session=True)
    try:
        child, zygote = map(int, host.stdout.readline().split())
        assert not gone(child) and not gone(zygote)
        os.kill(host.pid, signal.SIGKILL)
        host.wait(5)
        for pid in (zygote, child):
            wait_for(lambda: gone(pid) or open('/proc/%d/stat' % pid).read().rsplit(')', 1)[1].split()[0] == 'Z',
                     5, 'pid %d killed' % pid)
    finally:
        host.kill()
        host.wait(5)
        host.stdout.close()


# -- a real manager whose zygote dies ---------------------------------------------------------------

def test_manager_zygote_death_fails_the_node_and_falls_back(ros_master, rospy_client, tmp_path):
    from temoto_core.msg import ResourceStatus
    from temoto_core.rr import ResourceRegistrar
    from temoto_er_manager.srv import LoadProcess
    import rospy
    from temoto_core.srv import GetRegistry
    launcher = ProcessGroupLauncher(ros_master.env, str(tmp_path))
    rr = ResourceRegistrar('zy_consumer', namespace='zyg')
    events = []
    try:
        launcher.node('temoto_er_manager', 'temoto_er_manager', name='er_zyg',
                      params={'temoto_namespace': 'zyg', 'preload_python': 'true', 'log_dir': str(tmp_path / 'logs'),
                              'sigint_grace': 1.0, 'sigterm_grace': 1.0})

        def load(name):
            req = LoadProcess._request_class(action='ros_execute', package_name='temoto_er_manager',
                                             executable='er_test_node', args='__name:=' + name)
            return rr.call('temoto_er_manager', 'load_process', req, status_cb=events.append)

        def rows():
            srv = rospy.ServiceProxy('/zyg/temoto_er_manager/processes', GetRegistry)
            return {r['pid']: r['processes'][0] for r in json.loads(srv().json)['processes']}
        first = load('zy_first')
        assert rows()[first.pid]['preloaded']
        zygote = int(open('/proc/%d/stat' % first.pid).read().rsplit(')', 1)[1].split()[1])
        assert 'zygote' in open('/proc/%d/cmdline' % zygote, 'rb').read().decode()
        t0 = time.monotonic()
        os.kill(zygote, signal.SIGKILL)
        wait_for(lambda: [e for e in events if e.code == ResourceStatus.FAILED], 10, 'FAILED for the node')
        assert time.monotonic() - t0 < 5.0
        msg = [e for e in events if e.code == ResourceStatus.FAILED][0].message
        assert 'preload zygote died' in msg and 'er_test_node' in msg, msg
        rr.unload(first.trr.resource_id)
        second = load('zy_second')
        assert not rows()[second.pid]['preloaded'], 'started plainly after the zygote died'
        rr.unload(second.trr.resource_id)
        assert gone(second.pid)
    finally:
        rr.shutdown()
        launcher.stop_all()
