"""ProcessSupervisor, request policy and resolver: real processes, no ROS master needed."""
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from temoto_core.errors import ErrorCode
from temoto_testing import wait_for
from temoto_er_manager.policy import ERConfig, RequestRefused, validate_request
from temoto_er_manager.resolve import Resolver
from temoto_er_manager import supervisor as supervisor_module
from temoto_er_manager.supervisor import (ProcessExitedEarly, ProcessSpec, ProcessSupervisor, ReadyTimeout,
                                          SpawnerStuck, StartCancelled)

TEST_NODE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                         'temoto_er_manager', 'test_nodes', 'er_test_node')


def gone(pid):
    """True when ``pid`` no longer exists at all (not even as a zombie)."""
    return not os.path.exists('/proc/%d' % pid)


@pytest.fixture
def sup():
    exits = []
    s = ProcessSupervisor(lambda p, info: exits.append(info), sigint_grace=1.0, sigterm_grace=1.0)
    s.exits = exits
    yield s
    s.shutdown()


def spec(tmp_path, argv, name='p'):
    return ProcessSpec(argv=list(argv), env=dict(os.environ), log_path=str(tmp_path / ('%s.log' % name)), label=name)


def test_a_child_answers_sigint_even_when_its_parent_ignores_it(sup, tmp_path):
    """A manager started from a script's background job inherits SIGINT ignored (POSIX shells do that to
    asynchronous commands); its children used to inherit it too, and every stop waited for SIGTERM."""
    saved = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        proc = sup.start(spec(tmp_path, ['sleep', '60']))
    finally:
        signal.signal(signal.SIGINT, saved)
    sup.wait_ready(proc, None, 0.05)
    info = sup.stop(proc, sigint_grace=10.0, sigterm_grace=10.0)
    assert info.returncode == -signal.SIGINT, info


def test_stop_is_intentional_and_reaped(sup, tmp_path):
    proc = sup.start(spec(tmp_path, ['sleep', '60']))
    sup.wait_ready(proc, None, 0.05)
    assert proc.state == 'running'
    info = sup.stop(proc)
    assert info.intentional and info.returncode == -signal.SIGINT
    assert gone(proc.pid), 'stopped child must be reaped, not a zombie'
    assert sup.exits == [], 'an intentional stop is never reported as a failure'


@pytest.mark.parametrize('how, expect', [
    ('kill', 'SIGKILL'), ('segv', 'SIGSEGV'), ('exit0', 'exited with code 0')])
def test_unexpected_exit_is_reported_with_reason(sup, tmp_path, how, expect):
    on_usr1 = {'kill': 'segv', 'segv': 'segv', 'exit0': 'exit0'}[how]
    proc = sup.start(spec(tmp_path, [sys.executable, TEST_NODE, '_register:=false', '_on_usr1:=' + on_usr1]))
    wait_for(lambda: 'not registering' in open(proc.spec.log_path).read(), 10, 'test node up')
    os.kill(proc.pid, signal.SIGKILL if how == 'kill' else signal.SIGUSR1)
    wait_for(lambda: sup.exits, 5, 'exit callback')
    info = sup.exits[0]
    assert expect in info.message() and not info.intentional
    assert info.command in info.message()
    assert 'not registering' in info.log_tail, 'the last lines of output are in the report'
    assert gone(proc.pid)


def test_escalates_to_sigkill(sup, tmp_path):
    code = 'import signal,time; [signal.signal(s, signal.SIG_IGN) for s in (2, 15)]; print("up", flush=True); time.sleep(60)'
    proc = sup.start(spec(tmp_path, [sys.executable, '-c', code]))
    wait_for(lambda: '\nup\n' in open(proc.spec.log_path).read(), 10, 'child up')
    t0 = time.monotonic()
    info = sup.stop(proc, sigint_grace=0.2, sigterm_grace=0.2)
    assert info.returncode == -signal.SIGKILL
    assert time.monotonic() - t0 < 3.0
    assert gone(proc.pid) and sup.exits == []


def test_stop_reaches_the_whole_group(sup, tmp_path):
    code = 'import subprocess,time; p=subprocess.Popen(["sleep","60"]); print(p.pid, flush=True); time.sleep(60)'
    proc = sup.start(spec(tmp_path, [sys.executable, '-c', code]))
    grandchild = int(wait_for(lambda: open(proc.spec.log_path).read().split('\n')[1].strip(), 10, 'grandchild pid'))
    sup.stop(proc)
    wait_for(lambda: gone(grandchild) or open('/proc/%d/stat' % grandchild).read().split()[2] == 'Z', 5,
             'grandchild gone')


def test_exit_while_starting_fails_fast(sup, tmp_path):
    proc = sup.start(spec(tmp_path, [sys.executable, TEST_NODE, '_exit_at_start:=4']))
    t0 = time.monotonic()
    with pytest.raises(ProcessExitedEarly) as err:
        sup.wait_ready(proc, lambda p: False, timeout=30)
    assert time.monotonic() - t0 < 5, 'must not wait for the registration timeout'
    assert 'exited with code 4' in str(err.value) and 'exiting at start' in str(err.value)


def test_ready_timeout(sup, tmp_path):
    proc = sup.start(spec(tmp_path, ['sleep', '60']))
    with pytest.raises(ReadyTimeout):
        sup.wait_ready(proc, lambda p: False, timeout=0.3)
    sup.stop(proc)
    assert gone(proc.pid)


def test_stop_while_starting_cancels_the_wait(sup, tmp_path):
    proc = sup.start(spec(tmp_path, ['sleep', '60']))
    errors = []

    def waiter():
        try:
            sup.wait_ready(proc, lambda p: False, timeout=30)
        except Exception as e:
            errors.append(e)

    t = threading.Thread(target=waiter)
    t.start()
    sup.stop(proc)
    t.join(5)
    assert not t.is_alive() and isinstance(errors[0], StartCancelled)
    assert gone(proc.pid) and sup.exits == []


def test_child_survives_the_thread_that_asked_for_it(sup, tmp_path):
    """PDEATHSIG fires when the *forking thread* exits: spawns happen on the supervisor's own thread."""
    box = []
    t = threading.Thread(target=lambda: box.append(sup.start(spec(tmp_path, ['sleep', '60']))))
    t.start()
    t.join(5)
    proc = box[0]
    sup.wait_ready(proc, None, 0.3)
    assert proc.alive and not gone(proc.pid)
    sup.stop(proc)


def test_children_die_with_a_sigkilled_supervisor(tmp_path):
    script = textwrap.dedent('''
        import os, sys, time
        sys.path.insert(0, %r)
        from temoto_er_manager.supervisor import ProcessSpec, ProcessSupervisor
        s = ProcessSupervisor()
        p = s.start(ProcessSpec(['sleep', '60'], dict(os.environ), %r))
        print(p.pid, flush=True)
        time.sleep(60)
    ''' % (os.path.dirname(os.path.dirname(TEST_NODE.rsplit('/', 1)[0])), str(tmp_path / 'c.log')))
    host = subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE, start_new_session=True)
    try:
        child = int(host.stdout.readline())
        assert not gone(child)
        os.kill(host.pid, signal.SIGKILL)
        host.wait(5)
        wait_for(lambda: gone(child) or open('/proc/%d/stat' % child).read().split()[2] == 'Z', 5, 'orphan killed')
    finally:
        host.kill()
        host.wait(5)
        host.stdout.close()


def test_shutdown_stops_everything(tmp_path):
    s = ProcessSupervisor(sigint_grace=1.0, sigterm_grace=1.0)
    procs = [s.start(spec(tmp_path, ['sleep', '60'], 'p%d' % i)) for i in range(3)]
    s.shutdown()
    assert all(gone(p.pid) for p in procs)
    assert all(p.exit_info.intentional for p in procs)


# -- policy and resolver ----------------------------------------------------------------------

CFG = ERConfig(sys_allowlist=['echo'])


@pytest.mark.parametrize('fields, kind, words', [
    (('sys_execute', '', '', 'touch', '/tmp/x'), 'NOT_ALLOWED', 'sys_allowlist'),
    (('run_anything', '', 'p', 'e', ''), 'BAD_REQUEST', 'action'),
    (('ros_execute', 'a b', 'temoto_er_manager', 'er_test_node', ''), 'BAD_REQUEST', 'ros_namespace'),
    (('ros_execute', '/ok', 'temoto_er_manager', 'er_test_node', 'x\x00y'), 'BAD_REQUEST', 'NUL'),
    (('ros_execute', '', 'temoto_er_manager', '../../bin/sh', ''), 'BAD_REQUEST', 'executable'),
    (('ros_execute', '', 'temoto_er_manager', '.hidden', ''), 'BAD_REQUEST', 'executable'),
    (('ros_execute', '', 'bad-pkg;rm', 'x', ''), 'BAD_REQUEST', 'package_name'),
    (('ros_execute', '', 'temoto_er_manager', 'er_test_node', "'unbalanced"), 'BAD_REQUEST', 'args'),
    (('ros_execute', '', 'temoto_er_manager', 'er_test_node', '__master:=http://evil:1'), 'BAD_REQUEST', '__master'),
])
def test_refused_requests(fields, kind, words):
    with pytest.raises(RequestRefused) as err:
        validate_request(*fields, config=CFG)
    assert err.value.kind == kind and err.value.code == ErrorCode[kind]
    assert words in str(err.value)


def test_package_allowlist():
    cfg = ERConfig(package_allowlist=['temoto_core'])
    with pytest.raises(RequestRefused, match='package_allowlist'):
        validate_request('ros_execute', '', 'temoto_er_manager', 'er_test_node', '', config=cfg)
    validate_request('ros_execute', '', 'temoto_core', 'x', '', config=cfg)


def test_namespace_normalisation():
    req = validate_request('ros_execute', 'sub/ns', 'temoto_er_manager', 'er_test_node', '', CFG, base_ns='/robot')
    assert req.ros_namespace == '/robot/sub/ns'
    assert validate_request('ros_execute', '', 'p', 'e', '', CFG, base_ns='/robot').ros_namespace == '/robot'
    assert validate_request('ros_execute', '/abs/', 'p', 'e', '', CFG).ros_namespace == '/abs'


@pytest.mark.parametrize('exe, kind, words', [
    ('no_such_node', 'EXECUTABLE_NOT_FOUND', 'no executable'),
    ('er_not_executable', 'EXECUTABLE_NOT_FOUND', 'not an executable file'),
    ('nothing.launch', 'EXECUTABLE_NOT_FOUND', 'no launch file'),
])
def test_resolver_refusals(tmp_path, exe, kind, words):
    r = Resolver(ERConfig(log_dir=str(tmp_path)))
    with pytest.raises(RequestRefused) as err:
        r.resolve(validate_request('ros_execute', '', 'temoto_er_manager', exe, '', CFG))
    assert err.value.kind == kind and words in str(err.value)


def test_resolver_unknown_package(tmp_path):
    with pytest.raises(RequestRefused, match="package 'no_such_pkg' not found"):
        Resolver(ERConfig(log_dir=str(tmp_path))).resolve(validate_request('ros_execute', '', 'no_such_pkg', 'x', '', CFG))


def test_resolver_node_and_launch(tmp_path):
    r = Resolver(ERConfig(log_dir=str(tmp_path)))
    plan = r.resolve(validate_request('ros_execute', '/robot', 'temoto_er_manager', 'er_test_node', 'a:=b "two words"',
                                      CFG), name_taken=lambda n: n == '/robot/er_test_node')
    [s] = plan.specs
    assert s.argv[-4:] == ['a:=b', 'two words', '__name:=er_test_node_2', '__ns:=/robot']
    assert s.node_names == ['/robot/er_test_node_2'] and s.env['ROS_NAMESPACE'] == '/robot'
    assert s.log_path.startswith(str(tmp_path)) and plan.log_path == s.log_path
    plan = r.resolve(validate_request('ros_execute', '/robot', 'temoto_er_manager', 'er_two_nodes.launch', '', CFG))
    assert [s.node_names for s in plan.specs] == [['/robot/first'], ['/robot/inner/second']]
    assert all(s.argv[1].endswith('/er_test_node') and s.log_path == plan.log_path for s in plan.specs)
    assert plan.specs[1].argv[-2:] == ['__name:=second', '__ns:=/robot/inner']
    assert plan.specs[1].env['ROS_NAMESPACE'] == '/robot/inner'


def test_shell_metacharacters_are_plain_arguments(sup, tmp_path):
    marker = tmp_path / 'pwned'
    args = '; touch %s $(touch %s) `touch %s` | touch %s' % ((marker,) * 4)
    req = validate_request('sys_execute', '', '', 'echo', args, CFG)
    [s] = Resolver(ERConfig(sys_allowlist=['echo'], log_dir=str(tmp_path))).resolve(req).specs
    proc = sup.start(s)
    wait_for(lambda: not proc.alive, 5, 'echo done')
    assert not marker.exists()
    assert '$(touch' in open(s.log_path).read()


def _launch_plan(cfg, exe, args=''):
    return Resolver(cfg).resolve(validate_request('ros_execute', '/lp', 'temoto_er_manager', exe, args, cfg))


def test_launch_file_roslaunch_features_resolve(tmp_path):
    plan = _launch_plan(ERConfig(log_dir=str(tmp_path)), 'er_features.launch', 'prefix:=xy topic:=renamed')
    talker, listener = plan.specs
    assert talker.node_names == ['/lp/grp/talker']
    assert listener.node_names[0].startswith('/lp/grp/inc/listener_'), 'anon name resolved once, here'
    assert talker.argv[2:] == ['_publish:=chatter', '_print_env:=ER_TEST_ENV', 'chatter:=renamed', '__name:=talker',
                               '__ns:=/lp/grp']
    assert talker.env['ER_TEST_ENV'] == 'from_launch_xy' and 'ER_TEST_ENV' not in listener.env
    assert plan.params['/lp/top_value'] == 'xy_top' and plan.params['/lp/grp/inner_value'] == 42
    assert plan.params['/lp/grp/talker/private_value'] == 'xy'
    assert plan.params['/lp/grp/inc/included_by'] == 'xy' and plan.params['/lp/loaded/b'] == ['x', 'y']
    assert '/lp/grp/' in plan.clear_params


@pytest.mark.parametrize('cfg, exe, args, kind, words', [
    (ERConfig(), 'er_refused.launch', 'prefix:="nice -n 5"', 'NOT_ALLOWED', "launch-prefix 'nice -n 5' runs 'nice'"),
    (ERConfig(package_allowlist=['temoto_er_manager']), 'er_refused.launch', '', 'NOT_ALLOWED',
     "node /lp/elsewhere (temoto_core/anything): package 'temoto_core' is not in"),
    (ERConfig(), 'er_refused.launch', '', 'EXECUTABLE_NOT_FOUND', "no executable 'anything' in package 'temoto_core'"),
    (ERConfig(), 'er_included.launch', '', 'BAD_REQUEST', 'cannot be loaded'),      # required arg "who" not set
])
def test_launch_file_refusals(tmp_path, cfg, exe, args, kind, words):
    cfg.log_dir = str(tmp_path)
    with pytest.raises(RequestRefused) as err:
        _launch_plan(cfg, exe, args)
    assert err.value.kind == kind and words in str(err.value), str(err.value)


def test_allowlisted_launch_prefix_runs_without_a_shell(tmp_path):
    plan = _launch_plan(ERConfig(sys_allowlist=['nice'], log_dir=str(tmp_path)), 'er_refused.launch',
                        'prefix:="nice -n 5" other:=false')
    [s] = plan.specs
    assert s.argv[:4] == ['nice', '-n', '5', sys.executable] and s.argv[4].endswith('/er_test_node')


def test_a_stuck_spawner_fails_the_start_with_the_stacks_and_stops_what_it_starts_late(sup, tmp_path, monkeypatch,
                                                                                       capfd):
    """The chaos history of seed 17 twice had an ER Manager that answered no load after a restart, for good,
    and left no trace of where it hung. A start now waits for the spawner within a bound, and then fails,
    naming the command, with every thread's stack in the log; what the spawner starts after its caller gave
    up is stopped. Here the spawner is held up opening the child's log, a FIFO nobody reads yet."""
    monkeypatch.setattr(supervisor_module, 'SPAWN_SLACK_S', 0.5)
    sup.preload_ready_timeout = 0.0
    fifo = tmp_path / 'held.log'
    os.mkfifo(fifo)
    stuck = ProcessSpec(argv=['sleep', '60'], env=dict(os.environ), log_path=str(fifo), label='held')
    with pytest.raises(SpawnerStuck, match='did not start sleep 60 within 0.5 s: it is stuck'):
        sup.start(stuck)
    assert 'in _spawn' in capfd.readouterr().err       # the spawner's own stack, where it hung
    # the spawner goes on: the process starts, late (read and write: the exit's log tail must not wait either)
    reader = os.open(fifo, os.O_RDWR)
    try:
        late = wait_for(lambda: [p for p in sup.processes() if p.spec.label == 'held'], 10, 'the late start')
        wait_for(lambda: not late[0].alive, 15, 'the late process stopped')
        assert sup.exits == []                             # stopped on purpose: no unexpected exit reported
    finally:
        os.close(reader)
