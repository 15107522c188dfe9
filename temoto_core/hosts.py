"""Two hosts on one machine: two Linux network namespaces, cabled to a switch.

Teleoperation spans at least two machines, the robot and the operator's station.
To run and test that here, each "host" is a network namespace with its own
loopback and one end of a veth pair, addressed in 198.18.0.0/15 (the range set
aside for benchmarking, RFC 2544), so nothing else can be reached from it. ROS 1's
own transport joins them: one master on the robot host, ``ROS_IP`` set per host.

The switch is a third namespace holding a bridge; each host's cable is a veth
pair, one end in the host, one on the bridge. Pulling the cable sets the switch's
ends down, so each host keeps its own interface up with no carrier, as a real
pulled cable leaves it: its own address still works for its own nodes (a host
whose interface went down would lose the address its nodes talk to each other
on), and what it sends the other way is lost.

Faults a partition test needs, without the kernel's netem: the cable pulled and
plugged back, an address removed, and every process of a host killed (a host
that dies).

Needs root (``CAP_NET_ADMIN``); :func:`unavailable` says in one line why not.
Every command is an argument list: nothing goes through a shell.
"""
import ctypes
import dataclasses
import os
import signal
import subprocess
import threading
import time
from typing import Callable, Dict, List, Optional, Sequence, TypeVar

from temoto_core.master import RosMaster
from temoto_core.processes import ProcessGroupLauncher

T = TypeVar('T')
MASTER_PORT = 11311          # each host has its own ports: the robot's master takes ROS's usual one
_CLONE_NEWNET = 0x40000000      # <sched.h>; os.setns arrives only in Python 3.12

SUBNET_PREFIX = 24
CARRIER_WAIT = 5.0      # s: the most a plugged cable takes to carry (measured: about 0.5 s)
ADDRESSES = ('198.18.0.1', '198.18.0.2')    # robot, operator


@dataclasses.dataclass(frozen=True)
class Host:
    name: str          # the namespace
    device: str        # its end of the veth pair
    address: str


# capability bits (<linux/capability.h>): a veth pair needs the first, a named network namespace the second
_NEEDED_CAPS = {'CAP_NET_ADMIN': 12, 'CAP_SYS_ADMIN': 21}


def _effective_capabilities() -> int:
    with open('/proc/self/status') as status:
        for line in status:
            if line.startswith('CapEff:'):
                return int(line.split()[1], 16)
    return 0


def unavailable() -> str:
    """'' if two hosts can be made here, else why not, in one line."""
    effective = _effective_capabilities()
    missing = [name for name, bit in _NEEDED_CAPS.items() if not effective >> bit & 1]
    if missing:
        return 'two hosts need root (network namespaces and a veth pair need %s, which this process lacks)' \
            % ' and '.join(missing)
    try:
        subprocess.run(['ip', '-V'], check=True, capture_output=True, timeout=5)
    except (OSError, subprocess.SubprocessError) as err:
        return 'two hosts need iproute2 (`ip`): %s' % err
    return ''


def _setns_fd(fd: int, what: str) -> None:
    if ctypes.CDLL(None, use_errno=True).setns(fd, _CLONE_NEWNET) != 0:
        err = ctypes.get_errno()
        raise OSError(err, 'setns into %s: %s' % (what, os.strerror(err)))


def _setns(path: str) -> None:
    """The calling thread joins the network namespace at ``path``."""
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        _setns_fd(fd, path)
    finally:
        os.close(fd)


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(['ip'] + list(args), check=check, capture_output=True, text=True, timeout=10)


class TwoHosts:
    """``robot`` and ``operator``, made by :meth:`up` and removed, with every process in them, by :meth:`down`."""

    def __init__(self, tag: str) -> None:
        if not tag.isalnum() or len(tag) > 8:
            raise ValueError('host tag %r: up to 8 letters or digits (it names namespaces and devices)' % tag)
        self.robot = Host('tm-%s-robot' % tag, 'tm%sr' % tag, ADDRESSES[0])
        self.operator = Host('tm-%s-op' % tag, 'tm%so' % tag, ADDRESSES[1])
        self.hosts = (self.robot, self.operator)
        self.switch = 'tm-%s-sw' % tag
        self._ports = {host.name: 'sw%s%s' % (tag, host.device[-1]) for host in self.hosts}

    def up(self) -> 'TwoHosts':
        self.down()                              # what a killed run left behind
        try:
            _ip('netns', 'add', self.switch)
            _ip('-n', self.switch, 'link', 'add', 'br0', 'type', 'bridge')
            _ip('-n', self.switch, 'link', 'set', 'br0', 'up')
            for host in self.hosts:
                _ip('netns', 'add', host.name)
                _ip('-n', host.name, 'link', 'set', 'lo', 'up')
                port = self._ports[host.name]
                _ip('-n', self.switch, 'link', 'add', port, 'type', 'veth', 'peer', 'name', host.device,
                    'netns', host.name)
                _ip('-n', self.switch, 'link', 'set', port, 'master', 'br0')
                _ip('-n', self.switch, 'link', 'set', port, 'up')
                _ip('-n', host.name, 'addr', 'add', '%s/%d' % (host.address, SUBNET_PREFIX), 'dev', host.device)
                _ip('-n', host.name, 'link', 'set', host.device, 'up')
        except subprocess.CalledProcessError as err:
            self.down()
            raise RuntimeError('making two hosts failed: %s: %s' % (' '.join(err.cmd), err.stderr.strip())) from err
        return self

    def down(self) -> None:
        """Kill every process of both hosts, then remove them and the switch (the cables go with them)."""
        for host in self.hosts:
            self.kill_all(host)
            _ip('netns', 'delete', host.name, check=False)
        _ip('netns', 'delete', self.switch, check=False)

    def names(self) -> List[str]:
        """The network namespaces of these hosts and of their switch."""
        return [host.name for host in self.hosts] + [self.switch]

    def exist(self) -> List[str]:
        """The namespaces of these hosts and their switch that exist now (none after :meth:`down`)."""
        listed = _ip('netns', 'list', check=False).stdout.split()
        return [name for name in self.names() if name in listed]

    # ------------------------------------------------------------------------------------------ running
    def master(self, workdir: str, session_token: str = '') -> RosMaster:
        """The master on the robot host (not started)."""
        return RosMaster(workdir, session_token, address=self.robot.address, port=MASTER_PORT,
                         wrap=lambda argv: self.argv(self.robot, argv),
                         run_in=lambda fn: self.run_in(self.robot, fn, 30.0))

    def launcher(self, host: Host, master: RosMaster, workdir: str) -> ProcessGroupLauncher:
        """Starts nodes on ``host`` against ``master``, and stops them all."""
        return ProcessGroupLauncher(self.env(host, master.uri, base=master.env), workdir,
                                    wrap=lambda argv: self.argv(host, argv),
                                    run_in=lambda fn: self.run_in(host, fn, 60.0))

    def argv(self, host: Host, argv: Sequence[str]) -> List[str]:
        """``argv`` run inside ``host``."""
        return ['ip', 'netns', 'exec', host.name] + list(argv)

    def env(self, host: Host, master: Optional[str] = None, base: Optional[Dict[str, str]] = None) -> Dict[str, str]:
        """An environment for ROS on ``host``: its own address, and the master on the robot host."""
        env = dict(os.environ if base is None else base)
        env['ROS_IP'] = host.address
        env.pop('ROS_HOSTNAME', None)            # ROS_HOSTNAME wins over ROS_IP; each host has only its address
        env['ROS_MASTER_URI'] = master or 'http://%s:11311' % self.robot.address
        return env

    def run_in(self, host: Host, fn: Callable[[], T], timeout: float = 10.0) -> T:
        """``fn()`` in ``host``'s network, from this process: a thread joins the namespace and runs it.

        A socket belongs to the namespace of the thread that makes it, so what
        ``fn`` connects to is resolved on ``host`` (the master, a node's XML-RPC).
        The thread ends with ``fn``, and the rest of the process stays where it is.
        """
        result: Dict[str, object] = {}

        def run() -> None:
            try:
                _setns('/var/run/netns/%s' % host.name)
                result['value'] = fn()
            except BaseException as err:        # handed to the caller, raised there
                result['error'] = err
        thread = threading.Thread(target=run, name='in-%s' % host.name, daemon=True)
        thread.start()
        thread.join(timeout)
        if thread.is_alive():
            raise TimeoutError('%s: no result within %.1f s' % (host.name, timeout))
        if 'error' in result:
            raise result['error']
        return result['value']

    def enter(self, host: Host) -> Callable[[], None]:
        """Move the calling thread into ``host``'s network; return the call that moves it back.

        Threads started meanwhile stay on ``host``. A command that talks ROS from
        the operator's station (``temoto demo --hosts 2``) enters it from its main
        thread before anything else connects, and leaves it before :meth:`down`,
        which kills every process whose main thread is on a host.
        """
        back = os.open('/proc/thread-self/ns/net', os.O_RDONLY | os.O_CLOEXEC)
        try:
            _setns('/var/run/netns/%s' % host.name)
        except OSError:
            os.close(back)
            raise

        def leave() -> None:
            try:
                _setns_fd(back, 'the namespace the thread came from')
            finally:
                os.close(back)
        return leave

    def pids(self, host: Host) -> List[int]:
        out = _ip('netns', 'pids', host.name, check=False)
        return [int(p) for p in out.stdout.split()] if out.returncode == 0 else []

    # ------------------------------------------------------------------------------------------ faults
    def link(self, up: bool) -> None:
        """The cables between the hosts, pulled or plugged back at the switch: each host's interface stays up,
        with no carrier while pulled."""
        for host in self.hosts:
            _ip('-n', self.switch, 'link', 'set', self._ports[host.name], 'up' if up else 'down')
        if up:
            # the kernel brings a carrier up in the background (its link watch, up to a second later); until
            # then the host drops what it sends, so the cable counts as plugged once both ends say so
            deadline = time.monotonic() + CARRIER_WAIT
            while not all(self._carrier(host) for host in self.hosts):
                if time.monotonic() > deadline:
                    raise RuntimeError('the cable was plugged back, but no carrier came within %.0f s'
                                       % CARRIER_WAIT)
                time.sleep(0.01)
            for host in self.hosts:
                # an address asked for during the cut waits for its next ARP probe (a second apart): asked afresh
                _ip('-n', host.name, 'neigh', 'flush', 'dev', host.device, check=False)

    def _carrier(self, host: Host) -> bool:
        """Whether ``host``'s interface is up and has a carrier (operational state UP)."""
        shown = _ip('-n', host.name, '-br', 'link', 'show', 'dev', host.device, check=False).stdout.split()
        return len(shown) > 1 and shown[1] == 'UP'

    def remove_address(self, host: Host) -> None:
        _ip('-n', host.name, 'addr', 'del', '%s/%d' % (host.address, SUBNET_PREFIX), 'dev', host.device)

    def restore_address(self, host: Host) -> None:
        _ip('-n', host.name, 'addr', 'add', '%s/%d' % (host.address, SUBNET_PREFIX), 'dev', host.device)

    def kill_all(self, host: Host, timeout: float = 5.0, spare: Sequence[int] = ()) -> None:
        """Every process of ``host`` SIGKILLed, as a host that loses power (then reaped, if ours); but those of
        ``spare``: a test's own instrument on that host."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            pids = [pid for pid in self.pids(host) if pid not in spare]
            if not pids:
                return
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            time.sleep(0.05)
