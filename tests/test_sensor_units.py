"""ROS-free parts of the sensor and context managers: reliability, catalogue, selection, stall detector, blob finding."""
import os
import subprocess
import sys
import threading
import time
import types

import numpy as np
import pytest

from temoto_core.errors import ErrorCode, TemotoError
from temoto_context_manager.blob import find_blob, parse_rgb
from temoto_sensor_manager.catalogue import Catalogue, load_file, parse_entry
from temoto_core.reliability import Reliability
from temoto_sensor_manager.selection import candidates, plan, validate
from temoto_sensor_manager.start_times import StartDeadline
from temoto_core.stall import starvation
from temoto_core.stall.detector import StallDetector
from temoto_testing import wait_for


def test_reliability_is_a_100_sample_moving_average_from_the_prior():
    r = Reliability()
    assert r.value == pytest.approx(0.8)
    assert r.failure() == pytest.approx(0.792)          # one event moves it by (0.8 - 0) / 100
    for _ in range(100):
        r.success()
    assert r.value == pytest.approx(1.0)                # the prior and the failure have left the window
    assert Reliability(0.5).adjust(7.0) == pytest.approx(0.505)   # clamped to [0, 1]
    with pytest.raises(ValueError):
        Reliability(1.5)


def entry(name, kind='lidar', exe='x.launch', prior=0.8, topics=None):
    return parse_entry({'name': name, 'type': kind, 'package': 'p', 'executable': exe, 'reliability': prior,
                        'output_topics': topics or {'lidar_data': {'topic': '/%s/scan' % name, 'arg': 'scan'}}})


def test_one_failure_reorders_equal_priors_and_the_stable_order_breaks_ties():
    cat = Catalogue([entry('a'), entry('b')])
    q = validate('lidar', '', '', [])
    assert [e.name for e in candidates(cat, q)] == ['a', 'b']
    cat.get('a').reliability.failure()
    assert [e.name for e in candidates(cat, q)] == ['b', 'a']


def test_selection_filters_by_package_executable_and_topic_types():
    cat = Catalogue([entry('a', exe='a.launch'), entry('b', exe='b', topics={'lidar_data': '/b/scan',
                                                                           'cloud_data': '/b/cloud'})])
    assert [e.name for e in candidates(cat, validate('lidar', '', 'b', []))] == ['b']
    assert [e.name for e in candidates(cat, validate('lidar', '', '', [('cloud_data', '')]))] == ['b']
    with pytest.raises(TemotoError) as info:
        candidates(cat, validate('lidar', 'other', '', []))
    assert info.value.code == ErrorCode.SENSOR_NOT_FOUND and "package 'other'" in str(info.value)


def test_requested_names_become_launch_args_or_node_remaps():
    launch = entry('a')
    q = validate('lidar', '', '', [('lidar_data', 'pinned/scan')])
    assert plan(launch, q).args == 'scan:=/pinned/scan'
    assert plan(launch, q).topics == {'lidar_data': '/pinned/scan'}
    node = parse_entry({'name': 'n', 'type': 'lidar', 'package': 'p', 'executable': 'drv', 'args': '_rate:=5',
                        'output_topics': {'lidar_data': {'topic': '/n/scan', 'remap': 'scan'}}})
    assert plan(node, q).args == '_rate:=5 scan:=/pinned/scan'
    assert plan(node, validate('lidar', '', '', [])).args == '_rate:=5 scan:=/n/scan'


def test_requests_for_different_outputs_of_one_device_launch_it_alike():
    """Issue 52: the view asked the arm LIDAR for its scan and cloud, navigation for its cloud alone, and the
    arguments came in each request's order: two launches of one device, and the second was refused."""
    lidar = parse_entry({'name': 'h', 'type': 'lidar', 'package': 'p', 'executable': 'h.launch', 'output_topics': {
        'lidar_data': {'topic': '/h/scan', 'arg': 'scan_topic'}, 'cloud_data': {'topic': '/h/cloud', 'arg': 'cloud_topic'}}})
    view = plan(lidar, validate('lidar', '', '', [('lidar_data', ''), ('cloud_data', '')]))
    navigation = plan(lidar, validate('lidar', '', '', [('cloud_data', '')]))
    assert view.args == navigation.args == 'scan_topic:=/h/scan cloud_topic:=/h/cloud'
    assert list(view.topics) == ['lidar_data', 'cloud_data'] and navigation.topics == {'cloud_data': '/h/cloud'}


def test_malformed_entries_are_reported_with_file_and_line(tmp_path):
    path = tmp_path / 'cat.yaml'
    path.write_text('sensors:\n'
                    '  - name: ok\n    type: lidar\n    package: p\n    executable: e\n'
                    '    output_topics: {lidar_data: /s}\n'
                    '  - name: no_topics\n    type: lidar\n    package: p\n    executable: e\n'
                    '  - name: bad_rate\n    type: lidar\n    package: p\n    executable: e\n    rate: fast\n'
                    '    output_topics: {lidar_data: /s}\n')
    entries, problems = load_file(str(path))
    assert [e.name for e in entries] == ['ok']
    assert [p.where for p in problems] == ['%s:7' % path, '%s:11' % path]
    assert 'output_topics must be a non-empty mapping' in str(problems[0])
    assert 'rate must be a number' in str(problems[1])
    path.write_text('sensors: [\n')
    entries, problems = load_file(str(path))
    assert not entries and 'not valid YAML' in str(problems[0])


def test_silence_limit_defaults_to_three_periods_and_at_least_100_ms():
    e = parse_entry({'name': 'a', 'type': 't', 'package': 'p', 'executable': 'e', 'rate': 10,
                     'output_topics': {'fast': {'topic': '/f', 'rate': 100}, 'slow': '/s',
                                       'set': {'topic': '/x', 'stall_timeout': 2.5}}})
    assert e.output_topics['fast'].silence_limit() == pytest.approx(0.1)
    assert e.output_topics['slow'].silence_limit() == pytest.approx(0.3)
    assert e.output_topics['set'].silence_limit() == pytest.approx(2.5)


def fixed_probe(topic, limit, last):
    """What the stall detector reads of a probe, with a fixed limit."""
    return types.SimpleNamespace(topic=topic, limit=limit, last=last, armed=False, quiet_from=0.0,
                                 current_limit=lambda: limit, arrivals=None, silence_from=-1.0, late=0.0,
                                 caught_up=False, starved=0.0, reader_starved=lambda: 0.0,
                                 publisher_wait=None, publisher_starved=lambda since, now: 0.0)


def test_stall_detector_fires_once_after_the_limit_of_silence_and_not_while_messages_arrive():
    fired = []
    done = threading.Event()
    dog = StallDetector(lambda probe, silence, limit: (fired.append((probe.topic, silence, time.monotonic())), done.set()))
    try:
        busy = fixed_probe('busy', 0.15, last=time.monotonic())
        quiet = fixed_probe('quiet', 0.15, last=time.monotonic())
        dog.arm([busy, quiet])
        start = time.monotonic()
        while time.monotonic() - start < 0.5:          # 'busy' gets a message every 20 ms
            busy.last = time.monotonic()
            time.sleep(0.02)
        assert done.wait(1.0)
        assert [f[0] for f in fired] == ['quiet']
        # after the limit (0.15 s); the upper bound only catches a stall detector that waits for the loop to end
        assert 0.15 <= fired[0][1] < 1.0 and fired[0][2] - start < 1.0
        busy.armed = False                              # disarmed (unloaded): never fires
        time.sleep(0.3)
        assert [f[0] for f in fired] == ['quiet']
    finally:
        dog.stop()


def test_stall_detector_grace_gives_a_probe_without_messages_time_to_connect():
    """A sensor taken back after a restart has a new, still connecting subscription: no stall before the
    grace, one stall after it if nothing comes."""
    fired = threading.Event()
    stalls = []
    dog = StallDetector(lambda probe, silence, limit: (stalls.append((time.monotonic(), silence)), fired.set()))
    try:
        probe = fixed_probe('new', 0.05, last=0.0)
        start = time.monotonic()
        dog.arm([probe], grace=0.4)
        assert fired.wait(5.0)
        when, silence = stalls[0]
        assert when - start >= 0.4, 'a stall within the grace: %.3f s' % (when - start)
        assert 0.05 <= silence < 5.0, 'the silence counts from the end of the grace, not from boot: %.3f' % silence
    finally:
        dog.stop()


def test_blob_centroid_of_green_points_only():
    dtype = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('rgb', '<f4')])
    pts = np.zeros(100, dtype=dtype)
    rgb = np.full(100, (200 << 16) | (50 << 8) | 50, dtype=np.uint32)
    rgb[:20] = (10 << 16) | (250 << 8) | 5
    pts['rgb'] = rgb.view(np.float32)
    pts['x'][:20], pts['y'][:20], pts['z'][:20] = 1.0, -0.5, 2.0
    pts['z'][0] = np.nan                                # invalid depth is ignored
    x, y, z, n = find_blob(pts, parse_rgb('0,255,0'), 60, 10)
    assert (x, y, z, n) == (pytest.approx(1.0), pytest.approx(-0.5), pytest.approx(2.0), 19)
    assert find_blob(pts, (0, 255, 0), 60, 50) is None
    with pytest.raises(ValueError):
        parse_rgb('green')


def test_likely_topics_follow_the_ranking_of_the_catalogue_rows():
    from temoto_sensor_manager.selection import likely_topics

    def row(name, rel, **topics):
        return {'name': name, 'type': 'lidar', 'reliability': rel,
                'output_topics': {k: {'topic': t, 'rate': 0, 'stall_limit': 0} for k, t in topics.items()}}
    rows = [row('hokuyo', 0.79, lidar_data='/hokuyo/scan', cloud_data='/cloud'),
            row('sick', 0.8, lidar_data='/sick/scan'), row('other', 0.8, lidar_data='/other/scan')]
    assert likely_topics(rows, 'lidar', ['lidar_data']) == {'lidar_data': '/sick/scan'}   # best, then file order
    assert likely_topics(rows, 'lidar', ['lidar_data', 'cloud_data']) == {'lidar_data': '/hokuyo/scan',
                                                                         'cloud_data': '/cloud'}
    assert likely_topics(rows, 'depth camera', ['camera_data']) is None
    assert likely_topics(rows, 'lidar', ['image']) is None
    assert likely_topics([{'type': 'lidar', 'output_topics': {'lidar_data': 'not a mapping'}}], 'lidar',
                         ['lidar_data']) is None


def test_reliability_continues_from_a_kept_window():
    from temoto_core.reliability import Reliability
    before = Reliability(0.8, window=10)
    before.failure()
    before.failure()
    after = Reliability(0.8, window=10)
    after.restore(before.samples())
    assert after.value == pytest.approx(before.value) and after.value < 0.8
    assert after.failure() == pytest.approx(before.failure())
    wider = Reliability(0.8, window=20)
    wider.restore(before.samples())     # another window: the kept samples are the newest, the prior fills up
    assert wider.value == pytest.approx((10 * 0.8 + sum(before.samples())) / 20)


def first_stall(probe) -> float:
    """Arm a stall detector with ``probe`` alone; the silence it reports its stall after."""
    fired = threading.Event()
    stalls = []
    dog = StallDetector(lambda probe, silence, limit: (stalls.append(silence), fired.set()))
    try:
        dog.arm([probe])
        assert fired.wait(5.0), 'no stall within 5 s'
        return stalls[0]
    finally:
        dog.stop()


def test_stall_detector_allows_for_the_time_its_receive_thread_waited_for_a_cpu():
    """A silence during which the probe's receive thread sat on a run queue (messages sent, unread) is the
    machine's, not the sensor's: the stall comes that much later (at most half a limit later), and still comes."""
    probe = fixed_probe('starved', 0.1, last=time.monotonic())
    probe.reader_starved = lambda: 0.04
    silence = first_stall(probe)
    assert silence >= 0.14, silence      # the limit (0.1 s) and the 0.04 s the reader was held back
    assert probe.starved >= 0.04


def test_usual_lateness_is_not_counted_only_what_goes_beyond_it():
    from temoto_core.stall.detector import Lateness
    seen = Lateness()
    assert [seen.beyond_usual(0.03) for _ in range(30)][-1] == 0.0      # a loaded machine's norm
    assert abs(seen.beyond_usual(0.53) - 0.5) < 1e-9                     # held back for half a second


def test_stall_detector_allows_for_the_time_the_publishing_driver_waited_for_a_cpu():
    """Beside two CPU hogs the machine's pressure saturates and says nothing of a burst; the driver's own
    run-queue time still does: a silence it spent waiting for a CPU comes that much later, and still comes."""
    probe = fixed_probe('driver_starved', 0.1, last=time.monotonic())
    spans = []
    probe.publisher_starved = lambda since, now: spans.append((since, now)) or 0.04
    silence = first_stall(probe)
    assert silence >= 0.14, silence      # the limit (0.1 s) and the 0.04 s the driver was held back
    assert spans and all(since == probe.last for since, _ in spans)    # the silence's span, from its start


def test_a_wait_meter_counts_only_what_goes_beyond_the_usual_rate():
    from temoto_core.stall.starvation import WaitMeter
    total = [0.0]
    meter = WaitMeter(lambda: total[0])
    t = 100.0
    for _ in range(300):                 # 30 s waiting 0.2 s per s: the usual
        t += 0.1
        total[0] += 0.02
        meter.sample(t)
    since = t
    for _ in range(5):                   # then 0.5 s of a burst, waiting all the time
        t += 0.1
        total[0] += 0.1
        meter.sample(t)
    assert meter.excess(since, t) == pytest.approx(0.5 - 0.5 * 0.2, abs=0.06)
    assert meter.excess(t - 20.0, t - 1.0) >= 0.0         # older than what is kept: from the oldest kept
    assert not WaitMeter(lambda: None).available and WaitMeter(lambda: None).excess(0.0, 1.0) == 0.0


def test_a_process_made_to_wait_for_its_cpu_shows_it_in_its_run_queue_time():
    """process_wait reads a real process's threads: one busy loop sharing its only CPU with another waits
    about half the time."""
    import os
    import subprocess
    import sys
    from temoto_core.stall.starvation import process_wait
    cpu = sorted(os.sched_getaffinity(0))[0]
    loops = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(2)]
    try:
        for proc in loops:
            os.sched_setaffinity(proc.pid, {cpu})
        before = process_wait(loops[0].pid)
        deadline = time.monotonic() + 30.0        # generous: the two share the CPU from the start
        while time.monotonic() < deadline and process_wait(loops[0].pid) - before < 0.2:
            time.sleep(0.05)
        assert process_wait(loops[0].pid) - before >= 0.2
    finally:
        for proc in loops:
            proc.kill()
            proc.wait()
    assert process_wait(loops[0].pid) is None     # gone


def test_the_driver_s_and_the_reader_s_waits_add_up():
    """A message waits for the driver to run, then for the receive thread: a silence that held both back
    by 0.03 s each comes 0.06 s later."""
    probe = fixed_probe('both_starved', 0.2, last=time.monotonic())
    probe.reader_starved = lambda: 0.03
    probe.publisher_starved = lambda since, now: 0.03
    silence = first_stall(probe)
    assert silence >= 0.26 and probe.starved >= 0.06, (silence, probe.starved)


def test_a_start_allowance_grows_by_the_cpu_time_the_driver_waited_and_never_past_its_cap():
    """Issue 52, item 5: a fixed allowance in seconds failed a D435 that started slowly beside other work. The time
    the driver's processes wait for a CPU is added; a driver that runs and sends nothing gets nothing more."""
    waited = {'s': 1.0}
    deadline = StartDeadline(start=100.0, limit=4.0, cap=20.0, waited=lambda: waited['s'])
    assert deadline.remaining(101.0) == pytest.approx(3.0) and deadline.describe() == '4.0 s'
    waited['s'] = 3.5                                   # 2.5 s on a run queue since the start
    assert deadline.remaining(104.0) == pytest.approx(2.5)
    assert deadline.describe() == '4.0 s, and 2.5 s its driver waited for a CPU'
    waited['s'] = None                                  # the driver gone: what it waited stays counted
    assert deadline.remaining(104.0) == pytest.approx(2.5)
    waited['s'] = 60.0                                  # a machine stuck for a minute: the cap holds
    assert deadline.remaining(104.0) == pytest.approx(16.0)
    idle = StartDeadline(start=0.0, limit=4.0, cap=20.0, waited=lambda: 0.0)
    assert idle.remaining(4.0) == pytest.approx(0.0), 'an idle silent driver fails at its allowance'


def test_a_process_tree_s_cpu_waiting_counts_its_children():
    child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)'])
    try:
        wait_for(lambda: os.path.exists('/proc/%d/task' % child.pid), 5, 'the child')
        mine, tree = starvation.process_wait(os.getpid()), starvation.tree_wait(os.getpid())
        assert mine is not None and tree is not None and tree >= mine
        assert starvation.tree_wait(child.pid) is not None
    finally:
        child.kill()
        child.wait()
    assert starvation.tree_wait(child.pid) is None
