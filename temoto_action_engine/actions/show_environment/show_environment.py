"""show_environment: the paper's demo. Keep the operator seeing the surroundings.

The original ``ShowEnv`` task stepped through depth camera -> Hokuyo -> Sick in its sensor
status callback and never released the failed sensors. This port:
- takes the priority list from the engine parameter ``~actions/show_environment/sensor_priority``
  (default: the VaultBot's, from the paper's section 4);
- states its own failure policy with each request (``on_status=``): a FAILED of the sensor or of
  its display comes to this action's run loop, never to an interface's default reload;
- on a FAILED of the active sensor, hides its display at once (a frozen last frame must not look
  live), requests the next entry and shows it, and only then releases the failed sensor, on a
  background thread: unloading a stalled driver can take seconds (SIGINT, then SIGTERM), and the
  operator's view must not wait for it. Each failed pair is released exactly once, and on_stop
  waits for the releases still running, so a stopped action holds nothing;
- on a FAILED of the display alone (the RViz host crashed), shows the same sensor again (the
  Output Manager starts a new host); only if that fails does it fail over to the next entry;
- tries the entries with ``temoto_core.fallback.first_that_works``, the same loop the managers use;
- asks for the display on the topic the sensor will most likely get (the Sensor Manager's
  catalogue ranking) while the sensor starts, instead of after: RViz then subscribes while the
  driver starts, and draws its first message at once. A wrong guess is hidden and the right
  topic shown, as without the guess (parameter ``speculative_display``, default true);
- when every entry has failed, says so on the feedback topic and in the log, and retries from
  the top of the list with a bounded exponential backoff until a device comes back;
- keeps a spare ready under the ``standby`` policy (configuration, or said in the request:
  "... with a hot standby"; ``failover_policy.py``): ``warm`` runs the next entry's driver, ``hot``
  also streams it into a hidden display, so a failover is one visibility change. The spare is a
  real resource of its own: its FAILED is reported (``standby_failed``) and it is replaced. It is
  never the device on screen: the manager's ranking would give the same device to two entries;
- fails back: while it shows a worse entry, it tries the better ones (with a doubling wait), holds
  one that starts with a hidden display for ``failback_hold_s``, and shows it if it did not fail
  meanwhile, by a visibility change, so with no blank frame. A source that fails within a hold
  flaps: ``quarantine_after`` flaps in a row keep it out for ``quarantine_s``;
- publishes each step (sensor_active with ``via``, sensor_failed, sensor_unavailable, all_failed,
  retry, standby_ready, standby_failed, standby_unavailable, failback_candidate, failback,
  failback_abandoned) on /<ns>/action_engine/events, so a bag shows when FAILED arrived, what
  replaced the sensor, and which policy did it.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Optional

import yaml

from temoto_action_engine.action_base import ActionBase, ActionError
from temoto_action_engine.failover_policy import Backoff, FailoverConfig, Standby
from temoto_core.errors import Subsystem
from temoto_core.fallback import NoCandidateLeft, first_that_works
RELEASE_JOIN_S = 30.0   # on_stop waits this long for each background release (an unload is bounded itself)
GUESS_JOIN_S = 30.0     # how long the right guess may still take once the sensor is up
CATALOGUE_TIMEOUT_S = 0.5
# where an entry's sensor is asked for: the robot's Sensor Manager (the action's robot, or the engine's own when
# there is none), or the station's (the engine's own namespace: a sensor wired to the operator's station)
SENSOR_MANAGERS = ('robot', 'station')

# what the run loop holds, and its timers
ACTIVE, SPARE, BETTER = 'active', 'standby', 'failback candidate'
RETRY, FAILBACK = 'retry', 'failback'

DEFAULT_PRIORITY = [
    {'label': 'RGB-D camera cloud', 'sensor_type': 'depth camera', 'output_topics': ['camera_data'],
     'display_type': 'point cloud', 'display_key': 'camera_data'},
    {'label': 'arm LIDAR stitched cloud', 'sensor_type': 'lidar', 'output_topics': ['lidar_data', 'cloud_data'],
     'display_type': 'point cloud', 'display_key': 'cloud_data'},
    {'label': 'base LIDAR scan', 'sensor_type': 'lidar', 'output_topics': ['lidar_data'],
     'display_type': 'laser scan', 'display_key': 'lidar_data',
     'display_config': {'Style': 'Flat Squares', 'Size (m)': 0.05, 'Color Transformer': 'FlatColor',
                        'Color': '255; 120; 0'}},
]


@dataclass(frozen=True)
class SensorChoice:
    label: str
    sensor_type: str
    output_topics: tuple
    display_type: str
    display_key: str
    display_config: str = ''     # RViz properties (YAML) for the display, e.g. point size and colour
    station: bool = False        # served by the operator's station's Sensor Manager, not the robot's


@dataclass
class Active:
    """An entry whose sensor runs: the one on screen, the spare, or a fail-back candidate."""
    index: int
    choice: SensorChoice
    sensor_name: str
    resource_id: int
    topic: str
    display_id: object          # None: no display yet (a warm spare)
    since: float = 0.0          # when it went on screen (time.monotonic())


@dataclass
class Prepared:
    """What a helper thread brings the run loop: a spare or a fail-back candidate held, or why none."""
    role: str                   # SPARE or BETTER
    held: Optional[Active]
    why: str
    failed: list                # the priority indexes that were tried and failed


class SpeculativeDisplay:
    """A display requested, on a helper thread, on the topic a sensor will most likely be given.

    ``take(topic)`` returns its id when it shows ``topic`` (the caller then owns it); otherwise,
    and from ``discard()``, it is hidden exactly once, now or when its request returns (a
    discard can come while the request is still out, when the sensor request fails fast).
    """

    def __init__(self, action: 'ShowEnvironment', choice: SensorChoice):
        self.action, self.choice = action, choice
        self.topic = ''
        self.display_id = None
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._settled = False          # taken or discarded
        self._thread = threading.Thread(target=self._run, daemon=True, name='display guess for %s' % choice.label)
        self._thread.start()

    def _run(self) -> None:
        did = None
        try:
            topic = self.action.likely_topic(self.choice)
            if topic:
                with self._lock:
                    self.topic = topic
                    settled = self._settled
                if not settled:
                    did = self.action.show(self.choice, topic)
        except Exception as e:          # only a guess: the display is requested after the sensor then
            self.action.log_info('no early display for %s: %s' % (self.choice.label, e))
        with self._lock:
            self.display_id = did
            orphan = did if self._settled else None
        self._done.set()
        if orphan is not None:
            self.action.hide_display(orphan, self.choice.label)

    def take(self, topic: str):
        """The display's id if it shows ``topic``; else it is hidden and None returned.

        Waits for the guess to finish: it has had the whole sensor start to do so, and when
        it shows the right topic, waiting is quicker than asking for the display again.
        """
        self._done.wait(GUESS_JOIN_S)
        with self._lock:
            if self.topic == topic and self.display_id is not None and not self._settled:
                self._settled = True
                return self.display_id
        self.discard()
        return None

    def discard(self) -> None:
        with self._lock:
            if self._settled:
                return
            self._settled = True
            did, self.display_id = self.display_id, None
        if did is not None:
            self.action.hide_display(did, self.choice.label)


def parse_priority(raw) -> list[SensorChoice]:
    """Validate the priority list parameter; raise ActionError naming the bad entry."""
    if not isinstance(raw, list) or not raw:
        raise ActionError('sensor_priority must be a non-empty list, got %r' % (raw,))
    out = []
    for i, e in enumerate(raw):
        if not isinstance(e, dict):
            raise ActionError('sensor_priority[%d] must be a mapping, got %r' % (i, e))
        keys = e.get('output_topics')
        if not isinstance(keys, list) or not keys or not all(isinstance(k, str) and k for k in keys):
            raise ActionError('sensor_priority[%d].output_topics must be a non-empty list of keys' % i)
        for f in ('sensor_type', 'display_type'):
            if not isinstance(e.get(f), str) or not e[f]:
                raise ActionError('sensor_priority[%d].%s must be a non-empty string' % (i, f))
        key = e.get('display_key', keys[0])
        if key not in keys:
            raise ActionError('sensor_priority[%d].display_key %r is not one of its output_topics %s'
                              % (i, key, keys))
        config = e.get('display_config', '')
        if isinstance(config, dict):
            config = yaml.safe_dump(config, default_flow_style=True).strip()
        elif not isinstance(config, str):
            raise ActionError('sensor_priority[%d].display_config must be a mapping of RViz properties or YAML, '
                              'got %r' % (i, config))
        where = e.get('sensor_manager', 'robot')
        if where not in SENSOR_MANAGERS:
            raise ActionError('sensor_priority[%d].sensor_manager must be one of %s, got %r'
                              % (i, ', '.join(SENSOR_MANAGERS), where))
        out.append(SensorChoice(str(e.get('label', e['sensor_type'])), e['sensor_type'], tuple(keys),
                                e['display_type'], key, config, where == 'station'))
    return out


class ShowEnvironment(ActionBase):
    def on_start(self):
        self.priority = parse_priority(self.config.get('sensor_priority', DEFAULT_PRIORITY))
        try:
            self.policy = FailoverConfig.from_config(self.config, self.input('standby'))
        except ValueError as e:
            raise ActionError(str(e)) from None
        self.speculative = bool(self.config.get('speculative_display', True))
        self.backoff = self.policy.retry_initial_s
        self.spare_wait = self.policy.retry_initial_s
        self.active: Active | None = None
        self.spare: Active | None = None      # warm/hot: the next working entry, held ready
        self.better: Active | None = None     # fail-back: a better entry that works again, held hidden
        self.timers: dict[str, float] = {}    # RETRY, SPARE, BETTER, FAILBACK -> when (time.monotonic())
        self.preparing: dict[str, threading.Thread] = {}
        self.source_backoff = [Backoff(self.policy.failback_check_s, self.policy.failback_max_s,
                                       self.policy.quarantine_after, self.policy.quarantine_s) for _ in self.priority]
        self.releases: list[threading.Thread] = []   # background releases of failed sensors
        self.omi = self.output_manager
        self.activate_from(0, 'start')     # sets the output 'topic' when a sensor is up (children start after this)

    def execute(self):
        while self.action_ok():
            due = min(self.timers.values()) if self.timers else None
            item = self.next_item(3600.0 if due is None else max(0.0, due - time.monotonic()))
            if not self.action_ok():
                break
            if isinstance(item, Prepared):
                self.on_prepared(item)
            elif item is not None:
                self.handle_status(item)
            self.run_due_timers()

    def on_stop(self):
        for held in (self.active, self.spare, self.better):
            if held is not None:
                self._release(held)
        self.active = self.spare = self.better = None
        for thread in list(self.preparing.values()):
            thread.join(RELEASE_JOIN_S)
        while True:        # what a preparer brought after the run loop ended is released, not leaked
            item = self.next_item(0.0)
            if item is None:
                break
            if isinstance(item, Prepared) and item.held is not None:
                self._release(item.held)
        for thread in self.releases:
            thread.join(RELEASE_JOIN_S)
            if thread.is_alive():
                self.log_warn('%s still running after %.0f s; the registrar releases what is left'
                              % (thread.name, RELEASE_JOIN_S))

    def run_due_timers(self) -> None:
        now = time.monotonic()
        for name in [n for n, t in self.timers.items() if t <= now]:
            if self.timers.pop(name, None) is None:     # cancelled by an earlier handler in this pass
                continue
            if name == RETRY:
                self.event('retry', backoff_s=self.backoff)
                self.activate_from(0, 'retry')
            elif name == FAILBACK:
                self.fail_back()
            else:
                self.prepare(name)

    # ------------------------------------------------------------------ steps
    def handle_status(self, ev) -> None:
        rid = ev.resource_id
        role, held = next(((r, h) for r, h in ((ACTIVE, self.active), (SPARE, self.spare), (BETTER, self.better))
                           if h is not None and rid in (h.resource_id, h.display_id)), (None, None))
        if held is None:
            self.log_info('status %s for resource %s, which is not in use any more; ignored' % (ev.code.name, rid))
            return
        if not ev.failed:
            self.log_info('status %s for %s: %s' % (ev.code.name, held.sensor_name, ev.message))
            return
        if role == ACTIVE:
            self.fail_over(held, ev)
        elif role == SPARE:
            self.spare = None
            self.event('standby_failed', sensor_name=held.sensor_name, label=held.choice.label,
                       priority_index=held.index, message=ev.message, standby=self.policy.standby.value)
            self.release_in_background(held)
            self._retry_spare_later()
        else:
            self.better = None
            self.timers.pop(FAILBACK, None)
            wait = self.source_backoff[held.index].failed(time.monotonic(), flapped=True)
            self.event('failback_abandoned', sensor_name=held.sensor_name, label=held.choice.label,
                       priority_index=held.index, message=ev.message, retry_in_s=wait,
                       quarantined=self.source_backoff[held.index].quarantined)
            self.release_in_background(held)
            self._plan()

    def fail_over(self, a: Active, ev) -> None:
        """The shown entry failed: the better candidate or the spare if one is held, else the next that works."""
        display_only = ev.resource_id == a.display_id and ev.resource_id != a.resource_id
        self.event('sensor_failed', sensor_name=a.sensor_name, sensor_type=a.choice.sensor_type,
                   label=a.choice.label, priority_index=a.index, message=ev.message,
                   failed_part='display' if display_only else 'sensor', standby=self.policy.standby.value)
        if display_only and self.reshow(a, ev.message):
            return
        now = time.monotonic()
        backoff = self.source_backoff[a.index]
        flapped = now - a.since < self.policy.failback_hold_s
        if not flapped:
            backoff.succeeded()          # it ran a whole hold: this failure starts a new count
        backoff.failed(now, flapped)
        # The failed view goes off screen at once; the substitute comes next; the failed sensor is
        # released once the substitute is up (or none is).
        self.active = None
        self.hide_in_background(a)
        for held, via in ((self.better, 'failback candidate'), (self.spare, 'standby')):
            if held is None:
                continue
            self.better = None if held is self.better else self.better
            self.spare = None if held is self.spare else self.spare
            if self._promote(held, via):
                break
        else:
            self.activate_from(a.index + 1, 'failover')
        if self.better is None:
            self.timers.pop(FAILBACK, None)
        self.release_in_background(a)
        self._plan()

    def fail_back(self) -> None:
        """A better entry ran a whole hold: show it, and keep the one it replaces as the spare if that helps."""
        b, a = self.better, self.active
        self.better = None
        if b is None:
            return
        if a is None or b.index >= a.index:
            self.release_in_background(b)
            self._plan()
            return
        self.active = None
        if not self._promote(b, 'failback'):
            self.active = a
            self._plan()
            return
        self.source_backoff[b.index].succeeded()
        kept = self._keep_as_spare(a)
        if not kept:
            self.hide_in_background(a)
            self.release_in_background(a)
        self.event('failback', label=b.choice.label, sensor_name=b.sensor_name, priority_index=b.index,
                   from_label=a.choice.label, from_sensor=a.sensor_name, from_index=a.index,
                   kept_as_standby=kept, standby=self.policy.standby.value)
        self._plan()

    def _keep_as_spare(self, a: Active) -> bool:
        """Under warm and hot, the entry a fail-back leaves is the best spare there is: keep it running."""
        if self.policy.standby is Standby.COLD or (self.spare is not None and self.spare.index < a.index):
            return False
        if self.policy.standby is Standby.HOT:
            try:
                self.omi.set_visible(a.display_id, False)
            except Exception as e:
                self.log_warn('could not hide the display of %s to keep it as the standby: %s' % (a.choice.label, e))
                return False
        else:
            self.hide_in_background(a)
        previous, self.spare = self.spare, a
        if previous is not None:
            self.release_in_background(previous)
        return True

    def _promote(self, held: Active, via: str) -> bool:
        """Put a held entry on screen: show its hidden display (hot), or add its display (warm)."""
        try:
            if held.display_id is not None:
                self.omi.set_visible(held.display_id, True)
            else:
                held.display_id = self.show(held.choice, held.topic)
        except Exception as e:
            self.event('standby_failed', sensor_name=held.sensor_name, label=held.choice.label,
                       priority_index=held.index, message='could not show it: %s' % e,
                       standby=self.policy.standby.value)
            self.hide_in_background(held)
            self.release_in_background(held)
            return False
        self._now_active(held, via)
        return True

    # ------------------------------------------------------------------ spares and fail-back candidates
    def _plan(self) -> None:
        """Arm what the shown entry needs next: a spare (warm, hot), and a look at better entries (fail-back)."""
        a = self.active
        if a is None:
            return
        now = time.monotonic()
        if self.spare is not None and self.spare.index <= a.index:
            stale, self.spare = self.spare, None
            self.hide_in_background(stale)
            self.release_in_background(stale)
        if self.better is not None and self.better.index >= a.index:
            stale, self.better = self.better, None
            self.timers.pop(FAILBACK, None)
            self.hide_in_background(stale)
            self.release_in_background(stale)
        if (self.policy.standby is not Standby.COLD and self.spare is None and a.index + 1 < len(self.priority)
                and SPARE not in self.timers and not self._preparing(SPARE)):
            self.timers[SPARE] = now
        if (self.policy.failback and a.index > 0 and self.better is None and BETTER not in self.timers
                and not self._preparing(BETTER)):
            self.timers[BETTER] = max(now, min(self.source_backoff[i].not_before for i in range(a.index)))

    def _retry_spare_later(self) -> None:
        self.timers[SPARE] = time.monotonic() + self.spare_wait
        self.spare_wait = min(self.spare_wait * 2.0, self.policy.retry_max_s)

    def _preparing(self, role: str) -> bool:
        thread = self.preparing.get(role)
        return thread is not None and thread.is_alive()

    def prepare(self, role: str) -> None:
        """Start holding a spare (entries after the shown one) or a fail-back candidate (entries before it)
        on a helper thread: a driver takes a while to start, and the run loop must hear FAILED meanwhile."""
        a = self.active
        if a is None or self._preparing(role):
            return
        now = time.monotonic()
        if role == SPARE:
            indexes = list(range(a.index + 1, len(self.priority)))
        else:
            indexes = [i for i in range(a.index) if self.source_backoff[i].ready(now)]
        if not indexes:
            self._plan()
            return
        # a fail-back candidate is always hidden: showing it is then a visibility change, with no blank frame
        hidden = role == BETTER or self.policy.standby is Standby.HOT
        avoid = frozenset(h.sensor_name for h in (a, self.spare, self.better) if h is not None)
        thread = threading.Thread(target=self._prepare, args=(role, indexes, hidden, avoid), daemon=True,
                                  name='%s for the operator\'s view' % role)
        self.preparing[role] = thread
        thread.start()

    def _prepare(self, role: str, indexes: list, hidden: bool, avoid: frozenset) -> None:
        failed: list = []
        try:
            _, held = first_that_works(indexes, lambda i: self._hold(i, hidden, avoid), what='a %s' % role,
                                       subsystem=Subsystem.ACTION_ENGINE, name=lambda i: self.priority[i].label,
                                       on_failure=lambda tried: failed.append(tried.candidate),
                                       keep_going=self.action_ok, errors=(Exception,))
            why = ''
        except NoCandidateLeft as e:
            held, why = None, str(e)
        except Exception as e:          # handed to the run loop, which reports it
            held, why = None, 'preparing a %s failed: %s' % (role, e)
        self.post(Prepared(role, held, why, failed))

    def _hold(self, i: int, hidden: bool, avoid: frozenset) -> Active:
        """Entry ``i``'s sensor, running, and (``hidden``) its display, subscribed but not drawn.

        The device must not be one in ``avoid`` (those the view already holds): the manager would answer a
        spare's request with the device on screen when it ranks first for both entries, and a spare on the
        same device fails with it. So the best other device is asked for by package and executable.
        """
        choice = self.priority[i]
        keys = list(choice.output_topics)
        smi = self.smi_for(choice)
        rows = [r for r in smi.ranked_sensors(choice.sensor_type, keys, CATALOGUE_TIMEOUT_S)
                if r.get('name') not in avoid]
        if not rows:
            raise ActionError('no %s with %s other than %s' % (choice.sensor_type, ', '.join(keys),
                                                               ', '.join(sorted(avoid)) or 'none'))
        result = smi.start_sensor(choice.sensor_type, output_topics={k: '' for k in keys},
                                  package_name=str(rows[0].get('package', '')),
                                  executable=str(rows[0].get('executable', '')), on_status=self.post)
        topic = dict(result.output_topics).get(choice.display_key, '')
        display_id = None
        try:
            if result.sensor_name in avoid:
                raise ActionError('the manager gave %s, which the view holds already' % result.sensor_name)
            if not topic:
                raise ActionError('the sensor gave no %r topic' % choice.display_key)
            if hidden:
                display_id = self.show(choice, topic, hidden=True)
        except Exception:
            self._stop_sensor(choice, result.resource_id)
            raise
        return Active(i, choice, result.sensor_name, result.resource_id, topic, display_id)

    def on_prepared(self, p: 'Prepared') -> None:
        self.preparing.pop(p.role, None)
        now = time.monotonic()
        if p.role == BETTER:
            for i in p.failed:
                self.source_backoff[i].failed(now, flapped=False)
        held, a = p.held, self.active
        if held is None:
            if p.role == BETTER:
                # each try is told, so the timeline shows the backoff at work (a flapping cable, a dead one)
                self.event('failback_unavailable', message=p.why, priority_indexes=list(p.failed),
                           retry_in_s=round(max(0.0, min((self.source_backoff[i].not_before for i in p.failed),
                                                         default=now) - now), 3))
            if p.role == SPARE:
                self.event('standby_unavailable', message=p.why, standby=self.policy.standby.value)
                self._retry_spare_later()
            self._plan()
            return
        in_use = {h.sensor_name for h in (a, self.spare, self.better) if h is not None}
        wanted = a is not None and held.sensor_name not in in_use and (
            (p.role == SPARE and self.spare is None and held.index > a.index) or
            (p.role == BETTER and self.better is None and held.index < a.index))
        if not wanted:
            self.hide_in_background(held)
            self.release_in_background(held)
        elif p.role == SPARE:
            self.spare = held
            self.event('standby_ready', sensor_name=held.sensor_name, label=held.choice.label,
                       priority_index=held.index, topic=held.topic, standby=self.policy.standby.value,
                       display='hidden' if held.display_id is not None else 'none')
        else:
            self.better = held
            self.timers[FAILBACK] = now + self.policy.failback_hold_s
            self.event('failback_candidate', sensor_name=held.sensor_name, label=held.choice.label,
                       priority_index=held.index, hold_s=self.policy.failback_hold_s)
        self._plan()

    def reshow(self, a: Active, why: str) -> bool:
        """The display of a healthy sensor failed: show the same topic again (a new RViz host)."""
        failed_display, a.display_id = a.display_id, None
        self.release_display_in_background(failed_display, a.choice.label)
        try:
            a.display_id = self.show(a.choice, a.topic)
        except Exception as e:
            self.event('display_failed', sensor_name=a.sensor_name, label=a.choice.label,
                       priority_index=a.index, message=str(e))
            return False
        self.event('display_restored', sensor_name=a.sensor_name, label=a.choice.label, priority_index=a.index,
                   topic=a.topic, message=why)
        self.feedback('the display of the %s failed (%s); showing it again' % (a.choice.label, why))
        return True

    def show(self, choice: SensorChoice, topic: str, hidden: bool = False):
        """A display of ``topic`` whose failures come to this action's run loop."""
        return self.omi.show_in_rviz(choice.display_type, topic, name=self.display_name(choice),
                                     config=choice.display_config, on_status=self.post, hidden=hidden)

    def display_name(self, choice: SensorChoice) -> str:
        """The entry's label, and the robot's name when the view is of a named robot: one station shows
        several robots, and RViz's display names must differ (the Output Manager refuses a taken name)."""
        robot = self.input('robot')
        return '%s (%s)' % (choice.label, robot.strip('/')) if isinstance(robot, str) and robot.strip('/') \
            else choice.label

    def activate_from(self, start: int, via: str) -> None:
        """Bring up the first entry from ``start`` on that works (``via``: why, for the event); on none,
        schedule a retry."""
        try:
            _, active = first_that_works(
                range(start, len(self.priority)), self._activate, what='the operator\'s view',
                subsystem=Subsystem.ACTION_ENGINE, name=lambda i: self.priority[i].label,
                on_failure=lambda tried: self.source_backoff[tried.candidate].failed(time.monotonic(), flapped=False),
                keep_going=self.action_ok, errors=(Exception,))
        except NoCandidateLeft:
            if self.action_ok():
                self._schedule_retry()
            return
        self._now_active(active, via)
        self._plan()

    def _now_active(self, a: Active, via: str) -> None:
        """``a`` is on screen: say so (event, output, feedback)."""
        a.since = time.monotonic()
        self.active = a
        self.set_output('topic', a.topic)       # the topic shown now (list_graphs reports it)
        self.timers.pop(RETRY, None)
        self.backoff = self.policy.retry_initial_s
        if via in ('standby', 'failback candidate'):
            self.spare_wait = self.policy.retry_initial_s
        self.event('sensor_active', sensor_name=a.sensor_name, sensor_type=a.choice.sensor_type,
                   label=a.choice.label, priority_index=a.index, topic=a.topic, display_type=a.choice.display_type,
                   via=via, standby=self.policy.standby.value)
        if via == 'failback':
            said = 'a better sensor is back: '
        elif via == 'retry':
            said = 'a sensor is back: '
        else:
            said = ''
        self.feedback('%sshowing the %s (%s) as %s on %s' % (said, a.choice.label, a.sensor_name,
                                                             a.choice.display_type, a.topic))

    def _activate(self, i: int) -> Active:
        """Entry ``i``: its sensor, then its display; raises (after rolling back) when either fails."""
        choice = self.priority[i]
        guess = SpeculativeDisplay(self, choice) if self.speculative else None
        try:
            result = self.smi_for(choice).start_sensor(
                choice.sensor_type, output_topics={k: '' for k in choice.output_topics}, on_status=self.post)
        except Exception as e:
            if guess is not None:
                guess.discard()
            self.event('sensor_unavailable', sensor_type=choice.sensor_type, label=choice.label,
                       priority_index=i, message=str(e))
            raise
        topic = dict(result.output_topics).get(choice.display_key, '')
        display_id = guess.take(topic) if guess is not None else None
        try:
            if not topic:
                raise ActionError('the sensor gave no %r topic' % choice.display_key)
            if display_id is None:
                display_id = self.show(choice, topic)
        except Exception as e:
            self.event('display_failed', sensor_name=result.sensor_name, label=choice.label,
                       priority_index=i, message=str(e))
            self._stop_sensor(choice, result.resource_id)
            raise
        return Active(i, choice, result.sensor_name, result.resource_id, topic, display_id)

    def _schedule_retry(self) -> None:
        """Every entry failed: say so, keep watching with a bounded backoff."""
        delay = self.backoff
        self.timers[RETRY] = time.monotonic() + delay
        self.backoff = min(self.backoff * 2.0, self.policy.retry_max_s)
        labels = ', '.join(c.label for c in self.priority)
        self.event('all_failed', retry_in_s=delay, sensors=labels)
        self.log_err('every sensor failed (%s); the operator has no view; retrying in %.1f s' % (labels, delay))
        self.feedback('every sensor failed (%s); nothing to show. Retrying in %.0f s.' % (labels, delay))

    def _in_background(self, target, name: str, *args) -> None:
        self.releases = [t for t in self.releases if t.is_alive()]
        thread = threading.Thread(target=target, args=args, daemon=True, name=name)
        self.releases.append(thread)
        thread.start()

    def hide_in_background(self, a: Active) -> None:
        """Take a failed sensor's view off the screen now, without holding up the failover."""
        display_id, a.display_id = a.display_id, None
        self.release_display_in_background(display_id, a.choice.label)

    def release_display_in_background(self, display_id, label: str) -> None:
        if display_id is not None:
            self._in_background(self.hide_display, 'hide the display of %s' % label, display_id, label)

    def release_in_background(self, a: Active) -> None:
        """Release a failed sensor (and its display, unless hidden already) without holding up the run loop."""
        self._in_background(self._release, 'release of %s (%s)' % (a.sensor_name, a.choice.label), a)

    def _release(self, a: Active) -> None:
        if a.display_id is not None:
            self.hide_display(a.display_id, '%s (%s)' % (a.choice.label, a.sensor_name))
        self._stop_sensor(a.choice, a.resource_id)

    def hide_display(self, display_id, what: str) -> None:
        try:
            self.omi.hide(display_id)
        except Exception as e:
            self.log_warn('hiding the display of %s: %s' % (what, e))

    def likely_topic(self, choice: SensorChoice) -> str:
        """The topic ``choice``'s display will most likely show: the Sensor Manager's catalogue ranking."""
        topics = self.smi_for(choice).likely_topics(choice.sensor_type, list(choice.output_topics),
                                                    CATALOGUE_TIMEOUT_S)
        return (topics or {}).get(choice.display_key, '')

    def smi_for(self, choice: SensorChoice):
        """The Sensor Manager interface that serves ``choice``: the robot's or the station's."""
        return self.station_sensor_manager if choice.station else self.sensor_manager

    def _stop_sensor(self, choice: SensorChoice, resource_id) -> None:
        try:
            self.smi_for(choice).stop_sensor(resource_id)
        except Exception as e:
            self.log_warn('stopping sensor resource %s: %s' % (resource_id, e))
