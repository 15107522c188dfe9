"""The Sensor Manager with fake drivers: selection, sharing, failures, stalls, bad input.

Real roscore, real ER Manager and Sensor Manager processes (shared by the module),
fake drivers (temoto_sensor_manager/test_nodes/fake_sensor) started through them.
Reliabilities persist across tests in the shared manager, so a test that depends
on the ranking reads the current ranking first.
"""
import os
import signal
import time

import pytest

from temoto_testing import made_interfaces
import rospy

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.master_lookup import lookup_node, node_pid
from temoto_core.msg import ResourceStatus
from temoto_testing import wait_for
from temoto_core.stall import arrivals
from temoto_sensor_manager.interface import SensorManagerInterface
from temoto_sensor_manager.srv import LoadSensor
from temoto_testing.sensor_manager import (FAKE_CATALOGUE, FakeCables, TopicWatch, catalogue, catalogue_problems,
                                           er_processes, managers_idle, pid_gone, registry, start_er_manager,
                                           start_sensor_manager)


@pytest.fixture(scope='module')
def managers(rospy_client, module_procs, tmp_path_factory):
    start_er_manager(module_procs, tmp_path_factory.mktemp('er_logs'))
    start_sensor_manager(module_procs, first_data_timeout=3.0)
    return module_procs


@pytest.fixture
def smi(managers):
    """Interfaces made by a test; each is shut down (releasing what it holds) at its end."""
    with made_interfaces(SensorManagerInterface) as make:
        yield make
    managers_idle()


def failed_events(events):
    return [e for e in events if e.code == ResourceStatus.FAILED]


def test_start_returns_with_data_flowing_and_stop_releases_the_driver(smi):
    sm = smi()
    res = sm.start_sensor('fake lidar', ['lidar_data'], package_name='temoto_sensor_manager')
    assert res.sensor_name in ('fake_lidar_a', 'fake_lidar_b')
    topic = res.topic('lidar_data')
    assert topic == '/fake/%s/scan' % res.sensor_name[len('fake_'):]
    watch = TopicWatch(topic)
    wait_for(lambda: watch.count >= 3, 5, 'data on %s' % topic)
    watch.close()
    procs = er_processes()
    assert len(procs) == 1 and procs[0]['label'] == 'temoto_sensor_manager/fake_sensor'
    # the driver process is a linked sub-resource of the sensor query
    reg = registry()
    assert len(reg['server_queries']) == 1 and reg['server_queries'][0]['links'] == \
        reg['client_queries'][0]['local_ids']
    pid = procs[0]['pid']
    # the driver runs on the manager's host: its CPU waiting is measured against a false stall
    assert catalogue()[res.sensor_name]['driver_pids'] == {topic: pid}
    sm.stop_sensor(res.resource_id)
    wait_for(lambda: pid_gone(pid), 10, 'the driver to stop with the sensor')


def test_requested_topic_names_are_honoured_by_remapping(smi):
    sm = smi()
    res = sm.start_sensor('fake lidar', {'lidar_data': 'my/scan'}, executable='fake_sensor')
    assert res.output_topics == {'lidar_data': '/my/scan'}
    watch = TopicWatch('/my/scan')
    wait_for(lambda: watch.count >= 1, 5, 'data on the requested name')
    watch.close()


def test_two_clients_share_one_driver_process(smi):
    first, second = smi(), smi()
    r1 = first.start_sensor('fake lidar', ['lidar_data'])
    r2 = second.start_sensor('fake lidar', ['lidar_data'])
    assert (r1.sensor_name, r1.output_topics) == (r2.sensor_name, r2.output_topics)
    assert len(er_processes()) == 1
    queries = registry()['server_queries']
    assert len(queries) == 1 and len(queries[0]['consumers']) == 2
    pid = er_processes()[0]['pid']
    first.stop_sensor(r1.resource_id)
    assert not pid_gone(pid) and len(er_processes()) == 1          # still held by the second client
    second.stop_sensor(r2.resource_id)
    wait_for(lambda: pid_gone(pid), 10, 'the shared driver to stop with its last consumer')


def test_client_and_server_share_by_one_rule(smi):
    """Input topics do not change which device runs: the server shares such requests, and so must the
    client (its equality comes from the same contract module), or it holds two references to one sensor."""
    sm = smi()
    r1 = sm.start_sensor('fake lidar', ['lidar_data'], input_topics={'cmd': '/a'})
    r2 = sm.start_sensor('fake lidar', ['lidar_data'], input_topics={'cmd': '/b'})
    assert r1.resource_id != r2.resource_id and r1.output_topics == r2.output_topics
    held = sm.rr.registry().client_queries
    assert len(held) == 1 and held[0].local_ids == sorted([r1.resource_id, r2.resource_id])
    queries = registry()['server_queries']
    assert len(queries) == 1 and len(queries[0]['consumers']) == 1
    sm.stop_sensor(r1.resource_id)
    sm.stop_sensor(r2.resource_id)


def test_crash_reaches_the_client_and_the_reload_picks_the_other_device(smi):
    """As the original: one failure reorders equal priors, the reload keeps the topic names."""
    before = catalogue()
    assert before['fake_twin_a']['reliability'] == before['fake_twin_b']['reliability'] == 0.8
    ranking = ['fake_twin_a', 'fake_twin_b']          # a tie: catalogue order
    sm = smi()
    events = []
    res = sm.start_sensor('fake twin', ['lidar_data'])
    assert res.sensor_name == ranking[0]
    sm.rr.register_status_callback(events.append)
    topic = res.topic('lidar_data')
    FakeCables().send('crash', res.sensor_name.replace('fake_', ''))
    wait_for(lambda: failed_events(events), 10, 'FAILED at the client')
    assert events[0].resource_id == res.resource_id
    assert 'exit' in ' '.join(f.message for f in events[0].error_stack).lower()
    new_id = wait_for(lambda: sm.replacement_of(res.resource_id), 15, 'the default reload')
    replacement = sm.result_of(new_id)
    assert replacement.sensor_name == ranking[1]
    assert replacement.output_topics == {'lidar_data': topic}        # pinned to the old name
    cat = catalogue()
    assert cat[ranking[0]]['reliability'] < cat[ranking[1]]['reliability']
    watch = TopicWatch(topic)
    wait_for(lambda: watch.count >= 1, 5, 'data from the replacement on the old topic')
    watch.close()
    assert len(er_processes()) == 1


def test_stall_is_reported_within_its_limit_and_the_stalled_driver_is_stopped(smi):
    sm = smi()
    events = []
    sm.register_update_callback(events.append)        # keep the failed sensor: no reload
    res = sm.start_sensor('fake lidar', ['lidar_data'])
    limit = catalogue()[res.sensor_name]['output_topics']['lidar_data']['stall_limit']
    pid = er_processes()[0]['pid']
    sent = FakeCables().send('stall', res.sensor_name.replace('fake_', ''))
    wait_for(lambda: failed_events(events), 10, 'the stall detector FAILED at the client')
    delay = time.monotonic() - sent
    # the limit follows the stream's rhythm (temoto_core/stall/arrivals.py): never under 2.5 periods
    floor = arrivals.FLOOR_PERIODS / catalogue()[res.sensor_name]['output_topics']['lidar_data']['rate']
    assert floor <= delay + 0.02 and delay < limit + 2.0, (delay, limit)     # generous hang bound
    assert 'stalled' in events[0].message and res.topic('lidar_data') in events[0].message
    assert not pid_gone(pid)                          # a stalled driver is alive ...
    sm.stop_sensor(res.resource_id)
    wait_for(lambda: pid_gone(pid), 10, 'the stalled driver to be stopped')  # ... until its consumer lets go


def test_a_driver_seen_stalling_is_refused_within_its_stall_limit_until_its_data_comes_back(smi):
    """An equal request shares the stalled driver that a holder keeps: it is not given the driver's start-up
    allowance again (it used to wait 4.3 s for the D435 each time), but its stall limit and a
    connection's second; once the device publishes again, the same request is served by the same driver."""
    holder, asker = smi(), smi()
    events = []
    holder.register_update_callback(events.append)        # keeps the failed sensor
    res = holder.start_sensor('fake solo', ['lidar_data'])
    pid = er_processes()[0]['pid']
    cables = FakeCables()
    cables.send('stall', 'solo')
    wait_for(lambda: failed_events(events), 10, 'the stall FAILED at the holder')
    with pytest.raises(TemotoError) as refused:
        asker.start_sensor('fake solo', ['lidar_data'])
    message = str(refused.value)
    assert 'has sent nothing since it stalled' in message and 'pid %d' % pid in message, message
    # waited its stall limit and a connection's second, not the first-data limit (3 s in this module)
    stall_limit = catalogue()['fake_solo']['output_topics']['lidar_data']['stall_limit']
    assert 'within %.1f s' % (stall_limit + 1.0) in message, message
    cables.send('resume', 'solo')
    again = asker.start_sensor('fake solo', ['lidar_data'])
    assert er_processes()[0]['pid'] == pid and len(er_processes()) == 1
    asker.stop_sensor(again.resource_id)
    holder.stop_sensor(res.resource_id)


def test_a_stall_is_caught_by_the_stream_s_own_rhythm_well_within_the_catalogue_limit(smi, capsys):
    sm = smi()
    events = []
    sm.register_update_callback(events.append)
    res = sm.start_sensor('fake patient')
    cap = catalogue()['fake_patient']['output_topics']['data']['stall_limit']
    assert cap == 5.0
    watch = TopicWatch(res.topic('data'))       # the manager subscribed before the driver started: it has seen
    try:                                        # at least as many
        wait_for(lambda: watch.count > 2 * arrivals.WARMUP, 20, 'enough messages to learn the rhythm')
    finally:
        watch.close()
    from temoto_sensor_manager.cli import main
    assert main([]) == 0
    [line] = [x for x in capsys.readouterr().out.splitlines() if x.startswith('watching /fake/patient/data')]
    assert 'stalled' not in line, line      # a healthy sensor: the line shows its limit, not a stall
    assert 'what its driver (pid %d) waits for a CPU' % er_processes()[0]['pid'] in line, line
    assert float(line.split('stall limit ')[1].split(' ms')[0]) < cap * 1e3, line    # the rhythm's, shown
    sent = FakeCables().send('stall', 'patient')
    wait_for(lambda: failed_events(events), 10, 'the stall FAILED at the client')
    delay = time.monotonic() - sent
    assert delay < cap / 2, (delay, events[0].message)
    assert 'adaptive limit' in events[0].message, events[0].message
    sm.stop_sensor(res.resource_id)


def test_a_manager_held_back_by_the_machine_does_not_call_its_own_lateness_a_stall(smi):
    """The Sensor Manager is stopped (SIGSTOP) for several of a healthy stream's learnt limits, three times:
    when it runs again, its stall detector wakes late beside a receive thread with messages waiting unread, and
    it used to fail the sensor on a silence that was its own (temoto_core/stall/detector.py, starvation.py). A stall that
    follows is still caught by the rhythm's limit."""
    sm = smi()
    events = []
    sm.register_update_callback(events.append)
    res = sm.start_sensor('fake patient')
    watch = TopicWatch(res.topic('data'))
    try:
        wait_for(lambda: watch.count > 2 * arrivals.WARMUP, 20, 'enough messages to learn the rhythm')
        pid = node_pid(lookup_node(os.environ['ROS_MASTER_URI'], '/temoto_sensor_manager'))
        for _ in range(3):
            os.kill(pid, signal.SIGSTOP)
            try:
                time.sleep(0.6)          # the fault itself: held back for several learnt limits (~0.1 s)
            finally:
                os.kill(pid, signal.SIGCONT)
            seen = watch.count
            # the stall detector looks at least every 0.1 s: half a second of data later it has judged the silence
            wait_for(lambda: watch.count >= seen + 25 and catalogue()['fake_patient']['active'], 10,
                     'half a second of data after the manager ran again')
            assert not failed_events(events), events[0].message
    finally:
        watch.close()
    sent = FakeCables().send('stall', 'patient')
    wait_for(lambda: failed_events(events), 10, 'the stall FAILED at the client')
    assert time.monotonic() - sent < 2.5, events[0].message       # the catalogue's limit is 5 s
    assert 'adaptive limit' in events[0].message, events[0].message
    sm.stop_sensor(res.resource_id)


def test_a_stall_early_in_a_load_is_caught_at_the_rhythm_an_earlier_load_learnt(smi):
    """The rhythm is learnt from 100 gaps; a device stalled before that was caught only at the catalogue's
    limit (the demo's Hokuyo: 12 periods). What an earlier load of the same device learnt is the limit
    until this load has learnt its own."""
    sm = smi()
    res = sm.start_sensor('fake patient')
    watch = TopicWatch(res.topic('data'))
    try:
        wait_for(lambda: watch.count > 2 * arrivals.WARMUP, 20, 'enough messages to learn the rhythm')
    finally:
        watch.close()
    sm.stop_sensor(res.resource_id)
    managers_idle()
    events = []
    sm.register_update_callback(events.append)
    again = sm.start_sensor('fake patient')
    sent = FakeCables().send('stall', 'patient')          # at once: far fewer than 100 gaps in this load
    wait_for(lambda: failed_events(events), 10, 'the stall FAILED at the client')
    delay = time.monotonic() - sent
    assert delay < 2.5, (delay, events[0].message)        # the catalogue's limit is 5 s
    assert 'learnt in an earlier load' in events[0].message, events[0].message
    sm.stop_sensor(again.resource_id)


def test_a_driver_that_fails_to_start_or_stays_silent_makes_way_for_the_next(smi):
    before = catalogue()
    sm = smi()
    res = sm.start_sensor('fake flaky')
    assert res.sensor_name == 'fake_good'
    after = catalogue()
    assert after['fake_broken']['reliability'] < before['fake_broken']['reliability']
    assert after['fake_silent']['reliability'] < before['fake_silent']['reliability']
    assert len(er_processes()) == 1                   # the failed candidates were stopped


def call_raw(**fields):
    """One LoadSensor call straight to the service, to send what the interface would not."""
    from temoto_core.rr import ResourceRegistrar
    rr = ResourceRegistrar('sensor_bad_input_client')
    try:
        return rr.call('temoto_sensor_manager', 'start_sensor', LoadSensor._request_class(**fields))
    finally:
        rr.shutdown()


@pytest.mark.parametrize('fields, code, words', [
    (dict(sensor_type='sonar'), ErrorCode.SENSOR_NOT_FOUND, ["unknown sensor type 'sonar'", "'depth camera'",
                                                            "'lidar'"]),
    (dict(sensor_type=''), ErrorCode.BAD_REQUEST, ['sensor_type is empty']),
    (dict(sensor_type='lidar', package_name='nopkg'), ErrorCode.SENSOR_NOT_FOUND, ["package 'nopkg'",
                                                                                   'hokuyo_utm30lx']),
    (dict(sensor_type='lidar', output_topics=[('camera_data', '')]), ErrorCode.SENSOR_NOT_FOUND,
     ['topic types camera_data']),
    (dict(sensor_type='lidar', output_topics=[('lidar_data', 'bad name!')]), ErrorCode.BAD_REQUEST,
     ['not a legal ROS topic name']),
    (dict(sensor_type='lidar', output_topics=[('lidar_data', ''), ('lidar_data', '/x')]), ErrorCode.BAD_REQUEST,
     ['requested twice']),
    (dict(sensor_type='fake dead'), ErrorCode.SENSOR_NOT_FOUND, ['no candidate left', 'fake_dead']),
    # a driver that runs and sends nothing is told from one whose publisher was never reached
    (dict(sensor_type='fake mute'), ErrorCode.SENSOR_NOT_FOUND, ['no data on /fake/mute/data (connected to 1 publisher)']),
])
def test_bad_input_gets_a_clear_error_and_leaves_nothing_loaded(smi, fields, code, words):
    from diagnostic_msgs.msg import KeyValue
    fields = dict(fields)
    fields['output_topics'] = [KeyValue(k, v) for k, v in fields.get('output_topics', [])]
    with pytest.raises(TemotoError) as info:
        call_raw(**fields)
    message = str(info.value)
    for word in words:
        assert word in message, message
    assert any(frame.code == code for frame in info.value.stack), info.value.stack
    assert not er_processes() and not registry()['server_queries']


def test_malformed_catalogue_entries_are_reported_with_file_and_line_and_skipped(managers):
    problems = catalogue_problems()
    assert any('fake_sensors.yaml:' in p and "'bad_no_type'" in p and 'type is missing' in p for p in problems)
    assert any("'bad_topic'" in p and 'not a legal ROS topic name' in p for p in problems)
    names = catalogue()
    assert 'bad_no_type' not in names and 'bad_topic' not in names and 'fake_lidar_a' in names
    with open(FAKE_CATALOGUE) as f:
        lines = f.read().splitlines()
    where = next(p for p in problems if "'bad_no_type'" in p).split(': ')[0]
    line = int(where.rsplit(':', 1)[1])
    assert 'bad_no_type' in lines[line - 1]


def test_cli_lists_the_live_catalogue_and_checks_files(managers, capsys):
    from temoto_sensor_manager.cli import main
    assert main([]) == 0
    out = capsys.readouterr().out
    assert 'fake_lidar_a' in out and 'realsense_d435' in out and 'catalogue problem' in out
    assert main(['check', FAKE_CATALOGUE]) == 1
    out = capsys.readouterr().out
    assert "error %s:" % FAKE_CATALOGUE in out and 'bad_no_type' in out
    assert main(['--ns', 'nowhere']) == 1
