"""The demo's stages, waited on by events (never by sleeps), each printed with its time.

1. roscore, the nodes of demo.launch, the recording;
2. "show the environment" on the chatter -> the first priority entry's stream drawn in RViz;
3. for every further entry: unplug the device of the one shown -> the next entry's stream drawn;
4. stop everything in reverse order and check, by the session token every child inherits, that no
   process is left; then the report.

With ``--kill-managers`` the stack runs with ``recovery:=true`` (journals, respawn), and once the first
view is on screen every manager is SIGKILLed once, in a seeded random order at seeded random moments;
each must come back with its registry before the next is killed, and the view must stay up. The first
device is unplugged while the Sensor Manager is down: nobody can hear its driver's FAILED then, so the
failover to the second view proves that the FAILED reached the action after the Sensor Manager's
recovery. The remaining failover stages run on the recovered managers.

A stage is reached when the action reported ``sensor_active`` for that priority index and the RViz
host reported ``first_frame`` for the topic it named.
"""
from __future__ import annotations

import json
import os
import random
import signal
import sys
import threading
import time
import uuid
import xml.etree.ElementTree as ElementTree
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

import rosgraph
import rospy
import yaml
from sensor_msgs.msg import CompressedImage, PointCloud2
from std_msgs.msg import String

import temoto_sensor_manager
from temoto_action_engine.srv import StopGraph
from temoto_core import master_lookup, rospy_internals
from temoto_core.hosts import TwoHosts
from temoto_core.master import RosMaster, connected
from temoto_core.node import prime_log_parameter
from temoto_core.processes import kill_leftovers, leftover_processes
from temoto_core.srv import GetRegistry
from temoto_core.wait import wait_for
from temoto_output_manager.first_frame import received_count
from temoto_output_manager.host_client import RvizHostClient, host_node_name
from temoto_output_manager.interface import OutputManagerInterface
from temoto_output_manager.msg import DisplayEvent
from temoto_speech.msg import AudioData
from temoto_speech.voice import synthesize_pcm
from vaultbot_sim.srv import SetDeviceState

from . import topics as T
from .recording import RECORDER_NODE, Recording
from .report import write_report
from .stack import Stack, load_launch

# --priority names -> (index in action_engine.yaml's sensor_priority, device to unplug, screenshot name)
PRIORITY_ENTRIES = OrderedDict([('rgbd', (0, 'd435')), ('arm_cloud', (1, 'hokuyo')), ('base_scan', (2, 'sick'))])
# --hosts 2: the station's own sensor (config/station_view.yaml), after the robot's entries
STATION_ENTRY = 3
PRIORITY_PARAM = '/temoto_action_engine/actions/show_environment/sensor_priority'
STANDBY_PARAM = '/temoto_action_engine/actions/show_environment/standby'
INSTRUCTION = 'show the environment'
STARTUP_TIMEOUT = 60.0
# seconds each view stays on screen at least before the next failure (or the end): the bag, its report and
# its replay then show every view, the last one too (it lasted 0.15 s, 4 scans, when the demo stopped at once).
# 2 s of a stream in the bag, and the half second a 10 Hz cloud's last message and the recorder may lag by
MIN_VIEW_S = 2.5
# --kill-managers: node -> the registrars it runs (each must answer, recovered, before the next kill)
KILLABLE = OrderedDict([('/temoto_er_manager', ['temoto_er_manager']),
                        ('/temoto_sensor_manager', ['temoto_sensor_manager']),
                        ('/temoto_output_manager', ['temoto_output_manager']),
                        ('/temoto_context_manager', ['temoto_context_manager', 'temoto_context_manager_trackers'])])
RECOVERY_TIMEOUT = 30.0
SENSOR_MANAGER = '/temoto_sensor_manager'
# the system's launch files (temoto_bringup), found beside this package
LAUNCH_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'temoto_bringup', 'launch')


def write_station_catalogue(robot: str, workdir: str) -> str:
    """The station's catalogue (temoto_sensor_manager config/station.yaml), its scanner joined to ``robot``,
    written into ``workdir``: the file names the robot whose simulated lab the scanner stands in."""
    src = os.path.join(os.path.dirname(temoto_sensor_manager.__file__), 'config', 'station.yaml')
    with open(src) as f:
        catalogue = yaml.safe_load(f)
    for entry in catalogue['sensors']:
        entry['args'] = 'sim_ns:=/%s/vaultbot_sim joint_states:=/%s/joint_states' % (robot, robot)
    path = os.path.join(workdir, 'station.yaml')
    with open(path, 'w') as f:
        yaml.safe_dump(catalogue, f)
    return path


def _declared_args(launch: str, args: List[str]) -> List[str]:
    """The ``name:=value`` of ``args`` that ``launch`` declares (roslaunch refuses the others)."""
    declared = {arg.get('name') for arg in ElementTree.parse(launch).getroot().findall('arg')}
    return [a for a in args if a.split(':=', 1)[0] in declared]


def _rel(path: str) -> str:
    rel = os.path.relpath(path)
    return path if rel.startswith('..') else rel


class StageTimeout(RuntimeError):
    pass


class StageFailed(StageTimeout):
    """What a stage waits for can no longer come: the graph that would bring it ended FAILED."""


@dataclass
class DemoOptions:
    out_dir: str
    live: bool = False
    stage_timeout: float = 30.0
    modes: Dict[str, str] = field(default_factory=lambda: {'d435': 'crash', 'hokuyo': 'stall', 'sick': 'crash'})
    priority: List[str] = field(default_factory=lambda: list(PRIORITY_ENTRIES))
    report: bool = True
    namespace: str = T.DEFAULT_NS
    launch_args: List[str] = field(default_factory=list)
    kill_managers: bool = False
    seed: int = 0
    hosts: int = 1               # 2: the robot and the operator's station on two hosts (network namespaces)
    robot: str = 'vaultbot'      # --hosts 2: the robot's TeMoto namespace
    standby: str = 'cold'        # the view's standby policy: cold, warm or hot
    replug: bool = False         # at the end, plug the first device back and wait for the fail-back
    voice: bool = False          # the instruction spoken (espeak-ng) to the speech node, the failures announced
    unplug_all: bool = False     # after the first view, unplug every device at once and time "every sensor failed"


class Progress:
    """One line per stage: total time since start, and the stage's own time."""

    def __init__(self) -> None:
        self.t0 = self.mark = time.monotonic()
        self.lines: List[dict] = []

    def line(self, text: str, ok: bool = True) -> None:
        now = time.monotonic()
        self.lines.append({'t': now - self.t0, 'stage_s': now - self.mark, 'text': text, 'ok': ok})
        print('[%5.1f s] %-58s (%.2f s)' % (now - self.t0, text, now - self.mark), flush=True)
        self.mark = now


class EventWatcher:
    """The action engine's events and the RViz host's display events, as they arrive."""

    def __init__(self, ns: str) -> None:
        self._cond = threading.Condition()
        self.actions: List[dict] = []
        self.display: List[tuple] = []      # (arrival, event, topic)
        self._subs = [rospy.Subscriber(T.action_events(ns), String, self._on_action, queue_size=100),
                      rospy.Subscriber(T.display_events(ns), DisplayEvent, self._on_display, queue_size=100)]

    def _on_action(self, msg) -> None:
        try:
            ev = json.loads(msg.data)
        except ValueError:
            return
        with self._cond:
            self.actions.append(dict(ev, arrival=time.monotonic()))
            self._cond.notify_all()

    def _on_display(self, msg) -> None:
        with self._cond:
            self.display.append((time.monotonic(), msg.event, msg.topic))
            self._cond.notify_all()

    def _stage_topic(self, index: int, since: float) -> Optional[str]:
        active = [e for e in self.actions if e.get('event') == 'sensor_active' and e.get('priority_index') == index
                  and e['arrival'] >= since]
        if not active:
            return None
        topic = active[-1].get('topic')
        if any(a >= since and ev == 'first_frame' and t == topic for a, ev, t in self.display):
            return topic
        return None

    def _wait(self, found, timeout: float, why) -> object:
        """``found()``'s first truthy answer, asked again on every event, within ``timeout``; else
        StageTimeout with ``why()``."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                result = found()
                if result:
                    return result
                left = deadline - time.monotonic()
                if left <= 0:
                    raise StageTimeout(why())
                self._cond.wait(min(left, 1.0))

    def wait_stage(self, index: int, since: float, timeout: float, what: str) -> str:
        return self._wait(lambda: self._stage_topic(index, since), timeout,
                          lambda: 'timed out after %.0f s waiting for %s on screen; action events since: %s'
                          % (timeout, what, self._recent(since)))

    def wait_action(self, match, since: float, timeout: float, what: str, graph: Optional[str] = None) -> dict:
        """The first action event since ``since`` that ``match`` accepts.

        With ``graph``, a FAILED end of that graph (or of any graph, for ``'*'``) started since ``since`` ends
        the wait at once with its reason, rather than letting the stage time out on an event that can no longer
        come. Started since: the engine reuses a finished graph's name, and an earlier graph's end can come
        after ``since`` (the engine sends it before the next graph of that name starts).
        """
        def found():
            started = set()
            for e in self.actions:
                if e['arrival'] < since:
                    continue
                if match(e):
                    return e
                if e.get('event') == 'graph_started':
                    started.add(e.get('graph'))
                elif graph and e.get('event') == 'graph_finished' and e.get('state') == 'FAILED' \
                        and e.get('graph') in started and graph in ('*', e.get('graph')):
                    raise StageFailed('%s failed while waiting for %s: %s'
                                      % (e.get('graph'), what, e.get('reason') or 'no reason given'))
            return None
        return self._wait(found, timeout, lambda: 'timed out after %.0f s waiting for %s; action events since: %s'
                          % (timeout, what, self._recent(since)))

    def wait_first_frame(self, topic: str, since: float, timeout: float) -> None:
        """RViz has drawn a frame of ``topic`` (the Output Manager's ``first_frame``) since ``since``."""
        self._wait(lambda: any(a >= since and ev == 'first_frame' and t == topic for a, ev, t in self.display),
                   timeout, lambda: 'RViz drew no frame of %s within %.0f s' % (topic, timeout))

    def wait_removed(self, since: float, timeout: float) -> None:
        self._wait(lambda: any(a >= since and ev == 'removed' and t for a, ev, t in self.display), timeout,
                   lambda: 'no display was removed within %.0f s of stopping the action' % timeout)

    def _recent(self, since: float) -> str:
        evs = [e for e in self.actions if e['arrival'] >= since and e.get('event') != 'state'] or \
              [e for e in self.actions if e['arrival'] >= since]
        return '; '.join(' '.join(str(part) for part in (e.get('event'), e.get('message') or e.get('label')
                                                          or e.get('state'), e.get('reason')) if part)
                         for e in evs[-6:]) or 'none'


class Demo:
    def __init__(self, opts: DemoOptions) -> None:
        self.opts = opts
        self.progress = Progress()
        self.master = None
        self.stacks: list = []             # one Stack per host, in start order
        self.hosts = None                  # --hosts 2: temoto_core.hosts.TwoHosts
        self._leave_operator_host = None
        self.recording = None
        self.rospy_up = False
        self.bag_path = os.path.join(opts.out_dir, 'failover.bag')
        self.omi = None
        self.screenshots: List[str] = []
        self.token = os.environ.get('TEMOTO_TEST_SESSION') or 'demo_' + uuid.uuid4().hex
        self.results: dict = {'stages': [], 'errors': [], 'kills': []}
        self.unplugged_while_down: Dict[str, float] = {}     # device -> when (--kill-managers)

    # ------------------------------------------------------------------ setup
    @property
    def _robot_ns(self) -> str:
        """The ROS namespace the robot's simulation runs in: its own on two hosts (robot.launch), else the root."""
        return self.opts.robot if self.opts.hosts == 2 else ''

    def _env(self, host=None) -> Dict[str, str]:
        env = dict(self.master.env) if host is None else self.hosts.env(host, self.master.uri, base=self.master.env)
        if not self.opts.live:
            env.pop('DISPLAY', None)      # the RViz host then runs its own Xvfb
        env['TEMOTO_TEST_SESSION'] = self.token
        return env

    def _priority_override(self, default: list) -> list:
        """The entries of ``--priority``; on two hosts, then the station's own sensor (the lab's fixed scanner)."""
        robot = [default[PRIORITY_ENTRIES[name][0]] for name in self.opts.priority]
        return robot + ([default[STATION_ENTRY]] if self.opts.hosts == 2 else [])

    def _overrides(self, params: dict) -> dict:
        """The engine's parameters this run sets: the view's priority list and its standby policy."""
        return {PRIORITY_PARAM: self._priority_override(params[PRIORITY_PARAM]), STANDBY_PARAM: self.opts.standby}

    def start(self) -> None:
        os.makedirs(self.opts.out_dir, exist_ok=True)
        os.environ['TEMOTO_TEST_SESSION'] = self.token     # RosMaster's env (and so every child) carries it
        workdir = os.path.join(self.opts.out_dir, 'ros')
        os.makedirs(workdir, exist_ok=True)
        launch_args = list(self.opts.launch_args) + (['recovery:=true'] if self.opts.kill_managers else [])
        if self.opts.voice:
            said = os.path.join(self.opts.out_dir, 'speech')
            os.makedirs(said, exist_ok=True)
            launch_args += ['speech:=true', 'speak:=%s' % str(self.opts.live).lower(), 'speech_wav_dir:=' + said]
        if self.opts.hosts == 2:
            self._start_two_hosts(workdir, launch_args)
        else:
            self.master = RosMaster(workdir, session_token=self.token).start()
            self.progress.line('roscore on 127.0.0.1:%d' % self.master.port)
            env = self._env()
            launch = os.path.join(LAUNCH_DIR, 'demo.launch')
            _, params = load_launch(launch, launch_args)
            overrides = self._overrides(params)
            self.stacks = [self._stack(launch, env, 'logs', launch_args, overrides)]
        for stack in self.stacks:
            stack.start(STARTUP_TIMEOUT)
        env = self.stacks[-1].env
        self._init_rospy(env)
        self._wait_services(env)
        self.progress.line('simulation, managers and action engine up (%d nodes)'
                           % sum(len(stack.running) for stack in self.stacks))
        self.recording = Recording(self.bag_path, env, self.opts.namespace, os.path.join(self.opts.out_dir, 'logs'),
                                   robot=self._robot_ns, extra=self.recorded_extra())
        self.recording.start()
        self._wait_connected(env)
        self.progress.line('recording %s' % _rel(self.bag_path))

    def recorded_extra(self) -> List[str]:
        """Topics this scenario records besides the failover set (none: the paper's demo)."""
        return []

    def _stack(self, launch: str, env: Dict[str, str], logs: str, launch_args: List[str],
               overrides: Optional[dict] = None, wrap=None):
        return Stack(launch, env, os.path.join(self.opts.out_dir, logs), launch_args, overrides, wrap)

    def _start_two_hosts(self, workdir: str, launch_args: List[str]) -> None:
        """The robot host (master, simulation, the robot's ER and Sensor Managers) and the operator host
        (action engine, Output Manager with RViz, its own ER Manager); this process joins the operator's."""
        self.hosts = TwoHosts('d' + self.token[-6:].replace('_', 'x'))
        self.results['hosts'] = self.hosts.names()       # what must be gone at the end (the report, a test)
        self.hosts.up()
        robot, operator = self.hosts.robot, self.hosts.operator
        self.master = self.hosts.master(workdir, self.token).start()
        self._leave_operator_host = self.hosts.enter(operator)
        self.progress.line('two hosts: robot %s (roscore, simulation, drivers), operator %s (engine, RViz)'
                           % (robot.address, operator.address))
        args = ['robot:=' + self.opts.robot, 'station_sensors:=true',
                'station_catalogue:=' + self._station_catalogue(workdir)] + launch_args
        robot_launch = os.path.join(LAUNCH_DIR, 'robot.launch')
        operator_launch = os.path.join(LAUNCH_DIR, 'operator.launch')
        _, params = load_launch(operator_launch, _declared_args(operator_launch, args))
        overrides = self._overrides(params)
        self.stacks = [
            self._stack(robot_launch, self._env(robot), os.path.join('logs', 'robot'),
                        _declared_args(robot_launch, args), wrap=lambda argv: self.hosts.argv(robot, argv)),
            self._stack(operator_launch, self._env(operator), os.path.join('logs', 'operator'),
                        _declared_args(operator_launch, args), overrides,
                        wrap=lambda argv: self.hosts.argv(operator, argv))]

    def _station_catalogue(self, workdir: str) -> str:
        return write_station_catalogue(self.opts.robot, workdir)

    def _init_rospy(self, env: Dict[str, str]) -> None:
        for key in ('ROS_MASTER_URI', 'ROS_HOSTNAME', 'ROS_IP', 'ROS_LOG_DIR', 'ROS_HOME'):
            if key in env:
                os.environ[key] = env[key]
            else:                          # two hosts: ROS_IP, and no ROS_HOSTNAME (it would win)
                os.environ.pop(key, None)
        rospy_internals.install_shutdown_guard()     # another master's bump of a dead node on this port
        rospy.init_node('temoto_demo', disable_signals=True)
        prime_log_parameter()      # its logging must not wait for the master (node.py)
        self.rospy_up = True
        ns = self.opts.namespace
        self.watcher = EventWatcher(ns)
        self.chatter = rospy.Publisher(T.chatter(ns), String, queue_size=5)
        self.shot_pub = rospy.Publisher(T.SCREENSHOTS, CompressedImage, queue_size=5)
        self.stage_pub = rospy.Publisher(T.STAGES, String, queue_size=20)
        if self.opts.voice:
            self.audio_pub = rospy.Publisher(T.speech_audio(ns), AudioData, queue_size=1000)
            self.heard: List[dict] = []
            self.speech_actions: List[str] = []
            base = '/%s/speech/' % ns.strip('/')
            rospy.Subscriber(base + 'heard', String, lambda m: self.heard.append(json.loads(m.data)))
            rospy.Subscriber(base + 'grammar', String,
                             lambda m: self.speech_actions.extend(json.loads(m.data)['actions']))

    def _wait_services(self, env: Dict[str, str]) -> None:
        master = rosgraph.Master('/temoto_demo')
        wanted = T.manager_services(self.opts.namespace, self._robot_ns)

        def ready():
            dead = [name for stack in self.stacks for name in stack.dead()]
            if dead:
                raise RuntimeError('node(s) died during startup: %s (logs in %s)'
                                   % (', '.join(dead), os.path.join(self.opts.out_dir, 'logs')))
            services = {s for s, _ in master.getSystemState()[2]}
            return all(s in services for s in wanted)

        wait_for(ready, STARTUP_TIMEOUT, 'the services %s' % ', '.join(wanted))

    def _wait_connected(self, env: Dict[str, str]) -> None:
        """The engine and the recorder hear the chatter; the recorder hears the screenshots and stages."""
        uri = env['ROS_MASTER_URI']
        pairs = [('/temoto_action_engine', T.chatter(self.opts.namespace)), (RECORDER_NODE, T.chatter(self.opts.namespace)),
                 (RECORDER_NODE, T.SCREENSHOTS), (RECORDER_NODE, T.STAGES)]
        if self.opts.voice:
            pairs += [('/temoto_speech', T.speech_audio(self.opts.namespace)),
                      (RECORDER_NODE, T.speech_audio(self.opts.namespace))]
        wait_for(lambda: all(connected(uri, '/temoto_demo', sub, topic) for sub, topic in pairs), 15.0,
                 'the action engine and the recorder to connect to the demo\'s publishers')
        if self.opts.voice:
            wait_for(lambda: 'show_environment' in self.speech_actions and
                     connected(uri, '/temoto_speech', '/temoto_action_engine', T.chatter(self.opts.namespace)), 30.0,
                     'the speech node to take the actions into its grammar and connect to the action engine')

    # ------------------------------------------------------------------ stages
    def _mark(self, stage: str, **fields) -> None:
        self.stage_pub.publish(String(data=json.dumps(dict(fields, stage=stage, stamp=rospy.get_time()))))

    # The operator's view for the report: from behind and above the robot, looking ahead, where the
    # sensors look (the host's default frames the robot alone).
    OPERATOR_VIEW = 'Distance: 7.5\nYaw: 3.14159\nPitch: 0.6\nFocal Point: [2.2, 0.0, 0.4]\n'

    def _screenshot(self, name: str, settle_frames: int = 0) -> str:
        """The view as RViz draws it now; after ``settle_frames`` more frames when a display was just added
        (its first message reaches the display before RViz's update loop has drawn it)."""
        host = RvizHostClient(host_node_name(self.opts.namespace), timeout=10.0)
        if settle_frames:
            first = host.screenshot('view').frame_count
            wait_for(lambda: host.screenshot('view').frame_count >= first + settle_frames, self.opts.stage_timeout,
                     'RViz to draw %d frames' % settle_frames)
        resp = host.screenshot('view')
        # Numbered in the order taken, as the report numbers them when it extracts them from the bag.
        path = os.path.join(self.opts.out_dir, 'screenshot_%d_%s.png' % (len(self.screenshots) + 1, name))
        with open(path, 'wb') as f:
            f.write(bytes(resp.png))
        msg = CompressedImage(format='png', data=bytes(resp.png))
        msg.header.stamp = rospy.Time.now()
        msg.header.frame_id = name
        self.shot_pub.publish(msg)
        self.screenshots.append(path)
        return path

    def set_device(self, device: str, plugged: bool, mode: str = '') -> None:
        """Plug ``device``'s cable in or pull it (``mode``: crash or stall) in the simulation."""
        state = 'plugged' if plugged else 'unplugged'
        resp = rospy.ServiceProxy(T.set_device_state(self._robot_ns), SetDeviceState)(
            device=device, state=state, mode='' if plugged else mode)
        if not resp.success:
            raise RuntimeError('the simulation refused to set %s %s: %s' % (device, state, resp.message))

    def show_first_view(self) -> str:
        """Say the instruction and wait for the first priority entry on screen; its topic."""
        labels = [e['label'] for e in self._priority_override_labels()]
        since = time.monotonic()
        self._mark('say', text=INSTRUCTION, voice=self.opts.voice)
        if self.opts.voice:
            self._speak(INSTRUCTION)
        else:
            self.chatter.publish(String(data=INSTRUCTION))
        return self.watcher.wait_stage(0, since, self.opts.stage_timeout, labels[0])

    def _speak(self, text: str) -> None:
        """``text`` spoken by espeak-ng to the speech node; returns once it understood it, else raises."""
        pcm = synthesize_pcm(text)
        for i in range(0, len(pcm), 3200):                  # 0.1 s of audio a message, as a microphone sends
            self.audio_pub.publish(AudioData(data=pcm[i:i + 3200]))
        self.audio_pub.publish(AudioData(data=b''))          # the end of the utterance
        heard = wait_for(lambda: self.heard, 20.0, 'the speech node to report what it heard')[0]
        if not heard['accepted']:
            raise RuntimeError('the speech node did not understand "%s" (heard "%s": %s)'
                               % (text, heard['text'], heard['reason']))
        self.progress.line('heard "%s" (margin %.1f)' % (heard['text'], heard['margin']))

    def scenario(self) -> None:
        timeout = self.opts.stage_timeout
        labels = [e['label'] for e in self._priority_override_labels()]
        since = time.monotonic()
        on_screen = since
        for k, name in enumerate(self.opts.priority):
            if k > 0:
                self._hold_view(on_screen)
                prev = self.opts.priority[k - 1]
                device = PRIORITY_ENTRIES[prev][1]
                mode = self.opts.modes.get(device, 'crash')
                if device in self.unplugged_while_down:          # done during the kills
                    since = self.unplugged_while_down[device]
                    what = '%s on screen after unplugging %s (%s) while the Sensor Manager was down' % (
                        labels[k], device, mode)
                else:
                    self.wait_standby(k, timeout)
                    since = time.monotonic()
                    self._mark('unplug', device=device, mode=mode)
                    self.set_device(device, False, mode)
                    what = '%s on screen after unplugging %s (%s)' % (labels[k], device, mode)
            if k == 0:
                topic = self.show_first_view()
                what = '%s on screen after "%s"' % (labels[k], INSTRUCTION)
            else:
                topic = self.watcher.wait_stage(k, since, timeout, labels[k])
            self._mark('on_screen', priority_index=k, entry=name, topic=topic)
            on_screen = time.monotonic()
            self.results['stages'].append({'entry': name, 'topic': topic, 'seconds': time.monotonic() - since})
            self.progress.line(what)
            if k == 0:
                self._set_operator_view()
            if name == 'arm_cloud':
                self._wait_full_sweep(topic)
            self._screenshot(name)
            if k == 0:
                self._hold_host()
            if k == 0 and self.opts.kill_managers:
                self._kill_managers()
            if k == 0 and self.opts.unplug_all:
                self._unplug_all(timeout)
                break
        self._hold_view(on_screen)
        if self.opts.replug:
            self._replug(labels[0], timeout)
        if self.hosts is not None:
            last = len(self.opts.priority) - 1
            self._partition(last, labels[last], labels[last + 1] if last + 1 < len(labels) else '')
        self._empty_view()

    @staticmethod
    def _hold_view(on_screen: float) -> None:
        """Pacing, not a wait for anything: the view that came on screen at ``on_screen`` stays there for
        MIN_VIEW_S in all."""
        left = MIN_VIEW_S - (time.monotonic() - on_screen)
        if left > 0:
            time.sleep(left)

    def _unplug_all(self, timeout: float) -> None:
        """Every device of the view unplugged one right after another (its mode from the options), then the
        action's all_failed event, timed from the last unplug."""
        devices = [PRIORITY_ENTRIES[name][1] for name in self.opts.priority]
        for device in devices:
            mode = self.opts.modes.get(device, 'crash')
            self._mark('unplug', device=device, mode=mode)
            self.set_device(device, False, mode)
        last = time.monotonic()
        self.watcher.wait_action(lambda e: e.get('event') == 'all_failed', last, timeout,
                                 'the action to say every sensor failed')
        took = time.monotonic() - last
        self.results['all_failed_s'] = took
        self._mark('all_failed', seconds=took)
        self.progress.line('every sensor failed, said %.2f s after the last unplug (%s)' % (took, ', '.join(devices)))

    # ------------------------------------------------------------------ --hosts 2
    def _partition(self, index: int, label: str, station_label: str) -> None:
        """Cut the cable between the hosts while the robot's last view is up: the action must hear FAILED within
        the owner liveness bound. The station's own scanner (``station_label``) comes next in its list: under
        hot standby it already streams into a hidden display, and it is shown within the failover; under the
        other policies it cannot start while the robot's master is across the cut, and the frozen view goes
        off screen. Plug the cable back: the robot's view must come back (a fail-back, or a retry), and the
        cut sensor was released, not kept."""
        hot_station = bool(station_label) and self.opts.standby == 'hot'
        if hot_station:
            self.wait_standby(index + 1, self.opts.stage_timeout)
        since = time.monotonic()
        self._mark('link_down')
        self.hosts.link(False)
        failed = self.watcher.wait_action(lambda e: e.get('event') == 'sensor_failed', since, self.opts.stage_timeout,
                                          'the FAILED of the %s after the link was cut' % label)
        heard = failed['arrival'] - since
        result = {'failed_heard_s': heard, 'message': failed.get('message', '')}
        if hot_station:
            self.watcher.wait_stage(index + 1, since, self.opts.stage_timeout, station_label)
            result['station_view_s'] = time.monotonic() - since
            self._mark('on_screen', priority_index=index + 1, entry='station')
            self.progress.line('link cut: FAILED heard in %.2f s; the %s (station) on screen'
                               % (heard, station_label))
        else:
            self.watcher.wait_removed(since, self.opts.stage_timeout)
            self.progress.line('link cut: the action heard FAILED in %.2f s, view taken off screen' % heard)
        healed = time.monotonic()
        self._mark('link_up')
        self.hosts.link(True)
        self.watcher.wait_stage(index, healed, self.opts.stage_timeout, label)
        result['view_back_s'] = time.monotonic() - healed
        self._mark('link_restored', priority_index=index)
        self.results['partition'] = result
        self.progress.line('link plugged back: %s on screen again' % label)

    # ------------------------------------------------------------------ --kill-managers
    def _kill_managers(self) -> None:
        rng = random.Random(self.opts.seed)
        order = [name for name in KILLABLE if any(spec.name == name for spec, _ in self.stacks[0].running)]
        rng.shuffle(order)
        since = time.monotonic()
        for name in order:
            time.sleep(rng.uniform(0.2, 1.0))       # a seeded moment of the run, not a wait for anything
            victim = self._node_pid(name)           # the manager's own process (a warm-respawn parent's child)
            self._mark('kill', node=name, pid=victim)
            killed = time.monotonic()
            os.kill(victim, signal.SIGKILL)
            device = self._unplug_while_down() if name == SENSOR_MANAGER else None
            self._wait_recovered(name, victim)
            seconds = time.monotonic() - killed
            self._mark('recovered', node=name, seconds=seconds, pid=self._node_pid(name))
            self.results['kills'].append({'node': name, 'recovered_s': seconds})
            self.progress.line('SIGKILLed %s: respawned and recovered in %.2f s' % (name, seconds))
            if device is not None:
                # the next kill only once the view is steady again: on the second entry
                label = self._priority_override_labels()[1]['label']
                self.watcher.wait_stage(1, self.unplugged_while_down[device], self.opts.stage_timeout, label)
        failed = [e for e in self.watcher.actions if e['arrival'] >= since and
                  e.get('event') in ('sensor_failed', 'graph_finished')]
        # the one failover allowed: of the device unplugged while the Sensor Manager was down
        if len(failed) > len(self.unplugged_while_down) or any(e.get('event') == 'graph_finished' for e in failed):
            raise RuntimeError('the view did not survive the manager kills: %s' % '; '.join(
                '%s %s' % (e.get('event'), e.get('message') or e.get('reason') or '') for e in failed))

    def _unplug_while_down(self) -> Optional[str]:
        """Unplug the device of the first view now, while the Sensor Manager is down; its name."""
        if len(self.opts.priority) < 2:
            return None
        device = PRIORITY_ENTRIES[self.opts.priority[0]][1]
        mode = self.opts.modes.get(device, 'crash')
        self._mark('unplug', device=device, mode=mode, while_down=SENSOR_MANAGER)
        self.unplugged_while_down[device] = time.monotonic()
        self.set_device(device, False, mode)
        self.progress.line('unplugged %s (%s) while %s is down' % (device, mode, SENSOR_MANAGER))
        return device

    def _node_pid(self, name: str) -> Optional[int]:
        """The pid of the process registered as ``name`` (None while nobody answers there)."""
        uri = master_lookup.lookup_node(self.master.uri, name)
        return master_lookup.node_pid(uri) if uri else None

    def _wait_recovered(self, name: str, old_pid: int) -> None:
        """The node was respawned, and every registrar of it answers with its registry recovered."""

        def back() -> bool:
            if self._node_pid(name) in (None, old_pid):
                return False
            for rr in KILLABLE[name]:
                try:
                    snapshot = json.loads(rospy.ServiceProxy('/%s/%s/registry' % (self.opts.namespace, rr),
                                                             GetRegistry)().json)
                except (rospy.ServiceException, rospy.ROSException, OSError, ValueError):
                    return False        # its services are not up yet (or still point at the dead process)
                if snapshot.get('recovering', True) or snapshot.get('node') != name:
                    return False
            return True
        wait_for(back, RECOVERY_TIMEOUT, '%s to come back with its registry' % name)

    def _set_operator_view(self) -> None:
        """Turn the view, then wait (bounded) until RViz has drawn two frames with it."""
        try:
            host = RvizHostClient(host_node_name(self.opts.namespace), timeout=10.0)
            host.set_view(self.OPERATOR_VIEW)
            first = host.screenshot('view').frame_count
            deadline = time.monotonic() + 2.0
            while host.screenshot('view').frame_count < first + 2 and time.monotonic() < deadline:
                time.sleep(0.02)
        except Exception as e:   # the run goes on with the default view; the report says so
            self.results['errors'].append('could not set the operator view: %s' % e)

    def _wait_full_sweep(self, topic: str, limit: float = 4.0) -> None:
        """The rolling stitched cloud is on screen from its first few scans; the screenshot shows
        it once it holds a whole sweep, i.e. once its point count stops growing (bounded)."""
        sizes, grown = [], threading.Event()

        def on_cloud(msg):
            sizes.append(msg.width * msg.height)
            if len(sizes) >= 4 and sizes[-1] <= max(sizes[:-3]):
                grown.set()
        sub = rospy.Subscriber(topic, PointCloud2, on_cloud, queue_size=1, buff_size=2 ** 24)
        try:
            grown.wait(limit)
        finally:
            sub.unregister()

    def _replug(self, label: str, timeout: float) -> None:
        """Plug the first device back: the action tries it again (its wait doubles up to failback_max_s), holds it
        hidden for failback_hold_s, and shows it again by a visibility change."""
        name = self.opts.priority[0]
        device = PRIORITY_ENTRIES[name][1]
        since = time.monotonic()
        self._mark('replug', device=device)
        self.set_device(device, True)
        self.watcher.wait_action(lambda e: e.get('event') == 'failback' and e.get('priority_index') == 0, since,
                                 timeout, 'the fail-back to the %s' % label)
        topic = self.watcher.wait_stage(0, since, timeout, label)
        self._mark('on_screen', priority_index=0, entry=name, topic=topic)
        self.results['stages'].append({'entry': name, 'topic': topic, 'seconds': time.monotonic() - since})
        self.progress.line('%s on screen again after plugging %s back (fail-back)' % (label, device))

    def wait_standby(self, index: int, timeout: float) -> None:
        """Under warm and hot, unplug only once the spare for entry ``index`` runs (and, hot, its hidden display
        holds data): a failure that comes before the spare is ready is a cold failover, whatever the policy."""
        if self.opts.standby == 'cold':
            return
        ready = self.watcher.wait_action(lambda e: e.get('event') == 'standby_ready' and
                                         e.get('priority_index') == index, 0.0, timeout,
                                         'the %s standby of entry %d' % (self.opts.standby, index))
        if self.opts.standby == 'hot':
            host = RvizHostClient(host_node_name(self.opts.namespace))

            def holds_data() -> bool:
                shown = [d for d in host.list_displays().displays if d.topic == ready.get('topic')]
                return any(received_count(part.split(': ', 1)[-1]) for d in shown for part in d.status.split('; '))
            wait_for(holds_data, timeout, 'the hidden display of %s to hold data' % ready.get('label'))
        self.progress.line('%s standby ready: %s' % (self.opts.standby, ready.get('label')))

    def _hold_host(self) -> None:
        """Keep the RViz host up after the action ends, for the empty-view baseline.

        The Output Manager stops its host with the last display; a marker display on a topic nobody
        publishes draws nothing and keeps it. Requested only once the action's first view is on
        screen, so the host's cold start still counts in the first stage.
        """
        try:
            self.omi = OutputManagerInterface(namespace=self.opts.namespace)
            self.omi.show_in_rviz('marker', T.DEMO_NS + '/no_markers', name='demo baseline (draws nothing)')
        except Exception as e:
            self.omi = None
            self.results['errors'].append('could not hold the RViz host for the empty view: %s' % e)

    def _empty_view(self) -> None:
        """Stop the action (it hides its display) and keep a screenshot of RViz with nothing shown.

        That picture is the baseline a screenshot with sensor data must differ from.
        """
        graphs = [e.get('graph') for e in self.watcher.actions if e.get('event') == 'sensor_active']
        if not graphs:
            return
        since = time.monotonic()
        resp = rospy.ServiceProxy('/%s/action_engine/stop_graph' % self.opts.namespace.strip('/'),
                                  StopGraph)(graph_name=graphs[-1])
        if resp.code != 0:
            raise RuntimeError('stopping graph %s: %s' % (graphs[-1], resp.message))
        if self.opts.unplug_all:       # every display went with its sensor: the screen is empty already
            self._screenshot('empty_view')
            self.progress.line('action stopped, view empty')
            return
        try:
            self.watcher.wait_removed(since, 10.0)
            self._screenshot('empty_view')
        except (StageTimeout, Exception) as e:   # the host may stop with its last display: no baseline then
            self.results['errors'].append('no empty-view screenshot: %s' % e)
        self.progress.line('action stopped, view empty')

    def _priority_override_labels(self) -> list:
        return rospy.get_param(PRIORITY_PARAM)

    # ------------------------------------------------------------------ teardown
    def stop(self) -> List[tuple]:
        if self.hosts is not None:
            self.hosts.link(True)     # a stage that failed during a cut: the nodes stop over a working link
        if self.recording is not None:
            try:
                self.recording.stop()
            except RuntimeError as e:
                self.results['errors'].append(str(e))
            self.recording = None
        if self.omi is not None:
            try:
                self.omi.shutdown()          # releases the baseline display (and with it the RViz host)
            except Exception as e:
                self.results['errors'].append('releasing the baseline display: %s' % e)
            self.omi = None
        if self.rospy_up:
            rospy.signal_shutdown('demo over')
        stops = []
        for stack in reversed(self.stacks):     # the operator's first: its actions release what they hold
            stops += stack.stop()
        bad = [(n, rc) for n, rc in stops if rc is None]
        if self.master is not None:
            self.master.stop()
        if self.hosts is not None:
            if self._leave_operator_host is not None:
                self._leave_operator_host()      # before down(), which kills every process on the hosts
                self._leave_operator_host = None
            self.hosts.down()
            if self.hosts.exist():
                self.results['errors'].append('network namespaces left behind: %s' % self.hosts.exist())
        leftovers = leftover_processes(self.token)
        if leftovers:
            kill_leftovers(self.token)
            self.results['errors'].append('processes left behind (killed now): %s' % leftovers)
        self.progress.line('stopped %d nodes, roscore and the recorder%s; %s'
                           % (len(stops), ', removed both hosts' if self.hosts is not None else '',
                              'no process left' if not leftovers else '%d LEFT BEHIND' % len(leftovers)),
                           ok=not leftovers and not bad)
        return leftovers


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run_stages(demo: Demo, name: str, report: Callable[[Demo], None]) -> int:
    """Start ``demo``, run its scenario, stop everything, make its report (``report(demo)``, from the bag) and
    write ``demo.json``; the exit code. ``name`` begins every line it prints (``temoto demo teleop``)."""
    opts = demo.opts
    rc = 0
    # a SIGTERM (a CI job's timeout, kill) stops the run as Ctrl-C does: every process and namespace goes
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        demo.start()
        demo.scenario()
    except StageTimeout as e:
        print('%s: FAILED: %s' % (name, e), file=sys.stderr, flush=True)
        demo.results['errors'].append(str(e))
        rc = 1
    except KeyboardInterrupt:
        print('%s: interrupted' % name, file=sys.stderr, flush=True)
        rc = 130
    except Exception as e:
        print('%s: FAILED: %s: %s' % (name, type(e).__name__, e), file=sys.stderr, flush=True)
        demo.results['errors'].append('%s: %s' % (type(e).__name__, e))
        rc = 1
    finally:
        if demo.stop():
            rc = rc or 1
        signal.signal(signal.SIGTERM, previous)
    if opts.report and os.path.exists(demo.bag_path):
        try:
            report(demo)
        except Exception as e:
            print('%s: report failed: %s: %s' % (name, type(e).__name__, e), file=sys.stderr)
            rc = rc or 1
    demo.results.update(rc=rc, total_s=time.monotonic() - demo.progress.t0, progress=demo.progress.lines,
                        screenshots=demo.screenshots, bag=demo.bag_path)
    with open(os.path.join(opts.out_dir, 'demo.json'), 'w') as f:
        json.dump(demo.results, f, indent=2, default=str)
    for error in demo.results['errors']:       # what went wrong on the way is said, not only kept in demo.json
        print('%s: problem: %s' % (name, error), file=sys.stderr, flush=True)
    print('%s: %s in %.1f s' % (name, 'done' if rc == 0 else 'FAILED', demo.results['total_s']), flush=True)
    return rc


def announce(title: str, opts: DemoOptions) -> None:
    """A demo's first line: what it shows, where its files go, and where RViz draws."""
    print('%s; run folder %s (%s)' % (title, _rel(opts.out_dir),
                                      'RViz on ' + os.environ['DISPLAY'] if opts.live else 'headless'), flush=True)


def run_demo(opts: DemoOptions) -> int:
    demo = Demo(opts)
    announce('temoto demo: the paper\'s sensor failover', opts)

    def report(demo: Demo) -> None:
        rep = write_report(demo.bag_path, opts.out_dir, opts.namespace)
        demo.results['failures'] = [f.as_dict() for f in rep.analysis.failures]
        demo.progress.line('report %s' % _rel(rep.path))
        for f in rep.analysis.failures:
            gap = '-' if f.display_gap is None else '%.3f s' % f.display_gap
            det = '-' if f.detection is None else '%.3f s' % f.detection
            print('          %s (%s): FAILED detected in %s, display gap %s' % (f.device, f.mode, det, gap))
    return run_stages(demo, 'temoto demo', report)
