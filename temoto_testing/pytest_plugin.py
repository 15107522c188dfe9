"""pytest fixtures, registered by TeMoto's install as the ``pytest11`` entry point ``temoto``.

- ``ros_master`` (session): one roscore per test session, so one per xdist worker;
- ``rospy_client`` (session): the in-process rospy node (``init_node`` works once per process);
- ``collect`` (function): ``collect(topic, type)`` records a topic's messages with their arrival times;
- ``procs`` (function) and ``module_procs`` (module): node scripts and launch files as subprocesses,
  stopped at teardown;
- ``bag_recorder`` (function): a factory for bags recorded during a test;
- ``two_hosts`` (module): the robot and the operator's station as two network namespaces joined by a
  switch (``temoto_core/hosts.py``; needs root), removed with every process in them at the end.

At the end of the session every process that carries this session's token is
a leak: it is killed and the session fails, naming it.

A failed test's report carries the last lines of every log under the work folders of the launchers
it used (the nodes', and what the ER Manager started there): a failure on CI is then read from the
report alone, without the machine that ran it.
"""
import glob
import os
import uuid

import pytest

from temoto_core import hosts
from temoto_core.master import RosMaster
from temoto_core.processes import SESSION_ENV, ProcessGroupLauncher, kill_leftovers, tail
from temoto_testing.bag import BagRecorder
from temoto_testing.topics import TopicLog

# A test that runs an inner pytest session passes this so it knows the inner token.
FORCED_TOKEN_ENV = 'TEMOTO_TEST_SESSION_FORCE'
LOG_TAIL_LINES = 25          # per log, in a failed test's report
LOG_TAIL_FILES = 30          # logs per report at most: the newest

_live_workdirs = []          # the launchers' work folders in use now (a module's, a test's)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.failed and _live_workdirs:
        for path in newest_logs(_live_workdirs, LOG_TAIL_FILES):
            report.sections.append(('log %s' % os.path.basename(path), tail(path, LOG_TAIL_LINES)))


def newest_logs(workdirs, count):
    """The ``count`` most recently written ``*.log`` files under ``workdirs``, oldest first."""
    paths = {p for d in workdirs for p in glob.glob(os.path.join(d, '**', '*.log'), recursive=True)}
    dated = sorted((os.path.getmtime(p), p) for p in paths if os.path.isfile(p))
    return [p for _, p in dated[-count:]]


def _tracked(workdir):
    """Report this work folder's logs while the fixture lives."""
    _live_workdirs.append(workdir)
    return workdir


@pytest.fixture(scope='session')
def session_token():
    token = os.environ.pop(FORCED_TOKEN_ENV, '') or uuid.uuid4().hex
    os.environ[SESSION_ENV] = token
    return token


@pytest.fixture(scope='session')
def ros_master(tmp_path_factory, session_token):
    master = RosMaster(str(tmp_path_factory.mktemp('roscore')), session_token).start()
    saved = master.point_this_process()
    yield master
    master.stop()
    master.restore_process(saved)
    leaked = kill_leftovers(session_token)
    if leaked:
        pytest.fail('processes outlived the test session (killed now): %s' % leaked, pytrace=False)


@pytest.fixture(scope='session')
def rospy_client(ros_master):
    import rospy
    from temoto_core import rospy_internals
    rospy_internals.install_shutdown_guard()    # another test's master may bump a dead node whose port this is
    rospy.init_node('pytest_client', anonymous=True, disable_signals=True)
    yield rospy
    rospy.signal_shutdown('test session over')


@pytest.fixture
def collect(rospy_client):
    """``collect(topic, msg_type)``: a :class:`TopicLog` of that topic, unsubscribed after the test."""
    made = []

    def make(topic, msg_type):
        log = TopicLog(rospy_client, topic, msg_type)
        made.append(log)
        return log

    yield make
    for log in made:
        log.close()


@pytest.fixture
def procs(ros_master, tmp_path):
    launcher = ProcessGroupLauncher(ros_master.env, _tracked(str(tmp_path)))
    yield launcher
    launcher.stop_all()
    _live_workdirs.remove(launcher.workdir)


@pytest.fixture(scope='module')
def module_procs(ros_master, tmp_path_factory):
    """Like ``procs``, for processes that a whole test module shares (they are slow to start)."""
    launcher = ProcessGroupLauncher(ros_master.env, _tracked(str(tmp_path_factory.mktemp('module_procs'))))
    yield launcher
    launcher.stop_all()
    _live_workdirs.remove(launcher.workdir)


@pytest.fixture
def bag_recorder(ros_master, tmp_path):
    started = []

    def record(topics, name='test.bag'):
        recorder = BagRecorder(str(tmp_path / name), topics, ros_master.env, 'bag_%s' % uuid.uuid4().hex[:8])
        started.append(recorder)
        return recorder.start()

    yield record
    for recorder in started:
        if recorder.process is not None:
            recorder.stop()


@pytest.fixture(scope='module')
def two_hosts():
    """``.robot`` and ``.operator`` (each with ``.address``), ``.master(workdir)`` on the robot,
    ``.launcher(host, master, workdir)``, ``.link(up)`` to pull or plug the cable between them."""
    why = hosts.unavailable()
    assert not why, why          # not a skip: a test that needs two hosts says why it cannot have them
    pair = hosts.TwoHosts('t%d' % (os.getpid() % 100000)).up()
    yield pair
    pair.down()
    assert pair.exist() == [], 'network namespaces left behind: %s' % pair.exist()
