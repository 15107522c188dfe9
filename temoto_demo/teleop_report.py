"""The report of a teleoperation run (``temoto demo teleop``), made from its bag alone.

What it shows, each from the simulation's ground truth recorded in the bag rather than from a manager's word:

- **the path over the map**: the base's pose (``vaultbot_sim/base_state``) over the lab's map, with the
  pointed goal, the navigator's plans, and where the SICK was unplugged;
- **the hand against the end-effector**: the servo targets (the hand's motion through the clutch, scaled by
  the dial) and the tool's position, chained from the recorded ``/tf`` (the sim publishes every joint's
  transform), in the arm's base frame; the error between them;
- **the timeline** of the drive and the arm: commanded and actual speeds, with the unplugs, the halts, the
  obstacle source's failover, the actions' events and the failure;
- **the screenshots** the run took.

Definitions: "commanded zero" is the first ground-truth sample after a fault whose commanded velocity is
zero; the bag's stamps are the publishers' (the sim's wall clock).
"""
from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import matplotlib
import numpy as np
from rosbags.highlevel import AnyReader

matplotlib.use('Agg')       # drawn headless, before anything imports pyplot

from . import topics as T   # noqa: E402
from .report import action_event, stamp_of as _t   # noqa: E402

ARM = 'left_arm'
ARM_BASE, TOOL = 'left_base_link', 'left_tool0'


def _matrix(tr) -> np.ndarray:
    x, y, z, w = tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = tr.translation.x, tr.translation.y, tr.translation.z
    return m


@dataclass
class TeleopRun:
    bag: str
    start: float = 0.0
    end: float = 0.0
    base: List[tuple] = field(default_factory=list)       # t, x, y, commanded linear, angular, linear, contacts
    arm: List[tuple] = field(default_factory=list)        # t, commanded speed, speed (the camera arm)
    gripper: List[tuple] = field(default_factory=list)    # t, gap
    grid: Optional[dict] = None                           # the map: origin, resolution, width, height, cells
    plans: List[tuple] = field(default_factory=list)      # t, [(x, y)]
    pointed: List[tuple] = field(default_factory=list)    # t, x, y (RViz's goal as pointed)
    targets: List[tuple] = field(default_factory=list)    # t, x, y, z (the arm's servo targets, its base frame)
    hand: List[tuple] = field(default_factory=list)       # t, x, y, z, grab
    hand_arrivals: List[float] = field(default_factory=list)  # when each hand sample reached the recorder
    holds: List[tuple] = field(default_factory=list)      # t, reason
    halts: List[tuple] = field(default_factory=list)      # t, reason
    tf: Dict[str, tuple] = field(default_factory=dict)    # child -> (parent, [t], [4 x 4])
    actions: List[dict] = field(default_factory=list)
    feedback: List[tuple] = field(default_factory=list)   # t, text
    stages: List[dict] = field(default_factory=list)
    unplugs: List[tuple] = field(default_factory=list)    # t, device, mode
    screenshots: List[tuple] = field(default_factory=list)
    topics: Dict[str, tuple] = field(default_factory=dict)


def load_teleop(bag_path: str, namespace: str = T.DEFAULT_NS) -> TeleopRun:
    run = TeleopRun(bag=os.path.abspath(bag_path))
    ns = namespace.strip('/')
    plugged: Dict[str, bool] = {}
    with AnyReader([Path(bag_path)]) as reader:
        run.start, run.end = reader.start_time * 1e-9, reader.end_time * 1e-9
        for c in reader.connections:
            kind, n = run.topics.get(c.topic, (c.msgtype, 0))
            run.topics[c.topic] = (kind, n + c.msgcount)
        for conn, bag_ns, raw in reader.messages():
            topic, bag_t = T.live_name(conn.topic), bag_ns * 1e-9
            if topic.startswith(T.STREAMS_PREFIX + '/') or topic == T.TICKS:
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            if topic.endswith('/vaultbot_sim/base_state'):
                run.base.append((_t(msg, bag_t), msg.x, msg.y, msg.commanded_linear, msg.commanded_angular,
                                 msg.linear, msg.contacts))
            elif topic.endswith('/vaultbot_sim/arm_states'):
                if msg.arm == ARM:
                    run.arm.append((_t(msg, bag_t), msg.commanded_speed, msg.speed))
            elif topic.endswith('/vaultbot_sim/gripper_state'):
                run.gripper.append((_t(msg, bag_t), msg.gap))
            elif conn.msgtype == 'nav_msgs/msg/OccupancyGrid':
                i = msg.info
                run.grid = {'x0': i.origin.position.x, 'y0': i.origin.position.y, 'res': i.resolution,
                            'w': i.width, 'h': i.height, 'cells': np.asarray(msg.data, dtype=np.int16)}
            elif topic.endswith('/plan') and conn.msgtype == 'nav_msgs/msg/Path':
                run.plans.append((_t(msg, bag_t), [(p.pose.position.x, p.pose.position.y) for p in msg.poses]))
            elif topic == '/move_base_simple/goal':
                run.pointed.append((_t(msg, bag_t), msg.pose.position.x, msg.pose.position.y))
            elif topic.endswith('%s/servo_target' % ARM):
                p = msg.pose.position
                run.targets.append((_t(msg, bag_t), p.x, p.y, p.z))
            elif topic.endswith('%s/servo_hold' % ARM):
                run.holds.append((bag_t, msg.data))
            elif topic == '/%s/halt' % ns:
                run.halts.append((bag_t, msg.data))
            elif topic in ('/hand/sample', '/virtual_hand/sample'):
                p = msg.palm.position
                run.hand.append((_t(msg, bag_t), p.x, p.y, p.z, msg.grab_strength))
                if topic == '/hand/sample':
                    run.hand_arrivals.append(bag_t)
            elif topic in ('/tf', '/tf_static'):
                for tr in msg.transforms:
                    parent, times, mats = run.tf.setdefault(tr.child_frame_id, (tr.header.frame_id, [], []))
                    times.append(_t(tr, bag_t))
                    mats.append(_matrix(tr.transform))
            elif topic == T.action_events(ns):
                ev = action_event(msg.data, bag_t)
                if ev is not None:
                    run.actions.append(ev)
            elif topic == T.action_feedback(ns):
                run.feedback.append((bag_t, msg.data))
            elif topic == T.STAGES:
                try:
                    run.stages.append(json.loads(msg.data))
                except ValueError:
                    pass
            elif T.is_device_states(topic):
                t = _t(msg, bag_t)
                for d in msg.devices:
                    if plugged.get(d.name) and not d.plugged:
                        run.unplugs.append((t, d.name, d.mode or 'crash'))
                    plugged[d.name] = bool(d.plugged)
            elif topic == T.SCREENSHOTS:
                run.screenshots.append((_t(msg, bag_t), msg.header.frame_id, bytes(msg.data)))
    for lst in (run.base, run.arm, run.targets, run.hand, run.gripper):
        lst.sort(key=lambda r: r[0])
    run.hand_arrivals.sort()
    run.actions.sort(key=lambda e: e['t'])
    return run


def tool_at(run: TeleopRun, t: float) -> Optional[np.ndarray]:
    """The tool's position in the arm's base frame at ``t``, chained from the recorded TF (latest at or before)."""
    m, frame = np.eye(4), TOOL
    for _ in range(20):
        if frame == ARM_BASE:
            return m[:3, 3]
        entry = run.tf.get(frame)
        if entry is None:
            return None
        parent, times, mats = entry
        i = int(np.searchsorted(times, t, side='right')) - 1
        if i < 0:
            return None
        m = mats[i] @ m
        frame = parent
    return None


@dataclass
class TeleopFigures:
    sick_zero_ms: Optional[float] = None          # the SICK unplugged → the base commanded zero
    failover_s: Optional[float] = None            # the SICK unplugged → obstacles from the next source
    arrival_error_m: Optional[float] = None
    contacts: Optional[int] = None
    path_m: Optional[float] = None
    tracking_rms_mm: Optional[float] = None       # the tool against the servo target (the scaled hand)
    hand_to_target_scale: Optional[float] = None  # the target's motion over the hand's, while engaged
    arm_zero_ms: Optional[float] = None           # the arm's controller crashed → the arm commanded zero
    failing_s: Optional[float] = None             # → follow_hand says it fails (its first word)
    failed_s: Optional[float] = None              # → follow_hand FAILED, its resources released
    announced: str = ''
    halts: int = 0
    cut_hold_ms: Optional[float] = None           # --hosts 2, link cut while following: the last servo target
                                                  # on the robot → the arm commanded zero (robot.bag)
    cut_failing_s: Optional[float] = None         # … the link cut → the station hears follow_hand fail
    hand_to_joint_ms: Optional[Tuple[float, float, int]] = None   # --hosts 2, before the cut: a hand sample at
                                                  # the station → the joint command it became on the robot;
                                                  # (p50, p95, n)


def _first(rows, pred):
    return next((r for r in rows if pred(r)), None)


@dataclass
class RobotSide:
    """``robot.bag`` (--hosts 2, recorded on the robot's host). Arrivals, not stamps: over the cut link TCP keeps
    the station's last targets and delivers them once the link is back, stamped before the cut."""
    arm: List[tuple] = field(default_factory=list)         # t, commanded speed (the camera arm's ground truth)
    targets: List[float] = field(default_factory=list)     # when each servo target reached the robot
    sent: List[float] = field(default_factory=list)        # … and when the station sent it (its stamp)
    commands: List[float] = field(default_factory=list)    # when each joint command left the manipulator


def robot_side(bag_path: str) -> RobotSide:
    side = RobotSide()
    with AnyReader([Path(bag_path)]) as reader:
        for conn, bag_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic.endswith('/vaultbot_sim/arm_states') and msg.arm == ARM:
                side.arm.append((_t(msg, bag_ns * 1e-9), msg.commanded_speed))
            elif conn.topic.endswith('%s/servo_target' % ARM):
                side.targets.append(bag_ns * 1e-9)
                side.sent.append(_t(msg, bag_ns * 1e-9))
            elif conn.topic.endswith('%s/servo_command' % ARM):
                side.commands.append(bag_ns * 1e-9)
    side.arm.sort()
    order = np.argsort(side.targets)
    side.targets, side.sent = [side.targets[i] for i in order], [side.sent[i] for i in order]
    side.commands.sort()
    return side


def hand_to_joint(hand_arrivals: List[float], side: RobotSide, before: float) -> List[float]:
    """For each servo target sent before ``before``: from the hand sample it came of (the last to reach the
    station's recorder before the target was sent) to the first joint command on the robot after the target
    reached it. The hosts are network namespaces of one machine, so the two recorders share a clock."""
    out = []
    for sent, arrived in zip(side.sent, side.targets):
        if sent >= before:
            break
        k = int(np.searchsorted(hand_arrivals, sent, side='right')) - 1
        j = int(np.searchsorted(side.commands, arrived, side='left'))
        if k >= 0 and j < len(side.commands) and sent - hand_arrivals[k] < 0.05:
            out.append(side.commands[j] - hand_arrivals[k])
    return out


def cut_figures(run: TeleopRun, f: 'TeleopFigures', robot_bag: str) -> None:
    down = next((st['stamp'] for st in run.stages if st.get('stage') == 'link_down'), None)
    if down is None:
        return
    failing = _first(run.actions, lambda e: e['t'] > down and e.get('event') == 'failing'
                     and e.get('action') == 'follow_hand')
    f.cut_failing_s = None if failing is None else failing['t'] - down
    if os.path.exists(robot_bag):
        side = robot_side(robot_bag)
        zero = _first(side.arm, lambda a: a[0] > down and a[1] == 0.0)
        last = max((t for t in side.targets if zero is not None and t <= zero[0]), default=None)
        if zero is not None and last is not None:
            f.cut_hold_ms = 1e3 * (zero[0] - last)
        took = hand_to_joint(run.hand_arrivals, side, down)
        if took:
            f.hand_to_joint_ms = (1e3 * float(np.percentile(took, 50)), 1e3 * float(np.percentile(took, 95)),
                                  len(took))


def figures(run: TeleopRun) -> TeleopFigures:
    f = TeleopFigures()
    sick = _first(run.unplugs, lambda u: u[1] == 'sick')
    if sick is not None:
        zero = _first(run.base, lambda b: b[0] > sick[0] and b[3] == 0.0 and b[4] == 0.0)
        f.sick_zero_ms = None if zero is None else 1e3 * (zero[0] - sick[0])
        taken = _first(run.feedback, lambda x: x[0] > sick[0] and 'obstacles from' in x[1])
        f.failover_s = None if taken is None else taken[0] - sick[0]
    if run.base:
        xy = np.array([(b[1], b[2]) for b in run.base])
        f.path_m = float(np.sum(np.hypot(*np.diff(xy, axis=0).T))) if len(xy) > 1 else 0.0
        f.contacts = int(run.base[-1][6])
        arrived = _first(run.actions, lambda e: e.get('event') == 'arrived')
        if arrived is not None and run.pointed:
            at = _first(run.base, lambda b: b[0] >= arrived['t']) or run.base[-1]
            f.arrival_error_m = float(np.hypot(at[1] - run.pointed[-1][1], at[2] - run.pointed[-1][2]))
    errors = []
    for t, x, y, z in run.targets:
        tool = tool_at(run, t)
        if tool is not None:
            errors.append(float(np.linalg.norm(tool - np.array([x, y, z]))))
    if errors:
        f.tracking_rms_mm = 1e3 * float(np.sqrt(np.mean(np.square(errors))))
    # the dial's scale as the run shows it: within each grab, the slope of the target's y against the hand's y
    # at its time (the clutch maps the hand's motion since that grab, so the two move by the dial's ratio)
    if run.hand and len(run.targets) > 10:
        times = [h[0] for h in run.hand]
        grab_of = np.cumsum([0] + [h[4] >= 0.8 > p[4] for p, h in zip(run.hand, run.hand[1:])])   # which grab
        grabs: Dict[int, list] = {}
        for g in run.targets:
            i = int(np.searchsorted(times, g[0], side='right')) - 1
            if i >= 0 and run.hand[i][4] >= 0.8:
                grabs.setdefault(int(grab_of[i]), []).append((run.hand[i][2], g[2]))
        slopes = [float(np.polyfit(*zip(*pairs), 1)[0]) for pairs in grabs.values()
                  if len(pairs) > 10 and np.ptp([p[0] for p in pairs]) > 5e-3]
        f.hand_to_target_scale = float(np.median(slopes)) if slopes else None
    arm = _first(run.unplugs, lambda u: u[1] == ARM)
    if arm is not None:
        zero = _first(run.arm, lambda a: a[0] > arm[0] and a[1] == 0.0)
        f.arm_zero_ms = None if zero is None else 1e3 * (zero[0] - arm[0])
        failing = _first(run.actions, lambda e: e['t'] > arm[0] and e.get('event') == 'failing'
                         and e.get('action') == 'follow_hand')
        f.failing_s = None if failing is None else failing['t'] - arm[0]
        failed = _first(run.actions, lambda e: e['t'] > arm[0] and e.get('event') == 'state'
                        and e.get('action') == 'follow_hand' and e.get('state') == 'FAILED')
        f.failed_s = None if failed is None else failed['t'] - arm[0]
        said = _first(run.feedback, lambda x: x[0] > arm[0] and x[1].startswith('follow_hand: failing'))
        f.announced = said[1] if said else ''
    f.halts = len(run.halts)
    return f


# ============================================================================ the pictures
def _saved(fig, path: str) -> str:
    import matplotlib.pyplot as plt
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_path(run: TeleopRun, path: str) -> str:
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 6))
    if run.grid is not None:
        g = run.grid
        cells = g['cells'].reshape(g['h'], g['w'])
        ax.imshow(np.where(cells > 50, 0.2, 1.0), cmap='gray', vmin=0, vmax=1, origin='lower',
                  extent=(g['x0'], g['x0'] + g['w'] * g['res'], g['y0'], g['y0'] + g['h'] * g['res']))
    for _, points in run.plans[-1:]:
        if points:
            ax.plot(*zip(*points), '--', color='tab:blue', lw=1, label='the last plan')
    if run.base:
        ax.plot([b[1] for b in run.base], [b[2] for b in run.base], color='tab:green', lw=2, label='the base (sim)')
    for t, x, y in run.pointed:
        ax.plot(x, y, '*', ms=16, color='tab:orange', label='pointed goal (2D Nav Goal)')
    for t, device, mode in run.unplugs:
        at = _first(run.base, lambda b: b[0] >= t)
        if at is not None and device == 'sick':
            ax.plot(at[1], at[2], 'x', ms=12, mew=3, color='tab:red', label='SICK unplugged')
    ax.set_aspect('equal')
    if run.base:
        xs = [b[1] for b in run.base] + [p[1] for p in run.pointed]
        ys = [b[2] for b in run.base] + [p[2] for p in run.pointed]
        ax.set_xlim(min(xs) - 1.5, max(xs) + 1.5)
        ax.set_ylim(min(ys) - 1.5, max(ys) + 1.5)
    ax.set_xlabel('x (m, world)')
    ax.set_ylabel('y (m)')
    ax.legend(loc='best', fontsize=8)
    ax.set_title('The drive over the lab\'s map')
    return _saved(fig, path)


def plot_hand(run: TeleopRun, path: str) -> str:
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 3.5))
    if run.targets:
        t0 = run.targets[0][0]
        ts = [g[0] - t0 for g in run.targets]
        ax.plot(ts, [1e3 * g[2] for g in run.targets], color='tab:orange', lw=2, label='target: the scaled hand')
        tools = [(g[0] - t0, tool_at(run, g[0])) for g in run.targets]
        ax.plot([t for t, p in tools if p is not None], [1e3 * p[1] for t, p in tools if p is not None],
                color='tab:blue', lw=1, label='the tool (TF from the sim)')
        hand = [h for h in run.hand if t0 - 1.0 <= h[0] <= run.targets[-1][0]]
        if hand:
            ax2 = ax.twinx()
            ax2.plot([h[0] - t0 for h in hand], [1e3 * h[2] for h in hand], color='tab:gray', lw=0.8, alpha=0.7,
                     label='the hand (unscaled)')
            ax2.set_ylabel('hand y (mm)', color='tab:gray')
        ax.set_xlabel('s since the first target')
    ax.set_ylabel('y in %s (mm)' % ARM_BASE)
    if run.targets:
        ax.legend(loc='upper left', fontsize=8)
    ax.set_title('The hand moves the camera arm (y, the hand path\'s axis)')
    return _saved(fig, path)


def plot_timeline(run: TeleopRun, path: str) -> str:
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    t0 = run.start
    if run.base:
        a1.plot([b[0] - t0 for b in run.base], [b[3] for b in run.base], color='tab:orange', lw=1, label='commanded')
        a1.plot([b[0] - t0 for b in run.base], [b[5] for b in run.base], color='tab:green', lw=1, label='actual')
    a1.set_ylabel('base (m/s)')
    if run.arm:
        a2.plot([a[0] - t0 for a in run.arm], [a[1] for a in run.arm], color='tab:orange', lw=1, label='commanded')
        a2.plot([a[0] - t0 for a in run.arm], [a[2] for a in run.arm], color='tab:green', lw=1, label='actual')
    a2.set_ylabel('%s top joint (rad/s)' % ARM)
    a2.set_xlabel('s since the bag began')
    for t, device, _ in run.unplugs:
        for ax in (a1, a2):
            ax.axvline(t - t0, color='tab:red', lw=1.5)
        a1.annotate('%s unplugged' % device, (t - t0, a1.get_ylim()[1]), fontsize=7, color='tab:red',
                    rotation=90, va='top')
    marks = [('driving', 'tab:blue'), ('arrived', 'tab:blue'), ('following', 'tab:purple'), ('halted', 'black')]
    for e in run.actions:
        colour = dict(marks).get(e.get('event'))
        if e.get('event') == 'state' and e.get('state') == 'FAILED':
            colour = 'tab:red'
        if colour:
            for ax in (a1, a2):
                ax.axvline(e['t'] - t0, color=colour, lw=0.8, ls='--')
    for t, text in run.feedback:
        if 'obstacles from' in text:
            a1.axvline(t - t0, color='tab:cyan', lw=1.2, ls=':')
    a1.legend(loc='upper right', fontsize=7)
    a1.set_title('Stops and failovers: red unplug, cyan obstacle source taken over, dashed the actions\' events')
    return _saved(fig, path)


# ============================================================================ the report
@dataclass
class TeleopReport:
    path: str
    figures: TeleopFigures
    images: List[str]
    screenshots: List[str]

    @property
    def summary(self) -> dict:
        return {'report': self.path, 'figures': self.figures.__dict__, 'images': self.images,
                'screenshots': self.screenshots}


def _ms(v: Optional[float], unit: str = 'ms') -> str:
    return '-' if v is None else ('%.0f %s' % (v, unit) if unit == 'ms' else '%.2f %s' % (v, unit))


def write_teleop_report(bag_path: str, out_dir: Optional[str] = None,
                        namespace: str = T.DEFAULT_NS) -> TeleopReport:
    out_dir = out_dir or os.path.dirname(os.path.abspath(bag_path))
    os.makedirs(out_dir, exist_ok=True)
    run = load_teleop(bag_path, namespace)
    f = figures(run)
    cut_figures(run, f, os.path.join(os.path.dirname(os.path.abspath(bag_path)), 'robot.bag'))
    images = [plot_path(run, os.path.join(out_dir, 'path.png')),
              plot_hand(run, os.path.join(out_dir, 'hand.png')),
              plot_timeline(run, os.path.join(out_dir, 'teleop_timeline.png'))]
    shots = []
    for i, (_, stage, data) in enumerate(run.screenshots, 1):
        name = 'screenshot_%d_%s.png' % (i, re.sub(r'[^A-Za-z0-9_-]+', '_', stage) or 'stage')
        with open(os.path.join(out_dir, name), 'wb') as fh:
            fh.write(data)
        shots.append(name)
    L = ['# TeMoto teleoperation: run report', '',
         'Bag: `%s` (%.1f s, %d topics). A goal pointed in RViz, "robot please go", the SICK unplugged on the way, '
         '"robot please follow my hand at 0.1", "robot please close the gripper", and the camera arm\'s controller '
         'crashing. Every figure is from the simulation\'s ground truth in the bag.'
         % (os.path.basename(bag_path), run.end - run.start, len(run.topics)), '',
         '| figure | measured | bound |', '| --- | --- | --- |',
         '| SICK unplugged while driving → the base commanded zero | %s | 3 scans + 20 ms = 140 ms |'
         % _ms(f.sick_zero_ms),
         '| … obstacles from the next source (the holder hears it) | %s | - |' % _ms(f.failover_s, 's'),
         '| arrival at the pointed goal: error; contacts; path | %s; %s; %s | 0.10 m; 0 |'
         % (_ms(f.arrival_error_m, 'm'), '-' if f.contacts is None else f.contacts, _ms(f.path_m, 'm')),
         '| the tool against its target (the scaled hand), RMS over the run | %s | 2 mm at steady motion '
         '(bench_teleop) |' % _ms(f.tracking_rms_mm, 'mm'),
         '| the target\'s motion over the hand\'s, while engaged | %s | the dial: 0.10 |'
         % ('-' if f.hand_to_target_scale is None else '%.3f' % f.hand_to_target_scale),
         '| the arm\'s controller crashed → the arm commanded zero | %s | the motors\' command timeout: 50 ms |'
         % _ms(f.arm_zero_ms),
         '| … follow_hand says it fails (the operator hears it) | %s | 1 s |' % _ms(f.failing_s, 's'),
         '| … follow_hand FAILED, the arm\'s processes released | %s | - |' % _ms(f.failed_s, 's'),
         '| … said to the operator | %s | - |' % (('"%s"' % f.announced[:120]) if f.announced else '-')]
    if f.cut_failing_s is not None:
        L += ['| two hosts, the link cut while following: the last servo target on the robot → the arm commanded '
              'zero (robot.bag) | %s | 100 ms (the servo stream\'s timeout) |' % _ms(f.cut_hold_ms),
              '| … the link cut → the station hears follow_hand fail | %s | 1 s |' % _ms(f.cut_failing_s, 's')]
        if f.hand_to_joint_ms is not None:
            L += ['| two hosts, before the cut: a hand sample at the station → its joint command on the robot, '
                  'p50 / p95 (n=%d) | %.1f / %.1f ms | 25 ms p95 |' % (f.hand_to_joint_ms[2], f.hand_to_joint_ms[0],
                                                                       f.hand_to_joint_ms[1])]
    L += ['']
    L += ['## The drive', '', '![path](path.png)', '',
          '## The hand and the end-effector', '', '![hand](hand.png)', '',
          '## Stops and failovers', '', '![timeline](teleop_timeline.png)', '',
          '## What the operator saw', '']
    L += ['**%s**\n\n![%s](%s)\n' % (n[len('screenshot_'):-4], n, n) for n in shots] or ['No screenshots.', '']
    L += ['## Recorded topics', '', 'Inputs that would move a live robot (pointing, the hand, the servo stream, '
          'the halt) are kept under `%s`, so that a plain `rosbag play` moves nothing.' % T.INERT_PREFIX, '',
          '| topic | type | messages |', '| --- | --- | --- |']
    L += ['| `%s` | %s | %d |' % (t, k, n) for t, (k, n) in sorted(run.topics.items())]
    path = os.path.join(out_dir, 'report.md')
    with open(path, 'w') as fh:
        fh.write('\n'.join(L) + '\n')
    report = TeleopReport(path, f, images, [os.path.join(out_dir, n) for n in shots])
    with open(os.path.join(out_dir, 'report.json'), 'w') as fh:
        json.dump(report.summary, fh, indent=2, default=str)
    return report
