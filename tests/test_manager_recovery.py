"""Managers survive their own crash: the Sensor Manager and the ER Manager, SIGKILLed for real mid-use,
come back with the registry they had, keep the driver running, keep watching it, and still report what
failed while they were down.

Real roscore, real ER Manager and Sensor Manager processes with journals, fake drivers; the consumer is a
Sensor Manager interface in this test process.
"""
import json
import os
import signal
import sqlite3

import pytest
import rosgraph
import rospy

from temoto_core.msg import ResourceStatus
from temoto_core.process_group import start_ticks
from temoto_testing import ProcessGroupLauncher, made_interfaces, wait_for
from temoto_sensor_manager.interface import SensorManagerInterface
from temoto_testing.sensor_manager import (ER_PARAMS, FAKE_CATALOGUE, FakeCables, TopicWatch, catalogue,
                                           er_processes, registry)

SM, ER, OM = 'temoto_sensor_manager', 'temoto_er_manager', 'temoto_output_manager'
CM, CM_TRACKERS = 'temoto_context_manager', 'temoto_context_manager_trackers'
SERVES = {SM: 'start_sensor', ER: 'load_process', OM: 'load_rviz_plugin', CM: 'track_object'}
REGISTRARS = {CM: [CM, CM_TRACKERS]}


class Managers:
    """An ER Manager and a Sensor Manager, each with a journal, that a test can kill and restart."""

    def __init__(self, env, tmp):
        self.launcher = ProcessGroupLauncher(env, str(tmp / 'launch'))
        os.makedirs(self.launcher.workdir, exist_ok=True)
        self.params = {
            ER: dict(ER_PARAMS, log_dir=str(tmp / 'er_logs'), journal=str(tmp / 'er.sqlite'), adoption_bound=20.0),
            SM: {'extra_catalogues': FAKE_CATALOGUE, 'first_data_timeout': 3.0, 'journal': str(tmp / 'sm.sqlite'),
                 'first_data_allowance': 2.0},
            OM: {'host_ready_timeout': 20.0, 'journal': str(tmp / 'om.sqlite')},
        }
        self.procs = {}

    def start(self, name):
        self.procs[name] = self.launcher.node(name, name, name=name, params=self.params[name])
        rospy.wait_for_service('/temoto/%s/%s' % (name, SERVES[name]), timeout=30)
        # serving is not recovered: the registry says when it has taken everything back
        for rr in REGISTRARS.get(name, [name]):
            wait_for(lambda rr=rr: not registry(rr)['recovering'], 30, '%s to finish recovering' % rr)

    def journal_caught_up(self, name):
        """The journal of ``name`` has committed every resource its registry shows: it is written behind, a
        burst's changes up to 50 ms late (temoto_core/rr/recorder.py)."""
        reg = registry(name)
        db = sqlite3.connect('file:%s?mode=ro' % self.params[name]['journal'], uri=True)
        try:
            served = {row[0] for row in db.execute('SELECT internal_id FROM served')}
            consumers = {row[0] for row in db.execute('SELECT external_id FROM consumers')}
            holds = {row[0] for row in db.execute('SELECT local_id FROM holds')}
        finally:
            db.close()
        return (served == {q['internal_id'] for q in reg['server_queries']}
                and consumers == {c['resource_id'] for q in reg['server_queries'] for c in q['consumers']}
                and holds == {i for q in reg['client_queries'] for i in q['local_ids']})

    def kill(self, *names):
        for name in names:
            os.kill(self.procs[name].pid, signal.SIGKILL)
        for name in names:
            wait_for(lambda: not self.procs[name].alive(), 10, '%s to die' % name)


@pytest.fixture
def managers(ros_master, rospy_client, tmp_path, request):
    """The managers; an indirect parameter sets the Sensor Manager's ``journal_pause``."""
    m = Managers(ros_master.env, tmp_path)
    if getattr(request, 'param', None) is not None:
        m.params[SM]['journal_pause'] = request.param
    m.start(ER)
    m.start(SM)
    yield m
    m.launcher.stop_all()


@pytest.fixture
def sensor(managers):
    """A fake lidar held by an interface that records every status and keeps a failed sensor (no reload)."""
    with made_interfaces(SensorManagerInterface) as make:
        sm = make()
        sm.events = []
        sm.register_update_callback(sm.events.append)
        result = sm.start_sensor('fake lidar', ['lidar_data'], executable='fake_sensor')
        yield sm, result


def failed(events):
    return [e for e in events if e.code == ResourceStatus.FAILED]


def registry_state(rr):
    """The registry, as JSON lines (a failed comparison then shows the lines that differ)."""
    snapshot = registry(rr)
    snapshot.pop('node', None)
    snapshot.pop('incarnation')         # one more after a restart, by design
    for query in snapshot['server_queries']:
        for consumer in query['consumers']:
            consumer.pop('client_uri')      # a restarted consumer is the same consumer at a new URI
    return json.dumps(snapshot, indent=1, sort_keys=True).splitlines()


def data_flows(result):
    """The sensor's data keeps coming (a few messages more, seen by a fresh subscriber)."""
    watch = TopicWatch(result.topic('lidar_data'))
    try:
        wait_for(lambda: watch.count > 5, 10, 'data still flowing')
    finally:
        watch.close()


def pull_cable(result, how):
    FakeCables().send(how, result.sensor_name[len('fake_'):])


def driver_pid():
    rows = er_processes()
    assert len(rows) == 1, rows
    return rows[0]['pid']


def test_killed_sensor_manager_comes_back_with_its_registry_and_keeps_watching(managers, sensor):
    sm, result = sensor
    before, pid = registry_state(SM), driver_pid()
    managers.kill(SM)
    managers.start(SM)
    assert registry_state(SM) == before, 'the registry after the restart is the one before the kill'
    assert driver_pid() == pid, 'nothing that still runs is restarted'
    data_flows(result)
    assert not failed(sm.events)
    # the restored watch still catches a stall, and the consumer hears it from the new incarnation
    pull_cable(result, 'stall')
    wait_for(lambda: failed(sm.events), 15, 'the stall FAILED at the client')
    assert 'stalled' in failed(sm.events)[0].message, failed(sm.events)[0].message


def journal_rows(path, sql):
    db = sqlite3.connect('file:%s?mode=ro' % path, uri=True)
    try:
        return db.execute(sql).fetchall()
    finally:
        db.close()


# with a 5 s pause (the longest a registrar accepts) the journal has the driver's hold, committed at once, and
# lacks what followed within the pause (its link to the sensor, the sensor itself): the neighbours must give
# those back. The kill must come within that pause of the driver's load; beside the other worker a sensor's
# start took longer once, and the journal had caught up: that case runs alone
@pytest.mark.parametrize('managers', [pytest.param(None, id='default_pause'),
                                      pytest.param(5.0, id='journal_behind', marks=pytest.mark.alone)],
                         indirect=True)
def test_a_driver_crash_while_the_sensor_manager_is_down_reaches_the_client_after_the_restart(managers, sensor):
    sm, result = sensor
    pid = driver_pid()
    behind = 'journal_pause' in managers.params[SM]
    managers.kill(SM)
    if behind:
        journal = managers.params[SM]['journal']
        assert journal_rows(journal, 'SELECT parent FROM holds') == [(None,)], 'the hold, not yet its link'
        assert journal_rows(journal, 'SELECT internal_id FROM served') == [], 'the sensor is not journaled yet'
    pull_cable(result, 'crash')
    wait_for(lambda: start_ticks(pid) is None, 10, 'the driver to crash')
    assert not failed(sm.events), 'nobody could tell the client while its manager was down'
    managers.start(SM)
    wait_for(lambda: failed(sm.events), 20, 'the FAILED of the crash at the client')
    event = failed(sm.events)[0]
    assert event.resource_id == result.resource_id
    text = event.message + ' ' + ' '.join(f.message for f in event.error_stack)
    assert 'exit' in text.lower() or 'failed' in text.lower(), text


def test_reliabilities_survive_a_restart(managers, sensor):
    sm, result = sensor
    pull_cable(result, 'stall')
    wait_for(lambda: failed(sm.events), 15, 'the stall FAILED')
    lowered = catalogue()[result.sensor_name]['reliability']
    assert lowered < 0.8
    managers.kill(SM)
    managers.start(SM)
    assert catalogue()[result.sensor_name]['reliability'] == lowered


def test_two_neighbours_killed_at_once_recover_from_their_journals(managers, sensor):
    sm, result = sensor
    before = {rr: registry_state(rr) for rr in (SM, ER)}
    pid = driver_pid()
    # with both neighbours gone, only the journals can give back what they had: let them catch up first
    for rr in (SM, ER):
        wait_for(lambda rr=rr: managers.journal_caught_up(rr), 10, 'the journal of %s to catch up' % rr)
    managers.kill(SM, ER)
    assert start_ticks(pid) is not None, 'the driver outlives both managers'
    managers.start(ER)
    managers.start(SM)
    for rr in (SM, ER):
        assert registry_state(rr) == before[rr], rr
    # the driver's owner now reports to the Sensor Manager's new incarnation
    uris = [c['client_uri'] for q in registry(ER)['server_queries'] for c in q['consumers']]
    assert uris == [rosgraph.Master('/recovery_test').lookupNode('/' + SM)]
    assert driver_pid() == pid
    data_flows(result)
    sm.stop_sensor(result.resource_id)
    wait_for(lambda: start_ticks(pid) is None, 10, 'the driver to stop with the sensor')
    assert not failed(sm.events)


@pytest.fixture
def display(managers):
    """A laser scan display held by an Output Manager interface that records every status."""
    from temoto_output_manager.interface import OutputManagerInterface
    managers.start(OM)
    with made_interfaces(lambda: OutputManagerInterface(namespace='temoto')) as make:
        om = make()
        om.events = []
        om.register_update_callback(om.events.append)
        yield om, om.show('laser scan', '/recovery/scan')


def host_pid():
    rows = [r for r in er_processes() if r['label'].endswith('/rviz_host')]
    assert len(rows) == 1, rows
    return rows[0]['pid']


def test_killed_output_manager_leaves_the_display_on_screen_and_comes_back_with_it(managers, display):
    from temoto_output_manager.host_client import RvizHostClient
    om, shown = display
    before, pid = registry_state(OM), host_pid()
    host = RvizHostClient('/temoto/rviz_host')
    managers.kill(OM)
    assert shown.display_name in host.display_names(), 'the view stays up while its manager is down'
    managers.start(OM)
    assert registry_state(OM) == before
    assert host_pid() == pid, 'the RViz host is not started again'
    assert not failed(om.events)
    os.kill(pid, signal.SIGKILL)          # the host's crash reaches the display's holder through the new incarnation
    wait_for(lambda: failed(om.events), 20, 'the FAILED of the host crash')
    assert failed(om.events)[0].resource_id == shown.trr.resource_id


def test_a_display_gone_while_the_output_manager_is_down_is_reported_failed_after_the_restart(managers, display):
    from temoto_output_manager.host_client import RvizHostClient
    om, shown = display
    managers.kill(OM)
    RvizHostClient('/temoto/rviz_host').remove_display(shown.display_name)
    managers.start(OM)
    wait_for(lambda: failed(om.events), 20, 'the FAILED of the display that went')
    assert 'not in the RViz host any more' in failed(om.events)[0].message, failed(om.events)[0].message


@pytest.fixture
def vaultbot(ros_master, rospy_client, tmp_path):
    """The simulated VaultBot with ER, Sensor and Context Managers, each with a journal."""
    from temoto_testing.sensor_manager import start_sim
    m = Managers(ros_master.env, tmp_path)
    m.params[SM] = {'first_data_timeout': 20.0, 'journal': str(tmp_path / 'sm.sqlite')}
    m.params[CM] = {'journal': str(tmp_path / 'cm.sqlite')}
    start_sim(m.launcher)
    for name in (ER, SM, CM):
        m.start(name)
    yield m
    from temoto_testing.sensor_manager import set_cable
    set_cable('d435', 'plugged')
    m.launcher.stop_all()


def test_killed_context_manager_keeps_the_tracker_pipe_and_a_later_camera_crash_still_reaches_the_client(vaultbot):
    from geometry_msgs.msg import PoseStamped
    from temoto_context_manager.interface import ContextManagerInterface
    from temoto_testing.sensor_manager import set_cable
    with made_interfaces(ContextManagerInterface) as make:
        cm = make()
        cm.events = []
        cm.register_update_callback(cm.events.append)
        obj = cm.track_object('hand')
        before = {rr: registry_state(rr) for rr in (CM, CM_TRACKERS)}
        vaultbot.kill(CM)
        vaultbot.start(CM)
        for rr in (CM, CM_TRACKERS):
            assert registry_state(rr) == before[rr], rr
        poses = []
        sub = rospy.Subscriber(obj.topic, PoseStamped, poses.append)
        wait_for(lambda: len(poses) > 3, 15, 'poses still flowing after the restart')
        sub.unregister()
        assert not failed(cm.events)
        set_cable('d435', 'unplugged', 'crash')
        wait_for(lambda: failed(cm.events), 20, 'the camera crash at the track_object client')
        event = failed(cm.events)[0]
        assert event.resource_id == obj.resource_id
        assert sum('sub-resource' in f.message for f in event.error_stack) >= 3, event.error_stack


def lose_journal(path):
    """The journal file is gone (a disk replaced, a container recreated): with its WAL and index."""
    for suffix in ('', '-wal', '-shm'):
        if os.path.exists(path + suffix):
            os.remove(path + suffix)


@pytest.mark.parametrize('victim', [SM, ER])
def test_a_manager_whose_journal_is_lost_rebuilds_its_registry_from_its_neighbours(managers, sensor, victim):
    """The paper's P2P backup: the consumers keep each owner's record of what they hold (and the owners their
    consumer records), so a manager killed together with its journal comes back with the same registry."""
    sm, result = sensor
    before, pid = registry_state(victim), driver_pid()
    managers.kill(victim)
    lose_journal(managers.params[victim]['journal'])
    managers.start(victim)
    assert registry_state(victim) == before
    assert driver_pid() == pid, 'the driver runs on, adopted: nothing is started again'
    data_flows(result)
    assert not failed(sm.events)
    # the rebuilt registry carries status as before
    pull_cable(result, 'crash')
    wait_for(lambda: failed(sm.events), 20, 'the crash FAILED at the client')
