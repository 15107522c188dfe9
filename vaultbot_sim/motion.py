"""The sim's kinematic state: the held arm pose, the Hokuyo wrist sweep, the waving hand.

Also JointHistory, which drivers and the stitcher use to place a sensor at a
given time from the joint states the sim publishes: both apply the same rule
(latest sample at or before t, extrapolated with its velocity), so the
stitcher puts each scan exactly where the driver rendered it.
"""
from __future__ import annotations

import bisect
import math
from typing import Mapping, Sequence

from vaultbot_sim.spec import STOW_POSE, PERSON_JOINT, SWEEP_JOINT


class WristSweep:
    """Triangle-wave motion of one joint between centre-amplitude and centre+amplitude."""

    def __init__(self, centre: float, amplitude: float = math.pi / 2, speed: float = math.pi / 2,
                 enabled: bool = True):
        self.centre, self.amplitude = centre, amplitude
        self.speed = speed
        self.enabled = enabled
        self.position = centre
        self.direction = 1.0

    def set(self, enabled: bool, speed: float = 0.0) -> None:
        """speed 0 keeps the current speed; otherwise 0 < speed <= pi (the UR5's joint limit)."""
        if speed < 0 or speed > math.pi + 1e-9 or math.isnan(speed):
            raise ValueError(f'sweep speed {speed} rad/s out of range: use 0 < speed <= pi (0 keeps {self.speed:.3f})')
        if speed > 0:
            self.speed = speed
        self.enabled = enabled

    @property
    def velocity(self) -> float:
        return self.direction * self.speed if self.enabled else 0.0

    def advance(self, dt: float) -> float:
        if not self.enabled or dt <= 0:
            return self.position
        lo, hi = self.centre - self.amplitude, self.centre + self.amplitude
        pos = self.position + self.direction * self.speed * dt
        for _ in range(4):  # bounded reflection at the ends
            if pos > hi:
                pos, self.direction = 2 * hi - pos, -1.0
            elif pos < lo:
                pos, self.direction = 2 * lo - pos, 1.0
            else:
                break
        self.position = min(max(pos, lo), hi)
        return self.position


class HandWave:
    """The person's arm swinging slowly so a tracker sees motion."""

    def __init__(self, amplitude: float = 0.3, period: float = 8.0, enabled: bool = True):
        self.amplitude, self.period, self.enabled = amplitude, period, enabled

    def at(self, t: float) -> tuple[float, float]:
        if not self.enabled:
            return 0.0, 0.0
        w = 2 * math.pi / self.period
        return self.amplitude * math.sin(w * t), self.amplitude * w * math.cos(w * t)


class SimState:
    """Robot and world joint state as a function of time."""

    def __init__(self, sweep: WristSweep | None = None, hand: HandWave | None = None,
                 hold: Mapping[str, float] = STOW_POSE):
        self.hold = dict(hold)
        self.sweep = sweep or WristSweep(self.hold[SWEEP_JOINT])
        self.hand = hand or HandWave()
        self._last_t: float | None = None

    def step(self, t: float):
        """Returns (robot names, positions, velocities), (world names, positions, velocities)."""
        dt = 0.0 if self._last_t is None else t - self._last_t
        self._last_t = t
        self.sweep.advance(min(max(dt, 0.0), 0.5))
        cfg = dict(self.hold)
        cfg[SWEEP_JOINT] = self.sweep.position
        names = list(cfg)
        vel = [self.sweep.velocity if n == SWEEP_JOINT else 0.0 for n in names]
        q, qd = self.hand.at(t)
        return (names, [cfg[n] for n in names], vel), ([PERSON_JOINT], [q], [qd])


class JointHistory:
    """Time-ordered joint samples; cfg_at(t) = latest sample at or before t, extrapolated."""

    def __init__(self, horizon: float = 10.0, max_extrapolation: float = 0.2):
        self.horizon, self.max_extrapolation = horizon, max_extrapolation
        self._t: list[float] = []
        self._s: list[tuple[dict, dict]] = []

    def __len__(self) -> int:
        return len(self._t)

    def add(self, t: float, names: Sequence[str], positions: Sequence[float],
            velocities: Sequence[float] = ()) -> None:
        pos = dict(zip(names, positions))
        vel = dict(zip(names, velocities)) if len(velocities) == len(names) else {}
        if self._t and t < self._t[-1]:
            i = bisect.bisect_right(self._t, t)
            self._t.insert(i, t)
            self._s.insert(i, (pos, vel))
        else:
            self._t.append(t)
            self._s.append((pos, vel))
        cut = bisect.bisect_left(self._t, self._t[-1] - self.horizon)
        if cut > 0:
            del self._t[:cut], self._s[:cut]

    def latest_time(self) -> float | None:
        return self._t[-1] if self._t else None

    def cfg_at(self, t: float) -> dict[str, float] | None:
        if not self._t:
            return None
        i = max(bisect.bisect_right(self._t, t) - 1, 0)
        pos, vel = self._s[i]
        dt = min(max(t - self._t[i], 0.0), self.max_extrapolation)
        return {n: q + vel.get(n, 0.0) * dt for n, q in pos.items()}
