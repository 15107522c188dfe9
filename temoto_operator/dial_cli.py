"""`temoto dial`: the dial that scales the operator's hand while an arm follows it (docs/teleoperation.md).

    temoto dial                      the scale now
    temoto dial SCALE                set it: a number from 0.01 to 10, or a word (tenth, half, ...)
    temoto dial finer|coarser [N]    turn it N clicks of the 1-2-5 series (default 1)
    temoto dial --keys               turn it with keys: + coarser, - finer, q quits
"""
from __future__ import annotations

import argparse
import sys
import termios
import threading
import tty
from typing import List, Optional

import rospy
from std_msgs.msg import Float32, Int8

from temoto_core.wait import wait_for
from temoto_operator import dial
from temoto_operator.dial import Dial

WAIT_S = 3.0


class DialClient:
    """What follow_hand's dial says, and the two ways to turn it."""

    def __init__(self, ns: str) -> None:
        self.ns = ns
        self.heard: List[float] = []
        self.cond = threading.Condition()
        self.sub = rospy.Subscriber(dial.topic(ns, dial.SCALE), Float32, self._on_scale, queue_size=5)
        self.pub_set = rospy.Publisher(dial.topic(ns, dial.SET), Float32, queue_size=1)
        self.pub_step = rospy.Publisher(dial.topic(ns, dial.STEP), Int8, queue_size=1)

    def _on_scale(self, msg) -> None:
        with self.cond:
            self.heard.append(msg.data)
            self.cond.notify_all()

    def now(self) -> Optional[float]:
        try:
            wait_for(lambda: self.heard, WAIT_S, 'the dial')
        except TimeoutError:
            return None
        return self.heard[-1]

    def turn(self, pub, msg) -> Optional[float]:
        """Send ``msg`` once follow_hand listens; the scale it answers, or None."""
        try:
            wait_for(lambda: pub.get_num_connections() > 0 and self.heard, WAIT_S, 'follow_hand')
        except TimeoutError:
            return None
        with self.cond:
            before = len(self.heard)
        pub.publish(msg)
        with self.cond:
            if not self.cond.wait_for(lambda: len(self.heard) > before, WAIT_S):
                return None
            return self.heard[-1]


def _keys(client: DialClient) -> int:
    if not sys.stdin.isatty():
        print('error: --keys needs a terminal', file=sys.stderr)
        return 2
    print('+ coarser, - finer, q quits; scale now %s' % client.now(), flush=True)
    saved = termios.tcgetattr(sys.stdin)
    try:
        tty.setcbreak(sys.stdin.fileno())
        while not rospy.is_shutdown():
            key = sys.stdin.read(1)
            if key in ('q', '\x04', ''):
                return 0
            if key in '+-=':
                got = client.turn(client.pub_step, Int8(1 if key in '+=' else -1))
                print('scale %gx' % got if got is not None else 'no hand is followed now', flush=True)
    finally:
        termios.tcsetattr(sys.stdin, termios.TCSADRAIN, saved)
    return 0


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='temoto dial', description='The dial that scales the hand while an arm '
                                 'follows it.')
    ap.add_argument('--ns', '--namespace', dest='ns', default='temoto', help='TeMoto namespace (default temoto)')
    ap.add_argument('--keys', action='store_true', help='turn it with keys: + coarser, - finer, q quits')
    ap.add_argument('value', nargs='?', default='', help='a scale (0.01 to 10, or a word), or finer / coarser')
    ap.add_argument('clicks', nargs='?', type=int, default=1, help='with finer / coarser: how many clicks (1)')
    args = ap.parse_args(argv)
    value = args.value.lower()
    msg = None
    if value in ('finer', 'coarser'):
        if args.clicks < 1:
            ap.error('clicks must be 1 or more')
        msg = Int8(-args.clicks if value == 'finer' else args.clicks)
    elif value:
        try:
            msg = Float32(Dial(dial.scale_of(value)).scale)
        except ValueError as err:
            print('error: %s' % err, file=sys.stderr)
            return 2
    rospy.init_node('temoto_dial', anonymous=True, disable_signals=True)
    client = DialClient(args.ns)
    try:
        if args.keys:
            return _keys(client)
        if msg is None:
            now = client.now()
            print('scale %gx' % now if now is not None else 'no hand is followed now (nothing on %s)'
                  % dial.topic(args.ns, dial.SCALE))
            return 0 if now is not None else 1
        got = client.turn(client.pub_step if isinstance(msg, Int8) else client.pub_set, msg)
        if got is None:
            print('error: no hand is followed now: nothing listens on %s' % dial.topic(args.ns, dial.SET),
                  file=sys.stderr)
            return 1
        print('scale %gx' % got)
        return 0
    finally:
        rospy.signal_shutdown('temoto dial: done')
