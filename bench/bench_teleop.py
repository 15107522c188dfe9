"""bench_teleop.py: the operator's motion paths across processes, judged by the simulation's ground truth.

The whole stack as `demo.launch` runs it (the sim, its base controller, the ER, Sensor (with the hand source)
and Robot Managers, the pointer, the action engine), each in its own process, driven through the engine's
start_graph service as `temoto say` does. Figures:

- **stop given as text → zero commanded** (``vaultbot_sim/base_state``), from the moment the text is sent, while
  the robot drives to a place, and the robot at rest. Beside it, in the same run, the path there was before
  the halt topic: stopping the navigate graph, whose goal's client then goes.
- **the hand unplugged → the arm commanded zero** (``vaultbot_sim/arm_states``), from the hand's last sample,
  while the arm follows a hand moving steadily.
- **hand sample → servo command**: a still, grabbing hand steps 1 cm; from the sample that carries the step
  (its stamp) to the first servo command that moves the arm (its stamp). The hand was still, so nothing else
  can have moved it.
- **tracking at 0.1x**: the tool (TF from the sim's joint states) against the scaled hand's target, RMS,
  while the hand moves steadily.
- **"stop" spoken** (``--only voice``): the speech node added; "stop" synthesized (espeak-ng) and sent as
  audio while the robot drives: the end of speech → the base commanded zero.
- **navigation mode** (``--only drive``): the hand unplugged while it turns the base → the base commanded
  zero (``vaultbot_sim/base_state``), from the hand's last sample.

Prints a markdown table and writes bench/results/teleop.json.
"""
import argparse
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import cpu_hogs, loopback_master, pct, print_table, stop_hogs, write_results  # noqa: E402

HANG = 90.0
STEP_M = 0.01                 # the still hand's step, for the latency
RAMP_M, RAMP_S = 0.10, 2.0    # the steady hand, for tracking and for the unplug: 5 cm/s
# a grab, a step out and back with the hand still between, then a steady sweep out and back; looped
HAND_PATH = """# t x y z grab (vaultbot_sim/hand_path.py)
0.0 0 0 0.2 0
0.3 0 0 0.2 0
0.4 0 0 0.2 1
1.5 0 0 0.2 1
1.501 0 {step} 0.2 1
2.5 0 {step} 0.2 1
2.501 0 0 0.2 1
3.5 0 0 0.2 1
{r1} 0 {ramp} 0.2 1
{r2} 0 0 0.2 1
{r3} 0 0 0.2 0
""".format(step=STEP_M, ramp=RAMP_M, r1=3.5 + RAMP_S, r2=3.5 + 2 * RAMP_S, r3=3.6 + 2 * RAMP_S)
LOOP_S = 3.6 + 2 * RAMP_S


def stack(launcher, work):
    import rospy
    from temoto_testing.operator import Operator
    from temoto_testing.sensor_manager import NS, start_robot_stack
    path = os.path.join(work, 'hand_path.txt')
    with open(path, 'w') as f:
        f.write(HAND_PATH)
    catalogue = os.path.join(work, 'hands.yaml')
    with open(catalogue, 'w') as f:
        f.write('sensors:\n  - {name: sim_hand_tracker, type: hand, package: vaultbot_sim, executable: '
                'hand_tracker_driver, args: "_path:=%s", reliability: 0.8, rate: 100, stall_timeout: 0.2,\n'
                '     output_topics: {hand_data: {topic: hand/sample, remap: hand/sample}}}\n' % path)
    start_robot_stack(launcher, os.path.join(work, 'er_logs'), extra=catalogue, hand_motion=False)
    launcher.node('temoto_operator', 'pointer', params={'temoto_namespace': NS})
    launcher.node('temoto_action_engine', 'temoto_action_engine', name='temoto_action_engine',
                  params={'temoto_namespace': NS})
    rospy.wait_for_service('/%s/action_engine/start_graph' % NS, timeout=60)
    return Operator()


def graph_end(op, graph, key, timeout=HANG * 2):
    from temoto_core.wait import wait_for
    return wait_for(lambda: op.node_state(graph, key) if op.node_state(graph, key) in ('FINISHED', 'FAILED')
                    else None, timeout, '%s of %s to end' % (key, graph))


def bench_stops(op, trials):
    import rospy
    from temoto_core.wait import wait_for
    from vaultbot_sim.msg import BaseState
    states = []
    rospy.Subscriber('/vaultbot_sim/base_state', BaseState, states.append, queue_size=200, tcp_nodelay=True)
    wait_for(lambda: states, HANG, 'the base state')
    out = {'halt': [], 'halt_rest': [], 'graph_stop': [], 'graph_stop_rest': [], 'ended': []}
    places = ['shelf', 'drums', 'table', 'home']

    def zero_after(t0):
        return wait_for(lambda: next((s.header.stamp.to_sec() for s in states[-30:]
                                      if s.header.stamp.to_sec() > t0 and s.commanded_linear == 0.0
                                      and s.commanded_angular == 0.0), None), HANG, 'zero commanded')

    def at_rest():
        wait_for(lambda: states[-1].linear == 0.0 and states[-1].angular == 0.0, HANG, 'at rest')
        return states[-1].header.stamp.to_sec()

    for k in range(2 * trials):
        by_halt = k % 2 == 0                     # the two paths alternate, so the machine's noise hits both
        graph = op.say('robot please go to the %s' % places[k % len(places)])
        wait_for(lambda: states[-1].commanded_linear > 0.3 or op.node_state(graph, 'navigate_0') in
                 ('FINISHED', 'FAILED'), HANG, 'the base driving')
        if states[-1].commanded_linear <= 0.3:
            continue                             # arrived or failed before it drove fast: no trial
        t0 = time.time()
        if by_halt:
            op.say('stop')
        else:
            op.stop(graph_name=graph)
        z = zero_after(t0)
        rest = at_rest()
        out['halt' if by_halt else 'graph_stop'].append(z - t0)
        out['halt_rest' if by_halt else 'graph_stop_rest'].append(rest - t0)
        out['ended'].append(graph_end(op, graph, 'navigate_0'))
    return out


def bench_hand(op, trials, loops):
    import numpy as np
    import rospy
    import tf2_ros
    from geometry_msgs.msg import PoseStamped
    from std_msgs.msg import String
    from temoto_core.msg import HandSample
    from temoto_core.wait import wait_for
    from temoto_testing.sensor_manager import set_cable
    from trajectory_msgs.msg import JointTrajectory
    from vaultbot_sim.msg import ArmState

    samples, commands, arms, targets, holds = [], [], [], [], []
    # the latency is taken between arrivals here, a third process beside the action's and the manipulator's: the
    # tracker stamps a sample with its tick's nominal time, not with when it sent it
    rospy.Subscriber('/hand/sample', HandSample, lambda m: samples.append((time.time(), m)), queue_size=500,
                     tcp_nodelay=True)
    rospy.Subscriber('/left_arm/servo_command', JointTrajectory, lambda m: commands.append((time.time(), m)),
                     queue_size=500, tcp_nodelay=True)
    rospy.Subscriber('/vaultbot_sim/arm_states', ArmState, lambda m: m.arm == 'left_arm' and arms.append(m),
                     queue_size=500, tcp_nodelay=True)
    rospy.Subscriber('/left_arm/servo_target', PoseStamped, targets.append, queue_size=500, tcp_nodelay=True)
    rospy.Subscriber('/left_arm/servo_hold', String, lambda m: holds.append(m.data), queue_size=50)
    buffer = tf2_ros.Buffer(cache_time=rospy.Duration(60.0))
    listener = tf2_ros.TransformListener(buffer)
    out = {'latency': [], 'unplug': [], 'tracking_mm': [], 'ended': [], 'stale_holds': 0, 'following_s': 0.0,
           'steps': 0, 'steps_not_still': 0}

    def follow(scale):
        set_cable('hand_tracker', 'plugged')
        graph = op.say('robot please follow my hand at %s' % scale)
        op.wait_event('following', graph, HANG, 'the arm following the hand')
        return graph

    # latency and tracking, at 1x for the step (a clear start) and 0.1x for the sweep (the figure)
    for scale in ('1', '0.1'):
        graph = follow(scale)
        t0 = rospy.get_time()
        n0, c0, g0, h0 = len(samples), len(commands), len(targets), len(holds)
        wait_for(lambda: rospy.get_time() - t0 > loops * LOOP_S, loops * LOOP_S + HANG, 'the hand\'s loops')
        out['stale_holds'] += sum('periods' in h for h in holds[h0:])     # a late sample, not a lost hand
        out['following_s'] += rospy.get_time() - t0
        sampled, sent, aimed = samples[n0:], commands[c0:], targets[g0:]
        op.stop(graph_name=graph)
        graph_end(op, graph, 'follow_hand_0')
        if scale == '1':
            # a step's first sample: the first that differs from a still hand (a sample may fall inside the
            # step's 1 ms keyframe, and already move the arm)
            for (_, before2), (_, prev), (t, cur) in zip(sampled, sampled[1:], sampled[2:]):
                still_hand = abs(prev.palm.position.y - before2.palm.position.y) < 1e-6
                if cur.grab_strength > 0.9 and still_hand and abs(cur.palm.position.y - prev.palm.position.y) > 1e-4:
                    out['steps'] += 1
                    first = next((at for at, c in sent if at >= t
                                  and max(abs(v) for v in c.points[0].velocities) > 0.02), None)
                    before = [c for at, c in sent if t - 0.2 <= at < t]
                    still = before and all(max(abs(v) for v in c.points[0].velocities) < 0.005 for c in before)
                    if first is not None and still:
                        out['latency'].append(first - t)
                    else:
                        out['steps_not_still'] += 1
        else:
            ramp_v = 0.1 * RAMP_M / RAMP_S
            for a, b, c in zip(aimed, aimed[10:], aimed[30:]):       # steady: the same speed 0.1 s and 0.3 s on
                dt1 = b.header.stamp.to_sec() - a.header.stamp.to_sec()
                dt2 = c.header.stamp.to_sec() - a.header.stamp.to_sec()
                if dt1 <= 0 or dt2 <= 0:
                    continue
                v1 = abs(b.pose.position.y - a.pose.position.y) / dt1
                v2 = abs(c.pose.position.y - a.pose.position.y) / dt2
                if not (0.8 * ramp_v <= v1 <= 1.2 * ramp_v and 0.8 * ramp_v <= v2 <= 1.2 * ramp_v):
                    continue
                try:
                    t = buffer.lookup_transform('left_base_link', 'left_tool0', b.header.stamp)
                except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException):
                    continue
                p = t.transform.translation
                e = np.hypot(np.hypot(p.x - b.pose.position.x, p.y - b.pose.position.y), p.z - b.pose.position.z)
                out['tracking_mm'].append(1e3 * float(e))
    # the hand unplugged while the arm follows the sweep
    for _ in range(trials):
        graph = follow('1')
        wait_for(lambda: arms and arms[-1].commanded_speed > 0.05, HANG, 'the arm following the sweep')
        set_cable('hand_tracker', 'unplugged', 'crash')
        cut = time.time()
        last = wait_for(lambda: max((at for at, _ in samples[-50:]), default=None)
                        if time.time() - cut > 0.2 else None, 5.0, 'the hand\'s last sample')
        zero = wait_for(lambda: next((a.header.stamp.to_sec() for a in arms[-50:] if a.header.stamp.to_sec() > last
                                      and a.commanded_speed == 0.0), None), 5.0, 'the arm commanded zero')
        out['unplug'].append(zero - last)
        out['ended'].append(graph_end(op, graph, 'follow_hand_0'))
    set_cable('hand_tracker', 'plugged')
    listener.unregister()
    return out


def bench_drive(op, trials):
    """Navigation mode: the hand unplugged while it turns the base → the base commanded zero, from its last
    sample (the follower's deadline, then the stream's zero through the navigator)."""
    import rospy
    from temoto_core.msg import HandSample
    from temoto_core.wait import wait_for
    from temoto_testing.sensor_manager import set_cable
    from vaultbot_sim.msg import BaseState

    samples, states = [], []
    rospy.Subscriber('/hand/sample', HandSample, lambda m: samples.append(time.time()), queue_size=500,
                     tcp_nodelay=True)
    rospy.Subscriber('/vaultbot_sim/base_state', BaseState, states.append, queue_size=500, tcp_nodelay=True)
    out = {'unplug': [], 'ended': []}
    for _ in range(trials):
        set_cable('hand_tracker', 'plugged')
        graph = op.say('robot please drive with my hand')
        op.wait_event('following', graph, HANG, 'the base following the hand')
        wait_for(lambda: states and abs(states[-1].commanded_angular) > 0.3, HANG, 'the hand turning the base')
        set_cable('hand_tracker', 'unplugged', 'crash')
        cut = time.time()
        last = wait_for(lambda: max(samples[-50:], default=None) if time.time() - cut > 0.2 else None, 5.0,
                        'the hand\'s last sample')
        zero = wait_for(lambda: next((s.header.stamp.to_sec() for s in states[-60:] if s.header.stamp.to_sec() > last
                                      and s.commanded_angular == 0.0 and s.commanded_linear == 0.0), None), 5.0,
                        'the base commanded zero')
        out['unplug'].append(zero - last)
        out['ended'].append(graph_end(op, graph, 'follow_hand_0'))
        wait_for(lambda: states[-1].angular == 0.0, HANG, 'the base at rest')
    set_cable('hand_tracker', 'plugged')
    return out


def bench_voice_stop(launcher, op, trials):
    """"stop" spoken while the robot drives: from the end of speech (the audio's end marker sent to the speech
    node) to the first ground-truth state with zero commanded. The speech node as the operator runs it."""
    import rospy
    from std_msgs.msg import String
    from temoto_core.wait import wait_for
    from temoto_speech.msg import AudioData
    from temoto_speech.voice import synthesize_pcm
    from vaultbot_sim.msg import BaseState

    launcher.node('temoto_speech', 'temoto_speech', params={'speak': False})
    states, heard = [], []
    rospy.Subscriber('/vaultbot_sim/base_state', BaseState, states.append, queue_size=200, tcp_nodelay=True)
    rospy.Subscriber('/temoto/speech/heard', String, lambda m: heard.append(json.loads(m.data)), queue_size=50)
    grammar = []
    rospy.Subscriber('/temoto/speech/grammar', String, lambda m: grammar.append(json.loads(m.data)), queue_size=5)
    pub = rospy.Publisher('/temoto/speech/audio', AudioData, queue_size=1000)
    wait_for(lambda: grammar and 'stop' in grammar[-1]['actions'] and pub.get_num_connections() > 0 and states,
             HANG, 'the speech node ready')
    pcm = synthesize_pcm('stop', 'en-us', 175)
    places = ['shelf', 'drums', 'table', 'home']
    out = {'zero': [], 'decode': [], 'missed': 0}
    for k in range(trials):
        graph = op.say('robot please go to the %s' % places[k % len(places)])
        wait_for(lambda: states[-1].commanded_linear > 0.3 or op.node_state(graph, 'navigate_0') in
                 ('FINISHED', 'FAILED'), HANG, 'the base driving')
        if states[-1].commanded_linear <= 0.3:
            continue
        before = len(heard)
        for i in range(0, len(pcm), 3200):
            pub.publish(AudioData(data=pcm[i:i + 3200]))
        end = time.time()
        pub.publish(AudioData(data=b''))
        wait_for(lambda: len(heard) > before, 30, 'the speech node\'s report')
        if not heard[before].get('accepted'):
            out['missed'] += 1
            op.say('stop')
        else:
            zero = wait_for(lambda: next((s.header.stamp.to_sec() for s in states[-60:] if s.header.stamp.to_sec() > end
                                          and s.commanded_linear == 0.0 and s.commanded_angular == 0.0), None),
                            HANG, 'zero commanded')
            out['zero'].append(zero - end)
            out['decode'].append(heard[before].get('decode_s'))
        graph_end(op, graph, 'navigate_0')
        wait_for(lambda: states[-1].linear == 0.0 and states[-1].angular == 0.0, HANG, 'at rest')
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--trials', type=int, default=20, help='stops of each kind, and unplugs of the hand')
    p.add_argument('--loops', type=int, default=8, help='loops of the hand path for the latency and tracking')
    p.add_argument('--hogs', type=int, default=0)
    p.add_argument('--only', choices=('stops', 'hand', 'drive', 'voice'))
    args = p.parse_args()
    import rospy
    master, launcher = loopback_master('bench_teleop_')
    hogs = cpu_hogs(args.hogs)
    results = {'hogs': args.hogs}
    try:
        rospy.init_node('bench_teleop', anonymous=True, disable_signals=True)
        op = stack(launcher, launcher.workdir)
        if args.only in (None, 'stops'):
            print('bench_teleop: stops x %d ...' % (2 * args.trials), file=sys.stderr, flush=True)
            results['stops'] = bench_stops(op, args.trials)
        if args.only in (None, 'hand'):
            print('bench_teleop: the hand ...', file=sys.stderr, flush=True)
            results['hand'] = bench_hand(op, args.trials, args.loops)
        if args.only in (None, 'voice'):
            print('bench_teleop: "stop" spoken x %d ...' % args.trials, file=sys.stderr, flush=True)
            results['voice'] = bench_voice_stop(launcher, op, args.trials)
        if args.only in (None, 'drive'):
            print('bench_teleop: the hand driving the base x %d ...' % args.trials, file=sys.stderr, flush=True)
            results['drive'] = bench_drive(op, args.trials)
        op.close()
    finally:
        stop_hogs(hogs)
        launcher.stop_all()
        master.stop()
    write_results('teleop' + ('_' + args.only if args.only else ''), results)
    ms = lambda v: '%.1f ms' % (v * 1e3) if v == v else '-'  # noqa: E731
    rows = []
    s, h = results.get('stops'), results.get('hand')
    if s:
        rows += [
            ('"stop" given as text while driving → zero commanded, p50 / p99 (n=%d)' % len(s['halt']),
             '%s / %s (max %s)' % (ms(pct(s['halt'], 50)), ms(pct(s['halt'], 99)), ms(max(s['halt']))),
             '≤ 50 ms p99'),
            ('… the robot at rest, p50 / p99', '%s / %s' % (ms(pct(s['halt_rest'], 50)),
                                                          ms(pct(s['halt_rest'], 99))), 'reported (braking)'),
            ('before the halt topic: the navigate graph stopped → zero commanded, p50 / p99 (n=%d)'
             % len(s['graph_stop']), '%s / %s' % (ms(pct(s['graph_stop'], 50)), ms(pct(s['graph_stop'], 99))),
             'for comparison'),
            ('… ratio of the medians (graph stop / halt)',
             '%.1f x' % (pct(s['graph_stop'], 50) / pct(s['halt'], 50)), '-'),
            ('navigate actions that ended FAILED after a stop', str(sum(e == 'FAILED' for e in s['ended'])), '0'),
        ]
    if h:
        rows += [
            ('hand sample → servo command that moves the arm, one host, p50 / p95 (n=%d of %d steps)'
             % (len(h['latency']), h['steps']), '%s / %s' % (ms(pct(h['latency'], 50)), ms(pct(h['latency'], 95))),
             '≤ 15 ms p95'),
            ('tool against the scaled hand, steady motion at 0.1x, RMS (n=%d)' % len(h['tracking_mm']),
             '%.2f mm' % math.sqrt(sum(e * e for e in h['tracking_mm']) / max(1, len(h['tracking_mm']))), '≤ 2 mm'),
            ('holds for a sample 2 periods late while a hand was followed (%.0f s)' % h['following_s'],
             str(h['stale_holds']), 'reported (each needs a new grab)'),
            ('hand unplugged while following → the arm commanded zero, from its last sample, p50 / max (n=%d)'
             % len(h['unplug']), '%s / %s' % (ms(pct(h['unplug'], 50)), ms(max(h['unplug']))),
             '≤ 2 periods + 20 ms = 40 ms'),
        ]
    v = results.get('voice')
    if v and v['zero']:
        rows.append(('"stop" spoken while driving: end of speech → zero commanded, median / p95 (n=%d; not heard: %d)'
                     % (len(v['zero']), v['missed']), '%s / %s (decoding: %s median)' % (
                         ms(pct(v['zero'], 50)), ms(pct(v['zero'], 95)),
                         ms(pct([x for x in v['decode'] if x is not None], 50))), '≤ 300 ms median'))
    d = results.get('drive')
    if d:
        rows.append(('navigation mode: hand unplugged while it turns the base → the base commanded zero, from its '
                     'last sample, p50 / max (n=%d; follow_hand ended FAILED: %d)' % (
                         len(d['unplug']), sum(e == 'FAILED' for e in d['ended'])),
                     '%s / %s' % (ms(pct(d['unplug'], 50)), ms(max(d['unplug']))), '≤ 2 periods + 20 ms = 40 ms'))
    print_table('Teleoperation (%d CPU hogs)' % args.hogs, rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
