"""A private roscore on a free loopback port (the demo's and the tests'), and master queries."""
import os
import socket
import subprocess
import tempfile
import time
import xmlrpc.client
from typing import Callable, Dict, List, Optional, TypeVar

from temoto_core.processes import SESSION_ENV, stop_process_group

ROSCORE_START_TIMEOUT = 10.0
T = TypeVar('T')


def free_port() -> int:
    """A TCP port that is free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def master_proxy(uri: str) -> xmlrpc.client.ServerProxy:
    return xmlrpc.client.ServerProxy(uri)


ROS_VARS = ('ROS_MASTER_URI', 'ROS_HOSTNAME', 'ROS_IP', 'ROS_LOG_DIR', 'ROS_HOME')


class RosMaster:
    """``roscore -p PORT`` in its own session, with logs kept in ``workdir``.

    A port held by a socket that is not ROS makes roscore hang rather than
    fail, so startup has a timeout and :meth:`start` retries on another port.
    """

    def __init__(self, workdir: Optional[str] = None, session_token: str = '', address: str = '127.0.0.1',
                 port: int = 0, wrap: Callable[[List[str]], List[str]] = list,
                 run_in: Callable[[Callable[[], T]], T] = lambda fn: fn()) -> None:
        """By default on a free loopback port. On another host (``temoto_core/hosts.py``): its ``address``, a
        fixed ``port``, ``wrap`` turning roscore's command line into one run there, and ``run_in`` running a
        check of the master from there."""
        self.workdir = workdir or tempfile.mkdtemp(prefix='temoto_roscore_')
        self.session_token = session_token
        self.address = address
        self.fixed_port = port
        self.port = port
        self._wrap = wrap
        self._run_in = run_in
        self.proc: Optional[subprocess.Popen] = None

    @property
    def uri(self) -> str:
        return 'http://%s:%d' % (self.address, self.port)

    @property
    def env(self) -> Dict[str, str]:
        """Environment for processes that should talk to this master."""
        env = dict(os.environ)
        env.update({
            'ROS_MASTER_URI': self.uri,
            'ROS_HOSTNAME': self.address,
            'ROS_IP': self.address,
            'ROS_LOG_DIR': os.path.join(self.workdir, 'log'),
            'ROS_HOME': os.path.join(self.workdir, 'home'),
            'PYTHONUNBUFFERED': '1',
            # a Python child that hangs is stopped at last with SIGABRT (stop_process_group): this
            # makes it write every thread's stack to its log first
            'PYTHONFAULTHANDLER': '1',
        })
        if self.session_token:
            env[SESSION_ENV] = self.session_token
        return env

    def point_this_process(self) -> Dict[str, Optional[str]]:
        """Make this process (its rospy, and children started with os.environ) use this master.

        Returns the values it replaced, so that a caller can put them back.
        """
        saved = {k: os.environ.get(k) for k in ROS_VARS}
        env = self.env
        for k in ROS_VARS:
            os.environ[k] = env[k]
        return saved

    @staticmethod
    def restore_process(saved: Dict[str, Optional[str]]) -> None:
        """Put back what :meth:`point_this_process` replaced."""
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value

    def start(self, attempts: int = 3) -> 'RosMaster':
        errors = []
        for _ in range(attempts):
            self.port = self.fixed_port or free_port()
            log = open(os.path.join(self.workdir, 'roscore_%d.log' % self.port), 'wb')
            self.proc = subprocess.Popen(self._wrap(['roscore', '-p', str(self.port)]), env=self.env,
                                         stdin=subprocess.DEVNULL,
                                         stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            log.close()
            if self._run_in(lambda: self._wait_ready(ROSCORE_START_TIMEOUT)):
                return self
            errors.append('port %d: roscore not ready after %.0f s (rc=%s)'
                          % (self.port, ROSCORE_START_TIMEOUT, self.proc.poll()))
            self.stop()
        raise RuntimeError('could not start roscore: ' + '; '.join(errors))

    def _wait_ready(self, timeout: float) -> bool:
        """Ready means the master answers and /rosout is registered."""
        proxy = master_proxy(self.uri)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                return False
            try:
                code, _, state = proxy.getSystemState('/temoto_test')
                if code == 1 and any('/rosout' in nodes for _, nodes in state[0]):
                    return True
            except OSError:
                pass
            time.sleep(0.02)
        return False

    def is_registered(self, node_name: str) -> bool:
        code, _, _ = master_proxy(self.uri).lookupNode('/temoto_test', node_name)
        return code == 1

    def stop(self) -> None:
        if self.proc is not None:
            stop_process_group(self.proc, sigint_grace=3.0, sigterm_grace=2.0)
            self.proc = None


def connected(master_uri: str, publisher_node: str, subscriber_node: str, topic: str) -> bool:
    """True once ``publisher_node`` has a live connection to ``subscriber_node`` on ``topic``.

    Registration at the master happens before the TCP connection exists; a test
    that needs the data to flow waits on this (the publisher's ``getBusInfo``).
    """
    code, _, uri = master_proxy(master_uri).lookupNode('/temoto_test', publisher_node)
    if code != 1:
        return False
    try:
        code, _, info = xmlrpc.client.ServerProxy(uri).getBusInfo('/temoto_test')
    except OSError:
        return False
    # rows: [connection_id, destination, direction, transport, topic, connected, ...]
    return code == 1 and any(row[1] == subscriber_node and row[4] == topic and (len(row) < 6 or row[5])
                             for row in info)
