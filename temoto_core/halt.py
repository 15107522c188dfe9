"""The halt topic: "stop" reaches every motion node of a TeMoto namespace in one hop.

Stopping an action releases what it holds, and its motion then stops through the connection watches of
``goal_holders.py``: correct, but it waits for a worker to end its graph. The operator's "stop" must not
wait for anything. The action engine publishes the reason on ``/<ns>/halt`` the moment it grounds a
stop, before any graph runs; each motion node of the namespace (the navigator, the manipulators) listens
with TCP_NODELAY, ends its goal ABORTED with the reason, and commands zero at once.

The engine publishes on its own namespace and on every namespace its actions name for the Robot Manager
(a robot's managers run in the robot's namespace, docs/two_hosts.md). The topic is not latched: a halt
is an event, and a node that starts later has nothing to stop.
"""
from std_msgs.msg import String

HALT = 'halt'
HALT_TYPE = String
MAX_REASON = 200          # characters of a reason kept; the rest is cut, so a flood of text costs nothing


def halt_topic(namespace: str) -> str:
    """``/<namespace>/halt``: where the motion nodes of a TeMoto namespace hear "stop"."""
    return '/%s/%s' % (namespace.strip('/'), HALT)


def reason_of(msg: String) -> str:
    """The halt's reason, bounded and never empty (a bare halt is the operator's)."""
    text = (msg.data or '').strip()[:MAX_REASON]
    return text or 'the operator said stop'
