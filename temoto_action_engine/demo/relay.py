"""The stream relay: exact frame timing of the displayed sensor streams, at a few bytes per frame.

A bag of the raw streams would be hundreds of MB (the D435 cloud is ~1.6 MB at 30 Hz). The report
needs two things from them: *when* each frame arrived (for the timeline and the display gap) and a
sample of the data (for replay). So for every message on a displayed topic this node publishes a
``std_msgs/Header`` tick (``frame_id`` = the source topic, ``stamp`` = arrival time), and it
republishes the message itself under ``/temoto_demo/throttled/<topic>`` at a low rate.
Messages are taken as ``rospy.AnyMsg`` and only the throttled ones are deserialised.

It also *announces* the recorded topics that may not exist yet (the RViz host's display events
appear only when the Output Manager starts it): a publisher that never publishes makes the topic
known to the master, so a recorder subscribes at once instead of at its next 1 s master poll and
misses no early event.

Run: ``python -m temoto_action_engine.demo.relay _temoto_namespace:=temoto``.
"""
from __future__ import annotations

import threading
import time
from typing import Dict, Iterable, Optional

from . import topics as T


class StreamRelay:
    def __init__(self, namespace: str = T.DEFAULT_NS, streams: Iterable[str] = T.DEFAULT_STREAMS,
                 follow_displays: bool = True, announce: bool = True) -> None:
        import rospy
        from std_msgs.msg import Header
        self._rospy = rospy
        self._lock = threading.Lock()
        self._subs: Dict[str, object] = {}
        self._throttled: Dict[str, object] = {}
        self._last_sample: Dict[str, float] = {}
        self._classes: Dict[str, object] = {}
        self._ticks = rospy.Publisher(T.TICKS, Header, queue_size=500, tcp_nodelay=True)
        self._announced = []
        if announce:
            from roslib.message import get_message_class
            for topic, type_name in T.fixed_topics(namespace).items():
                if topic == T.TICKS:
                    continue
                cls = get_message_class(type_name)
                if cls is not None:
                    self._announced.append(rospy.Publisher(topic, cls, queue_size=1))
        for s in streams:
            self.watch(s)
        if follow_displays:
            from temoto_output_manager.msg import DisplayEvent
            self._events = rospy.Subscriber(T.display_events(namespace), DisplayEvent, self._on_display_event,
                                            queue_size=100)

    def watch(self, topic: str) -> None:
        """Tick and sample ``topic`` from now on (idempotent)."""
        topic = '/' + topic.strip('/')
        with self._lock:
            if topic in self._subs or topic.startswith(T.DEMO_NS + '/'):
                return
            self._subs[topic] = self._rospy.Subscriber(topic, self._rospy.AnyMsg, self._on_message, callback_args=topic,
                                                       queue_size=5, tcp_nodelay=True, buff_size=1 << 22)

    def _on_display_event(self, ev) -> None:
        if ev.topic:
            self.watch(ev.topic)

    def _on_message(self, msg, topic: str) -> None:
        now = time.time()
        from std_msgs.msg import Header
        tick = Header(frame_id=topic)
        tick.stamp = self._rospy.Time.from_sec(now)
        self._ticks.publish(tick)
        type_name = (getattr(msg, '_connection_header', None) or {}).get('type', '')
        period = 1.0 / T.THROTTLE_HZ.get(type_name, T.DEFAULT_THROTTLE_HZ)
        if now - self._last_sample.get(topic, 0.0) < period:
            return
        cls = self._message_class(type_name)
        if cls is None:
            return
        self._last_sample[topic] = now
        full = cls()
        full.deserialize(msg._buff)
        pub = self._throttled.get(topic)
        if pub is None:
            pub = self._throttled[topic] = self._rospy.Publisher(T.THROTTLED_PREFIX + topic, cls, queue_size=2)
        pub.publish(full)

    def _message_class(self, type_name: str) -> Optional[object]:
        if type_name not in self._classes:
            from roslib.message import get_message_class
            try:
                self._classes[type_name] = get_message_class(type_name) if type_name else None
            except Exception:
                self._classes[type_name] = None
        return self._classes[type_name]


def main() -> None:
    import rospy
    from temoto_core.node import init_node, spin
    init_node('temoto_demo_relay')
    ns = str(rospy.get_param('~temoto_namespace', T.DEFAULT_NS))
    streams = rospy.get_param('~streams', T.DEFAULT_STREAMS)
    if isinstance(streams, str):
        streams = [s for s in streams.split(',') if s.strip()]
    StreamRelay(ns, streams)
    spin()


if __name__ == '__main__':
    main()
