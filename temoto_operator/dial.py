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
# where a running follow_hand listens, under /<ns>/: a scale set outright (std_msgs/Float32), clicks
# (std_msgs/Int8: negative finer, positive coarser), and the scale now (Float32, latched)
SET, STEP, SCALE = 'dial', 'dial/step', 'dial/scale'
# scales said in words ("scale one tenth"), for speech and the CLI
WORDS = {'hundredth': 0.01, 'tenth': 0.1, 'fifth': 0.2, 'half': 0.5, 'one': 1.0, 'double': 2.0, 'ten': 10.0}


def topic(namespace: str, which: str) -> str:
    """``/<namespace>/<which>`` for one of SET, STEP, SCALE."""
    return '/%s/%s' % (namespace.strip('/'), which)


def scale_of(word: str) -> float:
    """A scale said as a word (``WORDS``) or a number; ValueError naming both when it is neither (the range is
    checked by ``Dial``)."""
    word = word.strip().lower()
    if word in WORDS:
        return WORDS[word]
    try:
        return float(word)
    except ValueError:
        raise ValueError('%r is no scale: give a number from %g to %g or one of %s'
                         % (word, MINIMUM, MAXIMUM, ', '.join(sorted(WORDS, key=WORDS.get)))) from None
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
SNAP = 1e-6          # relative: a value this near a step is that step (a float32 carries about 7 digits)


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
        # a scale that came as a float32 (std_msgs/Float32: 0.05 arrives as 0.0500000007) is the step it means;
        # left unsnapped, "finer" from it lands on 0.05 itself, and 0.01 falls below the range
        value = next((s for s in STEPS if abs(value - s) <= SNAP * s), value) if math.isfinite(value) else value
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
            above = [s for s in STEPS if s > self._scale * (1 + SNAP)]
            ladder = above[:clicks]
        else:
            below = [s for s in STEPS if s < self._scale * (1 - SNAP)]
            ladder = below[::-1][:-clicks]
        if ladder:
            self._scale = ladder[-1]
        return self._scale

    def finer(self) -> float:
        return self.step(-1)

    def coarser(self) -> float:
        return self.step(1)
