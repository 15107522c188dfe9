"""The clutch between the operator's hand and an end-effector: a grab engages, an open hand lets go.

The original mapped the palm to the target absolutely, ``scale x gain x (palm - offset)``: wherever the
hand was when following began, the arm jumped there. Here the arm follows the hand's motion *relative*
to where it was grabbed, as a mouse moves a pointer: at the grab, the palm's pose and the tool's pose
are taken as the two origins; after that the tool's target is its origin moved by the palm's motion
times the dial's scale and the gain, and turned by the palm's turn. The operator can let go, move the
hand back, and grab again, to go further than an arm's length of hand.

Safety rules it keeps, each tested:
- **Nothing moves before a deliberate grab.** The clutch starts disarmed: it engages only on a grab
  that follows an open hand, so a fist held while following starts, or while a source fails over,
  moves nothing.
- **A lost hand disengages and disarms** (``lost``): the hand source failed or a sample is stale.
  The arm holds (no target is given, and the manipulator's deadman holds it), and the clutch needs an
  open hand and a new grab before anything moves again.
- **A new scale re-anchors** at the next sample: turning the dial does not make the target jump.
- Grab strength uses hysteresis (engage at 0.8, let go below 0.5), so a trembling fist does not
  chatter.
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from temoto_operator.dial import Dial

ENGAGE = 0.8          # grab strength (0 open .. 1 fist) that engages
RELEASE = 0.5         # below this the hand is open: the clutch lets go, and is armed for the next grab
GAIN_MANIPULATION = 1.0    # the hand's metre is the tool's metre at 1x (the original: 10, on its own units)


class HandClutch:
    def __init__(self, dial: Dial, gain: float = GAIN_MANIPULATION) -> None:
        if not gain > 0:
            raise ValueError('gain %r must be above 0' % gain)
        self.dial, self.gain = dial, gain
        self.engaged = False
        self._armed = False
        self._palm0: Optional[np.ndarray] = None
        self._tool0: Optional[np.ndarray] = None
        self._scale0 = dial.scale
        self._last: Optional[np.ndarray] = None      # the last target given

    @property
    def armed(self) -> bool:
        """An open hand has been seen since the last grab or loss: a grab will engage."""
        return self._armed

    def sample(self, palm: np.ndarray, grab: float, tool_now: Callable[[], np.ndarray]) -> Optional[np.ndarray]:
        """One hand sample (the palm's 4 x 4 pose in the robot's frame, the grab strength): the tool's target
        (4 x 4), or None when the clutch is not engaged (the arm holds). ``tool_now()`` gives the tool's pose
        at a grab."""
        if not np.all(np.isfinite(palm)) or not np.isfinite(grab):
            self.lost()
            return None
        if self.engaged and grab < RELEASE:
            self.engaged, self._armed = False, True
            return None
        if not self.engaged:
            if grab < RELEASE:
                self._armed = True
                return None
            if grab < ENGAGE or not self._armed:
                return None
            self.engaged, self._armed = True, False
            self._anchor(palm, tool_now())
            return self._last
        if self.dial.scale != self._scale0:          # the dial turned: go on from here, no jump
            self._anchor(palm, self._last)
        k = self.dial.scale * self.gain
        target = np.eye(4)
        target[:3, :3] = palm[:3, :3] @ self._palm0[:3, :3].T @ self._tool0[:3, :3]
        target[:3, 3] = self._tool0[:3, 3] + k * (palm[:3, 3] - self._palm0[:3, 3])
        self._last = target
        return target

    def hand_point(self, palm: np.ndarray) -> Optional[np.ndarray]:
        """Where the hand is, unscaled, from the tool's anchor (the scene draws it beside the scaled target), or
        None while nothing is engaged."""
        if not self.engaged or self._palm0 is None or not np.all(np.isfinite(palm)):
            return None
        return self._tool0[:3, 3] + (palm[:3, 3] - self._palm0[:3, 3])

    def lost(self) -> None:
        """The hand is gone (its source failed, its samples stale): let go, and wait for an open hand."""
        self.engaged = self._armed = False

    def _anchor(self, palm: np.ndarray, tool: np.ndarray) -> None:
        self._palm0, self._tool0 = palm.copy(), tool.copy()
        self._scale0 = self.dial.scale
        self._last = tool.copy()
