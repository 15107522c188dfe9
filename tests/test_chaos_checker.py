"""The chaos checker's invariants on hand-made snapshots: each violation it must see, and a clean system it
must pass. (The runner's history against the real managers is tests/test_chaos.py.)"""
import copy
import os
import subprocess
import sys

from temoto_chaos import checker
from temoto_chaos.history import NEMESIS, VERSION, history, step
from temoto_core.wait import wait_for

ME = os.getpid()      # a pid the kernel has: a "live" process


def clean():
    sensor_manager = {'recovering': False, 'server_queries': [
        {'server': 'start_sensor', 'internal_id': 1, 'state': 'active', 'failure': '',
         'summary': {'sensor_type': 'lidar'},
         'consumers': [{'client_name': '/chaos_client_0_1', 'resource_id': 11}]}]}
    # the driver is the Sensor Manager's (not a client's: not checked against the clients)
    er_manager = {'recovering': False, 'server_queries': [
        {'server': 'load_process', 'internal_id': 5, 'state': 'active', 'failure': '',
         'summary': {'executable': 'sick_driver'},
         'consumers': [{'client_name': '/chaos/temoto_sensor_manager', 'resource_id': 21}]}]}
    procs = {'processes': [{'resource_id': 5, 'label': 'vaultbot_sim/sick_driver', 'state': 'running',
                            'processes': [{'pid': ME, 'state': 'running'}]}]}
    client = {'node': '/chaos_client_0_1', 'registrar': 'rr0', 'pid': 1, 'held': {'101': {'kind': 'sensor', 'what': 'lidar'}},
              'failed_heard': {}, 'calls': {'load': {'count': 1, 'failed': 0, 'max_s': 0.5}}}
    registry = {'client_queries': [{'target': '/chaos/temoto_sensor_manager/start_sensor', 'external_id': 11,
                                    'local_ids': [101], 'state': 'active'}]}
    return checker.Snapshot(checker.managers('chaos'), {'Sensor Manager': sensor_manager, 'ER Manager': er_manager}, {'ER Manager': procs},
                            {0: client}, {0: registry}, {ME: ('sick_driver', 'python3 -m zygote')})


def sm(snap):
    return snap.registries['Sensor Manager']


def er(snap):
    return snap.registries['ER Manager']


def er_processes(snap):
    return snap.processes['ER Manager']


def with_throttle(snap):
    """``snap`` where client 0 also holds a throttle process of its own, served by the ER Manager."""
    er(snap)['server_queries'].append(
        {'server': 'load_process', 'internal_id': 6, 'state': 'active', 'failure': '',
         'summary': {'executable': '/usr/lib/topic_tools/throttle'},
         'consumers': [{'client_name': '/chaos_client_0_1', 'resource_id': 31}]})
    snap.clients[0]['held']['103'] = {'kind': 'process', 'what': 'messages sick/scan 2 sick/scan_throttled'}
    snap.client_registries[0]['client_queries'].append(
        {'target': '/chaos/temoto_er_manager/load_process', 'external_id': 31, 'local_ids': [103], 'state': 'active'})
    return snap


def test_a_consistent_system_passes():
    assert checker.check(clean()) == []


def test_an_unsettled_system_is_reported_as_such_and_not_checked_further():
    snap = clean()
    sm(snap)['recovering'] = True
    snap.resources[ME + 1] = ('sick_driver', '')   # would be a violation, but nothing is checked yet
    assert checker.check(snap) == ['the Sensor Manager is still recovering']
    snap = clean()
    snap.registries['ER Manager'] = None
    assert checker.check(snap) == ['the ER Manager does not answer']


def test_a_load_under_way_hides_only_its_own_entry():
    """With the clients working concurrently a manager almost always has a load under way somewhere: that
    entry's references are compared once it settles, and everything else is checked meanwhile."""
    snap = clean()
    sm(snap)['server_queries'][0]['state'] = 'loading'
    sm(snap)['server_queries'][0]['consumers'].append({'client_name': '/chaos_client_1_1', 'resource_id': 12})
    assert checker.check(snap) == []
    snap.resources[ME + 1] = ('sick_driver', 'python3 -m zygote')
    assert checker.check(snap) == ['sick_driver (pid %d) runs, but no ER Manager entry has it' % (ME + 1),
                                   'sick_driver runs 2 times: [%d, %d]' % (ME, ME + 1)]
    sm(snap)['server_queries'][0]['state'] = 'active'
    assert 'a leaked reference' in checker.check(snap)[-1]


def test_a_call_under_way_at_a_client_defers_only_its_own_kind_and_never_a_missed_failed():
    # an unload under way: the client's registry may already have dropped what it still lists as held
    snap = clean()
    snap.client_registries[0]['client_queries'] = []
    assert checker.check(snap) == ['client 0: acknowledged load 101 (lidar) is not in its registry: lost',
                                   'sensor id 11 of start_sensor is counted as held by /chaos_client_0_1, which '
                                   'holds nothing of it: a leaked reference']
    snap.clients[0]['pending'] = [{'op': 'unload', 'kind': 'sensor', 'id': 101}]
    assert checker.check(snap) == []
    # a load of a sensor under way: the Sensor Manager may count the reference before the client has it
    snap = clean()
    sm(snap)['server_queries'][0]['consumers'].append({'client_name': '/chaos_client_0_1', 'resource_id': 12})
    snap.clients[0]['pending'] = [{'op': 'load', 'kind': 'sensor', 'id': 0}]
    assert checker.check(snap) == []
    # ... which defers nothing of another kind, and no FAILED the client should have heard
    snap = with_throttle(snap)
    er(snap)['server_queries'][1]['consumers'] = []
    sm(snap)['server_queries'][0].update(state='failed', failure='sick_driver died')
    assert sorted(checker.check(snap)) == ['client 0 holds process id 31, which is not served to it: lost',
                                           'client 0 never heard the FAILED of its sensor lidar (sick_driver died)']


def test_a_driver_that_no_entry_has_and_a_driver_running_twice_are_violations():
    snap = clean()
    snap.resources[ME + 1] = ('sick_driver', 'python3 -m zygote')
    found = checker.check(snap)
    assert 'sick_driver (pid %d) runs, but no ER Manager entry has it' % (ME + 1) in found
    assert any('sick_driver runs 2 times' in v for v in found), found


def test_consumer_processes_run_once_per_command_line():
    snap = clean()
    er_processes(snap)['processes'][0]['processes'].append({'pid': ME + 1, 'state': 'running'})
    er_processes(snap)['processes'][0]['processes'].append({'pid': ME + 2, 'state': 'running'})
    snap.resources = {ME: ('sick_driver', ''), ME + 1: ('throttle', 'throttle messages a 2 a_throttled'),
                      ME + 2: ('throttle', 'throttle messages b 2 b_throttled')}
    assert [v for v in checker.check(snap) if 'runs' in v] == []
    snap.resources[ME + 2] = ('throttle', 'throttle messages a 2 a_throttled')
    assert [v for v in checker.check(snap) if 'runs' in v] == [
        'throttle messages a 2 a_throttled runs 2 times: [%d, %d]' % (ME + 1, ME + 2)]


def test_a_dead_process_still_listed_as_running_is_a_violation():
    snap = clean()
    dead = 2 ** 22 + 7           # above pid_max's default: no such process
    er_processes(snap)['processes'][0]['processes'][0]['pid'] = dead
    snap.resources = {}
    assert checker.check(snap) == ['the ER Manager lists vaultbot_sim/sick_driver (pid %d) as running, but it is gone'
                                   % dead]


def test_an_acknowledged_load_missing_from_the_client_or_the_manager_is_lost():
    snap = clean()
    snap.clients[0]['held']['102'] = {'kind': 'sensor', 'what': 'depth camera'}
    assert checker.check(snap) == ['client 0: acknowledged load 102 (depth camera) is not in its registry: lost']
    snap = clean()
    sm(snap)['server_queries'][0]['consumers'] = []
    assert checker.check(snap) == ['client 0 holds sensor id 11, which is not served to it: lost']
    snap = with_throttle(clean())
    assert checker.check(snap) == []
    er(snap)['server_queries'][1]['consumers'] = []
    assert checker.check(snap) == ['client 0 holds process id 31, which is not served to it: lost']


def test_a_reference_nobody_holds_is_a_leak():
    snap = clean()
    sm(snap)['server_queries'][0]['consumers'].append({'client_name': '/chaos_client_1_1',
                                                                  'resource_id': 12})
    assert checker.check(snap) == ['sensor id 12 of start_sensor is counted as held by /chaos_client_1_1, which holds '
                                   'nothing of it: a leaked reference']
    # a client the nemesis killed: its owner has its liveness bound to release what it held, and no longer
    snap.killed = {'chaos_client_1_1': 1.0}
    assert checker.check(snap) == []
    snap.killed = {'chaos_client_1_1': checker.KILLED_CLIENT_BOUND + 0.1}
    assert len(checker.check(snap)) == 1
    snap = clean()           # the Sensor Manager's own references to its drivers are not the clients' to hold
    er(snap)['server_queries'][0]['consumers'].append({'client_name': '/chaos/temoto_sensor_manager',
                                                              'resource_id': 22})
    assert checker.check(snap) == []


def test_a_failed_resource_whose_holder_never_heard_it_is_a_violation():
    snap = clean()
    sm(snap)['server_queries'][0].update(state='failed', failure='sick_driver died')
    assert checker.check(snap) == ['client 0 never heard the FAILED of its sensor lidar (sick_driver died)']
    heard = copy.deepcopy(snap)
    heard.clients[0]['failed_heard']['101'] = 'sick_driver died'
    assert checker.check(heard) == []
    snap = with_throttle(clean())
    er(snap)['server_queries'][1].update(state='failed', failure='throttle killed')
    assert checker.check(snap) == ['client 0 never heard the FAILED of its process /usr/lib/topic_tools/throttle '
                                   '(throttle killed)']


def test_a_call_past_its_deadline_is_a_violation():
    snap = clean()
    snap.clients[0]['calls']['unload'] = {'count': 3, 'failed': 1, 'max_s': 30.0}
    assert checker.check(snap) == ['client 0: a unload took 30.0 s, past its deadline']


def test_a_history_is_the_same_for_a_seed_and_its_prefix_replays_it():
    full = list(history(7, 200, 3))
    assert [s.describe() for s in full] == [s.describe() for s in history(7, 200, 3)]
    assert [s.describe() for s in history(7, 50, 3)] == [s.describe() for s in full[:50]]
    assert step(7, 120, 3) == full[120]
    assert {s.kind for s in full} >= {'load_sensor', 'load_process', 'unload', 'kill_driver', 'kill_consumer',
                                      'kill_client', 'kill_manager', 'stop_manager', 'unplug', 'replug'}
    assert [s.describe() for s in history(8, 50, 3)] != [s.describe() for s in full[:50]]


def test_every_fault_kind_is_drawn_and_an_older_history_version_still_replays_its_seeds():
    kinds = {s.kind for s in history(7, 3000, 3)}
    assert kinds >= {kind for kind, _ in NEMESIS[VERSION]}
    # version 1 (sensors only): seed 17's step 132 was the cut link that found the owner-watch race
    assert step(17, 132, 3, version=1).kind == 'partition'
    assert {s.kind for s in history(17, 300, 3, version=1)}.isdisjoint({'load_process', 'kill_consumer',
                                                                         'kill_robot'})


def test_history_6_draws_arm_goals_halts_and_manipulator_kills_and_leaves_history_5_as_it_was():
    sixth = list(history(7, 3000, 6, version=6))
    kinds = {s.kind for s in sixth}
    assert kinds >= {kind for kind, _ in NEMESIS[6]} | {'arm_goal'}
    goal = next(s for s in sixth if s.kind == 'arm_goal')
    assert goal.args['arm'] == 'left_arm' and len(goal.args['offsets']) == 6 and 0 < goal.args['speed'] <= 1.0
    assert all(abs(v) <= 0.3 for s in sixth if s.kind == 'arm_goal' for v in s.args['offsets'])
    fifth = [s.describe() for s in history(7, 300, 6, version=5)]
    assert not any(k in line for line in fifth for k in ('arm_goal', ' halt', 'kill_manipulator'))


def test_a_call_that_raised_no_temoto_error_is_a_violation():
    snap = clean()
    snap.clients[0]['unexpected'] = ["b'load_process' raised TransportTerminated: 32Broken pipe"]
    assert checker.check(snap) == ["client 0: a call failed with no TemotoError: b'load_process' raised "
                                   "TransportTerminated: 32Broken pipe"]


def test_a_driver_is_found_whether_it_was_forked_by_the_zygote_or_started_plainly(tmp_path):
    """A plain start is named after its interpreter ('python'): found by its script (history 2's robot started
    its drivers plainly, and the checker, which looked at the kernel's name only, saw none of them)."""
    script = tmp_path / 'd435_driver'
    script.write_text('import sys\nsys.stdin.read()\n')
    plain = subprocess.Popen([sys.executable, str(script), 'd435/depth'], stdin=subprocess.PIPE)
    try:
        # the kernel shows an empty command line for a moment after the exec
        wait_for(lambda: checker.resource_processes([plain.pid]), 10, "the driver's command line")
        assert checker.resource_processes([plain.pid]) == {
            plain.pid: ('d435_driver', '%s %s d435/depth' % (sys.executable, script))}
        assert checker.resource_processes([os.getpid()]) == {}       # pytest: not a resource
    finally:
        plain.communicate(b'', timeout=10)
    # forked from the zygote: the kernel's name (the script's, cut to 15 characters) and the zygote's cmdline
    assert checker.resource_name('color_blob_trac', ['python', '-c', 'zygote']) == 'color_blob_trac'
    assert checker.resource_name('python3', ['/usr/bin/python3', '/x/nodes/color_blob_tracker']) == 'color_blob_trac'
    assert checker.resource_name('throttle', ['/usr/lib/topic_tools/throttle', 'messages']) == 'throttle'


def test_a_display_whose_holder_never_heard_its_failed_and_a_station_process_nobody_lists_are_violations():
    snap = clean()
    snap.managers = checker.managers('chaos', 'chaos_station')
    om = {'recovering': False, 'server_queries': [
        {'server': 'load_rviz_plugin', 'internal_id': 3, 'state': 'failed', 'failure': 'the RViz host died',
         'summary': {'type': 'laser scan'}, 'consumers': [{'client_name': '/chaos_client_0_1', 'resource_id': 41}]}]}
    empty = {'recovering': False, 'server_queries': []}
    snap.registries.update({'Context Manager': empty, "station's ER Manager": empty, 'Output Manager': om})
    snap.processes["station's ER Manager"] = {'processes': []}
    snap.clients[0]['held']['104'] = {'kind': 'display', 'what': 'laser scan /chaos/sick/scan', 'failed': ''}
    snap.client_registries[0]['client_queries'].append(
        {'target': '/chaos_station/temoto_output_manager/load_rviz_plugin', 'external_id': 41, 'local_ids': [104],
         'state': 'active'})
    assert checker.check(snap) == ['client 0 never heard the FAILED of its display laser scan (the RViz host died)']
    snap.clients[0]['failed_heard']['104'] = 'the RViz host died'
    assert checker.check(snap) == []
    snap.resources[ME + 3] = ('rviz_host', 'python3 -c zygote')
    assert checker.check(snap) == ['rviz_host (pid %d) runs, but no ER Manager entry has it' % (ME + 3)]
    snap.processes["station's ER Manager"] = None
    assert checker.check(snap) == ["the station's ER Manager does not list its processes"]


def test_two_trackers_algorithms_each_in_an_entry_are_not_a_resource_running_twice():
    """A tracker that FAILED keeps its algorithm until released; an equal request meanwhile gets a new one."""
    live = [subprocess.Popen([sys.executable, '-c', 'import sys; sys.stdin.read()'], stdin=subprocess.PIPE)
            for _ in range(2)]
    try:
        snap = clean()
        for proc in live:
            snap.resources[proc.pid] = ('color_blob_trac', 'python3 -c zygote')
        assert checker.check(snap) == ['color_blob_trac (pid %d) runs, but no ER Manager entry has it' % proc.pid
                                       for proc in live]
        er_processes(snap)['processes'][0]['processes'] += [{'pid': proc.pid, 'state': 'running'} for proc in live]
        assert checker.check(snap) == []
    finally:
        for proc in live:
            proc.communicate(b'', timeout=10)


def test_a_resource_started_after_the_registries_were_read_is_not_expected_in_them_yet():
    snap = clean()
    snap.resources[ME + 1] = ('throttle', '/usr/lib/topic_tools/throttle messages a 1 b')
    assert checker.check(snap) == ['throttle (pid %d) runs, but no ER Manager entry has it' % (ME + 1)]
    snap.created = {ME + 1: 1000.0}
    snap.read_at = 999.0
    assert checker.check(snap) == []
    # ... or while the ER Manager was starting a resource (it lists a process once its start returns)
    snap.read_at = 1100.0
    assert checker.check(snap) != []
    er_processes(snap)['processes'].append({'resource_id': 7, 'label': 'throttle', 'state': 'starting',
                                            'started': 999.5, 'processes': []})
    assert checker.check(snap) == []
    er_processes(snap)['processes'][-1]['started'] = 1000.5       # a start that began after this process
    assert checker.check(snap) != []


def test_what_a_client_held_is_what_it_held_before_and_after_the_registries_were_read():
    """A call that ran between the two answers counts as under way; a client that started again is left
    out until the next look."""
    held = {'101': {'kind': 'sensor', 'what': 'lidar', 'failed': ''}}
    before = {0: {'node': '/chaos_client_0_1', 'held': dict(held), 'pending': []},
              1: {'node': '/chaos_client_1_1', 'held': {}, 'pending': []}}
    after = {0: {'node': '/chaos_client_0_1', 'held': {}, 'pending': [{'op': 'load', 'kind': 'display', 'id': 0}]},
             1: {'node': '/chaos_client_1_2', 'held': {}, 'pending': []}}
    states = checker._held_throughout(before, after)
    assert list(states) == [0]
    assert states[0]['held'] == {} and states[0]['pending'] == [{'op': 'load', 'kind': 'display', 'id': 0}]
    after[0]['held'] = dict(held, **{'102': {'kind': 'sensor', 'what': 'depth camera', 'failed': ''}})
    assert checker._held_throughout(before, after)[0]['held'] == held
