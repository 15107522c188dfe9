"""Other hosts' clocks against this one's, learnt from the stamps and arrivals of their messages.

A motion node judges a command by its stamp: refused when it was sent too long ago (a link that held it), or
before the operator's last "stop". The stamp is the sender's clock and the judgement is the robot's: two hosts
whose clocks are 0.5 s apart either refuse every command (the station behind: each looks 0.5 s late) or take
commands that were held up by a link (the station ahead: a command 0.4 s late looks fresh). ROS 1 does not
synchronise clocks, and a robot cannot assume that its operator's station runs chrony.

So each sending host's clock is learnt: its *offset*, the smallest (arrival - stamp) of its messages, which is
the skew of the two clocks plus the link's quickest delivery. A command's stamp on this host's clock is then
``stamp + offset``: a command delivered as quickly as any is on time, and one that a link held up is late by
exactly the hold. The offset may grow by at most ``RISE_S_PER_S`` a second, so that a clock that drifts, or is
stepped back, is forgiven in time, while a hold of a few seconds moves it by milliseconds only.

What this cannot tell: the link's steady latency, which looks like skew (it is not counted as lateness), and
the lateness of a host's very first message, which is taken as its offset. A host's nodes share its clock, so a
new process of a known host (a `temoto robots go` from the station's shell) is judged at once. A sender on
this node's own host is judged by its stamp as it is: one clock.
"""
from __future__ import annotations

import threading
import urllib.parse
from typing import Callable, Dict, Optional, Tuple

import rosgraph
import rospy

from temoto_core.master_lookup import node_host

RISE_S_PER_S = 0.01      # a clock stepped back 0.5 s is forgiven within 50 s; a stream held 2 s moves it by 20 ms
# a stamp that would put two clocks further apart than this is wrong, not skewed: it teaches nothing (one bad
# stamp would otherwise make every later message of its host look late, or early, for hours)
MAX_SKEW_S = 10.0


class PeerClocks:
    def __init__(self, host_of: Callable[[str], Optional[str]], own_host: Optional[str],
                 rise: float = RISE_S_PER_S) -> None:
        """``host_of(sender)``: the host a sending node runs on (None: not known, judged by its stamp as it is);
        ``own_host``: this node's. ``for_this_node()`` makes one that asks the master."""
        self._host_of, self.own_host, self.rise = host_of, own_host, rise
        self._hosts: Dict[str, Optional[str]] = {}
        self._offsets: Dict[str, Tuple[float, float]] = {}      # host -> (offset, when it was last taken)
        self._lock = threading.Lock()

    def host(self, sender: str) -> Optional[str]:
        """The sender's host, asked once per sender; None for this node's own host or one not known."""
        with self._lock:
            if sender in self._hosts:
                return self._hosts[sender]
        host = self._host_of(sender) if sender else None
        if host == self.own_host:
            host = None
        with self._lock:
            self._hosts[sender] = host
        return host

    def observe(self, sender: str, stamp: float, arrival: float) -> float:
        """A message of ``sender`` stamped ``stamp`` (its clock) that arrived at ``arrival`` (this host's wall
        clock): learn from it, and return its stamp on this host's clock."""
        host = self.host(sender)
        offset = arrival - stamp
        if host is None or not abs(offset) <= MAX_SKEW_S:
            return stamp
        with self._lock:
            known = self._offsets.get(host)
            if known is not None:
                offset = min(known[0] + self.rise * max(0.0, arrival - known[1]), offset)
            self._offsets[host] = (offset, arrival)
        return stamp + offset

    def goal_sent(self, goal_id, arrival: float) -> float:
        """When an actionlib goal (its ``actionlib_msgs/GoalID``) was sent, on this host's clock: its sender is the
        node its id begins with (``/node-N-stamp``), as actionlib's clients make them."""
        return self.observe(goal_id.id.split('-', 1)[0], goal_id.stamp.to_sec(), arrival)

    def offset(self, sender: str) -> Optional[float]:
        """The learnt offset of ``sender``'s host (None: its own clock is this one's, or nothing is known)."""
        host = self.host(sender)
        with self._lock:
            known = self._offsets.get(host) if host is not None else None
        return None if known is None else known[0]


def for_this_node() -> PeerClocks:
    """The clocks of the hosts that send to this node: a sender's host asked of the master (once per sender)."""
    master = rosgraph.get_master_uri()
    return PeerClocks(lambda sender: node_host(master, sender), urllib.parse.urlparse(rospy.get_node_uri()).hostname)
