"""``temoto chaos``: a seeded history of client operations and faults against the robot's real managers,
with the checker after every step (docs/chaos.md). ``make bench`` runs the long history."""
import json
import os
import subprocess
import sys

import pytest

from temoto_core.processes import SESSION_ENV, leftover_processes
from temoto_chaos.history import CLIENTS, NEMESIS, VERSION, history
from temoto_chaos.runner import CLIENT_STEPS

SEED = 20261104      # a seed whose first 300 steps hold every kind of fault, the robot's power loss once
STEPS = 300
# a seed whose first 60 steps cut the link once, two servo streams just before, clients' steps next, and kill
# the robot host once
TWO_HOSTS_SEED = 228
TIMEOUT = 900


def run_chaos(tmp_path, *args):
    token = 'test_chaos_' + os.urandom(6).hex()
    env = {k: v for k, v in os.environ.items() if k not in ('ROS_MASTER_URI', 'ROS_IP', 'ROS_HOSTNAME', 'ROS_HOME')}
    env[SESSION_ENV] = token
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'chaos', '--out', str(tmp_path)] + list(args),
                          env=env, capture_output=True, text=True, timeout=TIMEOUT)
    left = [p for p in leftover_processes(token) if p[0] != os.getpid()]
    with open(tmp_path / 'chaos.json') as f:
        return proc, json.load(f), left


# A whole robot under faults loads the machine: beside the other worker, its 300 steps starved that worker's
# sensors into real stalls (a D435 silent 0.5 s against its 0.5 s limit), so the histories run alone.
@pytest.mark.alone
@pytest.mark.timeout(TIMEOUT * 2 + 60)     # the history and its replay, each bounded by TIMEOUT
def test_a_seeded_history_with_every_fault_keeps_every_invariant_and_replays_from_its_seed(tmp_path):
    proc, result, left = run_chaos(tmp_path / 'full', '--seed', str(SEED), '--steps', str(STEPS))
    summary = result['summary']
    assert proc.returncode == 0, 'rc %s\n%s\n%s' % (proc.returncode, proc.stdout[-3000:], proc.stderr[-3000:])
    assert summary['violations'] == [] and summary['steps'] == STEPS, summary
    assert set(summary['faults']) == {kind for kind, _ in NEMESIS[VERSION]} - {'partition'}, summary['faults']
    # every step is checked after it, but those queued while a fault lasted, checked once it ended
    assert summary['checks'] >= STEPS - sum(1 for e in result['log'] if 'during' in e)
    assert summary['leftovers'] == 0 and left == []
    assert '0 violations' in proc.stdout.splitlines()[-1]
    # the faults hit something (a kill that finds nothing to kill is no fault), and every kind of resource
    # was acknowledged at least once
    did = {}
    for e in result['log']:
        did.setdefault(e['kind'], []).append(e['did'])
    for kind in ('kill_driver', 'kill_consumer', 'kill_client', 'kill_manager'):
        assert any(text.startswith('SIGKILL') for text in did[kind]), (kind, did[kind])
    # a killed manager is a fault that lasts until its next incarnation answers
    assert any('its next incarnation answered' in text for text in did['kill_manager']), did['kill_manager']
    assert any(text.startswith('SIGKILL') for text in did['kill_controller']), did['kill_controller']
    # a fault that needs nothing a lasting one cuts off goes on meanwhile: a cable is pulled (step 138) while a
    # manager is stopped (step 137), and what both left is checked once it goes on
    stopped, unplugged = result['log'][137], result['log'][138]
    assert stopped['kind'] == 'stop_manager' and stopped['did'].startswith('SIGSTOP'), stopped
    assert unplugged['kind'].startswith('unplug') and unplugged.get('during') == 137, unplugged
    # (a tracked hand is mostly refused once the robot has moved: the person's hand is out of the camera's
    # view, and the tracker says it saw nothing; history 4's static robot has it acknowledged)
    for kind, acknowledged in (('load_sensor', ': realsense_d435'), ('load_process', 'throttle pid'),
                               ('track_object', 'refused: /chaos/temoto_context_manager/track_object refused'),
                               ('show_display', 'display '), ('navigate', ' accepted'), ('navigate', 'REJECTED: '),
                               ('servo', ' streaming'), ('grip', ' accepted')):
        assert any(acknowledged in text for text in did[kind]), (kind, did[kind])
    # the motion invariants were held against the simulation's ground truth: goals of every kind were sent,
    # some refused, and a part that moved when a stop-case fault hit it came to rest within the case's bound
    motion = summary['motion']
    assert all(motion['counts'].get('goals ' + kind) for kind in ('goal', 'servo', 'grip')), motion['counts']
    assert motion['counts'].get('refused goal'), motion['counts']
    assert 'contacts' not in motion['counts'] and 'blind drives' not in motion['counts'], motion['counts']
    # (whether a stop-case fault meets a moving part in 300 steps is the machine's timing: the bench counts them)
    measured = {case: row for case, row in motion['stop_cases'].items() if row['measured']}
    assert motion['stop_cases'] and all(row['worst_s'] <= row['bound_s'] for row in measured.values()), \
        motion['stop_cases']
    # the log is the seed's history, step by step (the clients worked concurrently: their calls overlapped)
    assert [(e['kind'], e['args']) for e in result['log']] == [(s.kind, s.args)
                                                                for s in history(SEED, STEPS, CLIENTS[VERSION])]
    assert 'working concurrently' in proc.stdout.splitlines()[0]
    assert any(e.get('call_s', 0) > e['apply_s'] + e['check_s'] for e in result['log'] if 'call_s' in e), \
        'no call outlasted its own step: nothing ran concurrently'
    # --until replays the first steps of the same history; --serial one step at a time
    proc, replay, left = run_chaos(tmp_path / 'replay', '--seed', str(SEED), '--steps', str(STEPS), '--until', '8',
                                   '--serial')
    assert proc.returncode == 0 and left == [], proc.stdout[-2000:]
    assert 'concurrently' not in proc.stdout and not any('call_s' in e for e in replay['log'])
    assert [(e['kind'], e['args']) for e in replay['log']] == [(e['kind'], e['args']) for e in result['log'][:8]]


@pytest.mark.alone
@pytest.mark.timeout(TIMEOUT + 60)
def test_across_two_hosts_a_cut_link_and_a_dead_robot_host_keep_every_invariant(tmp_path):
    from temoto_core import hosts as hosts_mod
    assert not hosts_mod.unavailable(), hosts_mod.unavailable()
    before = set(hosts_mod._ip('netns', 'list').stdout.split())
    proc, result, left = run_chaos(tmp_path, '--seed', str(TWO_HOSTS_SEED), '--steps', '60', '--hosts', '2')
    summary = result['summary']
    assert proc.returncode == 0, 'rc %s\n%s\n%s' % (proc.returncode, proc.stdout[-3000:], proc.stderr[-3000:])
    assert summary['violations'] == [], summary
    [cut] = [e for e in result['log'] if e['kind'] == 'partition']
    assert 'FAILED at their clients' in cut['did'], cut
    # the clients' next steps were queued while the link was down, and met the cut
    assert any(e.get('during') == cut['step'] for e in result['log'] if e['kind'] in CLIENT_STEPS), cut
    [power_loss] = [e for e in result['log'] if e['kind'] == 'kill_robot']
    assert 'its master too' in power_loss['did'], power_loss
    # the clients moved the robot from the station; the ground truth's watch, on the robot's host, outlived the
    # power loss (a watch that does not answer is a violation)
    motion = summary['motion']
    assert motion['counts'].get('goals servo') and motion['counts'].get('goals goal'), motion
    assert left == [] and set(hosts_mod._ip('netns', 'list').stdout.split()) <= before


def test_bad_arguments_are_refused_in_one_line_and_start_nothing(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'chaos', '--seed', '1', '--steps', '0',
                           '--out', str(tmp_path / 'x')], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and 'must be positive' in proc.stderr
    assert not (tmp_path / 'x').exists()
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'chaos', '--seed', '1', '--history', '9',
                           '--out', str(tmp_path / 'y')], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and '--history' in proc.stderr and 'invalid choice' in proc.stderr
    assert not (tmp_path / 'y').exists()
