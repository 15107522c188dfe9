"""Reading a latched topic's last message, telling "nobody publishes it" from "it is slow to arrive".

``rospy.wait_for_message`` has one timeout for both. A short one fails a busy machine, where registering at
the master and connecting to the publisher can take seconds (a CI run saw the pointer's goal miss a 2 s
bound); a long one makes the user wait that long to hear that the publisher is not running at all. Here the
master is asked after ``absent_after``: no publisher there ends the wait at once; a known publisher gets
until ``timeout`` to deliver.
"""
import threading
import time
from typing import Any, Type

import rosgraph
import rospy

CHECK_PERIOD_S = 0.05


class NoPublisher(LookupError):
    """Nothing publishes the topic at the master."""


def _published(name: str) -> bool:
    try:
        return any(t == name for t, _ in rosgraph.Master(rospy.get_name()).getPublishedTopics(''))
    except (rosgraph.MasterException, OSError):
        return True                      # the master did not answer: do not conclude "nobody"


def latched_message(topic: str, msg_type: Type[Any], timeout: float, absent_after: float = 1.0) -> Any:
    """The message a latched ``topic`` holds.

    Raises ``NoPublisher`` when, after ``absent_after`` seconds with no message, the master knows no
    publisher of it; ``TimeoutError`` when a publisher is known but delivers nothing within ``timeout``.
    """
    name = rospy.resolve_name(topic)
    got: list = []
    arrived = threading.Event()

    def keep(msg) -> None:
        if not got:
            got.append(msg)
            arrived.set()

    sub = rospy.Subscriber(name, msg_type, keep, queue_size=1)
    try:
        start = time.monotonic()
        asked_master = False
        while not arrived.wait(CHECK_PERIOD_S):
            waited = time.monotonic() - start
            if not asked_master and waited >= absent_after:
                asked_master = True
                if sub.get_num_connections() == 0 and not _published(name):
                    raise NoPublisher('nothing publishes %s' % name)
            if waited >= timeout:
                raise TimeoutError('%s is published, but its message did not arrive within %.0f s'
                                   % (name, timeout))
        return got[0]
    finally:
        sub.unregister()
