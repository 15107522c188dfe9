"""Recording the failover topic set: the stream relay plus Debian's C++ bag recorder.

The C++ recorder (``/usr/lib/rosbag/record``) exits 0 on SIGINT with a closed bag; the Python
``rosbag record`` wrapper leaves a closed bag too but exits 1. Topics are given as anchored
regular expressions, so the status topics of registrars that appear during the run (the action's
manager interfaces) are recorded too; the relay announces the fixed ones so they are subscribed
before anything happens (see :mod:`relay`).
"""
from __future__ import annotations

import os
import sys
import xmlrpc.client
from typing import Dict, List, Optional

from temoto_core.processes import LoggedChild, stop_process_group
from temoto_core.wait import wait_for

from . import topics as T
from .bagfile import make_inert

RECORDER = '/usr/lib/rosbag/record'
RECORDER_NODE = '/temoto_demo_record'
RELAY_NODE = '/temoto_demo_relay'


def _subscribed_topics(master_uri: str, node: str) -> set:
    _, _, state = xmlrpc.client.ServerProxy(master_uri).getSystemState('/temoto_demo')
    return {topic for topic, nodes in state[1] if node in nodes}


def _registered(master_uri: str, node: str) -> bool:
    return xmlrpc.client.ServerProxy(master_uri).lookupNode('/temoto_demo', node)[0] == 1


class Recording:
    """Start with :meth:`start`; :meth:`stop` returns the closed bag's path."""

    def __init__(self, bag_path: str, env: Dict[str, str], namespace: str = T.DEFAULT_NS,
                 log_dir: Optional[str] = None, streams: Optional[List[str]] = None, robot: str = '',
                 extra: Optional[List[str]] = None) -> None:
        """``robot``: the ROS namespace the robot (its simulation) runs in; '' for the root. ``extra``: more
        topics recorded by name, whenever they exist (the recorder looks for new ones every second)."""
        self.bag_path = os.path.abspath(bag_path)
        self.env = env
        self.namespace = namespace
        self.robot = robot
        self.log_dir = log_dir or os.path.dirname(self.bag_path)
        self.streams = list(streams if streams is not None else T.DEFAULT_STREAMS)
        self.extra = list(extra or [])
        self.relay: Optional[LoggedChild] = None
        self.recorder: Optional[LoggedChild] = None

    @property
    def pids(self) -> List[int]:
        return [p.pid for p in (self.relay, self.recorder) if p is not None]

    def start(self, timeout: float = 15.0) -> 'Recording':
        os.makedirs(self.log_dir, exist_ok=True)
        master = self.env['ROS_MASTER_URI']
        self.relay = LoggedChild([sys.executable, '-m', 'temoto_demo.relay',
                                     '__name:=' + RELAY_NODE.lstrip('/'), '_temoto_namespace:=' + self.namespace,
                                     '_robot:=' + (self.robot or '/'),
                                     '_streams:=' + ','.join(self.streams)],
                                    self.env, os.path.join(self.log_dir, 'relay.log'), 'relay')
        # what the relay announces (the sim's /tf topics are recorded whenever they exist)
        wanted = {t for t in T.fixed_topics(self.namespace, self.robot) if t not in ('/tf', '/tf_static')}
        wanted |= {T.STREAMS_PREFIX + t for t in T.STREAM_TYPES}

        def relay_ready():
            if not self.relay.alive():
                raise RuntimeError('the stream relay exited early:\n' + self.relay.log())
            return _registered(master, RELAY_NODE)

        wait_for(relay_ready, timeout, 'the stream relay to register')
        argv = [RECORDER, '-O', self.bag_path, '--lz4', '-e'] + \
            T.record_regexes(self.namespace, self.robot, self.extra) + ['__name:=' + RECORDER_NODE.lstrip('/')]
        self.recorder = LoggedChild(argv, self.env, os.path.join(self.log_dir, 'record.log'), 'record')

        def recorder_ready():
            if not self.recorder.alive():
                raise RuntimeError('the bag recorder exited early:\n' + self.recorder.log())
            return wanted <= _subscribed_topics(master, RECORDER_NODE)

        # The recorder polls the master once a second, so this takes up to ~1 s.
        wait_for(recorder_ready, timeout, 'the bag recorder to subscribe to %s' % sorted(wanted))
        return self

    def stop(self) -> str:
        """Stop the recorder first (it closes the bag), then the relay; then give the bag's inputs inert
        names, so that playing it cannot act on a live stack."""
        rc = None
        if self.recorder is not None:
            rc = stop_process_group(self.recorder.proc, sigint_grace=10.0)
            self.recorder = None
        if self.relay is not None:
            stop_process_group(self.relay.proc, sigint_grace=3.0)
            self.relay = None
        if not os.path.exists(self.bag_path):
            raise RuntimeError('no bag was written at %s (recorder rc %s)' % (self.bag_path, rc))
        make_inert(self.bag_path, self.namespace)
        return self.bag_path
