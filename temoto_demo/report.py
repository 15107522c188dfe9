"""The report of a failover run, computed from its bag alone.

Reading uses the pip ``rosbags`` library (``AnyReader`` registers every type from the definitions
stored in the bag, the custom TeMoto ones included), so a bag recorded on any machine, with or
without this project's generated messages, gives the same report.

Times are the publishers' header stamps (the ``stamp`` field of the action engine's JSON events);
a message without one falls back to the recorder's receive time.

Definitions, per unplug of a device (from ``/vaultbot_sim/device_states``):
- detection latency: unplug -> the first FAILED ``ResourceStatus`` on any registrar's status topic
  (the ER Manager's for a crash, the Sensor Manager's stall detector for a stall);
- propagation latency: that FAILED -> the action's ``sensor_failed`` event (FAILED received by the
  action and acted upon);
- display gap: the last frame of the failed sensor's displayed stream (relay ticks) -> the
  ``first_frame`` display event of the substitute's stream;
- switch time: unplug -> that first frame.
"""
from __future__ import annotations

import io
import json
import os
import re
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import matplotlib
import numpy as np
from matplotlib.lines import Line2D
from PIL import Image
from rosbags.highlevel import AnyReader

matplotlib.use('Agg')       # the report is drawn headless, before anything imports pyplot

from . import topics as T

FAILED = 1


# ============================================================================ what the bag holds
@dataclass
class Status:
    t: float
    topic: str
    manager: str
    server: str
    resource_id: int
    code: int
    message: str


@dataclass
class DisplayEv:
    t: float
    event: str
    name: str
    topic: str
    seconds_since_added: float
    frame_count: int = 0        # RViz frames rendered when the host saw it


@dataclass
class Unplug:
    t: float
    device: str
    mode: str


@dataclass
class Run:
    bag: str
    start: float = 0.0
    end: float = 0.0
    chatter: List[Tuple[float, str]] = field(default_factory=list)
    unplugs: List[Unplug] = field(default_factory=list)
    replugs: List[Tuple[float, str]] = field(default_factory=list)
    statuses: List[Status] = field(default_factory=list)
    display: List[DisplayEv] = field(default_factory=list)
    actions: List[dict] = field(default_factory=list)
    ticks: Dict[str, List[float]] = field(default_factory=dict)
    streams: Dict[str, int] = field(default_factory=dict)      # recorded messages per displayed stream
    screenshots: List[Tuple[float, str, bytes]] = field(default_factory=list)
    stages: List[dict] = field(default_factory=list)
    topics: Dict[str, Tuple[str, int]] = field(default_factory=dict)


def stamp_of(msg, bag_t: float) -> float:
    """A message's own header stamp (s), or ``bag_t`` when it has none."""
    header = getattr(msg, 'header', None)
    if header is not None:
        s = header.stamp.sec + header.stamp.nanosec * 1e-9
        if s > 0:
            return s
    return bag_t


def action_event(data: str, bag_t: float) -> Optional[dict]:
    """One of the action engine's JSON events, its time as ``t`` (its own stamp, else the bag's); None when it
    is not a JSON object."""
    try:
        ev = json.loads(data)
    except ValueError:
        return None
    if not isinstance(ev, dict):
        return None
    ev['t'] = float(ev.get('stamp') or bag_t)
    return ev


def load_run(bag_path: str, namespace: str = T.DEFAULT_NS) -> Run:
    """Everything the report needs, read from the bag with ``rosbags``."""
    run = Run(bag=os.path.abspath(bag_path))
    status_re = re.compile('^%s$' % T.status_regex(namespace))
    plugged: Dict[str, bool] = {}
    with AnyReader([Path(bag_path)]) as reader:
        run.start, run.end = reader.start_time * 1e-9, reader.end_time * 1e-9
        for c in reader.connections:       # as the bag holds them (inert names included): what a reader plays
            kind, n = run.topics.get(c.topic, (c.msgtype, 0))
            run.topics[c.topic] = (kind, n + c.msgcount)
        for conn, bag_ns, raw in reader.messages():
            topic, bag_t = T.live_name(conn.topic), bag_ns * 1e-9
            if topic.startswith(T.STREAMS_PREFIX + '/'):
                src = topic[len(T.STREAMS_PREFIX):]
                run.streams[src] = run.streams.get(src, 0) + 1
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            if topic == T.TICKS:
                st = msg.stamp.sec + msg.stamp.nanosec * 1e-9
                run.ticks.setdefault(msg.frame_id, []).append(st if st > 0 else bag_t)
            elif status_re.match(topic):
                run.statuses.append(Status(stamp_of(msg, bag_t), topic, msg.manager_name, msg.server_name,
                                           int(msg.resource_id), int(msg.status_code), msg.message))
            elif topic == T.display_events(namespace):
                run.display.append(DisplayEv(stamp_of(msg, bag_t), msg.event, msg.display_name, msg.topic,
                                             float(msg.seconds_since_added), int(msg.frame_count)))
            elif topic == T.action_events(namespace):
                ev = action_event(msg.data, bag_t)
                if ev is not None:
                    run.actions.append(ev)
            elif T.is_device_states(topic):
                t = stamp_of(msg, bag_t)
                for d in msg.devices:
                    was = plugged.get(d.name)
                    if was is not None and was and not d.plugged:
                        run.unplugs.append(Unplug(t, d.name, d.mode or 'crash'))
                    elif was is not None and not was and d.plugged:
                        run.replugs.append((t, d.name))
                    plugged[d.name] = bool(d.plugged)
            elif topic == T.chatter(namespace):
                run.chatter.append((bag_t, msg.data))
            elif topic == T.SCREENSHOTS:
                run.screenshots.append((stamp_of(msg, bag_t), msg.header.frame_id, bytes(msg.data)))
            elif topic == T.STAGES:
                try:
                    run.stages.append(json.loads(msg.data))
                except ValueError:
                    pass
    for lst in (run.statuses, run.display, run.unplugs):
        lst.sort(key=lambda x: x.t)
    run.actions.sort(key=lambda e: e['t'])
    for v in run.ticks.values():
        v.sort()
    return run


# ============================================================================ what it means
@dataclass
class Stage:
    index: int              # priority index in the action's list
    label: str
    sensor: str
    topic: str
    active_t: float         # the action's sensor_active event
    first_frame_t: Optional[float]
    via: str = ''           # how it came on screen: start, failover, standby, failback, retry


@dataclass
class Failure:
    device: str
    mode: str
    unplug_t: float
    failed_sensor: str = ''
    failed_topic: str = ''
    failed_t: Optional[float] = None          # first FAILED status anywhere
    failed_by: str = ''                       # which registrar raised it
    action_t: Optional[float] = None          # the action's sensor_failed event
    last_frame_t: Optional[float] = None      # failed stream's last frame
    substitute: str = ''
    substitute_topic: str = ''
    first_frame_t: Optional[float] = None     # substitute's first frame

    @staticmethod
    def _d(a, b):
        return None if a is None or b is None else b - a

    @property
    def detection(self) -> Optional[float]:
        return self._d(self.unplug_t, self.failed_t)

    @property
    def propagation(self) -> Optional[float]:
        return self._d(self.failed_t, self.action_t)

    @property
    def display_gap(self) -> Optional[float]:
        return self._d(self.last_frame_t, self.first_frame_t)

    @property
    def switch(self) -> Optional[float]:
        return self._d(self.unplug_t, self.first_frame_t)

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d.update(detection_s=self.detection, propagation_s=self.propagation, display_gap_s=self.display_gap,
                 switch_s=self.switch)
        return d


@dataclass
class ManagerKill:
    """``temoto demo --kill-managers``: one manager SIGKILLed, respawned and recovered, and the view meanwhile."""
    node: str
    kill_t: float
    recovered_s: Optional[float]            # SIGKILL -> its registry answers again, recovered
    shown_topic: str = ''                   # the stream on screen when it was killed
    longest_gap: Optional[float] = None     # between frames of that stream, from the kill to the recovery
    frame_period: Optional[float] = None    # that stream's median frame period over the run
    own_gap: Optional[float] = None         # its p99 gap between frames outside every kill: its own jitter
    displays_removed: int = 0               # displays taken off screen meanwhile
    unplugged: str = ''                     # a device unplugged while this manager was down
    failover_gap: Optional[float] = None    # then: its stream's last frame -> the substitute's first frame

    @property
    def allowed_gap(self) -> Optional[float]:
        """The longest gap the stream shows by itself: 2 frame periods, or its own p99 gap if longer."""
        if self.frame_period is None:
            return None
        return max(2 * self.frame_period, self.own_gap or 0.0) + MIN_GAP_SLACK_S

    @property
    def view_stayed_up(self) -> bool:
        """No display removed, and no gap between frames beyond what the stream shows by itself; or, when a
        device was unplugged while the manager was down, the view failed over to its substitute."""
        if self.unplugged:
            return self.failover_gap is not None
        return (self.displays_removed == 0 and self.longest_gap is not None and self.allowed_gap is not None
                and self.longest_gap <= self.allowed_gap)

    def as_dict(self) -> dict:
        return dict(self.__dict__, view_stayed_up=self.view_stayed_up)


# frames arrive with the machine's jitter: a gap counts only beyond two periods and this
MIN_GAP_SLACK_S = 0.05


@dataclass
class Analysis:
    t0: float
    stages: List[Stage]
    failures: List[Failure]
    labels: Dict[str, str]      # topic -> sensor label
    kills: List[ManagerKill] = field(default_factory=list)
    failbacks: List['FailBack'] = field(default_factory=list)
    standby: str = ''           # the view's standby policy, from the action's events


@dataclass
class FailBack:
    """A better device plugged back, and the view's return to it."""
    device: str
    replug_t: float
    label: str = ''
    failback_t: Optional[float] = None        # the action's failback event
    first_frame_t: Optional[float] = None     # the better view's first frame on screen
    blank_frames: Optional[int] = None        # frames RViz rendered with neither view: 0 is a seamless switch

    @property
    def delay(self) -> Optional[float]:
        return None if self.first_frame_t is None else self.first_frame_t - self.replug_t

    def as_dict(self) -> dict:
        return dict(self.__dict__, delay_s=self.delay)


def analyse_failbacks(run: Run, stages: List[Stage]) -> List[FailBack]:
    """Each replug followed by a fail-back: when the better view was on screen, and whether any frame was blank.

    Blank frames come from the RViz host's frame counts: the old view went off (``hidden`` or ``removed``) at
    frame a, the better one was first drawn at frame b; b - a - 1 frames were rendered with neither.
    """
    out = []
    for t, device in run.replugs:
        fb = FailBack(device, t)
        ev = _first(run.actions, lambda e: e.get('event') == 'failback' and e['t'] >= t)
        if ev is not None:
            fb.label, fb.failback_t = str(ev.get('label', '')), ev['t']
            new = _first(stages, lambda s: s.active_t >= ev['t'] - 0.5 and s.label == fb.label)
            old_topic = next((s.topic for s in reversed(stages) if s.active_t < ev['t'] - 0.5), '')
            if new is not None and new.first_frame_t is not None:
                fb.first_frame_t = new.first_frame_t
                drawn = _first(run.display, lambda e: e.event == 'first_frame' and e.topic == new.topic
                               and e.t >= ev['t'] - 0.5)
                off = _first(run.display, lambda e: e.event in ('hidden', 'removed') and e.topic == old_topic
                             and e.t >= ev['t'] - 0.5)
                if drawn is not None and off is not None:
                    fb.blank_frames = max(0, drawn.frame_count - off.frame_count - 1)
        out.append(fb)
    return out


def _first(items, pred):
    return next((x for x in items if pred(x)), None)


def _first_frame(run: Run, topic: str, after: float) -> Optional[float]:
    ev = _first(run.display, lambda e: e.event == 'first_frame' and e.topic == topic and e.t >= after - 0.5)
    return ev.t if ev else None


def _same_failure(status: Status, reached: str) -> bool:
    """Whether ``status`` is the failure whose message reached the action (``reached``; '' when the action
    did not say: any FAILED then). Another FAILED may fall in the same window: a fail-back attempt of a
    sensor unplugged before failed while the shown one stalled, and was taken for its origin."""
    head = status.message.strip().splitlines()[0][:80] if status.message.strip() else ''
    return not reached or not head or head in reached


def analyse(run: Run) -> Analysis:
    t0 = run.chatter[0][0] if run.chatter else run.start
    actives = [e for e in run.actions if e.get('event') == 'sensor_active']
    stages, labels = [], {}
    for e in actives:
        topic = str(e.get('topic', ''))
        labels.setdefault(topic, str(e.get('label', topic)))
        stages.append(Stage(int(e.get('priority_index', -1)), str(e.get('label', '')), str(e.get('sensor_name', '')),
                            topic, e['t'], _first_frame(run, topic, e['t']), str(e.get('via', ''))))
    failures = []
    for i, u in enumerate(run.unplugs):
        nxt = run.unplugs[i + 1].t if i + 1 < len(run.unplugs) else float('inf')
        f = Failure(u.device, u.mode, u.t)
        before = [s for s in stages if s.active_t <= u.t]
        if before:
            f.failed_sensor, f.failed_topic = before[-1].label, before[-1].topic
        act = _first(run.actions, lambda e: e.get('event') == 'sensor_failed' and u.t <= e['t'] < nxt)
        reached = str(act.get('message', '')) if act else ''
        st = _first(run.statuses, lambda s: s.code == FAILED and u.t <= s.t < nxt and _same_failure(s, reached))
        if st:
            f.failed_t, f.failed_by = st.t, '%s (%s)' % (st.manager, st.server)
        if act:
            f.action_t = act['t']
            sub = _first(stages, lambda s: s.active_t >= act['t'])
            if sub:
                f.substitute, f.substitute_topic, f.first_frame_t = sub.label, sub.topic, sub.first_frame_t
        if f.failed_topic:
            end = f.first_frame_t if f.first_frame_t is not None else nxt
            frames = [t for t in run.ticks.get(f.failed_topic, []) if t < end]
            if frames:
                f.last_frame_t = frames[-1]
        failures.append(f)
    standby = next((str(e.get('standby')) for e in actives if e.get('standby')), '')
    return Analysis(t0, stages, failures, labels, analyse_kills(run, stages, failures),
                    analyse_failbacks(run, stages), standby)


def analyse_kills(run: Run, stages: List[Stage], failures: List[Failure]) -> List[ManagerKill]:
    kills, windows = [], []
    recovered = [m for m in run.stages if m.get('stage') == 'recovered']
    for mark in (m for m in run.stages if m.get('stage') == 'kill'):
        t = float(mark['stamp'])
        back = _first(recovered, lambda m: m.get('node') == mark.get('node') and float(m['stamp']) >= t)
        kills.append(ManagerKill(str(mark.get('node')), t, float(back['seconds']) if back else None))
        windows.append((t, float(back['stamp']) if back else run.end))
    for kill, (t, end) in zip(kills, windows):
        shown = [s for s in stages if s.first_frame_t is not None and s.first_frame_t <= t]
        if shown:
            kill.shown_topic = shown[-1].topic
            ticks = run.ticks.get(kill.shown_topic, [])
            inside = [x for x in ticks if t <= x <= end]
            before = [x for x in ticks if x < t][-1:]
            after = [x for x in ticks if x > end][:1]
            window = before + inside + after
            if len(window) >= 2:
                kill.longest_gap = max(b - a for a, b in zip(window, window[1:]))
            shown_from = shown[-1].first_frame_t
            own = sorted(b - a for a, b in zip(ticks, ticks[1:]) if a >= shown_from and
                         not any(a <= w_end and b >= w_t for w_t, w_end in windows))
            if len(own) >= 3:
                kill.frame_period = statistics.median(own)
                kill.own_gap = own[min(len(own) - 1, int(0.99 * len(own)))]
        kill.displays_removed = sum(1 for e in run.display if e.event == 'removed' and t <= e.t <= end)
        down = _first(failures, lambda f: t <= f.unplug_t <= end)
        if down is not None:
            kill.unplugged, kill.failover_gap = down.device, down.display_gap
    return kills


# ============================================================================ the pictures
def plot_timeline(run: Run, an: Analysis, path: str) -> str:
    """Which sensor's data reached the display, over time, with unplug / FAILED / switch marked."""
    import matplotlib.pyplot as plt     # here: after the Agg backend is chosen at the top (no display)

    rows = [s.topic for s in an.stages]
    rows = list(dict.fromkeys(rows + [t for t in run.ticks if t not in rows]))
    fig, ax = plt.subplots(figsize=(11, 1.4 + 0.75 * max(1, len(rows))))
    colors = plt.rcParams['axes.prop_cycle'].by_key()['color']
    # Displayed intervals of each topic: from its first frame to the display's removal.
    for y, topic in enumerate(rows):
        color = colors[y % len(colors)]
        shown = []
        start = None
        for e in run.display:
            if e.topic != topic:
                continue
            if e.event == 'first_frame' and start is None:
                start = e.t
            elif e.event in ('removed', 'host_stopping') and start is not None:
                shown.append((start, e.t))
                start = None
        if start is not None:
            shown.append((start, run.end))
        ax.broken_barh([(a - an.t0, b - a) for a, b in shown], (y - 0.3, 0.6), facecolors=color, alpha=0.25)
        ticks = [t - an.t0 for t in run.ticks.get(topic, [])]
        if ticks:
            ax.plot(ticks, [y] * len(ticks), '|', color=color, markersize=14, alpha=0.8)
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels(['%s\n%s' % (an.labels.get(t, ''), t) for t in rows], fontsize=8)
    ax.set_ylim(-0.7, len(rows) - 0.3)
    top = len(rows) - 0.35
    lines = [(u.t, 'tab:red', '--') for u in run.unplugs]
    lines += [(f.failed_t, 'tab:orange', ':') for f in an.failures if f.failed_t]
    lines += [(f.action_t, 'tab:purple', ':') for f in an.failures if f.action_t]
    lines += [(s.first_frame_t, 'tab:green', '-') for s in an.stages if s.first_frame_t]
    for t, color, style in lines:
        ax.axvline(t - an.t0, color=color, linestyle=style, linewidth=1.2)
    # One label per failure (its three lines are milliseconds apart) and one per stage.
    for f in an.failures:
        parts = ['unplug %s (%s)' % (f.device, f.mode)]
        if f.detection is not None:
            parts.append('FAILED +%.3f s' % f.detection)
        if f.action_t is not None:
            parts.append('action +%.3f s' % (f.action_t - f.unplug_t))
        ax.annotate('\n'.join(parts), (f.unplug_t - an.t0, top), rotation=90, fontsize=7, color='tab:red',
                    va='top', ha='right', xytext=(-2, 0), textcoords='offset points')
    for s in an.stages:
        if s.first_frame_t:
            ax.annotate('on screen: %s' % s.label, (s.first_frame_t - an.t0, top), rotation=90, fontsize=7,
                        color='tab:green', va='top', ha='left', xytext=(2, 0), textcoords='offset points')
    ax.legend([Line2D([], [], color=c, linestyle=st) for c, st in
               (('tab:red', '--'), ('tab:orange', ':'), ('tab:purple', ':'), ('tab:green', '-'))],
              ['unplug', 'first FAILED status', 'action received FAILED', 'first frame on screen'],
              loc='upper center', bbox_to_anchor=(0.5, -0.22), ncol=4, fontsize=8, frameon=False)
    ax.set_xlabel('seconds since "%s"' % (run.chatter[0][1] if run.chatter else 'start'))
    ax.set_title('Sensor data reaching the operator\'s display (ticks: frames; bars: displayed)', fontsize=10)
    ax.grid(axis='x', alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def non_background_fraction(png: bytes) -> float:
    """Share of pixels that differ from the image's most common colour (an empty view is ~0)."""
    img = np.asarray(Image.open(io.BytesIO(png)).convert('RGB')).reshape(-1, 3).astype(np.int16)
    colours, counts = np.unique(img, axis=0, return_counts=True)
    bg = colours[counts.argmax()]
    return float((np.abs(img - bg).sum(axis=1) > 24).mean())


def diff_fraction(png_a: bytes, png_b: bytes, threshold: int = 48) -> float:
    """Share of pixels whose colour differs (sum of |dRGB| > threshold) between two same-size images."""
    a = np.asarray(Image.open(io.BytesIO(png_a)).convert('RGB')).astype(np.int16)
    b = np.asarray(Image.open(io.BytesIO(png_b)).convert('RGB')).astype(np.int16)
    if a.shape != b.shape:
        return 1.0
    return float((np.abs(a - b).sum(axis=2) > threshold).mean())


EMPTY_VIEW = 'empty_view'


# ============================================================================ the document
def _fmt(x: Optional[float]) -> str:
    return '—' if x is None else '%.3f s' % x


@dataclass
class Report:
    path: str
    timeline: str
    screenshots: List[str]
    analysis: Analysis
    run: Run

    def summary(self) -> dict:
        return {'bag': self.run.bag, 'report': self.path, 'timeline': self.timeline, 'screenshots': self.screenshots,
                'stages': [s.__dict__ for s in self.analysis.stages],
                'failures': [f.as_dict() for f in self.analysis.failures],
                'kills': [k.as_dict() for k in self.analysis.kills],
                'standby': self.analysis.standby,
                'failbacks': [f.as_dict() for f in self.analysis.failbacks]}


def _screenshots(run: Run, bag_dir: str, out_dir: str) -> List[Tuple[str, str]]:
    """(file name in out_dir, stage) for each screenshot: from the bag, else PNGs beside the bag."""
    found = []
    if run.screenshots:
        for i, (_, stage, data) in enumerate(run.screenshots, 1):
            name = 'screenshot_%d_%s.png' % (i, re.sub(r'[^A-Za-z0-9_-]+', '_', stage) or 'stage')
            with open(os.path.join(out_dir, name), 'wb') as f:
                f.write(data)
            found.append((name, stage))
        return found
    for name in sorted(os.listdir(bag_dir)):
        if name.startswith('screenshot_') and name.endswith('.png'):
            if os.path.abspath(bag_dir) != os.path.abspath(out_dir):
                with open(os.path.join(bag_dir, name), 'rb') as src, open(os.path.join(out_dir, name), 'wb') as dst:
                    dst.write(src.read())
            found.append((name, name[len('screenshot_'):-4]))
    return found


def write_report(bag_path: str, out_dir: Optional[str] = None, namespace: str = T.DEFAULT_NS) -> Report:
    bag_dir = os.path.dirname(os.path.abspath(bag_path))
    out_dir = out_dir or bag_dir
    os.makedirs(out_dir, exist_ok=True)
    run = load_run(bag_path, namespace)
    an = analyse(run)
    timeline = plot_timeline(run, an, os.path.join(out_dir, 'timeline.png'))
    shots = _screenshots(run, bag_dir, out_dir)

    L = ['# TeMoto sensor failover: run report', '',
         'Bag: `%s` (%.1f s, %d topics). The paper\'s section 4: "show the environment", then the RGB-D camera '
         'and the arm LIDAR are unplugged; the view fails over down the sensor priority list.'
         % (os.path.basename(bag_path), run.end - run.start, len(run.topics)), '']
    L += ['## What the operator saw', '']
    if shots:
        def png(name):
            with open(os.path.join(out_dir, name), 'rb') as f:
                return f.read()
        baseline = next((png(n) for n, st in shots if st == EMPTY_VIEW), None)
        for name, stage in shots:
            if stage == EMPTY_VIEW:
                continue
            data = png(name)
            if baseline is not None:
                note = '%.1f%% of pixels differ from the empty view' % (100 * diff_fraction(data, baseline))
            else:
                note = '%.0f%% of pixels not background' % (100 * non_background_fraction(data))
            L += ['**%s** (%s)' % (stage, note), '', '![%s](%s)' % (stage, name), '']
        if baseline is not None:
            name = next(n for n, st in shots if st == EMPTY_VIEW)
            L += ['The empty view (the action stopped, nothing displayed), the baseline above:', '',
                  '![empty view](%s)' % name, '']
    else:
        L += ['No screenshots in the bag or beside it.', '']
    L += ['## Timeline', '', '![timeline](%s)' % os.path.basename(timeline), '',
          'Ticks: frames of each stream arriving (relay); bars: the stream displayed in RViz (first frame drawn to '
          'display removed); red: unplug; orange: first FAILED status; purple: the action received FAILED; '
          'green: the new stream\'s first frame on screen.', '']
    L += ['## Stages', '', '| # | sensor | topic | via | action chose it at | first frame on screen at | chose → drawn |',
          '| --- | --- | --- | --- | --- | --- | --- |']
    for s in an.stages:
        ff = s.first_frame_t
        L.append('| %d | %s (%s) | `%s` | %s | %.3f s | %s | %s |' % (
            s.index, s.label, s.sensor, s.topic, s.via or '-', s.active_t - an.t0,
            '—' if ff is None else '%.3f s' % (ff - an.t0), _fmt(None if ff is None else ff - s.active_t)))
    L += ['', 'Standby policy: **%s**. Each stage says how it came on screen: `start`, `failover` (the next '
          'sensor started), `standby` (the spare that was running), `failback` or `retry`.' % (an.standby or 'cold'),
          '']
    L += ['', '## Failures', '']
    if not an.failures:
        L += ['No device was unplugged in this run.', '']
    for n, f in enumerate(an.failures, 1):
        L += ['### %d. %s unplugged (%s) at %.3f s' % (n, f.device, f.mode, f.unplug_t - an.t0), '',
              'Showing before: %s (`%s`); after: %s (`%s`). FAILED first raised by %s.'
              % (f.failed_sensor or '?', f.failed_topic or '?', f.substitute or 'nothing', f.substitute_topic or '-',
                 f.failed_by or 'nobody'), '',
              '| figure | value | from → to |', '| --- | --- | --- |',
              '| detection latency | %s | unplug → first FAILED status |' % _fmt(f.detection),
              '| propagation latency | %s | FAILED → the action\'s sensor_failed event |' % _fmt(f.propagation),
              '| display gap | %s | last frame of the failed stream → first frame of the substitute |'
              % _fmt(f.display_gap),
              '| switch time | %s | unplug → first frame of the substitute |' % _fmt(f.switch), '']
    if an.failbacks:
        L += ['## Fail-backs', '', 'A better device plugged back; the view returns to it after the action\'s hold '
              '(`failback_hold_s`). Blank frames: frames RViz rendered after the old view went off and before the '
              'better one was drawn (RViz\'s own frame counts).', '',
              '| device | back on screen | replug → on screen | blank frames |', '| --- | --- | --- | --- |']
        for fb in an.failbacks:
            L.append('| %s | %s | %s | %s |' % (fb.device, fb.label or 'no', _fmt(fb.delay),
                                                '-' if fb.blank_frames is None else fb.blank_frames))
        L.append('')
    if an.kills:
        L += ['## Managers killed (`--kill-managers`)', '',
              'Each manager was SIGKILLed once, respawned, and recovered from its journal while the view was up. '
              'The view stayed up if no display was removed and the shown stream\'s frames kept coming: no gap '
              'longer than the stream shows by itself (two median periods, or its p99 gap outside the kills if '
              'longer, + 50 ms).', '',
              '| manager | killed at | recovered in | stream on screen | longest gap between frames | the stream '
              'by itself: median period / p99 gap | displays removed | view stayed up |',
              '| --- | --- | --- | --- | --- | --- | --- | --- |']
        for k in an.kills:
            if k.unplugged:
                verdict = ('failed over (%s unplugged while it was down), display gap %s'
                           % (k.unplugged, _fmt(k.failover_gap)) if k.view_stayed_up else
                           '**no** (%s unplugged while it was down, no failover)' % k.unplugged)
            else:
                verdict = 'yes' if k.view_stayed_up else '**no**'
            L.append('| %s | %.3f s | %s | `%s` | %s | %s / %s | %d | %s |' % (
                k.node, k.kill_t - an.t0, _fmt(k.recovered_s), k.shown_topic or '-', _fmt(k.longest_gap),
                _fmt(k.frame_period), _fmt(k.own_gap), k.displays_removed, verdict))
        L.append('')
    L += ['## Recorded topics', '', 'As the bag holds them. Topics under `%s` had the rest of their name on the '
          'live system; they are kept apart so that a plain `rosbag play` acts on nothing and announces '
          'nothing (docs/bags.md).' % T.INERT_PREFIX, '', '| topic | type | messages |', '| --- | --- | --- |']
    L += ['| `%s` | %s | %d |' % (t, k, n) for t, (k, n) in sorted(run.topics.items())]
    L.append('')
    path = os.path.join(out_dir, 'report.md')
    with open(path, 'w') as f:
        f.write('\n'.join(L))
    report = Report(path, timeline, [os.path.join(out_dir, n) for n, _ in shots], an, run)
    with open(os.path.join(out_dir, 'report.json'), 'w') as f:
        json.dump(report.summary(), f, indent=2, default=str)
    return report
