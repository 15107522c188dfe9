"""Status channels: the topics on which an owner tells each consumer what happened to its resource.

A consumer names its status topic in every request. rospy drops what a new
publisher sends before its first subscriber connects, so a channel is connected
(bounded wait) before a consumer is attached to anything, and a FAILED raised the
moment after finds someone to go to. Channels are counted, so the publisher of a
consumer that has gone (an action that ended) is unregistered after a grace
instead of kept for the life of the manager.

A new channel needs the master. rospy registers a new publisher in a loop that lasts until the master
answers, under its topic manager's lock: a channel made while the master is away (the robot's reboot, a
cut link to the robot that runs it) held its load until its caller's deadline, with a reason that did not
name the master, and it held every other status of this registrar behind it. So a load asks the master
first (a TCP connect, 0.2 s at most) and is refused at once, naming the master, when it does not answer;
and no channel is ever made under the lock that sending a status takes.
"""
import threading
import time
from typing import Dict, List, Optional

import rospy

from temoto_core.master_reach import MasterReach
from temoto_core.msg import ResourceStatus

# An unused status channel is unregistered after this long: long enough for a consumer that comes back at
# once (a reload, the next step of a loop) to find it still connected, short enough that the channels of
# ended actions do not pile up.
CHANNEL_GRACE = 5.0


class MasterAway(Exception):
    """A new status channel could not be registered: the master does not answer."""


class StatusChannels:
    def __init__(self, prefix: str, connect_timeout: float, master_reach: Optional[MasterReach] = None) -> None:
        self._prefix = prefix
        self._connect_timeout = connect_timeout
        self._lock = threading.Lock()
        self._publishers: Dict[str, rospy.Publisher] = {}
        self._making: Dict[str, threading.Event] = {}     # status topic -> set once its publisher is made
        self._master_reach = master_reach
        self._users: Dict[str, int] = {}     # status topic -> consumers (and loads in flight) using it
        self._idle: Dict[str, float] = {}    # status topic -> when its last user left

    def publisher(self, topic: str) -> rospy.Publisher:
        """The channel's publisher (``status_pipeline.announce`` publishes on it), made by one thread while the
        others wait for it. It is made outside the lock: rospy may hold the making thread until the master
        answers, and a status on another channel must not wait for that."""
        while True:
            with self._lock:
                pub = self._publishers.get(topic)
                if pub is not None:
                    return pub
                making = self._making.get(topic)
                if making is None:
                    making = self._making[topic] = threading.Event()
                    break
            making.wait()                     # made by another thread now; looked up again (it may have failed)
        try:
            pub = rospy.Publisher(topic, ResourceStatus, queue_size=1000, tcp_nodelay=True)
            with self._lock:
                self._publishers[topic] = pub
            return pub
        finally:
            with self._lock:
                del self._making[topic]
            making.set()

    def acquire(self, topic: str, master_needed: bool = False) -> None:
        """Count one more user of a consumer's status channel and make sure it is connected.

        The first request from a consumer waits (bounded) for the connection; later
        requests find it open. ``master_needed``: a channel not open yet is refused with
        :class:`MasterAway`, naming the master, when the master does not answer now.
        """
        if master_needed and topic and self._master_reach is not None:
            with self._lock:
                opened = topic in self._publishers
            if not opened and not self._master_reach.probe():
                raise MasterAway('the master at %s:%d does not answer, so the status channel %s cannot be '
                                 'registered and no status would reach this consumer'
                                 % (self._master_reach.address + (topic,)))
        self.acquire_all([topic])

    def acquire_all(self, topics: List[str]) -> None:
        """:meth:`acquire` for several channels, connected together (a restarted registrar has many)."""
        topics = [t for t in topics if t]
        with self._lock:
            for topic in topics:
                self._users[topic] = self._users.get(topic, 0) + 1
                self._idle.pop(topic, None)
        pubs = {topic: self.publisher(topic) for topic in topics}
        deadline = time.monotonic() + self._connect_timeout
        delay = 0.0005
        while any(p.get_num_connections() == 0 for p in pubs.values()) and time.monotonic() < deadline:
            time.sleep(delay)
            delay = min(delay * 2, 0.02)
        for topic, pub in pubs.items():
            if pub.get_num_connections() == 0:
                rospy.logwarn('%s: no subscriber on status topic %s yet; statuses may be lost', self._prefix, topic)

    def release(self, topic: str) -> None:
        """One user fewer; an unused channel is unregistered by ``reap_idle`` after a grace period
        (long enough for a last status queued on it to go out)."""
        if not topic:
            return
        with self._lock:
            users = self._users.get(topic, 0) - 1
            if users > 0:
                self._users[topic] = users
                return
            self._users.pop(topic, None)
            self._idle[topic] = time.monotonic()

    def reap_idle(self, grace: float) -> None:
        now = time.monotonic()
        with self._lock:
            pubs: List[rospy.Publisher] = []
            for topic in [t for t, since in self._idle.items() if now - since >= grace]:
                del self._idle[topic]
                pub = self._publishers.pop(topic, None)
                if pub is not None:
                    pubs.append(pub)
        for pub in pubs:
            pub.unregister()

    def close(self) -> None:
        with self._lock:
            for pub in self._publishers.values():
                pub.unregister()
            self._publishers.clear()
