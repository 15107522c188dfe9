"""The teleoperation dial: the scale from the operator's hand to the robot, from 0.01x to 10x.

The original turned a Griffin PowerMate and stepped the scale by a tenth of its decade, so that
a turn near 1x moved in steps of 0.1 and near 0.1x in steps of 0.01. That is logarithmic in its
decades but linear inside them: ten clicks from 0.1 to 0.2, one from 0.9 to 1.0. Here the dial
steps along the 1-2-5 series (0.01, 0.02, 0.05, 0.1, ... 5, 10), as an oscilloscope's volts per
division do: every click changes the scale by about the same ratio (x2 or x2.5), whether the
operator threads a needle at 0.01x or drives across a warehouse at 10x.

A scale can also be set outright (a spoken "scale one tenth", a dial topic); a value outside the
range, or not a number, is refused naming the range and leaves the scale as it was.
"""
from __future__ import annotations

import math
from typing import List

MINIMUM, MAXIMUM = 0.01, 10.0
_MANTISSAS = (1.0, 2.0, 5.0)


def _series() -> List[float]:
    """The 1-2-5 series from MINIMUM to MAXIMUM."""
    out = []
    for decade in range(int(round(math.log10(MINIMUM))), int(round(math.log10(MAXIMUM))) + 1):
        for m in _MANTISSAS:
            value = round(m * 10.0 ** decade, 10)
            if MINIMUM <= value <= MAXIMUM:
                out.append(value)
    return out


STEPS = tuple(_series())


class Dial:
    """The scale the hand's motion is multiplied by. Starts at ``scale`` (1x unless given)."""

    def __init__(self, scale: float = 1.0) -> None:
        self._scale = self._checked(scale)

    @property
    def scale(self) -> float:
        return self._scale

    @staticmethod
    def _checked(value: float) -> float:
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise ValueError('scale %r is not a number; give one from %g to %g' % (value, MINIMUM, MAXIMUM)) \
                from None
        if not (math.isfinite(value) and MINIMUM <= value <= MAXIMUM):
            raise ValueError('scale %r is outside %g to %g' % (value, MINIMUM, MAXIMUM))
        return value

    def set(self, value: float) -> float:
        """Set the scale outright; raises ValueError (the scale unchanged) for a bad value."""
        self._scale = self._checked(value)
        return self._scale

    def step(self, clicks: int) -> float:
        """Turn the dial ``clicks`` steps of the series (positive: coarser, negative: finer). A scale between
        two steps (set outright) moves to the next step in the direction turned. Stops at either end."""
        if clicks == 0:
            return self._scale
        if clicks > 0:
            above = [s for s in STEPS if s > self._scale * (1 + 1e-9)]
            ladder = above[:clicks]
        else:
            below = [s for s in STEPS if s < self._scale * (1 - 1e-9)]
            ladder = below[::-1][:-clicks]
        if ladder:
            self._scale = ladder[-1]
        return self._scale

    def finer(self) -> float:
        return self.step(-1)

    def coarser(self) -> float:
        return self.step(1)
