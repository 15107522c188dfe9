"""dial: turn the dial of a running follow_hand by words ("finer", "coarser", "scale a tenth", "scale 0.5").

The dial is follow_hand's (``temoto_operator/dial.py``): this action only says what to turn it to, on the
dial's topics, and waits for follow_hand to say the scale it took. With nothing following a hand there is
no dial to turn: the action fails, naming that. A scale out of range is refused before anything is sent.
"""
import threading

import rospy
from std_msgs.msg import Float32, Int8

from temoto_action_engine.action_base import ActionBase, ActionError
from temoto_core.wait import wait_for
from temoto_operator import dial
from temoto_operator.dial import Dial

LISTENER_WAIT_S = 1.0        # a running follow_hand is subscribed already; this only bounds the connection
ANSWER_WAIT_S = 2.0


class DialAction(ActionBase):
    def execute(self):
        ns = self.context.namespace
        scale, turn = self.input('scale'), (self.input('turn') or '').lower()
        if scale not in (None, ''):
            try:
                value = Dial(dial.scale_of(scale)).scale       # checked: the range is named, nothing sent
            except ValueError as err:
                raise ActionError(str(err)) from None
            topic, msg, what = dial.topic(ns, dial.SET), Float32(value), 'scale %gx' % value
        elif turn in ('finer', 'coarser'):
            topic, msg, what = dial.topic(ns, dial.STEP), Int8(-1 if turn == 'finer' else 1), turn
        else:
            raise ActionError('say "finer", "coarser", or "scale" with a scale (%s, or a number from %g to %g)'
                              % (', '.join(sorted(dial.WORDS, key=dial.WORDS.get)), dial.MINIMUM, dial.MAXIMUM))
        heard, cond = [], threading.Condition()

        def on_scale(m):
            with cond:
                heard.append(m.data)
                cond.notify_all()
        sub = rospy.Subscriber(dial.topic(ns, dial.SCALE), Float32, on_scale, queue_size=5)
        pub = rospy.Publisher(topic, type(msg), queue_size=1)
        try:
            try:
                wait_for(lambda: pub.get_num_connections() > 0 and heard, LISTENER_WAIT_S, 'follow_hand')
            except TimeoutError:
                raise ActionError('no hand is followed now: nothing listens on %s' % topic) from None
            with cond:
                before = len(heard)
            pub.publish(msg)
            with cond:
                if not cond.wait_for(lambda: len(heard) > before, ANSWER_WAIT_S):
                    raise ActionError('follow_hand did not answer the dial on %s' % topic)
                now = heard[-1]
        finally:
            sub.unregister()
            pub.unregister()
        self.set_output('scale', float(now))
        self.event('dial', turned=what, scale=now)
        self.feedback('%s: the hand now moves the arm at %gx' % (what, now))
