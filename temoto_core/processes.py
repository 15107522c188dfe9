"""Child processes of the tools (``temoto demo``, ``temoto record``) and of the tests: commands,
nodes and launch files, waited on until registered, always stopped by process group, and a
census of what outlived them (by the session token every child inherits)."""
import os
import signal
import subprocess
import sys
import time
import xmlrpc.client
from typing import Callable, Dict, List, Optional, Sequence, Tuple, TypeVar

from temoto_core.master_lookup import cleanup_dead_node, node_pid, parent_pid
from temoto_core.process_group import escalate, exit_status, group_members, stop_stages

T = TypeVar('T')

SESSION_ENV = 'TEMOTO_TEST_SESSION'
REGISTER_TIMEOUT = 20.0


def stop_process_group(proc: subprocess.Popen, sigint_grace: float = 3.0, sigterm_grace: float = 2.0) -> Optional[int]:
    """SIGINT, then SIGTERM, then SIGKILL to the child's process group; reap it.

    The child must have been started with ``start_new_session=True`` so that
    its group is its own. The group is signalled only while the leader is not
    reaped (see :mod:`temoto_core.process_group`); members left behind by a leader that has
    exited are killed before the leader is reaped. A leader that was already
    reaped elsewhere is not signalled at all: its number may be reused.
    """
    if proc.returncode is not None:
        return proc.returncode
    pgid = proc.pid
    # the stop every process gets, with a SIGABRT before the SIGKILL: a hang explains itself (below)
    stages = stop_stages(sigint_grace, sigterm_grace)
    stages = stages[:2] + ((signal.SIGABRT, 2.0),) + stages[2:]

    def send(sig: int) -> None:
        try:
            if sig == signal.SIGABRT:
                # the members first: a TeMoto node writes every thread's stack on SIGUSR1 (node.py), and the
                # node a warm-respawn parent forked is a member that SIGABRT to the leader would only take
                # down with it, silently (chaos seed 17: a wedged ER Manager left no trace of where it hung)
                asked = []
                for member in group_members(pgid, exclude=pgid):
                    try:
                        os.kill(member, signal.SIGUSR1)
                        asked.append(member)
                    except ProcessLookupError:
                        pass
                # ... and each has taken it before the leader goes: a leader killed at once had its members
                # SIGKILLed while their SIGUSR1 was still pending on a loaded machine, and no stack was written
                until = time.monotonic() + 2.0
                while any(signal_pending(m, signal.SIGUSR1) for m in asked) and time.monotonic() < until:
                    time.sleep(0.005)
                # only the leader: with PYTHONFAULTHANDLER set (the harness sets it) a Python child
                # writes every thread's stack to its log before dying, so a hang explains itself
                os.kill(pgid, sig)
            else:
                os.killpg(pgid, sig)
        except ProcessLookupError:
            pass

    def ended(timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while exit_status(proc) is None:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True
    escalate(stages, send, ended)
    if exit_status(proc) is not None and proc.returncode is None:
        # the zombie leader still holds the group id: its leftover members can be killed safely
        deadline = time.monotonic() + 3.0
        while group_members(pgid, exclude=pgid) and time.monotonic() < deadline:
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                break
            time.sleep(0.01)
    try:
        return proc.wait(timeout=1.0)
    except subprocess.TimeoutExpired:
        return None


def signal_pending(pid: int, signum: int) -> bool:
    """Whether ``signum`` waits to be delivered to process ``pid`` (``ShdPnd``/``SigPnd`` in /proc); False once
    its handler has begun, or when the process is gone."""
    try:
        with open('/proc/%d/status' % pid) as f:
            for line in f:
                if line.startswith(('ShdPnd:', 'SigPnd:')) and int(line.split()[1], 16) >> (signum - 1) & 1:
                    return True
    except (OSError, ValueError, IndexError):
        pass
    return False


def catches(pid: int, signum: int) -> bool:
    """Whether process ``pid`` has a handler for ``signum`` (``SigCgt`` in /proc): a signal it does not catch
    may kill it."""
    try:
        with open('/proc/%d/status' % pid) as f:
            for line in f:
                if line.startswith('SigCgt:'):
                    return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    except (OSError, ValueError, IndexError):
        pass
    return False


def dump_stacks(pgids: Sequence[int]) -> List[int]:
    """Ask every process in groups ``pgids`` that catches SIGUSR1 (a TeMoto node: ``node.py`` registers
    faulthandler for it) to write every thread's stack to its log, and leave the rest alone. The pids asked.

    For a run that found a wedged node: the stacks say where it hangs, and a stop that follows may end it
    cleanly, leaving no other trace."""
    asked = []
    for pgid in pgids:
        for pid in [pgid] + group_members(pgid, exclude=pgid):
            if catches(pid, signal.SIGUSR1):
                try:
                    os.kill(pid, signal.SIGUSR1)
                    asked.append(pid)
                except ProcessLookupError:
                    pass
    return asked


def tail(path: str, lines: int = 20) -> str:
    try:
        with open(path, 'rb') as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 8192))
            return '\n'.join(f.read().decode('utf-8', 'replace').splitlines()[-lines:])
    except OSError:
        return '(no log)'


class LoggedChild:
    """A child of a tool or a test (``temoto demo``, a fixture), in its own session so that a stop reaches
    everything it started, with its output in a log file. (The ER Manager's children, watched by pidfd and
    restarted by policy, are ``temoto_er_manager.supervisor.ManagedProcess``.)"""

    def __init__(self, argv: Sequence[str], env: Dict[str, str], log_path: str, name: str = '') -> None:
        self.argv = list(argv)
        self.name = name or os.path.basename(argv[0])
        self.log_path = log_path
        with open(log_path, 'ab') as log:
            self.proc = subprocess.Popen(self.argv, env=env, stdin=subprocess.DEVNULL, stdout=log,
                                         stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        """Running? Never reaps, so that stop() can still clean its group safely."""
        return exit_status(self.proc) is None

    @property
    def returncode(self) -> Optional[int]:
        """The exit code once it has exited (reaped or not), else None."""
        return exit_status(self.proc)

    def stop(self, sigint_grace: float = 3.0) -> Optional[int]:
        return stop_process_group(self.proc, sigint_grace=sigint_grace)

    def log(self, lines: int = 20) -> str:
        return tail(self.log_path, lines)


class ProcessGroupLauncher:
    """Starts node scripts and launch files against one master, and stops them all.

    ``node()`` and ``launch()`` return only once every node they start is
    registered with the master, or raise with the tail of the log.
    """

    def __init__(self, env: Dict[str, str], workdir: str, wrap: Callable[[List[str]], List[str]] = list,
                 run_in: Callable[[Callable[[], T]], T] = lambda fn: fn()) -> None:
        """On another host (``temoto_core/hosts.py``): ``wrap`` turns a command line into one run there, and
        ``run_in`` runs a call to the master from there."""
        self.env = env
        self.workdir = workdir
        self._wrap = wrap
        self._run_in = run_in
        self.processes: List[LoggedChild] = []
        self._private_params: List[str] = []     # set through a node's command line; removed by stop_all
        self._rospack = None

    # -- lookup -------------------------------------------------------------------------------
    def find_executable(self, package: str, executable: str) -> str:
        import rospkg               # lazy: ROS's package crawler, only for a launcher that starts something
        import roslib.packages
        if self._rospack is None:
            self._rospack = rospkg.RosPack(rospkg.get_ros_paths(self.env))
        found = roslib.packages.find_node(package, executable, self._rospack)
        if not found:
            raise FileNotFoundError('no executable %r in package %r' % (executable, package))
        return found[0]

    def _argv_for(self, path: str) -> List[str]:
        # Python node scripts run under this interpreter (the venv) whatever their shebang resolves to.
        with open(path, 'rb') as f:
            first = f.readline()
        return [sys.executable, path] if b'python' in first else [path]

    # -- start --------------------------------------------------------------------------------
    def command(self, argv: Sequence[str], name: str, env: Optional[Dict[str, str]] = None) -> LoggedChild:
        """Any command, tracked and stopped like a node (no registration wait)."""
        log = os.path.join(self.workdir, '%s.%d.log' % (name, len(self.processes)))
        proc = LoggedChild(self._wrap(list(argv)), env or self.env, log, name)
        self.processes.append(proc)
        return proc

    def node(self, package: str, executable: str, args: Sequence[str] = (), name: Optional[str] = None,
             namespace: str = '', params: Optional[Dict[str, object]] = None, wait: bool = True,
             timeout: float = REGISTER_TIMEOUT) -> LoggedChild:
        name = name or executable
        argv = self._argv_for(self.find_executable(package, executable)) + list(args) + ['__name:=' + name]
        if namespace:
            argv.append('__ns:=' + namespace)
        for key, value in (params or {}).items():
            argv.append('_%s:=%s' % (key, value))
        full = '/' + '/'.join(p for p in (namespace.strip('/'), name) if p)
        # a dead node of this name would pass the registration wait at once, and the master would send its
        # shutdown to whoever has the dead node's port now
        self._run_in(lambda: cleanup_dead_node(self.env['ROS_MASTER_URI'], full))
        self._private_params += ['%s/%s' % (full, key) for key in (params or {})]
        proc = self.command(argv, name)
        if wait:
            self.wait_registered(proc, [full], timeout)
        return proc

    def launch(self, package: str, launch_file: str, args: Sequence[str] = (), wait: bool = True,
               timeout: float = REGISTER_TIMEOUT) -> LoggedChild:
        import rospkg
        import roslaunch.config     # lazy: roslaunch's loader takes ~0.2 s to import
        path = os.path.join(rospkg.RosPack(rospkg.get_ros_paths(self.env)).get_path(package), 'launch', launch_file)
        proc = self.command(['roslaunch', '--wait', path] + list(args), os.path.splitext(launch_file)[0])
        if wait:
            config = roslaunch.config.load_config_default([(path, list(args))], None)
            names = [n.namespace.rstrip('/') + '/' + n.name for n in config.nodes]
            self.wait_registered(proc, names, timeout)
        return proc

    def wait_registered(self, proc: LoggedChild, node_names: Sequence[str], timeout: float) -> None:
        self._run_in(lambda: self._wait_registered(proc, node_names, timeout))

    def _wait_registered(self, proc: LoggedChild, node_names: Sequence[str], timeout: float) -> None:
        master = xmlrpc.client.ServerProxy(self.env['ROS_MASTER_URI'])
        pending = set(node_names)
        deadline = time.monotonic() + timeout
        while pending:
            if not proc.alive():
                raise RuntimeError('%s exited (rc %s) before %s registered; log:\n%s'
                                   % (proc.name, proc.returncode, sorted(pending), proc.log()))
            if time.monotonic() > deadline:
                raise TimeoutError('%s: %s not registered after %.0f s; log:\n%s'
                                   % (proc.name, sorted(pending), timeout, proc.log()))
            for n in list(pending):
                code, _msg, uri = master.lookupNode('/temoto_test', n)
                if code == 1 and _started_by(node_pid(uri, 1.0), proc.pid):
                    pending.discard(n)
            if pending:
                time.sleep(0.02)

    # -- stop ---------------------------------------------------------------------------------
    def stop_all(self) -> None:
        """Stop every process, then remove the private parameters given on their command lines: they
        outlive a node on the master, and the next node of that name (another test's) would inherit them."""
        for proc in reversed(self.processes):
            proc.stop()
        self.processes.clear()
        self._run_in(self._delete_private_params)

    def _delete_private_params(self) -> None:
        master = xmlrpc.client.ServerProxy(self.env['ROS_MASTER_URI'])
        for name in self._private_params:
            try:
                master.deleteParam('/temoto_test', name)     # a missing one is answered with an error code
            except OSError:                                  # the master is gone already: nothing to clean
                break
        self._private_params.clear()


def _started_by(pid: Optional[int], root: int, depth: int = 6) -> bool:
    """Whether ``pid`` (a node's, from its XML-RPC API) is ``root`` or one of its descendants. A registration
    the master still has from a dead node of the same name answers with no pid, or with another process's
    (its port reused): counting it as this start let a test go on before its node was up, and the master's
    shutdown for the old registration then reached whichever node had taken the dead one's port (a site
    LIDAR driver shut down as '/vaultbot_sim', in a suite run)."""
    for _ in range(depth):
        if not pid or pid <= 1:
            return False
        if pid == root:
            return True
        pid = parent_pid(pid)
    return False


def leftover_processes(token: str, exclude: Sequence[int] = ()) -> List[Tuple[int, str]]:
    """Processes (any depth) whose environment carries ``SESSION_ENV=token``."""
    return processes_with_env(SESSION_ENV, token, exclude)


def processes_with_env(name: str, value: str, exclude: Sequence[int] = ()) -> List[Tuple[int, str]]:
    """Every process but this one (and ``exclude``) that started with ``name=value`` in its environment:
    (pid, command line). The environment a process started with stays in /proc whatever it does, and a
    process forked without exec (from a zygote) shows its parent's."""
    marker = ('%s=%s' % (name, value)).encode()
    skip = {os.getpid(), *exclude}
    found = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit() or int(entry) in skip:
            continue
        try:
            with open('/proc/%s/environ' % entry, 'rb') as f:
                if marker not in f.read().split(b'\0'):
                    continue
            with open('/proc/%s/cmdline' % entry, 'rb') as f:
                cmd = f.read().replace(b'\0', b' ').decode('utf-8', 'replace').strip()
        except OSError:
            continue
        found.append((int(entry), cmd))
    return found


def kill_leftovers(token: str, exclude: Sequence[int] = ()) -> List[Tuple[int, str]]:
    """SIGKILL every leftover of ``token`` and return what was found."""
    found = leftover_processes(token, exclude)
    for pid, _ in found:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return found
