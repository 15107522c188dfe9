"""The stream relay: exact frame timing of the displayed sensor streams, and the streams themselves.

For every message on a displayed topic this node publishes a ``std_msgs/Header`` tick
(``frame_id`` = the source topic, ``stamp`` = arrival time), which the report's timeline and display
gaps come from, and republishes the message under ``/temoto_demo/streams/<topic>`` for the bag:
scans and small clouds (the stitched LIDAR cloud) at full rate, a large cloud (the D435's, 1.6 MB
at 30 Hz) at 5 Hz with every second point in both directions, anything else at 5 Hz. Messages are
taken as ``rospy.AnyMsg`` and only the recorded ones are deserialised. It also publishes, latched,
the robot description the views were drawn with, so that ``temoto replay`` can draw the robot.

It *announces* the recorded topics that may not exist yet (the RViz host's display events appear
only when the Output Manager starts it; a stream only when its driver runs): a publisher that never
publishes makes the topic known to the master, so a recorder subscribes at once instead of at its
next 1 s master poll and misses nothing early.

Run: ``python -m temoto_demo.relay _temoto_namespace:=temoto``.
"""
from __future__ import annotations

import threading
import time
from typing import Dict, Iterable, Optional

import numpy as np
import rospy
from roslib.message import get_message_class
from std_msgs.msg import Header, String

from temoto_core import params, rospy_internals
from temoto_core.node import init_node, spin
from temoto_output_manager.msg import DisplayEvent

from . import topics as T

NOT_ANNOUNCED = ('/tf', '/tf_static', T.TICKS, T.ROBOT_DESCRIPTION)   # published by others, or by us for real
ROBOT_DESCRIPTION_WAIT_S = 60.0


def decimate_cloud(cloud, step: int) -> None:
    """Keep every ``step``-th point of a PointCloud2 in both directions (in place)."""
    point_step = cloud.point_step
    data = np.frombuffer(cloud.data, np.uint8)
    if cloud.height > 1:
        grid = data.reshape(cloud.height, cloud.row_step)[:, :cloud.width * point_step]
        kept = grid.reshape(cloud.height, cloud.width, point_step)[::step, ::step]
        cloud.height, cloud.width = kept.shape[0], kept.shape[1]
    else:
        kept = data[:cloud.width * point_step].reshape(cloud.width, point_step)[::step * step]
        cloud.width = kept.shape[0]
    cloud.row_step = cloud.width * point_step
    cloud.data = kept.tobytes()


class StreamRelay:
    def __init__(self, namespace: str = T.DEFAULT_NS, streams: Iterable[str] = T.DEFAULT_STREAMS,
                 follow_displays: bool = True, announce: bool = True, robot: str = '') -> None:
        self._lock = threading.Lock()
        self._subs: Dict[str, object] = {}
        self._recorded: Dict[str, object] = {}
        self._last_sample: Dict[str, float] = {}
        self._classes: Dict[str, object] = {}
        self._ticks = rospy.Publisher(T.TICKS, Header, queue_size=500, tcp_nodelay=True)
        self._announced = []
        if announce:
            for topic, type_name in T.fixed_topics(namespace, robot).items():
                cls = get_message_class(type_name)
                if cls is not None and topic not in NOT_ANNOUNCED:
                    self._announced.append(rospy.Publisher(topic, cls, queue_size=1))
            for topic, type_name in T.STREAM_TYPES.items():
                self._recorder_for(topic, get_message_class(type_name))
        self._robot_description = T.robot_description(robot)
        threading.Thread(target=self._publish_robot_description, daemon=True,
                         name='relay-robot-description').start()
        for s in streams:
            self.watch(s)
        if follow_displays:
            self._events = rospy.Subscriber(T.display_events(namespace), DisplayEvent, self._on_display_event,
                                            queue_size=100)

    def watch(self, topic: str) -> None:
        """Tick and record ``topic`` from now on (idempotent)."""
        topic = '/' + topic.strip('/')
        with self._lock:
            if topic in self._subs or topic.startswith(T.DEMO_NS + '/'):
                return
            self._subs[topic] = rospy.Subscriber(topic, rospy.AnyMsg, self._on_message, callback_args=topic,
                                                       queue_size=5, tcp_nodelay=True, buff_size=1 << 22)

    def _on_display_event(self, ev) -> None:
        if ev.topic:
            self.watch(ev.topic)

    def _recorder_for(self, topic: str, cls):
        with self._lock:
            pub = self._recorded.get(topic)
            if pub is None and cls is not None:
                pub = self._recorded[topic] = rospy.Publisher(T.STREAMS_PREFIX + topic, cls, queue_size=50)
            return pub

    def _on_message(self, msg, topic: str) -> None:
        now = time.time()
        tick = Header(frame_id=topic)
        tick.stamp = rospy.Time.from_sec(now)
        self._ticks.publish(tick)
        type_name = rospy_internals.connection_header(msg).get('type', '')
        big_cloud = type_name == 'sensor_msgs/PointCloud2' and len(msg._buff) > T.BIG_CLOUD_BYTES
        if big_cloud:
            rate = T.BIG_CLOUD_HZ
        elif type_name in ('sensor_msgs/LaserScan', 'sensor_msgs/PointCloud2'):
            rate = 0.0                                  # every message: a few kB each
        else:
            rate = T.OTHER_HZ
        if rate and now - self._last_sample.get(topic, 0.0) < 1.0 / rate:
            return
        cls = self._message_class(type_name)
        if cls is None:
            return
        self._last_sample[topic] = now
        full = cls()
        full.deserialize(msg._buff)
        if big_cloud:
            decimate_cloud(full, T.DECIMATE)
        self._recorder_for(topic, cls).publish(full)

    def _publish_robot_description(self) -> None:
        pub = rospy.Publisher(T.ROBOT_DESCRIPTION, String, queue_size=1, latch=True)
        deadline = time.monotonic() + ROBOT_DESCRIPTION_WAIT_S
        while not rospy.is_shutdown() and time.monotonic() < deadline:
            urdf = rospy.get_param(self._robot_description, '')
            if urdf:
                pub.publish(String(data=urdf))
                return
            time.sleep(0.5)        # the simulation sets it when it starts; polled, bounded

    def _message_class(self, type_name: str) -> Optional[object]:
        if type_name not in self._classes:
            try:
                self._classes[type_name] = get_message_class(type_name) if type_name else None
            except Exception:
                self._classes[type_name] = None
        return self._classes[type_name]


def main() -> None:
    init_node('temoto_demo_relay')
    ns = params.text('temoto_namespace', T.DEFAULT_NS, empty=False)
    streams = params.strings('streams', T.DEFAULT_STREAMS)
    robot = params.text('robot', '').strip('/')      # where the robot's simulation runs
    StreamRelay(ns, streams, robot=robot)
    spin()


if __name__ == '__main__':
    main()
