"""The obstacle source of a loaded robot's navigation, failed over down the description's ranking.

The view fails over in the action that shows it; obstacles fail over here, in the Robot Manager,
because it is the navigator's, not any action's. So the obstacle sensor is held on this
registrar's own account (``call(..., link=False)``), not linked to the robot: its FAILED must not
fail the robot while another source can take over. Each step reaches the robot's holders as a
status of the robot (``send_status``):

1. the active source fails: UPDATE "obstacle source X failed: why; the robot waits". The navigator
   has stopped already, by itself, when the source went stale (``freshness.py``);
2. the next source that works, down the ranking, is started and the navigator told its topic on
   the robot's latched ``obstacle_source`` topic: UPDATE "obstacles from Y on T; the robot drives on";
3. none works: FAILED, naming each source and why, as the Sensor Manager's own failover does;
4. **fail-back**, by the view's rule (``temoto_core/backoff.py``): while a load drives on a source below the best,
   each better one is tried again (after 2 s, doubling to 8 s while it does not start). One that starts runs
   unseen for ``Failback.hold_s``; if it fails within that (a flap, counted towards a quarantine), it is let go.
   Having run the whole hold, it is the navigator's again: UPDATE "obstacles from X ... again", and the lower
   source is released. Without it, one stall verdict (a SICK starved for 0.4 s on a loaded machine) dropped
   the base's own scanner for the rest of the robot's load.

The failover and the fail-back run on threads of their own: a sensor's start takes seconds, and the
registrar's status thread must stay free for the next status.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from typing import Callable, Dict, List, Optional, Sequence

from temoto_core.backoff import Backoff
from temoto_core.errors import TemotoError
from temoto_core.fallback import first_that_works
from temoto_core.msg import ResourceStatus
from temoto_robot_manager.description import ObstacleSource


@dataclasses.dataclass
class Served:
    """The obstacle source one loaded robot holds now."""
    robot: str
    ranked: Sequence[ObstacleSource]
    source: Optional[ObstacleSource] = None
    local_id: int = 0
    topic: str = ''
    sensor: str = ''
    released: bool = False
    # a better source back, running unseen through its hold: (source, local id, sensor, topic, since)
    candidate: Optional[tuple] = None
    backoffs: Dict[str, Backoff] = dataclasses.field(default_factory=dict)     # by source label

    @property
    def summary(self) -> str:
        return '%s (%s) on %s' % (self.source.label, self.sensor, self.topic) if self.source else 'none'


@dataclasses.dataclass(frozen=True)
class Failback:
    """When a better-ranked obstacle source is taken back: the view's numbers (``failover_policy.FailoverConfig``)."""
    check_s: float = 2.0          # the first wait before a better source is tried again; doubles while it fails
    max_s: float = 8.0            # the longest wait between two tries
    hold_s: float = 2.0           # a source back runs this long without a FAILED before the navigator takes it
    quarantine_after: int = 3     # flaps in a row (back, then FAILED within the hold) ...
    quarantine_s: float = 60.0    # ... keep it out this long
    period_s: float = 0.25        # between two looks


# start(source) -> (local id, sensor name, topic); release(local id); tell(load id, code, message);
# announce(load id, served): a load's source is new (the navigator's latched topic, the journal)
Start = Callable[[ObstacleSource], tuple]


class ObstacleFailover:
    def __init__(self, start: Start, release: Callable[[int], None], tell: Callable[[int, int, str], None],
                 announce: Callable[[int, Served], None], subsystem: int, log: Callable[[str], None],
                 failback: Optional[Failback] = Failback()) -> None:
        """``failback``: None keeps a load on the source it failed over to."""
        self._start, self._release, self._tell, self._announce = start, release, tell, announce
        self._subsystem, self._log = subsystem, log
        self._lock = threading.Lock()
        self._served: Dict[int, Served] = {}          # load_robot internal id -> its source
        self._by_source: Dict[int, int] = {}          # a source's local id -> the load it serves
        self._candidates: Dict[int, int] = {}         # a source back, in its hold: local id -> its load
        self.failback = failback
        self._closed = threading.Event()
        if failback is not None:
            threading.Thread(target=self._watch_failback, name='obstacle failback', daemon=True).start()

    def _first(self, robot: str, ranked: Sequence[ObstacleSource], skip: Sequence[ObstacleSource] = ()):
        candidates = [s for s in ranked if s not in skip]
        return first_that_works(candidates, self._start, what='an obstacle source for %s' % robot,
                                subsystem=self._subsystem, name=lambda s: s.label,
                                on_failure=lambda tried: self._log('%s: obstacle source %s did not start: %s'
                                                                   % (robot, tried.name, tried.reason)))

    def take(self, load_id: int, robot: str, ranked: Sequence[ObstacleSource]) -> Served:
        """The best source that works, for a load in progress; raises naming every source tried."""
        source, (local_id, sensor, topic) = self._first(robot, ranked)
        served = Served(robot, tuple(ranked), source, local_id, topic, sensor)
        with self._lock:
            self._served[load_id] = served
            self._by_source[local_id] = load_id
        self._announce(load_id, served)
        return served

    def adopt(self, load_id: int, served: Served) -> None:
        """A source the previous incarnation of this manager held for ``load_id`` (a restart): watched and
        failed over again from here on."""
        with self._lock:
            self._served[load_id] = served
            if served.local_id:
                self._by_source[served.local_id] = load_id
        if served.topic:
            self._announce(load_id, served)

    def release(self, load_id: int) -> None:
        """The robot is unloaded (or its load rolled back): its source goes too, and a source back in its hold."""
        with self._lock:
            served = self._served.pop(load_id, None)
            if served is None:
                return
            served.released = True
            self._by_source.pop(served.local_id, None)
            candidate, served.candidate = served.candidate, None
            if candidate is not None:
                self._candidates.pop(candidate[1], None)
        if served.local_id:
            self._release(served.local_id)
        if candidate is not None:
            self._release(candidate[1])
        # another load of the robot shares its navigator: the navigator reads that load's source from now on
        with self._lock:
            other = next(((i, dataclasses.replace(s)) for i, s in self._served.items()
                          if s.robot == served.robot and s.topic), None)
        if other is not None:
            self._announce(*other)

    def close(self) -> None:
        """Stop the fail-back's watch (the manager shuts down)."""
        self._closed.set()

    def served(self, load_id: int) -> Optional[Served]:
        """A copy of what ``load_id`` holds now, or None."""
        with self._lock:
            served = self._served.get(load_id)
            return dataclasses.replace(served) if served is not None else None

    def holds(self, local_id: int) -> bool:
        with self._lock:
            return local_id in self._by_source

    def failed(self, local_id: int, why: str) -> bool:
        """The source ``local_id`` failed: fail over on a thread of its own (or, a source back in its hold, let it
        go: a flap). False if it is not one of ours."""
        if self._flapped(local_id, why):
            return True
        with self._lock:
            load_id = self._by_source.pop(local_id, None)
            served = self._served.get(load_id) if load_id is not None else None
            if served is None:
                return False
            failed, served.local_id, served.topic = served.source, 0, ''
        self._tell(load_id, ResourceStatus.UPDATE, 'obstacle source %s failed: %s; the robot waits for the next'
                   % (failed.label, why))
        self._release(local_id)
        threading.Thread(target=self._fail_over, args=(load_id, served, failed),
                         name='obstacle failover %s' % served.robot, daemon=True).start()
        return True

    def _fail_over(self, load_id: int, served: Served, failed: ObstacleSource) -> None:
        try:
            source, (local_id, sensor, topic) = self._first(served.robot, served.ranked, skip=[failed])
        except TemotoError as err:
            self._log('%s: no obstacle source left: %s' % (served.robot, err))
            self._tell(load_id, ResourceStatus.FAILED, 'navigation of %s has no obstacle source left: %s'
                       % (served.robot, err))
            return
        with self._lock:
            if served.released:                       # unloaded meanwhile: nobody wants it now
                keep = False
            else:
                keep = True
                served.source, served.local_id, served.topic, served.sensor = source, local_id, topic, sensor
                self._by_source[local_id] = load_id
        if not keep:
            self._release(local_id)
            return
        self._announce(load_id, served)
        self._tell(load_id, ResourceStatus.UPDATE, 'obstacles from %s (%s) on %s now; the robot drives on'
                   % (source.label, sensor, topic))

    # -- fail-back ---------------------------------------------------------------------------------------------
    def _flapped(self, local_id: int, why: str) -> bool:
        with self._lock:
            load_id = self._candidates.pop(local_id, None)
            served = self._served.get(load_id) if load_id is not None else None
            if served is None or served.candidate is None or served.candidate[1] != local_id:
                return False
            source, served.candidate = served.candidate[0], None
            wait = self._backoff(served, source).failed(time.monotonic(), flapped=True)
        self._log('%s: obstacle source %s came back and failed within its hold (%s): let go; tried again in %.0f s'
                  % (served.robot, source.label, why, wait))
        self._release(local_id)
        return True

    def _backoff(self, served: Served, source: ObstacleSource) -> Backoff:
        """(with the lock)"""
        fb = self.failback
        return served.backoffs.setdefault(source.label, Backoff(fb.check_s, fb.max_s, fb.quarantine_after,
                                                                fb.quarantine_s))

    def _watch_failback(self) -> None:
        while not self._closed.wait(self.failback.period_s):
            try:
                self._failback_once(time.monotonic())
            except Exception as err:             # noqa: BLE001 - the watch must outlive one bad step; said
                self._log('obstacle fail-back: %s: %s' % (type(err).__name__, err))

    def _failback_once(self, now: float) -> None:
        """One look at every load: a candidate through its hold is taken; else the best better source that may be
        tried is started (outside the lock: it takes seconds)."""
        with self._lock:
            loads = list(self._served.items())
        for load_id, served in loads:
            with self._lock:
                if served.released or served.source is None or not served.local_id:
                    continue                      # failing over now: the failover's, not ours
                candidate = served.candidate
                if candidate is not None:
                    if now - candidate[4] >= self.failback.hold_s:
                        self._take_back(load_id, served)
                    continue
                better = list(served.ranked[:list(served.ranked).index(served.source)]) \
                    if served.source in served.ranked else []
                ready = [s for s in better if self._backoff(served, s).ready(now)]
            if ready:
                self._try_back(load_id, served, ready[0])

    def _try_back(self, load_id: int, served: Served, source: ObstacleSource) -> None:
        try:
            local_id, sensor, topic = self._start(source)
        except TemotoError as err:
            with self._lock:
                wait = self._backoff(served, source).failed(time.monotonic(), flapped=False)
            self._log('%s: obstacle source %s is not back: %s; tried again in %.0f s'
                      % (served.robot, source.label, err, wait))
            return
        with self._lock:
            keep = not served.released and served.candidate is None and served.local_id != 0
            if keep:
                served.candidate = (source, local_id, sensor, topic, time.monotonic())
                self._candidates[local_id] = load_id
        if not keep:
            self._release(local_id)
            return
        self._log('%s: obstacle source %s (%s) is back on %s: held %.1f s before the navigator takes it'
                  % (served.robot, source.label, sensor, topic, self.failback.hold_s))

    def _take_back(self, load_id: int, served: Served) -> None:
        """(with the lock) The candidate ran its whole hold: it is the navigator's source; the lower one goes."""
        source, local_id, sensor, topic, _ = served.candidate
        served.candidate = None
        self._candidates.pop(local_id, None)
        lower = served.local_id
        self._by_source.pop(lower, None)
        served.source, served.local_id, served.topic, served.sensor = source, local_id, topic, sensor
        self._by_source[local_id] = load_id
        self._backoff(served, source).succeeded()
        threading.Thread(target=self._switched, args=(load_id, dataclasses.replace(served), lower),
                         name='obstacle failback switch', daemon=True).start()

    def _switched(self, load_id: int, served: Served, lower: int) -> None:
        """Said and done outside the lock: the navigator told first, then the lower source released."""
        self._announce(load_id, served)
        self._tell(load_id, ResourceStatus.UPDATE, 'obstacles from %s (%s) on %s again: it works again; the robot '
                   'drives on' % (served.source.label, served.sensor, served.topic))
        self._release(lower)

    def summary(self) -> List[dict]:
        with self._lock:
            return [{'load': load_id, 'robot': s.robot, 'obstacles': s.summary} for load_id, s in self._served.items()]

