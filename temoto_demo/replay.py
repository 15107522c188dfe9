"""``temoto replay BAG``: the operator's views of a recorded run, shown again in a real RViz.

The replay never touches a live system: it starts a master of its own on a free loopback port,
an RViz host on it (headless under Xvfb unless ``--live``), and plays only the bag's recorded
streams, ``/tf`` and ``/tf_static`` (with ``--clock``, on simulated time, so RViz transforms the
recorded data at its recorded time), and the action engine's events and feedback, mapped back from
their inert names to their own on that private master (a console pointed at it follows the run). A display is added for every recorded stream before the play
starts. When a stream's first message arrives, the views before it are taken off the screen, as
the failover did during the run, and a screenshot of the new view is saved.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
import xmlrpc.client
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

import rospy
from rosbags.highlevel import AnyReader

from temoto_core.master import RosMaster
from temoto_core.processes import LoggedChild, ProcessGroupLauncher
from temoto_core.wait import wait_for
from temoto_output_manager.host_client import RvizHostClient

from . import topics as T

DISPLAY_CLASSES = {'sensor_msgs/msg/PointCloud2': 'rviz/PointCloud2', 'sensor_msgs/msg/LaserScan': 'rviz/LaserScan'}
HOST_NAME = 'replay_rviz_host'
PLAY_DELAY_S = 2.0          # the player's own pause after advertising: RViz subscribes meanwhile
DRAWN_FRAMES = 3            # frames drawn after a switch before its screenshot


@dataclass
class Stream:
    topic: str              # as recorded: /temoto_demo/streams/<live topic>
    live_topic: str
    msgtype: str
    first_t: float          # bag time of its first message
    count: int


def read_bag(bag: str) -> tuple:
    """(streams in order of first appearance, robot description or '')."""
    firsts: Dict[str, Stream] = {}
    urdf = ''
    with AnyReader([Path(bag)]) as reader:
        streams = [c for c in reader.connections if c.topic.startswith(T.STREAMS_PREFIX + '/')]
        for conn, stamp, _raw in reader.messages(connections=streams):
            if conn.topic not in firsts:
                firsts[conn.topic] = Stream(conn.topic, conn.topic[len(T.STREAMS_PREFIX):], conn.msgtype,
                                            stamp * 1e-9, conn.msgcount)
        for conn, _stamp, raw in reader.messages(
                connections=[c for c in reader.connections if c.topic == T.ROBOT_DESCRIPTION]):
            urdf = reader.deserialize(raw, conn.msgtype).data
    return sorted(firsts.values(), key=lambda s: s.first_t), urdf


class Replay:
    def __init__(self, bag: str, out_dir: str, live: bool = False, rate: float = 1.0,
                 say=lambda text: print(text, flush=True)) -> None:
        self.bag = os.path.abspath(bag)
        self.out_dir = os.path.abspath(out_dir)
        self.live = live
        self.rate = rate
        self.say = say
        self.screenshots: List[str] = []

    def run(self, timeout: float = 300.0) -> List[str]:
        streams, urdf = read_bag(self.bag)
        if not streams:
            raise RuntimeError('%s holds no recorded stream (%s/...): nothing to show' % (self.bag, T.STREAMS_PREFIX))
        os.makedirs(self.out_dir, exist_ok=True)
        work = tempfile.mkdtemp(prefix='temoto_replay_')
        master = RosMaster(work).start()
        launcher = ProcessGroupLauncher(self._env(master), work)
        try:
            self.say('private master %s; %d stream(s): %s' % (master.uri, len(streams),
                                                               ', '.join(s.live_topic for s in streams)))
            proxy = xmlrpc.client.ServerProxy(master.uri)
            proxy.setParam('/temoto_replay', '/use_sim_time', True)
            if urdf:
                proxy.setParam('/temoto_replay', '/robot_description', urdf)
            self._show(launcher, master, streams, timeout)
        finally:
            launcher.stop_all()
            master.stop()
        return self.screenshots

    def _env(self, master: RosMaster) -> Dict[str, str]:
        env = dict(os.environ)
        env.update(master.env)
        if not self.live:
            env.pop('DISPLAY', None)
        return env

    def _show(self, launcher: ProcessGroupLauncher, master: RosMaster, streams: List[Stream], timeout: float):
        saved_env = master.point_this_process()      # this process's clients talk to the private master
        try:
            self._show_on(rospy, RvizHostClient, launcher, streams, timeout)
        finally:
            master.restore_process(saved_env)

    def _show_on(self, rospy, RvizHostClient, launcher: ProcessGroupLauncher, streams: List[Stream],
                 timeout: float) -> None:
        rospy.init_node('temoto_replay', anonymous=True, disable_signals=True)
        host_proc = launcher.node('temoto_output_manager', 'rviz_host', name=HOST_NAME, namespace='temoto',
                                  params={'show_robot': 'true', 'show_grid': 'true', 'fixed_frame': 'base_link'},
                                  timeout=60)
        host = RvizHostClient('/temoto/' + HOST_NAME)
        host.wait_ready(60, failed=lambda: None if host_proc.alive() else 'the RViz host exited:\n' + host_proc.log())
        names = {}
        for s in streams:
            cls = DISPLAY_CLASSES.get(s.msgtype)
            if cls is None:
                self.say('  %s: no display for %s; not shown' % (s.live_topic, s.msgtype))
                continue
            names[s.topic] = host.add_display(cls, s.topic, name=s.live_topic)
        self.say('RViz up with %d display(s); playing %s' % (len(names), os.path.basename(self.bag)))
        arrived: List[str] = []
        changed = threading.Condition()
        subs = [rospy.Subscriber(t, rospy.AnyMsg, lambda _m, t=t: self._first(changed, arrived, t), queue_size=1)
                for t in names]
        news = [T.action_events(), T.action_feedback()]      # under their live names: this master is private
        play = launcher.command(['rosbag', 'play', '-q', '--clock', '-d', str(PLAY_DELAY_S), '-r', str(self.rate),
                                 self.bag, '--topics', '/tf', '/tf_static'] + list(names) +
                                [T.inert_name(t) for t in news] + ['%s:=%s' % (T.inert_name(t), t) for t in news],
                                'rosbag_play')
        shown = 0
        removed = set()
        deadline = time.monotonic() + timeout
        while shown < len(names) and time.monotonic() < deadline:
            with changed:
                pending = arrived[shown:]
                if not pending:
                    if not play.alive():
                        break
                    changed.wait(0.2)       # woken by a stream's first message; the player is checked too
                    continue
            topic = pending[0]
            for earlier in arrived[:shown]:
                if earlier not in removed:
                    host.remove_display(names[earlier])       # the failover: the failed view goes
                    removed.add(earlier)
            shown += 1
            self._screenshot(host, shown, topic[len(T.STREAMS_PREFIX):])
        wait_for(lambda: not play.alive(), max(5.0, deadline - time.monotonic()), 'the bag to finish playing')
        for sub in subs:
            sub.unregister()
        rospy.signal_shutdown('replay done')

    @staticmethod
    def _first(changed: threading.Condition, arrived: List[str], topic: str) -> None:
        with changed:
            if topic not in arrived:
                arrived.append(topic)
                changed.notify_all()

    def _screenshot(self, host, index: int, live_topic: str) -> None:
        first = host.screenshot('view').frame_count
        wait_for(lambda: host.screenshot('view').frame_count >= first + DRAWN_FRAMES, 15,
                 'RViz to draw %s' % live_topic)
        path = os.path.join(self.out_dir, 'replay_%d_%s.png' % (index, live_topic.strip('/').replace('/', '_')))
        host.screenshot('view', path)
        self.screenshots.append(path)
        self.say('view %d: %s -> %s' % (index, live_topic, path))


def replay_main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog='temoto replay', description='Show the views of a recorded run again in RViz, '
                                'on a master of its own (a live stack is never touched).')
    p.add_argument('bag', help='a bag recorded by temoto demo or temoto record')
    p.add_argument('--out', default='', help='folder for the screenshots (default: beside the bag)')
    p.add_argument('--live', action='store_true', help='show RViz on $DISPLAY (default: headless under Xvfb)')
    p.add_argument('--rate', type=float, default=1.0, help='play rate (default 1)')
    args = p.parse_args(argv)
    if not os.path.isfile(args.bag):
        print('temoto replay: no bag file at %s' % args.bag, file=sys.stderr)
        return 1
    if args.rate <= 0:
        p.error('--rate must be positive')
    if args.live and not os.environ.get('DISPLAY'):
        p.error('--live needs a DISPLAY')
    out = args.out or os.path.dirname(os.path.abspath(args.bag))
    try:
        shots = Replay(args.bag, out, args.live, args.rate).run()
    except (RuntimeError, TimeoutError, OSError) as e:
        print('temoto replay: %s' % e, file=sys.stderr)
        return 1
    print('temoto replay: %d view(s) shown again' % len(shots))
    return 0 if shots else 1
