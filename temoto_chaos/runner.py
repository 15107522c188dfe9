"""``temoto chaos``: run a seeded history against the robot's real managers and check it as it goes.

The robot's stack is ``robot.launch`` with journals and respawn (``recovery:=true``): the simulated
VaultBot, its ER Manager, its Sensor Manager and (history 3 and later) its Context Manager, under their own
roscore. From history 3 the operator's station runs a stack too (``launch/station.launch``: an ER Manager
and the Output Manager with its RViz host). Each client is a process of its own (``chaos_client``) with its
own registrar. A step is a client operation (a sensor, a process, a tracked object or a display loaded, or
something held unloaded; equal requests are shared) or a fault (a driver, a consumer process, a client or
a manager SIGKILLed; a manager SIGSTOPped for a while; a cable pulled, crash or stall, or plugged back;
with two hosts, the link between them cut for a while; every process of the robot killed, then booted
again). After each step the checker reads the system from outside and the step passes once no invariant
is violated, within ``settle_s``.

From history 4 the clients work concurrently, as Jepsen's do: each has a worker here that makes its calls
in the history's order, and the runner goes on to the next step (and the checks) as soon as a call is
queued. The checker then sees a system at work, and defers what a call under way leaves in flux
(checker.py). A fault that lasts (a cut link, a stopped manager, a killed one until it is back) goes on
meanwhile in a thread of its own while the clients' next steps are queued (lasting.py); ``--serial`` runs one
step at a time.

From history 5 the clients hold motion too (drives, servo streams, gripper goals), and the nemesis hits what
moves. A watch on the robot's host turns the simulation's ground truth into spans of motion, and the motion
ledger holds them against the clients' journals and the faults (motion_checker.py).
"""
from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import json
import os
import signal
import sys
import threading
import time
from typing import Callable, Deque, Dict, List, Optional, Tuple, Union

import psutil
import rospy
from std_msgs.msg import String

from temoto_demo.stack import Stack
from temoto_core import control_socket, rospy_internals
from temoto_core.halt import HALT_TYPE, halt_topic
from temoto_core.hosts import TwoHosts
from temoto_core.latched import NoPublisher, latched_message
from temoto_core.master import RosMaster
from temoto_core.master_lookup import lookup_node, node_pid
from temoto_core import master_rejoin, process_group
from temoto_core.processes import ProcessGroupLauncher, dump_stacks, kill_leftovers, leftover_processes
from temoto_core.wait import wait_for
from vaultbot_sim.srv import SetDeviceState

from . import checker
from .history import CLIENTS, CONCURRENT_FROM, MOTION_FROM, VERSION, Step, history
from .lasting import LastingFault
from . import motion_checker
from .motion_checker import MotionLedger
from .motion_truth import BASE, GRIPPER, LEFT_ARM, RIGHT_ARM

ROBOT = 'chaos'                # the robot's TeMoto (and ROS) namespace
STATION = 'chaos_station'      # the station's, from history 3
HERE = os.path.dirname(os.path.abspath(__file__))
ER_CONFIG = os.path.join(HERE, 'config', 'er_chaos.yaml')
LAUNCH_ARGS = ['robot:=' + ROBOT, 'recovery:=true', 'er_config:=' + ER_CONFIG]
STATION_LAUNCH = os.path.join(HERE, 'launch', 'station.launch')
STATION_ARGS = ['temoto_namespace:=' + STATION, 'robot:=' + ROBOT]
# history 5: the hand sources too, on the robot's Sensor Manager (the simulated tracker has a cable of the sim's)
HANDS_CATALOGUE = os.path.join(os.path.dirname(HERE), 'temoto_sensor_manager', 'config', 'hands.yaml')
CLIENT_STEPS = ('load_sensor', 'load_process', 'track_object', 'show_display', 'unload', 'navigate', 'servo', 'grip',
                'arm_goal', 'cancel_motion')
MOTION_WATCH_START_S = 20.0
# which part each controller moves, and the devices the obstacle sources come from (the navigator's topic)
CONTROLLED = {'base_controller': BASE, 'left_arm_controller': LEFT_ARM, 'right_arm_controller': RIGHT_ARM,
              'gripper_controller': GRIPPER}
SOURCE_DEVICES = (('sick/', 'sick'), ('laser_stitcher/', 'hokuyo'), ('hokuyo/', 'hokuyo'), ('d435/', 'd435'))
OBSTACLE_SOURCE_TOPIC = '/%s/temoto_robot_manager/vaultbot/obstacle_source' % ROBOT
STATION_KINDS = ('display',)   # what a client holds of the station's, on the clients' side of a cut link
CLIENT_CALL_TIMEOUT = 130.0    # s: a client's answer to the runner (a robot's load has a 90 s deadline of its own)
# calls a client may have queued (concurrent histories): the runner waits for a client only when its queue is
# full, so one slow call (a display's first frame) does not hold up the steps of the others. With 6, a burst of
# slow calls (a tracker's start, 2.8 s on average) held the runner up for 43 % of a 10,000-step run (run AA)
CLIENT_BACKLOG = 12
STACK_START_S = 60.0           # s: the robot's nodes to register (at boot and after a power loss)
CLIENT_START_S = 20.0          # s: one attempt at starting a client (its registration, then its socket)
# s: a client that cannot start (its master out of reach: a cut link, a robot booting) is tried again this
# long before that is a violation
CLIENT_RESTART_S = 60.0
PARTITION_FAILED_BOUND = 3.0   # s after the cut: the owner liveness bound (0.7 s) with a margin for a loaded machine
# s past the settle bound (the longest a killed manager is waited for) before a lasting fault that has not
# ended is reported: a cut link ends within 3 s, a stopped manager within 2 s
LASTING_FAULT_SLACK_S = 10.0
# the faults that go on while a lasting fault does (concurrent histories), and are checked with it at its end:
# those that need nothing it cuts off. On two hosts this runner is on the station, so a cut link leaves it
# without the robot's simulation (the cables), and the cut's own check asks the clients it knew at the cut
# (not a client killed meanwhile). A manager stopped or killed (until it is back) takes none of them away.
_BESIDE_A_MANAGER_DOWN = ('kill_driver', 'kill_consumer', 'kill_client', 'unplug', 'replug', 'unplug_obstacle',
                          'unplug_hand', 'kill_controller', 'halt', 'kill_manipulator')
OVERLAPPING = {
    'partition': ('kill_driver', 'kill_consumer'),
    'stop_manager': _BESIDE_A_MANAGER_DOWN,
    'kill_manager': _BESIDE_A_MANAGER_DOWN,
}


@dataclasses.dataclass
class ChaosOptions:
    seed: int
    steps: int
    out_dir: str
    clients: Optional[int] = None   # default: the history version's (history.CLIENTS)
    settle_s: float = 20.0
    until: Optional[int] = None     # replay only the steps before this one
    hosts: int = 1                  # 2: the robot's stack on one host, the clients on the station (a partition fault)
    version: int = VERSION          # how steps are drawn from the seed (history.py)
    serial: bool = False            # one step at a time even where the version runs its clients concurrently

    def __post_init__(self) -> None:
        if self.clients is None:
            self.clients = CLIENTS[self.version]

    @property
    def concurrent(self) -> bool:
        """History 4 and later: each client does its calls in order, the clients at the same time."""
        return self.version >= CONCURRENT_FROM and not self.serial

    @property
    def motion(self) -> bool:
        """History 5 and later: the clients hold motion, and the ground truth is watched."""
        return self.version >= MOTION_FROM

    @property
    def station(self) -> bool:
        """History 3 and later: trackers on the robot, displays on a station stack of its own."""
        return self.version >= 3


class ClientHandle:
    """One client incarnation: its process and its control socket."""

    def __init__(self, launcher: ProcessGroupLauncher, index: int, generation: int, socket_path: str,
                 station: str = '', journal: str = '') -> None:
        if os.path.exists(socket_path):
            os.unlink(socket_path)      # a killed incarnation's
        self.index = index
        self.socket_path = socket_path
        self.name = '%s%d_%d' % (checker.CLIENT_NODE_PREFIX, index, generation)
        self.journal = journal
        self.proc = launcher.node('temoto_chaos', 'chaos_client', name=self.name, wait=False,
                                  params={'control_socket': socket_path, 'temoto_namespace': ROBOT,
                                          'station_namespace': station, 'motion_journal': journal})
        try:
            launcher.wait_registered(self.proc, ['/' + self.name], CLIENT_START_S)
            deadline = time.monotonic() + CLIENT_START_S
            while not os.path.exists(socket_path):
                if time.monotonic() > deadline or not self.proc.alive():
                    raise RuntimeError('chaos client %d did not open its socket; log:\n%s'
                                       % (index, self.proc.log()))
                time.sleep(0.02)
        except BaseException:
            self.proc.stop()          # a start that failed leaves no second client behind on the same socket
            raise

    def ask(self, **cmd) -> dict:
        return control_socket.ask(self.socket_path, cmd, CLIENT_CALL_TIMEOUT)


class Chaos:
    def __init__(self, opts: ChaosOptions) -> None:
        self.opts = opts
        self.token = 'chaos_' + os.urandom(6).hex()
        self.master: Optional[RosMaster] = None
        self.stack = None
        self.station_stack = None
        self.managers = checker.managers(ROBOT, STATION if opts.station else None, robot_manager=opts.motion)
        self.launch_args = LAUNCH_ARGS + (['context_manager:=true'] if opts.station else []) + \
            (['extra_catalogues:=' + HANDS_CATALOGUE] if opts.motion else [])
        # history 5: the ground truth of motion (the watch, on the robot's host), the clients' journals of
        # their motions (path -> bytes read), and the ledger that holds one against the other
        self.watch = None
        self._rejoin: Optional[master_rejoin.MasterRejoin] = None   # this runner's registrations, after a reboot
        self._watch_launcher: Optional[ProcessGroupLauncher] = None
        self._journals: Dict[str, int] = {}
        self.motion = MotionLedger()
        self.motion_violations: List[str] = []
        self.check_seconds = 0.0                  # the checker's share of the run's time
        self.motion_check_seconds = 0.0
        self.launcher: Optional[ProcessGroupLauncher] = None
        self.clients: Dict[int, ClientHandle] = {}
        self.generations: Dict[int, int] = collections.Counter()
        self.faults: Dict[str, int] = collections.Counter()
        self.checks = 0
        self.log: List[dict] = []
        self.started: Optional[float] = None          # when the first step began
        self.violations: List[str] = []
        self.failed_step: Optional[int] = None
        self.partition_violations: List[str] = []
        self.hosts: Optional[TwoHosts] = None
        self._leave_station = None
        # concurrent histories: a worker per client does its calls in order; the runner goes on to the next
        # step as soon as a call is queued, and waits only for a client with a full queue (CLIENT_BACKLOG)
        self._workers: Dict[int, concurrent.futures.ThreadPoolExecutor] = {}
        self._jobs: Dict[int, Deque[Tuple[concurrent.futures.Future, Optional[dict]]]] = \
            collections.defaultdict(collections.deque)      # each client's jobs not known done: (job, its step's log)
        self.call_violations: List[str] = []      # a client that did not answer a call it was not killed in
        self._print_lock = threading.Lock()
        self.waited_for = ''                      # what the last check waited to see settle, if anything
        self._killed: Dict[str, float] = {}       # a killed client incarnation's node name -> when
        self._lasting: Optional[LastingFault] = None   # a cut link, a stopped or killed manager, going on
        self.reader = checker.RegistryReader()
        # the clients are asked for their state all at once, twice a check (one by one was 0.02 s of it)
        self._asking = concurrent.futures.ThreadPoolExecutor(8, 'chaos-ask')

    # ------------------------------------------------------------------ setup
    def start(self) -> None:
        os.makedirs(os.path.join(self.opts.out_dir, 'ros'), exist_ok=True)
        os.environ['TEMOTO_TEST_SESSION'] = self.token       # every child carries it: the checker's process list
        launch = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'temoto_bringup',
                              'launch', 'robot.launch')
        logs = os.path.join(self.opts.out_dir, 'logs')
        clients_dir = os.path.join(self.opts.out_dir, 'clients')
        os.makedirs(clients_dir, exist_ok=True)
        if self.opts.hosts == 2:
            # the robot's stack and master on the robot host; this process and the clients on the station
            self.hosts = TwoHosts('c' + self.token[-6:]).up()
            robot, station = self.hosts.robot, self.hosts.operator
            self.master = self.hosts.master(os.path.join(self.opts.out_dir, 'ros'), self.token).start()
            env = self.hosts.env(robot, self.master.uri, base=dict(self.master.env, TEMOTO_TEST_SESSION=self.token))
            env.pop('DISPLAY', None)
            self._leave_station = self.hosts.enter(station)     # this process talks ROS from the station
            self._new_stack = lambda: Stack(launch, env, logs, self.launch_args,
                                            wrap=lambda argv: self.hosts.argv(robot, argv))
            self.stack = self._new_stack()
            self.stack.start(STACK_START_S)
            if self.opts.station:
                self.station_stack = Stack(STATION_LAUNCH, self.hosts.env(station, self.master.uri, base=env), logs,
                                           STATION_ARGS, wrap=lambda argv: self.hosts.argv(station, argv))
                self.station_stack.start(STACK_START_S)
            for key, value in self.hosts.env(station, self.master.uri).items():
                if key.startswith('ROS_'):
                    os.environ[key] = value
            os.environ.pop('ROS_HOSTNAME', None)
            self.launcher = self.hosts.launcher(station, self.master, clients_dir)
        else:
            self.master = RosMaster(os.path.join(self.opts.out_dir, 'ros'), session_token=self.token).start()
            self.master.point_this_process()
            env = dict(self.master.env, TEMOTO_TEST_SESSION=self.token)
            env.pop('DISPLAY', None)
            self._new_stack = lambda: Stack(launch, env, logs, self.launch_args)
            self.stack = self._new_stack()
            self.stack.start(STACK_START_S)
            if self.opts.station:
                self.station_stack = Stack(STATION_LAUNCH, env, logs, STATION_ARGS)
                self.station_stack.start(STACK_START_S)
            self.launcher = ProcessGroupLauncher(env, clients_dir)
        if self.opts.motion:
            watch_dir = os.path.join(self.opts.out_dir, 'watch')
            os.makedirs(watch_dir, exist_ok=True)
            self._watch_launcher = self.hosts.launcher(self.hosts.robot, self.master, watch_dir) \
                if self.hosts is not None else ProcessGroupLauncher(env, watch_dir)
            self._start_watch()
        rospy_internals.install_shutdown_guard()     # another master's bump of a dead node on this port
        rospy.init_node('temoto_chaos', disable_signals=True)
        # the operator's "stop" (history 6), as the action engine publishes it: made now, so that the motion nodes
        # are connected to it by the time a halt is drawn
        self._halt_pub = rospy.Publisher(halt_topic(ROBOT), HALT_TYPE, queue_size=5, tcp_nodelay=True)
        # the robot's power loss takes its master (two hosts): a new one knows nothing of this node, and a halt
        # would reach nobody (history 6, seed 17: every halt after step 213's power loss). Register again
        self._rejoin = master_rejoin.MasterRejoin().start()
        self._wait_managers()
        for i in range(self.opts.clients):
            self._start_client(i)

    def _start_watch(self) -> None:
        """The ground truth's watch, on the robot's host, outside the robot's stack: a power loss spares it."""
        path = os.path.join(self.opts.out_dir, 'motion_watch.sock')
        if os.path.exists(path):
            os.unlink(path)
        self.watch = self._watch_launcher.node('temoto_chaos', 'chaos_motion_watch', name='chaos_motion_watch',
                                               params={'control_socket': path, 'robot_namespace': ROBOT})
        self._watch_socket = path
        wait_for(lambda: os.path.exists(path) or not self.watch.alive(), MOTION_WATCH_START_S,
                 'the motion watch to open its socket')
        if not self.watch.alive():
            raise RuntimeError('the motion watch exited; log:\n%s' % self.watch.log())

    def _wait_managers(self) -> None:
        """Until every manager answers for its registry (a dead incarnation's service may still be listed)."""
        services = [m.path + '/registry' for m in self.managers]
        wait_for(lambda: all(reg is not None for reg in self.reader.read_all(services).values()),
                 STACK_START_S, 'the managers to answer')

    def _start_client(self, index: int) -> None:
        self.generations[index] += 1
        path = os.path.join(self.opts.out_dir, 'client_%d.sock' % index)
        journal = os.path.join(self.opts.out_dir, 'clients', 'motion_%d_%d.jsonl' % (index, self.generations[index])) \
            if self.opts.motion else ''
        if journal:
            os.makedirs(os.path.dirname(journal), exist_ok=True)
            self._journals.setdefault(journal, 0)
        self.clients[index] = ClientHandle(self.launcher, index, self.generations[index], path,
                                           STATION if self.opts.station else '', journal)
        if self.opts.concurrent and index not in self._workers:
            self._workers[index] = concurrent.futures.ThreadPoolExecutor(1, 'chaos-client-%d' % index)

    def dump_stacks(self) -> List[int]:
        """Ask every node of the stacks for every thread's stack (in its log); the pids asked."""
        stacks = [stack for stack in (self.stack, self.station_stack) if stack is not None]
        asked = dump_stacks([pid for stack in stacks for pid in stack.pids])
        print('temoto chaos: %d node(s) wrote every thread\'s stack to their logs in %s'
              % (len(asked), os.path.join(self.opts.out_dir, 'logs')), file=sys.stderr)
        return asked

    def stop(self) -> List[tuple]:
        if self.violations:
            # before anything stops: a wedged manager that a stop ends cleanly would leave no trace of where it hung
            self.dump_stacks()
        for worker in self._workers.values():
            worker.shutdown(wait=False, cancel_futures=True)   # a call under way ends when its client is stopped
        self._asking.shutdown(wait=False, cancel_futures=True)
        self.reader.close()
        if self._rejoin is not None:
            self._rejoin.stop()
        if self._lasting is not None:        # a run interrupted during a lasting fault: it ends on its clock
            fault, self._lasting = self._lasting, None
            try:
                fault.end(self.opts.settle_s + LASTING_FAULT_SLACK_S)
            except Exception as err:         # the run is over; what the fault raised is still told
                print('temoto chaos: the fault of step %d, cut short: %s' % (fault.entry['step'], err),
                      file=sys.stderr)
        if self.hosts is not None:
            self.hosts.link(True)        # a run stopped during a partition: the nodes stop over a working link
        if self.launcher is not None:
            self.launcher.stop_all()
        if self._watch_launcher is not None:
            self._watch_launcher.stop_all()
        if self.station_stack is not None:
            self.station_stack.stop()
        if self.stack is not None:
            self.stack.stop()
        if self.master is not None:
            self.master.stop()
        if self._leave_station is not None:
            self._leave_station()       # before down(), which kills every process whose main thread is on a host
            self._leave_station = None
        if self.hosts is not None:
            self.hosts.down()
        left = leftover_processes(self.token)
        if left:
            kill_leftovers(self.token)
        return left

    # ------------------------------------------------------------------ steps
    def apply(self, step: Step) -> Union[str, Callable[[], str]]:
        """Do ``step``: a sentence saying what was done (or why nothing was), or, for a fault that lasts (a
        cut link, a stopped manager, a killed one until it is back), the rest of the fault to run, begun
        here: waiting it out and undoing it, which returns the sentence."""
        kind, a = step.kind, step.args
        if kind in CLIENT_STEPS:
            return self._client_op(step, self.clients[a['client']])
        if kind == 'partition' and self.hosts is None:
            return 'one host: no link to cut'
        self.faults[kind] += 1
        if kind in ('kill_driver', 'kill_consumer'):
            wanted = checker.DRIVERS if kind == 'kill_driver' else checker.CONSUMERS + checker.ALGORITHMS
            running = sorted((pid, name) for pid, (name, _) in self._resources().items() if name in wanted)
            if not running:
                return 'none runs'
            pid, name = running[a['pick'] % len(running)]
            os.kill(pid, signal.SIGKILL)
            return 'SIGKILL %s %s (pid %d)' % (kind.split('_')[1], name, pid)
        if kind == 'kill_client':
            return self._kill_client(a['client'])
        if kind in ('kill_manager', 'stop_manager'):
            name = manager_node(a['manager'])
            uri = lookup_node(self.master.uri, name)
            pid = node_pid(uri) if uri else None
            if pid is None:
                return '%s not registered' % name
            if kind == 'kill_manager':
                os.kill(pid, signal.SIGKILL)
                return lambda: self._respawned(name, pid)
            os.kill(pid, signal.SIGSTOP)
            return lambda: self._resume(name, pid, a['seconds'])
        if kind == 'partition':
            return self._partition(a['seconds'])
        if kind == 'kill_robot':
            return self._kill_robot()
        if kind in ('kill_controller', 'stop_controller'):
            return self._hit_controller(step)
        if kind == 'halt':
            return self._halt(step)
        if kind == 'kill_manipulator':
            return self._kill_manipulator(step)
        if kind == 'unplug_obstacle':
            return self._unplug_obstacle(step)
        if kind == 'unplug_hand':
            self._stop_cases('hand_unplugged', step, [LEFT_ARM, RIGHT_ARM], hand_only=True)
            self._cable('hand_tracker', 'unplugged', a['mode'])
            return 'unplugged hand_tracker (%s)' % a['mode']
        if kind == 'unplug':
            self._cable(a['device'], 'unplugged', a['mode'])
            return 'unplugged %s (%s)' % (a['device'], a['mode'])
        self._cable(a['device'], 'plugged', '')
        return 'plugged %s' % a['device']

    def _hit_controller(self, step: Step) -> Union[str, Callable[[], str]]:
        """SIGKILL a controller (the base's respawns; an arm's or the gripper's is the Robot Manager's part,
        which FAILs), or SIGSTOP it for a while: either way its motors' command timeout stops the part."""
        moving = self._moving_parts()
        # among the controllers that run (an arm's and the gripper's run only while a client holds them): those of
        # a moving part first. A pick among all of them found none running three times in a 300-step history
        running = self._running({c: '/%s/%s' % (ROBOT, c) for c in CONTROLLED})
        if not running:
            return 'no controller runs'
        candidates = [c for c in running if CONTROLLED[c] in moving] or list(running)
        controller = candidates[step.args['pick'] % len(candidates)]
        name, pid = '/%s/%s' % (ROBOT, controller), running[controller]
        part = CONTROLLED[controller]
        if step.kind == 'kill_controller':
            self._stop_cases('controller_killed', step, [part])
            os.kill(pid, signal.SIGKILL)
            return 'SIGKILL %s (%d)' % (name, pid)
        self._stop_cases('controller_stalled', step, [part])
        os.kill(pid, signal.SIGSTOP)
        if self.opts.concurrent:
            return lambda: self._resume(name, pid, step.args['seconds'])
        return self._resume(name, pid, step.args['seconds'])

    def _halt(self, step: Step) -> str:
        """The operator's "stop" on the robot's halt topic, as the action engine publishes it: every part moving
        then is held to the halt's bound (a goal sent after it may move the part again)."""
        moving = self._moving_parts()
        self._stop_cases('halted', step, moving)
        self._halt_pub.publish(String('chaos step %d' % step.index))
        return 'halt (moving: %s)' % (', '.join(moving) or 'nothing')

    def _kill_manipulator(self, step: Step) -> str:
        """SIGKILL an arm's manipulator (the client of its controller's trajectory, and the servo stream's writer):
        that arm's controller must hold it. One whose arm moves first."""
        moving = self._moving_parts()
        running = self._running({arm: '/%s/%s_manipulator' % (ROBOT, arm) for arm in (LEFT_ARM, RIGHT_ARM)})
        if not running:
            return 'no manipulator runs'
        candidates = [a for a in sorted(running) if a in moving] or sorted(running)
        arm = candidates[step.args['pick'] % len(candidates)]
        self._stop_cases('manipulator_killed', step, [arm])
        os.kill(running[arm], signal.SIGKILL)
        return 'SIGKILL /%s/%s_manipulator (%d)%s' % (ROBOT, arm, running[arm], ', its arm moving' if arm in moving
                                                        else '')

    def _running(self, nodes: Dict[str, str]) -> Dict[str, int]:
        """Of ``nodes`` (a key -> a node's name), those registered now: the key -> the node's pid."""
        running = {}
        for key, name in sorted(nodes.items()):
            uri = lookup_node(self.master.uri, name)
            pid = node_pid(uri) if uri else None
            if pid is not None:
                running[key] = pid
        return running

    def _moving_parts(self) -> List[str]:
        """The parts moving now, as the ground truth says (the ledger reads it on)."""
        try:
            self.motion.truth(control_socket.ask(self._watch_socket, {'op': 'since', 'seq': self.motion.seq}, 10.0))
        except (OSError, ValueError) as err:
            self.motion_violations.append('motion: the ground-truth watch does not answer: %s' % err)
        return sorted(self.motion.moving)

    def _unplug_obstacle(self, step: Step) -> str:
        """Pull the cable of the device the navigator's obstacle source comes from (the Robot Manager's latched
        word; the SICK when it has said none)."""
        device = 'sick'
        try:
            topic = latched_message(OBSTACLE_SOURCE_TOPIC, String, 2.0, absent_after=0.5).data
            device = next((d for prefix, d in SOURCE_DEVICES if topic.lstrip('/').startswith(prefix) or
                           ('/' + prefix) in topic), device)
        except (NoPublisher, TimeoutError, rospy.ROSException):
            topic = ''
        self._stop_cases('obstacle_unplugged', step, [BASE], detection=self._stale_after(topic))
        self._cable(device, 'unplugged', step.args['mode'])
        return 'unplugged %s (%s), the obstacle source%s' % (device, step.args['mode'],
                                                            ' on ' + topic if topic else ' (none said: the SICK)')

    def _stale_after(self, topic: str) -> Optional[float]:
        """The obstacle source on ``topic``'s stale bound, as the watch has learnt it now: the detection bound of
        its unplugging (3 of the SICK's periods are 0.14 s; of the stitched Hokuyo cloud's, 0.3 s and more).
        None (the case's own, the SICK's) when the watch has not learnt one."""
        if not topic or not self.opts.motion:
            return None
        self._moving_parts()                          # the watch's answer, now
        return next((bound for source, bound in self.motion.stale_after.items()
                     if bound is not None and ('/' + topic.strip('/')).endswith('/' + source)), None)

    def _stop_cases(self, case: str, step: Step, parts: List[str], hand_only: bool = False,
                    detection: Optional[float] = None) -> None:
        """A fault that stops motion, about to be done: each part is held to the case's bound from now (or to
        ``detection`` and the part's braking)."""
        if self.opts.motion:
            self._read_journals()
            affected = ()
            if hand_only:      # only the arms that follow the hand; another hold of such an arm still moves it
                following = [h for h in self.motion.holds.values() if h.what.startswith('hand ') and h.end is None]
                affected = tuple(h.id for h in following)
                parts = [p for p in parts if any(h.part == p for h in following)]
            for part in parts:
                self.motion.fault(case, time.time(), part, step.index, affected, detection)

    def _client_op(self, step: Step, client: ClientHandle) -> str:
        """A client's step, done by ``client``: what it answered."""
        kind, a = step.kind, step.args
        if kind in ('navigate', 'servo', 'grip', 'arm_goal', 'cancel_motion'):
            answer = client.ask(op=kind, **{k: v for k, v in a.items() if k != 'client'})
            if not answer.get('ok'):
                return 'client %d: refused: %s' % (a['client'], answer.get('error', '')[:200])
            if kind == 'cancel_motion':
                return 'client %d: cancelled %s' % (a['client'], answer['cancelled'] or 'nothing (no motion held)')
            if 'accepted' in answer:
                return 'client %d: %s %s%s' % (a['client'], answer['id'], 'accepted' if answer['accepted']
                                               else answer['state'], '' if answer['accepted']
                                               else ': ' + answer['text'][:160])
            return 'client %d: %s streaming' % (a['client'], answer['id'])
        if kind == 'load_sensor':
            answer = client.ask(op='load_sensor', type=a['type'], keys=a['keys'])
            return 'client %d: %s' % (a['client'], answer.get('sensor') or
                                      'refused: %s' % answer.get('error', '')[:200])
        if kind == 'load_process':
            answer = client.ask(op='load_process', topic=a['topic'], rate=a['rate'])
            return 'client %d: %s' % (a['client'], 'throttle pid %s' % answer['pid'] if answer.get('ok')
                                      else 'refused: %s' % answer.get('error', '')[:200])
        if kind == 'track_object':
            answer = client.ask(op='track_object', object=a['object'])
            return 'client %d: %s' % (a['client'], '%s by %s' % (a['object'], answer['tracker']) if answer.get('ok')
                                      else 'refused: %s' % answer.get('error', '')[:200])
        if kind == 'show_display':
            answer = client.ask(op='show_display', type=a['type'], topic=a['topic'])
            return 'client %d: %s' % (a['client'], 'display %s' % answer['display'] if answer.get('ok')
                                      else 'refused: %s' % answer.get('error', '')[:200])
        if kind == 'unload':
            held = sorted(client.ask(op='state')['held'])
            if not held:
                return 'client %d holds nothing' % a['client']
            rid = held[a['pick'] % len(held)]
            answer = client.ask(op='unload', id=int(rid))
            return 'client %d unloaded %s%s' % (a['client'], rid, '' if answer['ok'] else ': ' + answer['error'][:200])
        raise ValueError('not a client step: %s' % kind)

    def _kill_client(self, index: int) -> str:
        """SIGKILL a client, whatever call it is in, and start a new incarnation. In a concurrent history the
        new one starts in the client's worker, after the call the kill cut short, and the checker leaves the
        client out until it answers (the dead incarnation's references must still go)."""
        if index not in self.clients:
            self._wait_client(index)        # killed a moment ago, and still starting again
        if index not in self.clients:
            return 'client %d did not start again: nothing to kill' % index
        old = self.clients.pop(index)
        if self.opts.motion:
            self._read_journals()
        killed_at = time.time()
        os.kill(old.proc.pid, signal.SIGKILL)
        self._killed[old.name] = time.monotonic()
        if self.opts.motion:
            self._read_journals()          # whatever it wrote up to its death
            self.motion.killed('/' + old.name, killed_at, getattr(self, '_step_index', -1))
        if not self.opts.concurrent:
            self._restart_client(index, old)
            return 'SIGKILL client %d, started again' % index
        # the calls queued behind the one the kill cut short die with the client
        dropped = 0
        for job, entry in self._jobs[index]:
            if job.cancel():
                entry['did'] = 'not done: client %d was killed before its turn' % index
                self._print(entry)
                dropped += 1
        self._jobs[index].append((self._workers[index].submit(self._restart_client, index, old), None))
        return 'SIGKILL client %d, starting again%s' % (index, ' (%d queued call(s) dropped)' % dropped
                                                        if dropped else '')

    def _restart_client(self, index: int, old: ClientHandle) -> None:
        """Start the killed client's next incarnation, again if an attempt fails (its registration may meet a
        cut link or a robot booting), within CLIENT_RESTART_S; a client that does not start is a violation."""
        old.proc.stop()          # reaps it (already dead: returns at once)
        deadline = time.monotonic() + CLIENT_RESTART_S
        while True:
            try:
                self._start_client(index)
                return
            except Exception as err:      # whatever it was (an OSError from the master, a timeout): told below
                if time.monotonic() > deadline:
                    self.call_violations.append('client %d did not start again within %.0f s: %s: %s'
                                                % (index, CLIENT_RESTART_S, type(err).__name__, err))
                    return
            time.sleep(0.5)

    # ------------------------------------------------------------------ concurrent clients
    def _dispatch(self, step: Step, entry: dict) -> None:
        """Queue a client's step for its worker, once the client has room in its queue."""
        index = step.args['client']
        jobs = self._jobs[index]
        while jobs and jobs[0][0].done():
            self._wait_job(jobs.popleft()[0])          # what a job raised reaches the runner, at once
        if len(jobs) >= CLIENT_BACKLOG:
            self._wait_job(jobs.popleft()[0])
        jobs.append((self._workers[index].submit(self._call, step, entry), entry))

    def _wait_client(self, index: int) -> None:
        """Until every job queued for the client is done."""
        jobs = self._jobs[index]
        while jobs:
            self._wait_job(jobs.popleft()[0])

    @staticmethod
    def _wait_job(job: concurrent.futures.Future) -> None:
        if not job.cancelled():
            # bounded by the calls queued before it; the jobs catch what they can raise
            job.result(timeout=CLIENT_BACKLOG * CLIENT_CALL_TIMEOUT + STACK_START_S)

    def _drain(self) -> None:
        """Until no client has a job queued or under way."""
        for index in list(self._jobs):
            self._wait_client(index)

    def _call(self, step: Step, entry: dict) -> None:
        """A worker's job: the step, its answer in the log. A client that does not answer is a violation,
        unless the nemesis killed it during the call."""
        index = step.args['client']
        client = self.clients.get(index)
        t0 = time.monotonic()
        if client is None:
            entry['did'] = 'not done: client %d did not start again' % index
        else:
            try:
                entry['did'] = self._client_op(step, client)
            except Exception as err:      # reported: a violation, unless the nemesis killed the client meanwhile
                if self.clients.get(index) is client:
                    entry['did'] = 'not done'
                    self.call_violations.append('step %d: client %d did not answer: %s: %s'
                                                % (step.index, index, type(err).__name__, err))
                else:
                    entry['did'] = 'client %d was killed during the call' % index
        entry['call_s'] = round(time.monotonic() - t0, 3)
        self._print(entry)

    def _print(self, entry: dict) -> None:
        with self._print_lock:
            print('[step %d] %s: %s%s' % (entry['step'], entry['kind'], entry['did'], '' if not entry['violations']
                                          else ' -> VIOLATION: ' + '; '.join(entry['violations'])), flush=True)

    def _respawned(self, name: str, pid: int) -> str:
        """The rest of a killed manager's fault: until its next incarnation answers for its registry, taken
        back from its journal (the checks would only wait for it), within the settle bound; the check that
        follows reports a manager that is not back."""
        t0 = time.monotonic()
        deadline = t0 + self.opts.settle_s
        while not process_group.ended(pid):
            if time.monotonic() > deadline:        # the dead one must not be the one that answers
                return 'SIGKILL %s (%d); it did not die within %.0f s' % (name, pid, self.opts.settle_s)
            time.sleep(0.01)
        while time.monotonic() < deadline:
            registry = self.reader.read_json(name + '/registry', timeout=1.0)
            if registry is not None and not registry.get('recovering'):
                return 'SIGKILL %s (%d); its next incarnation answered %.2f s later' % (
                    name, pid, time.monotonic() - t0)
            time.sleep(0.05)
        return 'SIGKILL %s (%d); no incarnation answered within %.0f s' % (name, pid, self.opts.settle_s)

    @staticmethod
    def _resume(name: str, pid: int, seconds: float) -> str:
        """The rest of a stopped manager's fault: stopped ``seconds`` in all, then SIGCONT."""
        time.sleep(seconds)          # the fault itself: stopped this long
        os.kill(pid, signal.SIGCONT)
        return 'SIGSTOP %s for %.2f s' % (name, seconds)

    def _partition(self, seconds: float) -> Callable[[], str]:
        """Cut the link; the rest of the fault: for ``seconds`` (at least as long as it takes) every resource
        of the robot's that a client held (all but the station's displays) must be FAILED at that client
        within the bound; then the cable is plugged back."""
        clients = dict(self.clients)        # a client starting again meanwhile is not asked
        held = {i: {lid for lid, info in state['held'].items()
                    if not info['failed'] and info['kind'] not in STATION_KINDS}
                for i, state in self._states(clients).items()}
        if self.opts.motion:
            self._read_journals()
            # a stream is cut, and a drive's client cut off: the navigator stops it (goal_holders.py)
            servoed = sorted({h.part for h in self.motion.holds.values()
                              if h.kind in ('servo', 'goal') and h.end is None and h.holds})
            for part in servoed:
                self.motion.fault('link_cut', time.time(), part, getattr(self, '_step_index', -1))
        cut = time.monotonic()
        if self.opts.motion:
            self.motion.link(False, time.time())
        self.hosts.link(False)
        return lambda: self._heal(clients, held, cut, seconds)

    def _heal(self, clients: Dict[int, ClientHandle], held: Dict[int, set], cut: float, seconds: float) -> str:
        """Wait out a cut link (made at ``cut``) until its FAILEDs are heard and ``seconds`` have passed, or
        its bound; plug it back."""
        unheard: List[str] = []
        down = 0.0
        try:
            while True:
                states = self._states(clients)
                unheard = ['client %d: %s' % (i, lid) for i, lids in held.items() for lid in lids
                           if lid in states[i]['held'] and not states[i]['held'][lid]['failed']]
                down = time.monotonic() - cut
                if (not unheard and down >= seconds) or down > max(seconds, PARTITION_FAILED_BOUND):
                    break
                time.sleep(0.05)
        finally:
            self.hosts.link(True)
            if self.opts.motion:
                self.motion.link(True, time.time())
        if unheard:
            self.partition_violations.append('link down: no FAILED heard within %.1f s for %s'
                                             % (PARTITION_FAILED_BOUND, ', '.join(unheard)))
        return 'link down for %.2f s; %d held resource(s) FAILED at their clients' % (
            down, sum(len(v) for v in held.values()))

    def _kill_robot(self) -> str:
        """Every process of the robot SIGKILLed at once, as a robot that loses power, then the robot boots
        again (its managers take their registries back from their journals). On two hosts that is the
        robot host, its master included; on one host the stack and every process its ER Manager started,
        while the master, the clients and this runner stay. On two hosts the clients' calls under way meet
        the power loss, as they would on a robot; on one host they end first, so that every client process is
        known (none halfway started) when the robot's processes die and the clients are spared."""
        if self.hosts is None:
            self._drain()
        under_way = sum(1 for jobs in self._jobs.values() for job, _ in jobs if not job.done())
        t0 = time.monotonic()
        self.stack.kill()
        spare = [self.watch.pid] if self.watch is not None else []
        if self.hosts is not None:
            self.hosts.kill_all(self.hosts.robot, spare=spare)
            self.master.stop()                  # reaps it
            self.master.start()                 # the robot boots: a new master at the same address
        else:
            # the master, the clients and the station's stack stay, with whatever they started
            roots = [self.master.proc.pid, *spare, *(c.proc.pid for c in self.clients.values()),
                     *(self.station_stack.pids if self.station_stack is not None else []), *self._station_processes()]
            kill_leftovers(self.token, exclude=_with_descendants(roots))
        self.stack = self._new_stack()
        self.stack.start(STACK_START_S)
        if self._rejoin is not None:
            self._rejoin.check()                  # at once, not at the watch's next period
        self._wait_managers()
        return 'the robot lost power and booted again in %.1f s%s' % (
            time.monotonic() - t0, ' (its master too; %d client call(s) queued or under way met it)' % under_way
            if self.hosts is not None else '')

    def _station_processes(self) -> List[int]:
        """What the station's ER Manager runs (its RViz host): with a journal its children outlive it, so
        they are not always its descendants."""
        if self.station_stack is None:
            return []
        procs = self.reader.read_json('/%s/temoto_er_manager/processes' % STATION) or {'processes': []}
        return [p['pid'] for row in procs['processes'] for p in row['processes']]

    def _cable(self, device: str, state: str, mode: str) -> None:
        resp = rospy.ServiceProxy('/%s/vaultbot_sim/set_device_state' % ROBOT, SetDeviceState)(device, state, mode)
        if not resp.success:
            raise RuntimeError('the simulation refused %s %s: %s' % (state, device, resp.message))

    def _resources(self) -> Dict[int, Tuple[str, str]]:
        """The live processes that are resources (drivers and the clients' own processes), by pid: their names."""
        return checker.resource_processes([pid for pid, _ in leftover_processes(self.token)])

    # ------------------------------------------------------------------ checks
    def check(self) -> List[str]:
        """The violations left once the system had ``settle_s`` to settle (none: the step passed). What the
        first look saw, if the system had to settle, is kept in ``waited_for`` (where a history's time goes)."""
        deadline = time.monotonic() + self.opts.settle_s
        self.waited_for = ''
        began = time.monotonic()
        try:
            return self._check_until_settled(deadline)
        finally:
            self.check_seconds += time.monotonic() - began

    def _check_until_settled(self, deadline: float) -> List[str]:
        while True:
            snap = checker.take(self.reader, self.managers, ROBOT, self._states,
                                lambda: [pid for pid, _ in leftover_processes(self.token)])
            now = time.monotonic()
            snap.killed = {name: now - t for name, t in self._killed.items()}
            for name, age in snap.killed.items():
                if age > checker.KILLED_CLIENT_BOUND + self.opts.settle_s:
                    del self._killed[name]      # past its bound long ago: a reference it left is a violation
            violations = self.partition_violations + self.call_violations + checker.check(snap) + \
                self._check_motion()
            self.checks += 1
            if not violations or time.monotonic() > deadline:
                return violations
            self.waited_for = self.waited_for or violations[0][:200]
            time.sleep(0.1)

    def _check_motion(self, final: bool = False) -> List[str]:
        """The motion invariants (history 5): the ground truth read first, then the journals, whose lines for
        any motion the watch saw are written by then. What is found stays found: it is not settled away."""
        if not self.opts.motion:
            return []
        try:
            answer = control_socket.ask(self._watch_socket, {'op': 'since', 'seq': self.motion.seq}, 10.0)
        except (OSError, ValueError) as err:
            self.motion_violations.append('motion: the ground-truth watch does not answer: %s' % err)
            return self.motion_violations
        began = time.monotonic()
        self.motion.truth(answer)
        self._read_journals()
        now = answer['now'] + (motion_checker.JUDGE_AFTER_S if final else 0.0)
        self.motion_violations += self.motion.check(now)
        self.motion_check_seconds += time.monotonic() - began
        return self.motion_violations

    def _read_journals(self) -> None:
        """Each client incarnation's journal lines not read yet (a line is whole: one write each)."""
        for path, offset in list(self._journals.items()):
            try:
                with open(path, 'rb') as f:
                    f.seek(offset)
                    data = f.read()
            except FileNotFoundError:
                continue
            end = data.rfind(b'\n') + 1
            if end:
                self.motion.journal(json.loads(line) for line in data[:end].splitlines() if line.strip())
                self._journals[path] = offset + end

    def _states(self, clients: Optional[Dict[int, ClientHandle]] = None) -> Dict[int, dict]:
        """Each client's own account, all asked at once: of ``clients``, or of every running one (one starting
        again is not asked)."""
        asked = {i: self._asking.submit(c.ask, op='state')
                 for i, c in (list(self.clients.items()) if clients is None else clients.items())}
        return {i: answer.result() for i, answer in asked.items()}      # each bounded by its socket's timeout

    def run(self) -> dict:
        last = self.opts.steps if self.opts.until is None else min(self.opts.steps, self.opts.until)
        self.started = time.monotonic()
        for step in history(self.opts.seed, last, self.opts.clients, self.opts.version):
            handed_over = self.opts.concurrent and step.kind in CLIENT_STEPS
            # a client's step overlaps a lasting fault, while it lasts, and so does a fault that needs nothing the
            # lasting one cuts off; another fault, or a check, waits for its end
            overlaps = handed_over or (self._lasting is not None and
                                       step.kind in OVERLAPPING.get(self._lasting.entry['kind'], ()))
            if self._lasting is not None and (not overlaps or self._lasting.done()) and self._end_lasting():
                break
            started = time.monotonic()
            self._step_index = step.index
            entry = {'step': step.index, 'kind': step.kind, 'args': step.args, 'did': 'under way', 'violations': []}
            self.log.append(entry)
            self.waited_for = ''
            try:
                if handed_over:
                    self._dispatch(step, entry)
                else:
                    did = self.apply(step)
                    if callable(did) and self.opts.concurrent:
                        self._lasting = LastingFault(entry, did)
                    else:
                        entry['did'] = did() if callable(did) else did
                applied = time.monotonic()
                violations = [] if self._lasting is not None else self.check()
            except (OSError, ValueError, concurrent.futures.TimeoutError) as err:
                # a client that does not answer is a finding, not a crash
                applied = time.monotonic()
                entry['did'], violations = 'not done', ['the runner could not do the step or check it: %s' % err]
                handed_over = False
            entry.update(violations=violations, apply_s=round(applied - started, 3),
                         check_s=round(time.monotonic() - applied, 3))
            if self._lasting is not None and self._lasting.entry is not entry:
                entry['during'] = self._lasting.entry['step']      # not checked on its own: the fault lasted
            if self.waited_for:
                entry['waited_for'] = self.waited_for
            if not handed_over and (self._lasting is None or self._lasting.entry is not entry):
                self._print(entry)
            if violations:
                self.violations, self.failed_step = violations, step.index
                break
        if not self.violations and self.opts.concurrent:
            # the last calls end, and the system they leave is checked once more
            try:
                if self._lasting is not None and self._end_lasting():
                    return self.summary()
                self._drain()
                self._check_motion(final=True)      # every span judged, up to the last sample
                violations = self.check()
            except (OSError, ValueError, concurrent.futures.TimeoutError) as err:
                violations = ['the runner could not check the end of the history: %s' % err]
            if violations:
                self.violations, self.failed_step = ['after the last call: ' + v for v in violations], last - 1
        return self.summary()

    def _end_lasting(self) -> bool:
        """Wait for the lasting fault to end, check what it left, and log both at its step. Whether that
        found a violation (the run stops there)."""
        fault, self._lasting = self._lasting, None
        entry = fault.entry
        t0 = time.monotonic()
        self.waited_for = ''
        try:
            entry['did'] = fault.end(self.opts.settle_s + LASTING_FAULT_SLACK_S)
            ended = time.monotonic()
            violations = self.check()
        except (OSError, ValueError, concurrent.futures.TimeoutError) as err:
            ended = time.monotonic()
            entry['did'], violations = 'not done', ['the runner could not do the step or check it: %s' % err]
        # the runner's time on the fault: starting it, and what was left of it when the runner had to wait
        entry.update(violations=violations, apply_s=round(entry['apply_s'] + ended - t0, 3),
                     check_s=round(time.monotonic() - ended, 3))
        if self.waited_for:
            entry['waited_for'] = self.waited_for
        self._print(entry)
        if violations:
            self.violations, self.failed_step = violations, entry['step']
        return bool(violations)

    def summary(self) -> dict:
        """What ran so far (also of a run that was interrupted)."""
        done = len(self.log)
        took = time.monotonic() - self.started if self.started is not None else 0.0
        return {'seed': self.opts.seed, 'history': self.opts.version, 'hosts': self.opts.hosts, 'steps': done,
                'faults': dict(self.faults), 'checks': self.checks,
                'violations': self.violations, 'failed_step': self.failed_step, 'seconds': took,
                'check_seconds': round(self.check_seconds, 1),
                **({'motion': self.motion.figures(), 'motion_check_seconds': round(self.motion_check_seconds, 1)}
                   if self.opts.motion else {}),
                'steps_per_s': done / took if took > 0 else 0.0}


def _with_descendants(pids: List[int]) -> List[int]:
    """``pids`` and every process below them, now."""
    out = set(pids)
    for pid in pids:
        try:
            out.update(child.pid for child in psutil.Process(pid).children(recursive=True))
        except psutil.NoSuchProcess:
            continue
    return sorted(out)


def manager_node(manager: str) -> str:
    """A history's manager (relative to the robot's namespace, or 'station/...') as its node's name."""
    if manager.startswith('station/'):
        return '/%s/%s' % (STATION, manager.split('/', 1)[1])
    return '/%s%s' % (ROBOT, manager)


def replay_command(opts: ChaosOptions, until: int) -> str:
    """The command that runs the same first ``until`` steps again."""
    extra = [('--clients', opts.clients, CLIENTS[opts.version]), ('--hosts', opts.hosts, 1),
             ('--history', opts.version, VERSION)]
    return 'temoto chaos --seed %d --until %d%s%s' % (opts.seed, until, ''.join(
        ' %s %s' % (flag, value) for flag, value, default in extra if value != default),
        ' --serial' if opts.serial else '')


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run_chaos(opts: ChaosOptions) -> int:
    chaos = Chaos(opts)
    summary: dict = {}
    previous = signal.signal(signal.SIGTERM, _interrupt)    # a SIGTERM stops the run as Ctrl-C does, cleanly
    try:
        chaos.start()
        summary = chaos.run()
    except KeyboardInterrupt:
        summary = dict(chaos.summary(), interrupted=True)
        print('temoto chaos: interrupted after %d steps, seed %d, faults %s, %d checks, 0 violations, %.1f steps/s'
              % (summary['steps'], opts.seed, summary['faults'], summary['checks'], summary['steps_per_s']), flush=True)
    finally:
        left = chaos.stop()
        signal.signal(signal.SIGTERM, previous)
        summary['leftovers'] = len(left)
        with open(os.path.join(opts.out_dir, 'chaos.json'), 'w') as f:
            json.dump({'summary': summary, 'log': chaos.log}, f, indent=1, default=str)
    if summary.get('interrupted'):
        return 130
    if summary.get('violations'):
        print('temoto chaos: VIOLATION at step %d of seed %d: %s\n  replay: %s'
              % (summary['failed_step'], opts.seed, '; '.join(summary['violations']),
                 replay_command(opts, summary['failed_step'] + 1)), flush=True)
        return 1
    print('temoto chaos: %d steps, seed %d, faults %s, %d checks, 0 violations, %.1f steps/s'
          % (summary['steps'], opts.seed, summary['faults'], summary['checks'], summary['steps_per_s']), flush=True)
    if left:
        print('temoto chaos: problem: %d process(es) left behind, killed now: %s' % (len(left), left[:5]), flush=True)
        return 1
    return 0
