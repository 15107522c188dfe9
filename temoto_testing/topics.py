"""A test's record of a topic: every message with its arrival time (the ``collect`` fixture makes them)."""
import threading
import time


class TopicLog:
    """Messages of one topic with their arrival times (monotonic), as a test's subscriber hears them."""

    def __init__(self, rospy, topic: str, msg_type) -> None:
        self.msgs, self.times = [], []
        self.lock = threading.Lock()
        self.sub = rospy.Subscriber(topic, msg_type, self._cb, queue_size=100, buff_size=2 ** 24,
                                    tcp_nodelay=True)

    def _cb(self, msg):
        with self.lock:
            self.msgs.append(msg)
            self.times.append(time.monotonic())

    def count_after(self, t):
        with self.lock:
            return sum(1 for x in self.times if x > t)

    def rate(self, window):
        """Messages per second over the last `window` seconds."""
        now = time.monotonic()
        return self.count_after(now - window) / window

    def last(self):
        with self.lock:
            return self.msgs[-1] if self.msgs else None

    def close(self):
        self.sub.unregister()
