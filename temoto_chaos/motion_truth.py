"""The robot's motion as the simulation says it happened: spans of motion per part, contacts, blind drives.

The checker must not take a manager's word for "the robot stopped". The simulation publishes each part's
ground truth (``vaultbot_sim/base_state``, ``arm_states``, ``gripper_state``: the bodies' own velocities)
and every contact. ``GroundTruth`` turns those samples into what the motion invariants need, kept free of
ROS so that every rule is tested alone:

- a *span* of motion per part: from the first sample above the part's rest threshold to the first below
  it (or to the part's last sample, when the samples stop: the robot lost power), with its peak speed;
- each contact;
- a *blind* span: the base moving while the obstacle source the navigator drives on (its *active* source: the
  one topic of the sources it subscribes to, as the master says) has sent nothing within its freshness bound
  plus the base's braking time, which a stop that came in time still needs. Another source flowing does not
  make a drive on a silent one safe. While the active source is not known (no navigator, or before the first
  look), any source fresh will do. A switch of the active source keeps the cover its predecessor gave: a base
  braking from a stop that came in time is not blind because the navigator now reads a silent source.

  The bound is the navigator's contract (docs/robots.md), worked out here on its own, never with the stack's
  code: three of the source's periods and 20 ms. The period is the one the robot's sensor catalogue declares
  for it, or, for a source that runs slower than it declares (a camera rendered on a busy machine), the 90th
  percentile of its last 20 intervals, its third longest.

The events are numbered, so a reader asks for what came after the last one it saw; a bounded deque keeps
the newest (a reader that asks every check never misses one).
"""
from __future__ import annotations

import collections
import dataclasses
from typing import Deque, Dict, List, Optional

BASE, LEFT_ARM, RIGHT_ARM, GRIPPER = 'base', 'left_arm', 'right_arm', 'gripper'
PARTS = (BASE, LEFT_ARM, RIGHT_ARM, GRIPPER)
# at rest below these (the sim's velocities are exact: a held part reads 0)
BASE_REST_LINEAR = 0.01      # m/s
BASE_REST_ANGULAR = 0.02     # rad/s
ARM_REST = 0.01              # rad/s, the fastest joint
GRIPPER_REST = 0.002         # m/s of the gap
# s without a sample after which a span is closed at its last sample: the robot lost power, or the sim died
SAMPLES_LOST_S = 0.5
# the base's braking from top speed (docs/robots.md: 2 m/s² from 0.5 m/s, and 0.25 s more to turn from top)
BASE_BRAKING_S = 0.5
# the navigator's obstacle sources (the robot description's, in the robot's namespace) and the period of the
# rate each declares in the VaultBot's sensor catalogue (temoto_sensor_manager/config/vaultbot.yaml;
# tests/test_chaos_motion.py checks that the two agree)
OBSTACLE_SOURCES = {'sick/scan': 1 / 25.0, 'laser_stitcher/cloud': 1 / 10.0, 'd435/depth_registered/points': 1 / 30.0}
STALE_PERIODS, STALE_MARGIN_S = 3, 0.02
WINDOW = 20                  # intervals a slow source's period is taken from
SLOW_RANK = 3                # its third longest of them: the 90th percentile of 20
SLOWER = 1.1                 # a source runs slower than it declares when its own pace is 10 % longer (jitter is not)
# a period learnt from arrivals (a slow source's) is learnt by two observers, the navigator and the watch, each
# receiving a megabyte-sized message when its own threads get a CPU: their estimates differ by tens of ms on
# a loaded machine (seed 17, step 2086: one base sample 14 ms past the watch's bound)
LEARNT_TOLERANCE_S = 0.05
MAX_EVENTS = 20000


def stale_after(period: float) -> float:
    """s after a source's last message beyond which the navigator must hold it stale (docs/robots.md)."""
    return STALE_PERIODS * period + STALE_MARGIN_S


def blind_after(period: float) -> float:
    """s after a source's last message beyond which a base still moving drove blind."""
    return stale_after(period) + BASE_BRAKING_S


class SourceClock:
    """When a source's messages came, and the period the contract holds it to: the declared one, or the slow
    source's own (the ``SLOW_RANK``-th longest of its last ``WINDOW`` intervals) when that is longer. An interval
    is the shorter of the arrivals' and the header stamps': the watch's own thread, starved, hears a message late,
    and the interval before it is longer than the source's."""

    def __init__(self, declared: Optional[float]) -> None:
        self.declared = declared
        self.last: Optional[float] = None
        self.intervals: Deque[float] = collections.deque(maxlen=WINDOW)
        self._stamp: Optional[float] = None

    def heard(self, t: float, stamp: Optional[float] = None) -> None:
        """A message at ``t``, with its header stamp if it had one."""
        if self.last is not None and t > self.last:
            interval = t - self.last
            if stamp is not None and self._stamp is not None and stamp > self._stamp:
                interval = min(interval, stamp - self._stamp)
            self.intervals.append(interval)
        self.last, self._stamp = t, stamp

    def slow_period(self) -> Optional[float]:
        """The source's own pace, when enough of it is known: the ``SLOW_RANK``-th longest interval."""
        if len(self.intervals) < SLOW_RANK:
            return None
        return sorted(self.intervals)[-SLOW_RANK]

    def period(self) -> Optional[float]:
        slow = self.slow_period()
        if self.declared is None:
            return slow
        return slow if slow is not None and slow > SLOWER * self.declared else self.declared

    def stale_bound(self) -> Optional[float]:
        """``stale_after`` of the period the contract holds the source to, with a learnt period's tolerance of
        two observers; None until a period is known."""
        period = self.period()
        if period is None:
            return None
        learnt = self.declared is None or period > self.declared
        return stale_after(period) + (LEARNT_TOLERANCE_S if learnt else 0.0)

    def covers_until(self) -> Optional[float]:
        """Until when a base driving on this source may still be moving: its freshness bound after its last
        message, and the braking a stop that came in time still needs; None until it is heard with a period."""
        stale = self.stale_bound()
        return self.last + stale + BASE_BRAKING_S if self.last is not None and stale is not None else None

    def fresh(self, t: float) -> bool:
        until = self.covers_until()
        return until is not None and t <= until


@dataclasses.dataclass
class _Open:
    start: float
    last: float
    peak: float


class GroundTruth:
    def __init__(self, sources: Optional[Dict[str, float]] = None, max_events: int = MAX_EVENTS) -> None:
        self.sources = {s: SourceClock(p) for s, p in (OBSTACLE_SOURCES if sources is None else sources).items()}
        self.active: Optional[str] = None               # the source the navigator drives on; None: not known
        self.moving: Dict[str, _Open] = {}              # part -> its span under way
        self.last: Dict[str, float] = {}                # part -> its last sample
        self._blind: Optional[_Open] = None
        # until when the sources the navigator has driven on cover a base still moving: a switch of the active
        # source does not take back the braking its predecessor's stop still needs (seed 17, history 7, step 6229:
        # the SICK died mid-drive, the navigator switched to a cloud silent for 12 s, and the base, braking from
        # the SICK's stop, was judged blind on the cloud's clock)
        self._covered = float('-inf')
        self.events: Deque[dict] = collections.deque(maxlen=max_events)
        self.seq = 0
        self.samples = 0

    # -- samples -----------------------------------------------------------------------------------------------
    def base(self, t: float, linear: float, angular: float) -> None:
        moving = abs(linear) > BASE_REST_LINEAR or abs(angular) > BASE_REST_ANGULAR
        self._sample(BASE, t, moving, max(abs(linear), abs(angular)))
        self._judge_blind(t, moving)

    def arm(self, t: float, arm: str, held: bool, speed: float) -> None:
        """An arm that nobody holds (the Hokuyo's, sweeping as the sim's own motion) is not the robot's."""
        self._sample(arm, t, held and speed > ARM_REST, speed)

    def gripper(self, t: float, speed: float) -> None:
        self._sample(GRIPPER, t, abs(speed) > GRIPPER_REST, abs(speed))

    def contact(self, t: float, robot_link: str, object_link: str, speed: float) -> None:
        self._emit({'type': 'contact', 't': t, 'robot_link': robot_link, 'object_link': object_link,
                    'speed': speed})

    def obstacle(self, t: float, source: str, stamp: Optional[float] = None) -> None:
        self.sources[source].heard(t, stamp)

    def navigator_reads(self, sources: List[str]) -> None:
        """The obstacle sources the navigator subscribes to now (the master's word): one is the active source;
        none or several, and it is not known."""
        known = [s for s in sources if s in self.sources]
        self.active = known[0] if len(known) == 1 else None

    def tick(self, now: float) -> None:
        """Close the spans of parts whose samples stopped (``SAMPLES_LOST_S``) at their last sample."""
        for part, span in list(self.moving.items()):
            if now - span.last > SAMPLES_LOST_S:
                self._close(part, span.last, lost=True)
        if self._blind is not None and now - self._blind.last > SAMPLES_LOST_S:
            self._close_blind()

    # -- what a reader asks --------------------------------------------------------------------------------------
    def since(self, seq: int) -> dict:
        """The events numbered above ``seq``, the spans under way, each part's last sample, and how long after its
        last message each obstacle source is stale (the bound of the "obstacle unplugged" stop case)."""
        return {'seq': self.seq, 'events': [e for e in self.events if e['seq'] > seq],
                'oldest': self.events[0]['seq'] if self.events else self.seq + 1,
                'moving': {p: {'start': s.start, 'last': s.last, 'peak': s.peak} for p, s in self.moving.items()},
                'last': dict(self.last), 'samples': self.samples,
                'stale_after': {s: c.stale_bound() for s, c in self.sources.items()}}

    # -- rules -------------------------------------------------------------------------------------------------
    def fresh(self, t: float) -> bool:
        """Whether a base moving at ``t`` is covered: by the active source's last message (while it is not known,
        any source's), or by what covered it before the active source changed."""
        clocks = [self.sources[self.active]] if self.active is not None else list(self.sources.values())
        for clock in clocks:
            until = clock.covers_until()
            if until is not None:
                self._covered = max(self._covered, until)
        return t <= self._covered

    def _sample(self, part: str, t: float, moving: bool, speed: float) -> None:
        self.samples += 1
        self.last[part] = t
        span = self.moving.get(part)
        if moving:
            if span is None:
                self.moving[part] = _Open(t, t, speed)
            else:
                span.last, span.peak = t, max(span.peak, speed)
        elif span is not None:
            self._close(part, t)

    def _close(self, part: str, end: float, lost: bool = False) -> None:
        span = self.moving.pop(part)
        self._emit({'type': 'span', 'part': part, 'start': span.start, 'end': end, 'peak': span.peak,
                    'lost': lost})

    def _judge_blind(self, t: float, moving: bool) -> None:
        blind = moving and not self.fresh(t)
        if blind:
            if self._blind is None:
                self._blind = _Open(t, t, 0.0)
            self._blind.last = t
        elif self._blind is not None:
            self._close_blind()

    def _close_blind(self) -> None:
        span, self._blind = self._blind, None
        heard = {s: (round(span.start - c.last, 3), round(c.period() or 0.0, 3))
                 for s, c in self.sources.items() if c.last is not None}
        self._emit({'type': 'blind', 'start': span.start, 'end': span.last, 'since_heard': heard,
                    'active': self.active or 'not known'})

    def _emit(self, event: dict) -> None:
        self.seq += 1
        event['seq'] = self.seq
        self.events.append(event)


def spans_of(events: List[dict]) -> List[dict]:
    return [e for e in events if e['type'] == 'span']
