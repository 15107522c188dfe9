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
3. none works: FAILED, naming each source and why, as the Sensor Manager's own failover does.

The failover runs on its own thread: a sensor's start takes seconds, and the registrar's status
thread must stay free for the next status.
"""
from __future__ import annotations

import dataclasses
import threading
from typing import Callable, Dict, List, Optional, Sequence

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

    @property
    def summary(self) -> str:
        return '%s (%s) on %s' % (self.source.label, self.sensor, self.topic) if self.source else 'none'


# start(source) -> (local id, sensor name, topic); release(local id); tell(load id, code, message);
# announce(load id, served): a load's source is new (the navigator's latched topic, the journal)
Start = Callable[[ObstacleSource], tuple]


class ObstacleFailover:
    def __init__(self, start: Start, release: Callable[[int], None], tell: Callable[[int, int, str], None],
                 announce: Callable[[int, Served], None], subsystem: int, log: Callable[[str], None]) -> None:
        self._start, self._release, self._tell, self._announce = start, release, tell, announce
        self._subsystem, self._log = subsystem, log
        self._lock = threading.Lock()
        self._served: Dict[int, Served] = {}          # load_robot internal id -> its source
        self._by_source: Dict[int, int] = {}          # a source's local id -> the load it serves

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
        """The robot is unloaded (or its load rolled back): its source goes too."""
        with self._lock:
            served = self._served.pop(load_id, None)
            if served is None:
                return
            served.released = True
            self._by_source.pop(served.local_id, None)
        if served.local_id:
            self._release(served.local_id)

    def served(self, load_id: int) -> Optional[Served]:
        """A copy of what ``load_id`` holds now, or None."""
        with self._lock:
            served = self._served.get(load_id)
            return dataclasses.replace(served) if served is not None else None

    def holds(self, local_id: int) -> bool:
        with self._lock:
            return local_id in self._by_source

    def failed(self, local_id: int, why: str) -> bool:
        """The source ``local_id`` failed: fail over on a thread of its own. False if it is not one of ours."""
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

    def summary(self) -> List[dict]:
        with self._lock:
            return [{'load': load_id, 'robot': s.robot, 'obstacles': s.summary} for load_id, s in self._served.items()]

