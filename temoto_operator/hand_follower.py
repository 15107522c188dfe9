"""From hand samples to one arm's servo commands: the clutch, the dial, and the hand's freshness.

What the ``follow_hand`` action runs, kept free of ROS so that every rule is tested alone:

- each tracked sample goes through the clutch (``hand_clutch.py``): a target for the tool while a grab
  holds it, nothing otherwise;
- the hand is *stale* when no sample has come for ``missed`` of its periods (2 at 100 Hz: 20 ms): the
  clutch lets go and the arm is told to hold at once, not one servo deadman (0.1 s) later. The caller
  asks ``deadline()`` for the moment to check, and waits for exactly that, as the navigator waits for its
  obstacle source's;
- a sample without a hand in view (``tracked`` false) or with a value that is not finite counts as a
  lost hand the same way.

The hold is said once per loss: a hold repeated at every tick would fight a goal given meanwhile.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from temoto_operator.dial import Dial
from temoto_operator.hand_clutch import GAIN_MANIPULATION, HandClutch

TARGET, HOLD = 'target', 'hold'


@dataclass(frozen=True)
class Command:
    kind: str                                # TARGET: follow ``pose``; HOLD: stop the arm where it is
    pose: Optional[np.ndarray] = None        # the tool's target (4 x 4, the arm's base frame)
    why: str = ''                            # for a hold: what was lost


class HandFollower:
    def __init__(self, dial: Dial, period: float = 0.01, missed: int = 2,
                 gain: float = GAIN_MANIPULATION) -> None:
        if not period > 0 or missed < 1:
            raise ValueError('period %r must be above 0 and missed %r at least 1' % (period, missed))
        self.clutch = HandClutch(dial, gain)
        self.period, self.missed = period, missed
        self.last: Optional[float] = None    # when the last good sample came
        self._held = True                    # the arm has been told to hold (or never moved)

    def deadline(self) -> Optional[float]:
        """When the hand goes stale if no sample comes before; None while nothing follows it."""
        if self.last is None or not self.clutch.engaged:
            return None
        return self.last + self.missed * self.period

    def sample(self, now: float, palm: np.ndarray, grab: float, tracked: bool,
               tool_now: Callable[[], np.ndarray]) -> Optional[Command]:
        """One hand sample at ``now``: the command to send, or None."""
        if not tracked or not np.all(np.isfinite(palm)) or not np.isfinite(grab):
            return self.lost('no hand in view' if not tracked else 'a hand sample that is not finite')
        self.last = now
        target = self.clutch.sample(palm, grab, tool_now)
        if target is None:
            return self._hold('the hand let go')
        self._held = False
        return Command(TARGET, target)

    def check(self, now: float) -> Optional[Command]:
        """At (or after) ``deadline()``: the hold, if the hand has gone stale."""
        deadline = self.deadline()
        if deadline is None or now < deadline:
            return None
        return self.lost('no hand sample for %.0f ms (%d of its periods)'
                         % ((now - self.last) * 1e3, self.missed))

    def lost(self, why: str) -> Optional[Command]:
        """The hand is gone (stale, out of view, its source failed): let go, and hold the arm once."""
        self.clutch.lost()
        return self._hold(why)

    def _hold(self, why: str) -> Optional[Command]:
        if self._held:
            return None
        self._held = True
        return Command(HOLD, why=why)
