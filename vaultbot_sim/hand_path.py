"""A recorded or scripted hand, for the simulated hand tracker to replay.

A path is keyframes ``t x y z grab`` (seconds from the start, the palm's position in the tracker's
frame in metres, grab strength 0..1), linear between them, played in a loop. A file holds one keyframe
per line, ``#`` comments allowed; a wrong line is refused naming its number and what is wrong.

The default path is a demonstration's: an open hand, a grab, 10 cm to the left over 2 s, a hold, an
open hand, and back.
"""
from __future__ import annotations

import bisect
import math
from typing import List, Sequence, Tuple

Keyframe = Tuple[float, float, float, float, float]       # t, x, y, z, grab

DEFAULT: Tuple[Keyframe, ...] = (
    (0.0, 0.0, 0.0, 0.20, 0.0),
    (0.5, 0.0, 0.0, 0.20, 0.0),
    (0.7, 0.0, 0.0, 0.20, 1.0),
    (2.7, 0.0, 0.10, 0.20, 1.0),
    (3.2, 0.0, 0.10, 0.20, 1.0),
    (3.4, 0.0, 0.10, 0.20, 0.0),
    (5.0, 0.0, 0.0, 0.20, 0.0),
)


class HandPath:
    def __init__(self, keyframes: Sequence[Keyframe] = DEFAULT) -> None:
        frames = [tuple(float(v) for v in k) for k in keyframes]
        if len(frames) < 2:
            raise ValueError('a hand path needs 2 keyframes or more, got %d' % len(frames))
        for n, k in enumerate(frames):
            if len(k) != 5 or not all(math.isfinite(v) for v in k):
                raise ValueError('keyframe %d: %r must be 5 finite numbers: t x y z grab' % (n, k))
            if not 0.0 <= k[4] <= 1.0:
                raise ValueError('keyframe %d: grab %g must be from 0 to 1' % (n, k[4]))
            if n and k[0] <= frames[n - 1][0]:
                raise ValueError('keyframe %d: t %g must come after %g' % (n, k[0], frames[n - 1][0]))
        self.frames = frames
        self.times = [k[0] for k in frames]
        self.period = frames[-1][0] - frames[0][0]

    @classmethod
    def read(cls, path: str) -> 'HandPath':
        """Keyframes from a file, one ``t x y z grab`` per line."""
        frames: List[Keyframe] = []
        with open(path) as f:
            for number, line in enumerate(f, 1):
                text = line.split('#', 1)[0].strip()
                if not text:
                    continue
                try:
                    values = tuple(float(v) for v in text.split())
                except ValueError:
                    raise ValueError('%s:%d: %r is not numbers: t x y z grab' % (path, number, text)) from None
                if len(values) != 5:
                    raise ValueError('%s:%d: %d numbers, want 5: t x y z grab' % (path, number, len(values)))
                frames.append(values)
        try:
            return cls(frames)
        except ValueError as err:
            raise ValueError('%s: %s' % (path, err)) from None

    def at(self, t: float) -> Keyframe:
        """The hand at ``t`` seconds from the start (looped)."""
        t = self.frames[0][0] + (t % self.period if self.period > 0 else 0.0)
        i = min(max(bisect.bisect_right(self.times, t) - 1, 0), len(self.frames) - 2)
        a, b = self.frames[i], self.frames[i + 1]
        u = (t - a[0]) / (b[0] - a[0])
        return (t,) + tuple(a[k] + u * (b[k] - a[k]) for k in range(1, 5))
