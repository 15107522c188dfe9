"""Recording a bag during a test with Debian's C++ recorder."""
import os
import subprocess
import xmlrpc.client
from typing import Dict, Optional, Sequence

from temoto_core.processes import LoggedChild, stop_process_group
from temoto_core.wait import wait_for

# The C++ recorder exits 0 on SIGINT; the Python `rosbag record` wrapper leaves
# a correctly closed bag too but exits 1 with a traceback.
RECORDER = '/usr/lib/rosbag/record'


class BagRecorder:
    """``record -O path topics...``; :meth:`start` returns once it subscribes to every topic."""

    def __init__(self, path: str, topics: Sequence[str], env: Dict[str, str], node_name: str = 'temoto_test_bag') -> None:
        self.path = path
        self.topics = list(topics)
        self.env = env
        self.node_name = '/' + node_name.lstrip('/')
        self.process: Optional[LoggedChild] = None

    def start(self, timeout: float = 15.0) -> 'BagRecorder':
        argv = [RECORDER, '-O', self.path, '__name:=' + self.node_name.lstrip('/')] + self.topics
        self.process = LoggedChild(argv, self.env, self.path + '.log', 'rosbag_record')
        wait_for(self._subscribed, timeout, 'the bag recorder to subscribe to %s' % self.topics)
        return self

    def _subscribed(self) -> bool:
        if not self.process.alive():
            raise RuntimeError('rosbag record exited early:\n' + self.process.log())
        master = xmlrpc.client.ServerProxy(self.env['ROS_MASTER_URI'])
        _, _, state = master.getSystemState('/temoto_test')
        subscribed = {topic for topic, nodes in state[1] if self.node_name in nodes}
        return all(t in subscribed for t in self.topics)

    def stop(self) -> str:
        """Stop recording; the bag is closed (no ``.active`` file) when this returns."""
        if self.process is not None:
            rc = stop_process_group(self.process.proc, sigint_grace=10.0)
            self.process = None
            if rc not in (0, None) and not os.path.exists(self.path):
                raise RuntimeError('rosbag record failed (rc %s)' % rc)
        if not os.path.exists(self.path):
            raise RuntimeError('no bag was written at %s' % self.path)
        return self.path
