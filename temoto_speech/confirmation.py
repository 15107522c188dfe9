"""A spoken motion waits for the operator's "yes": the issue's other guard, beside the wake phrase.

The wake phrase keeps talk to someone else from moving the robot; it does not keep a motion instruction from
being heard as another motion ("robot please go there" heard as "robot please move hand": 6 of 312 in the
speech benchmark, at margins no threshold separates). With confirmation on (``~confirm_motion``), a heard
motion is not sent: the node says it back ("go there? yes or no") and sends it only on "yes" within
``window`` seconds. "no", silence, or any other instruction drops it. "stop" is never held: it goes at once,
and drops a motion waiting for its answer. No ROS here; ``node.py`` speaks and sends.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

YES = ('yes', 'confirm')
NO = ('no', 'cancel')
ANSWERS = YES + NO
WINDOW_S = 6.0                 # from the question to the answer: a sentence said back, then a word


@dataclass(frozen=True)
class Decision:
    send: str = ''             # the text to send to the engine now ('' for nothing)
    say: str = ''              # what the node says aloud


class MotionConfirmation:
    def __init__(self, motion_wake: Sequence[str], stop_words: Sequence[str], window: float = WINDOW_S,
                 wake_words: Sequence[str] = ()) -> None:
        if not window > 0:
            raise ValueError('the confirmation window %r must be above 0 s' % window)
        self.wake_words = {w.lower() for w in wake_words}     # the node's, before anything said to it
        self.motion_wake = [w.lower() for w in motion_wake]
        self.stop_words = {w.lower() for w in stop_words}
        self.window = window
        self.pending: Optional[str] = None
        self.asked_at = 0.0

    def heard(self, text: str, now: float) -> Decision:
        """An accepted utterance at ``now`` (monotonic): what to send and say."""
        words = text.lower().split()
        lead = 1 if words and words[0] in self.wake_words else 0
        words = words[lead:]
        expired = self._expire(now)
        if words and all(w in ANSWERS for w in words):
            if self.pending is None:
                return Decision(say='%s: no motion is waiting for an answer' % (
                    'too late' if expired else 'nothing to confirm'))
            motion, self.pending = self.pending, None
            if words[0] in YES:
                return Decision(send=motion)
            return Decision(say='cancelled')
        if words and words[0] in self.stop_words:
            self.pending = None                   # a stop is never held, and ends any question
            return Decision(send=text)
        if words[:len(self.motion_wake)] == self.motion_wake:
            self.pending, self.asked_at = text, now
            said = ' '.join(text.split()[lead + len(self.motion_wake):])
            return Decision(say='%s? yes or no' % said)
        dropped = self.pending
        self.pending = None                       # another instruction: the question is not answered by it
        return Decision(send=text, say='not confirmed: %s' % dropped if dropped else '')

    def _expire(self, now: float) -> bool:
        if self.pending is not None and now - self.asked_at > self.window:
            self.pending = None
            return True
        return False

    def expire(self, now: float) -> Optional[str]:
        """The motion dropped for want of an answer by ``now``, if one was."""
        motion = self.pending
        return motion if self._expire(now) else None
