"""Waiting until a subscription of the test process really receives.

rospy counts a subscriber's connection (``get_num_connections``) as soon as it
starts connecting, before the publisher has taken it: a message published in
between is lost. A test that publishes, or makes a node publish, right after
such a wait missed the message now and then (test_action_engine_node, a clean
clone's suite). The publisher's own bus information says when the connection
is made at its end: that is what these wait for.
"""
from __future__ import annotations

import rosgraph
import rospy

from temoto_core.master import connected
from temoto_core.wait import wait_for


def publishers_of(topic: str) -> list:
    """The nodes the master lists as publishing ``topic``."""
    publishers, _, _ = rosgraph.Master(rospy.get_name()).getSystemState()
    return next((nodes for name, nodes in publishers if name == topic), [])


def receiving(sub: rospy.Subscriber) -> bool:
    """True once ``sub``'s topic has a publisher and every publisher has a live connection to this node."""
    nodes = publishers_of(sub.resolved_name)
    return bool(nodes) and all(connected(rosgraph.get_master_uri(), node, rospy.get_name(), sub.resolved_name)
                               for node in nodes)


def wait_receiving(subs, timeout: float, what: str) -> None:
    """Wait until every subscriber of ``subs`` is :func:`receiving`, or fail naming ``what``."""
    subs = [subs] if isinstance(subs, rospy.Subscriber) else list(subs)
    wait_for(lambda: all(receiving(s) for s in subs), timeout, what)
