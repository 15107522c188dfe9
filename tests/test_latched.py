"""``temoto_core.latched.latched_message`` across processes: a latched topic's message from a publisher in
another process, an absent publisher told at once, and a slow one (SIGSTOPped) waited for rather than taken
for absent."""
import os
import signal
import threading
import time

import pytest
import rosgraph
from std_msgs.msg import String

from temoto_core.latched import NoPublisher, latched_message
from temoto_testing import wait_for
from temoto_testing.signals import stop

TOPIC = '/latched_test/word'
HANG = 30.0
STALL_S = 3.0       # longer than the 2 s bound that failed a busy CI run


def _publisher(procs, word):
    child = procs.command(['rostopic', 'pub', '--latch', TOPIC, 'std_msgs/String', 'data: %s' % word], 'latched')
    master = rosgraph.Master('/latched_test')
    wait_for(lambda: any(t == TOPIC for t, _ in master.getPublishedTopics('')), HANG, 'the publisher registered')
    return child


def test_a_latched_message_comes_from_a_publisher_in_another_process(rospy_client, procs):
    _publisher(procs, 'hello')
    assert latched_message(TOPIC, String, HANG).data == 'hello'


def test_nothing_publishing_is_told_after_the_absence_bound_not_the_timeout(rospy_client):
    start = time.monotonic()
    with pytest.raises(NoPublisher, match='nothing publishes /latched_test/absent'):
        latched_message('/latched_test/absent', String, timeout=HANG, absent_after=0.5)
    assert time.monotonic() - start < HANG / 2, 'it waited for the timeout, not the absence bound'


def test_a_stalled_publisher_is_waited_for_and_not_taken_for_absent(rospy_client, procs):
    child = _publisher(procs, 'late')
    stop(child.pid)
    resume = threading.Timer(STALL_S, os.kill, (child.pid, signal.SIGCONT))     # the fault's length
    started = time.monotonic()
    resume.start()
    try:
        assert latched_message(TOPIC, String, HANG, absent_after=0.5).data == 'late'
        assert time.monotonic() - started >= STALL_S * 0.9
    finally:
        resume.cancel()
        os.kill(child.pid, signal.SIGCONT)


def test_a_publisher_that_never_delivers_times_out_naming_the_topic(rospy_client, procs):
    child = _publisher(procs, 'never')
    stop(child.pid)
    try:
        with pytest.raises(TimeoutError, match='/latched_test/word is published, but its message did not arrive'):
            latched_message(TOPIC, String, timeout=1.5, absent_after=0.5)
    finally:
        os.kill(child.pid, signal.SIGCONT)
