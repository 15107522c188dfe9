"""The whole demo, headless, as a user runs it (``temoto demo``); its assertions read the bag.

The demo starts its own roscore, so it runs as a subprocess with an environment that does not
point at the test session's master, and with a token of its own: every process it starts
inherits the token, so the census finds anything it leaves behind, at any depth. (Not the
session's token: the demo's own census would count this worker's roscore as its leftover.)
"""
import json
import os
import subprocess
import sys

import pytest

from temoto_testing.demo import run_demo_cli

DEMO_TIMEOUT = 150          # hang catcher; the goal (< 90 s) is the benchmark's business
MAX_GAP_S = 5.0
HANG_S = 5.0        # catches a FAILED that hangs, not a slow machine


def run_demo(tmp_path_factory, *args):
    out = tmp_path_factory.mktemp('demo') / 'run'
    proc, left = run_demo_cli(['--out', str(out), '--stage-timeout', '40'] + list(args), DEMO_TIMEOUT)
    return proc, out, left


@pytest.fixture(scope='module')
def demo_run(tmp_path_factory):
    return run_demo(tmp_path_factory)


def test_kill_managers_kills_each_manager_once_and_the_view_stays_up(tmp_path_factory):
    """``--kill-managers``: each manager SIGKILLed while the first view is up, respawned, recovered from its
    journal; the view stays up (the bag and the report say so); the camera unplugged while the Sensor Manager
    is down fails the view over once it is back; and the failover still works after."""
    proc, out, left = run_demo(tmp_path_factory, '--kill-managers', '--seed', '7')
    assert proc.returncode == 0, 'rc %s\nstdout:\n%s\nstderr:\n%s' % (proc.returncode, proc.stdout, proc.stderr[-4000:])
    assert left == []
    killed = [l for l in proc.stdout.splitlines() if 'SIGKILLed' in l]
    assert len(killed) == 4, proc.stdout
    report = json.loads((out / 'report.json').read_text())
    kills = report['kills']
    assert sorted(k['node'] for k in kills) == ['/temoto_context_manager', '/temoto_er_manager',
                                                '/temoto_output_manager', '/temoto_sensor_manager']
    for k in kills:
        assert k['recovered_s'] is not None, k
        if k['node'] == '/temoto_sensor_manager':
            # the camera was unplugged while it was down: its FAILED reached the action after the recovery
            assert k['unplugged'] == 'd435' and k['view_stayed_up'], k
            continue
        assert k['displays_removed'] == 0, k
        # the stream kept coming (no stop, no failover); whether its gaps stayed within its own frame period
        # is a timing figure of the report and the benchmark, on a machine this test shares with others
        assert k['longest_gap'] is not None and k['longest_gap'] < MAX_GAP_S, k
    assert any('unplugged d435 (crash) while /temoto_sensor_manager is down' in l for l in proc.stdout.splitlines())
    assert any('arm LIDAR stitched cloud on screen after unplugging d435 (crash) while the Sensor Manager was down'
               in l for l in proc.stdout.splitlines()), proc.stdout
    assert [(f['device'], f['mode']) for f in report['failures']] == [('d435', 'crash'), ('hokuyo', 'stall')]
    assert all(f['action_t'] is not None for f in report['failures']), 'FAILED reached the action after the kills'
    assert 'Managers killed' in (out / 'report.md').read_text()


def test_demo_exits_0_and_prints_one_line_per_stage(demo_run):
    proc, out, _ = demo_run
    assert proc.returncode == 0, 'rc %s\nstdout:\n%s\nstderr:\n%s' % (proc.returncode, proc.stdout, proc.stderr[-4000:])
    lines = [l for l in proc.stdout.splitlines() if l.startswith('[')]
    assert any('RGB-D camera cloud on screen' in l for l in lines)
    assert any('arm LIDAR stitched cloud on screen after unplugging d435 (crash)' in l for l in lines)
    assert any('base LIDAR scan on screen after unplugging hokuyo (stall)' in l for l in lines)


def test_no_process_remains(demo_run):
    _, _, left = demo_run
    assert left == []


def test_bag_shows_three_stages_in_order_and_failed_reaching_the_action(demo_run):
    proc, out, _ = demo_run
    from temoto_demo.report import analyse, load_run
    bag = out / 'failover.bag'
    assert bag.exists(), proc.stderr[-2000:]
    run = load_run(str(bag))
    an = analyse(run)
    assert [s.index for s in an.stages] == [0, 1, 2]
    assert [s.topic for s in an.stages] == ['/d435/depth_registered/points', '/laser_stitcher/cloud', '/sick/scan']
    frames = [s.first_frame_t for s in an.stages]
    assert None not in frames and frames == sorted(frames)
    assert [(f.device, f.mode) for f in an.failures] == [('d435', 'crash'), ('hokuyo', 'stall')]
    assert an.standby == 'cold' and [s.via for s in an.stages] == ['start', 'failover', 'failover']
    for f in an.failures:
        assert f.failed_t is not None, 'no FAILED status after unplugging %s' % f.device
        assert f.action_t is not None and f.action_t >= f.unplug_t, 'FAILED never reached the action (%s)' % f.device
        assert f.display_gap is not None and 0 < f.display_gap < MAX_GAP_S, \
            '%s: display gap %s s' % (f.device, f.display_gap)
    # the ER Manager sees the crash, the Sensor Manager's stall detector the stall
    assert 'temoto_er_manager' in an.failures[0].failed_by
    assert 'temoto_sensor_manager' in an.failures[1].failed_by


def test_report_files_exist_and_screenshots_show_data(demo_run):
    proc, out, _ = demo_run
    from temoto_demo.report import diff_fraction
    report = (out / 'report.md').read_text()
    assert (out / 'timeline.png').stat().st_size > 10000
    shots = {p.name.split('_', 2)[2][:-4]: p.read_bytes() for p in out.glob('screenshot_*.png')}
    # (a missing screenshot is one of the demo's problems, which it prints)
    assert set(shots) == {'rgbd', 'arm_cloud', 'base_scan', 'empty_view'}, proc.stderr[-3000:]
    for name in ('rgbd', 'arm_cloud', 'base_scan'):
        assert '](screenshot_' in report and name in report
        # a scan is a few thin lines: a real but small share of the 960x600 view
        assert diff_fraction(shots[name], shots['empty_view']) > 0.0005, name
    assert diff_fraction(shots['arm_cloud'], shots['rgbd']) > 0.005
    # the recorded topics as the bag holds them: the engine's events under their inert name, never the live one
    listed = report.split('## Recorded topics', 1)[1]
    assert '`/temoto_demo/recorded/temoto/action_engine/events`' in listed, listed
    assert '`/temoto/action_engine/events`' not in listed and '`/temoto/human_chatter`' not in listed, listed


def test_every_view_lasts_at_least_two_seconds_in_the_bag(demo_run):
    """The demo stopped right after the last failover: the SICK scan lasted 0.15 s (4 messages) in the bag,
    so neither the bag nor its replay showed the last view."""
    from pathlib import Path
    from rosbags.highlevel import AnyReader
    from temoto_demo import topics as T
    _, out, _ = demo_run
    spans = {}
    with AnyReader([Path(str(out / 'failover.bag'))]) as reader:
        streams = [c for c in reader.connections if c.topic.startswith(T.STREAMS_PREFIX + '/')]
        for conn, stamp, _ in reader.messages(connections=streams):
            first, _last = spans.get(conn.topic, (stamp, stamp))
            spans[conn.topic] = (first, stamp)
    lasted = {t[len(T.STREAMS_PREFIX):]: (b - a) * 1e-9 for t, (a, b) in spans.items()}
    for stream in ('/d435/depth_registered/points', '/laser_stitcher/cloud', '/sick/scan'):
        assert lasted.get(stream, 0) >= 2.0, lasted


BAG_BUDGET_BYTES = 30 * 1024 * 1024


def bag_topics(bag):
    from pathlib import Path
    from rosbags.highlevel import AnyReader
    with AnyReader([Path(str(bag))]) as reader:
        counts = {}
        for c in reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
    return counts


def test_the_bag_holds_every_displayed_stream_with_tf_and_the_robot_within_its_budget(demo_run):
    _, out, _ = demo_run
    from temoto_demo import topics as T
    bag = out / 'failover.bag'
    counts = bag_topics(bag)
    for stream in ('/d435/depth_registered/points', '/laser_stitcher/cloud', '/sick/scan'):
        assert counts.get(T.STREAMS_PREFIX + stream, 0) > 0, 'no %s in the bag: %s' % (stream, sorted(counts))
    assert counts.get('/tf', 0) > 0 and counts.get('/tf_static', 0) >= 1
    assert counts.get(T.ROBOT_DESCRIPTION) == 1
    assert bag.stat().st_size <= BAG_BUDGET_BYTES, '%.1f MB' % (bag.stat().st_size / 1e6)


def test_playing_the_bag_on_a_live_master_cannot_act(demo_run, rospy_client, ros_master):
    """The instruction, the cables, the registrars' statuses, the action engine's events and feedback and the
    displays' events are in the bag under inert names: a plain `rosbag play` publishes none of the topics a
    live stack listens to (it used to start a graph and unplug a live driver, and then made a live speech
    node announce failures that never happened)."""
    import rospy
    from std_msgs.msg import Header, String
    from vaultbot_sim.msg import DeviceStates
    from temoto_core.msg import ResourceStatus
    from temoto_testing import wait_for
    from temoto_demo import topics as T
    _, out, _ = demo_run
    bag = out / 'failover.bag'
    counts = bag_topics(bag)
    assert not [t for t in counts if T.acts_on_a_live_system(t)], sorted(counts)
    assert counts.get(T.inert_name('/temoto/human_chatter')) == 1
    assert counts.get(T.inert_name('/temoto/action_engine/events'), 0) > 0
    heard = []
    subs = [rospy.Subscriber('/temoto/human_chatter', String, heard.append),
            rospy.Subscriber('/temoto/action_engine/events', String, heard.append),
            rospy.Subscriber('/temoto/action_engine/feedback', String, heard.append),
            rospy.Subscriber('/vaultbot_sim/device_states', DeviceStates, heard.append),
            rospy.Subscriber('/temoto/temoto_sensor_manager/status', ResourceStatus, heard.append)]
    ticks = []
    subs.append(rospy.Subscriber(T.TICKS, Header, ticks.append))
    try:
        # -d: the player's own pause after advertising, so that subscribers are connected when it plays
        play = subprocess.run(['rosbag', 'play', '-q', '-r', '4', '-d', '1', str(bag)], env=ros_master.env,
                              capture_output=True, text=True, timeout=120)
        assert play.returncode == 0, play.stderr[-2000:]
        wait_for(lambda: ticks, 10, 'the played ticks')
    finally:
        for sub in subs:
            sub.unregister()
    assert heard == []


def test_temoto_replay_shows_the_three_views_again_on_a_master_of_its_own(demo_run, tmp_path):
    _, out, _ = demo_run
    from temoto_demo.report import diff_fraction
    master_vars = ('ROS_MASTER_URI', 'ROS_IP', 'ROS_HOSTNAME', 'DISPLAY')
    env = {k: v for k, v in os.environ.items() if k not in master_vars}   # it needs no master: it makes one
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'replay', str(out / 'failover.bag'),
                           '--out', str(tmp_path)], env=env, capture_output=True, text=True, timeout=DEMO_TIMEOUT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    shots = sorted(tmp_path.glob('replay_*.png'))
    assert [p.name for p in shots] == ['replay_1_d435_depth_registered_points.png',
                                       'replay_2_laser_stitcher_cloud.png', 'replay_3_sick_scan.png']
    views = [p.read_bytes() for p in shots]
    # each view differs from the next: the failed view went, the substitute came
    assert diff_fraction(views[0], views[1]) > 0.005 and diff_fraction(views[1], views[2]) > 0.0005


def test_demo_across_two_hosts_fails_over_with_the_sensors_on_the_robot_and_rviz_on_the_station(tmp_path_factory):
    """``--hosts 2``: the master, the simulation and the robot's managers (and so the drivers) on the robot host,
    the action engine and RViz on the operator's station, two network namespaces joined by a veth pair. The
    view fails over as on one host, each FAILED reaches the action across the link, and nothing is left behind:
    no process, no namespace."""
    from temoto_core import hosts as hosts_mod
    from temoto_demo.report import analyse, load_run
    assert not hosts_mod.unavailable(), hosts_mod.unavailable()
    proc, out, left = run_demo(tmp_path_factory, '--hosts', '2')
    assert proc.returncode == 0, 'rc %s\nstdout:\n%s\nstderr:\n%s' % (proc.returncode, proc.stdout, proc.stderr[-4000:])
    assert left == []
    # its own namespaces, by name: another two-host run on the machine (a benchmark, a chaos history) has its own
    names = json.loads((out / 'demo.json').read_text())['hosts']
    assert len(names) == 3 and not set(names) & set(hosts_mod._ip('netns', 'list').stdout.split()), names
    lines = [line for line in proc.stdout.splitlines() if line.startswith('[')]
    assert any('two hosts: robot 198.18.0.1' in line for line in lines), proc.stdout
    assert any('base LIDAR scan on screen after unplugging hokuyo (stall)' in line for line in lines), proc.stdout
    # the drivers were started by the robot's ER Manager, RViz by the station's
    robot_er = (out / 'logs' / 'robot' / 'vaultbot.temoto_er_manager.log').read_text()
    station_er = (out / 'logs' / 'operator' / 'temoto_er_manager.log').read_text()
    assert 'started vaultbot_sim/d435_driver for /vaultbot/temoto_sensor_manager' in robot_er
    assert 'rviz_host' in station_er and 'rviz_host' not in robot_er and 'd435_driver' not in station_er
    an = analyse(load_run(str(out / 'failover.bag')))
    # every topic of the robot is in its namespace; the last view is shown again once the cable is plugged back
    topics = [s.topic for s in an.stages]
    assert topics[:3] == ['/vaultbot/d435/depth_registered/points', '/vaultbot/laser_stitcher/cloud',
                          '/vaultbot/sick/scan'] and topics[-1] == '/vaultbot/sick/scan', topics
    # cold: the station's scanner cannot start while the master is across the cut; it may be shown after the
    # heal, before the view fails back to the better base scan
    assert topics[3:-1] in ([], ['/site_lidar/scan']), topics
    assert [(f.device, f.mode) for f in an.failures] == [('d435', 'crash'), ('hokuyo', 'stall')]
    for f in an.failures:
        assert f.action_t is not None and f.action_t >= f.unplug_t, 'FAILED never reached the action (%s)' % f.device
    # the cable pulled while the last view was up: the action heard FAILED (the owner liveness bound, 0.7 s, plus
    # a generous margin for a loaded machine), the frozen view went off screen, and came back after the heal
    assert any('link cut: the action heard FAILED' in line for line in lines), proc.stdout
    assert any('link plugged back: base LIDAR scan on screen again' in line for line in lines), proc.stdout
    partition = json.loads((out / 'demo.json').read_text())['partition']
    assert partition['failed_heard_s'] < HANG_S, partition
    assert 'its host is cut off or down' in partition['message'], partition


# Beside the other worker, the station's 20 Hz scanner once went 0.20 s without a message just after the link
# healed (limit 0.19 s), was found stalled, and the view failed back early (a clean-clone suite at 2634e2e), so
# this ran alone for a while. The stall detector now counts what the driver and its own threads waited for a
# CPU (temoto_core/stall/starvation.py; bench_stall_hosts.py: 0 false FAILED in 10 min of cut and healed
# links beside 2 CPU hogs), and the test runs with the others again.
def test_demo_across_two_hosts_under_hot_standby_shows_the_station_scanner_while_the_robot_is_cut_off(
        tmp_path_factory):
    """The station's own sensor (the lab's fixed scanner, served by the station's Sensor Manager) ends the view's
    list. Under hot standby it streams into a hidden display before the cut, so when the robot's link fails the
    view switches to it, with the robot's master out of reach; after the heal the view fails back to the robot."""
    from temoto_core import hosts as hosts_mod
    from temoto_demo.report import analyse, load_run
    assert not hosts_mod.unavailable(), hosts_mod.unavailable()
    proc, out, left = run_demo(tmp_path_factory, '--hosts', '2', '--standby', 'hot')
    assert proc.returncode == 0, 'rc %s\nstdout:\n%s\nstderr:\n%s' % (proc.returncode, proc.stdout, proc.stderr[-4000:])
    assert left == []
    lines = [line for line in proc.stdout.splitlines() if line.startswith('[')]
    assert any('link cut: FAILED heard in' in line and 'site LIDAR scan (station) on screen' in line
               for line in lines), proc.stdout
    assert any('link plugged back: base LIDAR scan on screen again' in line for line in lines), proc.stdout
    # the scanner ran on the station, started by the station's own Sensor Manager and ER Manager
    station_er = (out / 'logs' / 'operator' / 'temoto_er_manager.log').read_text()
    assert 'started vaultbot_sim/site_lidar.launch for /temoto_sensor_manager' in station_er, station_er[-2000:]
    an = analyse(load_run(str(out / 'failover.bag')))
    assert [(s.topic, s.via) for s in an.stages][2:] == [('/vaultbot/sick/scan', 'standby'),
                                                         ('/site_lidar/scan', 'standby'),
                                                         ('/vaultbot/sick/scan', 'failback')], an.stages
    station = an.stages[3]
    assert station.first_frame_t is not None, 'the station scanner was never drawn'
    partition = json.loads((out / 'demo.json').read_text())['partition']
    assert partition['failed_heard_s'] < HANG_S and partition['station_view_s'] < HANG_S, partition


def test_demo_on_two_hosts_without_root_says_why_in_one_line(tmp_path):
    """Two hosts need CAP_NET_ADMIN and CAP_SYS_ADMIN: a process without them (here: root with both dropped
    from its bounding set) is told so in one line, and nothing is started."""
    env = {k: v for k, v in os.environ.items() if k not in ('ROS_MASTER_URI', 'DISPLAY')}
    proc = subprocess.run(['setpriv', '--bounding-set=-net_admin,-sys_admin', '--inh-caps=-net_admin,-sys_admin',
                           sys.executable, '-m', 'temoto_bringup.cli', 'demo', '--hosts', '2', '--out',
                           str(tmp_path / 'run')], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == ['temoto demo --hosts 2: two hosts need root (network namespaces '
                                                'and a veth pair need CAP_NET_ADMIN and CAP_SYS_ADMIN, which this '
                                                'process lacks)'], proc.stderr
    assert not (tmp_path / 'run').exists()


@pytest.mark.parametrize('standby', ['warm', 'hot'])
def test_standby_policies_fail_over_to_the_running_spare_and_hot_fails_back_with_no_blank_frame(tmp_path_factory,
                                                                                                standby):
    """``--standby warm|hot --replug``: each failover takes the spare that was already running (no driver started
    after the FAILED), and the camera plugged back is shown again after the hold; under hot, with no frame
    rendered between the old view going off and the camera's view being drawn (RViz's frame counts)."""
    from temoto_demo.report import analyse, load_run
    proc, out, left = run_demo(tmp_path_factory, '--standby', standby, '--replug')
    assert proc.returncode == 0, 'rc %s\nstdout:\n%s\nstderr:\n%s' % (proc.returncode, proc.stdout, proc.stderr[-4000:])
    assert left == []
    assert sum('%s standby ready' % standby in line for line in proc.stdout.splitlines()) == 2, proc.stdout
    an = analyse(load_run(str(out / 'failover.bag')))
    assert an.standby == standby
    assert [(s.index, s.via) for s in an.stages] == [(0, 'start'), (1, 'standby'), (2, 'standby'), (0, 'failback')]
    for f in an.failures:
        assert f.action_t is not None and f.display_gap is not None and 0 < f.display_gap < MAX_GAP_S, f
    [fb] = an.failbacks
    assert fb.device == 'd435' and fb.label == 'RGB-D camera cloud' and fb.first_frame_t is not None
    if standby == 'hot':
        assert fb.blank_frames == 0, fb
    report = json.loads((out / 'report.json').read_text())
    assert report['standby'] == standby and report['failbacks'][0]['delay_s'] > 0
    assert 'Fail-backs' in (out / 'report.md').read_text()


# a whole demo with espeak-ng and pocketsphinx decoding: in the first suite run that had it beside the other
# worker, three tests there failed on timing (a stall seen as a crash, a fail-back frame missed, an RViz host
# still registered), each of which passed alone; so it runs alone
@pytest.mark.alone
def test_a_spoken_demo_hears_the_instruction_announces_each_failure_and_records_the_audio(tmp_path_factory):
    """``--voice``: espeak-ng says "show the environment" to the speech node, which the engine grounds; the
    failovers are announced; the bag holds the audio (renamed inert), what was heard and what was said."""
    from pathlib import Path
    from rosbags.highlevel import AnyReader
    proc, out, left = run_demo(tmp_path_factory, '--voice')
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert 'heard "show the environment"' in proc.stdout
    assert left == []
    said = {}
    with AnyReader([Path(str(out / 'failover.bag'))]) as reader:
        for conn, _, raw in reader.messages():
            if 'speech' in conn.topic:
                msg = reader.deserialize(raw, conn.msgtype)
                said.setdefault(conn.topic, []).append(msg.data)
    heard, announcements = '/temoto_demo/recorded/temoto/speech/heard', '/temoto_demo/recorded/temoto/speech/announcements'
    assert '/temoto/speech/heard' not in said and '/temoto/speech/announcements' not in said, sorted(said)
    assert [json.loads(h)['text'] for h in said[heard]] == ['show the environment']
    assert '/temoto/speech/audio' not in said and sum(len(a) for a in said['/temoto_demo/recorded/temoto/speech/audio']) \
        > 16000 * 2 * 0.5, 'the spoken instruction, inert, at least half a second of it'
    expected = ['showing the RGB-D camera cloud', 'the RGB-D camera cloud failed',
                'switching to the arm LIDAR stitched cloud', 'the arm LIDAR stitched cloud failed',
                'switching to the base LIDAR scan']
    announced = iter(said[announcements])
    assert all(any(a == e for a in announced) for e in expected), said[announcements]  # in order
    wavs = [f for f in os.listdir(out / 'speech') if f.endswith('.wav')]
    assert 0 < len(wavs) <= len(said[announcements])     # a backlog beyond 5 drops the oldest
