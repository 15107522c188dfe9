"""Keep an operator's view up: which source is shown, which are held ready, and what a FAILED changes.

The original ``ShowEnv`` task stepped through depth camera -> Hokuyo -> Sick in its sensor status
callback and never released the failed sensors. :class:`ViewFailover` is that logic as a state
machine, with no ROS in it, so any action with a priority list of sources can use it and a test
can drive it with plain objects:

- Each running source is a :class:`Held` with a :class:`Role`: ``SHOWN`` (on screen), ``SPARE``
  (the next working entry, run ahead under the warm or hot standby policy) or ``CANDIDATE`` (a
  better entry that works again, held hidden before a fail-back). A held source moves only along
  the edges of ``TRANSITIONS``, as the registrar's queries do (``temoto_core.rr.query``).
- On a FAILED of the shown source, its display is hidden at once (a frozen last frame must not
  look live); the candidate or the spare is promoted if one is held, else the next entry that
  works is started; only then is the failed source released, on a background thread: unloading
  a stalled driver takes seconds, and the view must not wait for it.
- On a FAILED of the shown display alone (the RViz host crashed), the same topic is shown again.
- When every entry failed, the list is tried again with a bounded exponential backoff.
- Spares and candidates are started on helper threads (a driver takes a while to start, and the
  run loop must hear FAILED meanwhile); what they bring arrives as a :class:`Prepared` item.
- Fail-back: a candidate that runs a whole ``failback_hold_s`` is shown by a visibility change;
  one that fails within the hold flapped, and ``failover_policy.Backoff`` quarantines a source
  that flaps too often.

Every step is an event (``sensor_active`` with ``via``, ``sensor_failed``, ``all_failed``,
``retry``, ``standby_ready``, ``standby_failed``, ``standby_unavailable``, ``failback_candidate``,
``failback``, ``failback_abandoned``, ``failback_unavailable``, ``display_restored``), so a bag
shows when FAILED arrived, what replaced the source, and which policy did it. The event names
and ``via`` values are part of the wire: the demo's report reads them.

The machine runs on its action's run loop only: ``start``, ``handle`` and ``stop`` are never called
concurrently. Helper threads talk to it only through ``port.post``.
"""
from __future__ import annotations

import enum
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol, Sequence

from temoto_action_engine.failover_policy import FailoverConfig, Standby
from temoto_core.backoff import Backoff
from temoto_action_engine.view_sources import SensorChoice
from temoto_core.errors import Subsystem
from temoto_core.fallback import NoCandidateLeft, first_that_works

JOIN_S = 30.0   # stop() waits this long for each helper thread (an unload is bounded itself)
IDLE_WAIT_S = 3600.0


class Role(str, enum.Enum):
    STARTING = 'starting'                  # its sensor runs; no role yet
    SHOWN = 'shown'                        # on screen
    SPARE = 'spare'                        # the next working entry, held ready (warm: driver; hot: hidden display)
    CANDIDATE = 'fail-back candidate'      # a better entry that works again, held hidden through a hold
    RELEASED = 'released'                  # given back to its managers

    def __str__(self) -> str:
        return self.value


STARTING, SHOWN, SPARE, CANDIDATE, RELEASED = Role
TRANSITIONS = {
    STARTING: frozenset({SHOWN, SPARE, CANDIDATE, RELEASED}),
    SPARE: frozenset({SHOWN, RELEASED}),            # a failover promotes it
    CANDIDATE: frozenset({SHOWN, RELEASED}),        # a fail-back promotes it
    SHOWN: frozenset({SPARE, RELEASED}),            # a fail-back keeps the source it leaves as the spare
    RELEASED: frozenset(),
}
# ``via`` of the sensor_active event when a held source is promoted (wire names, read by the demo's report)
VIA = {SPARE: 'standby', CANDIDATE: 'failback candidate'}


class Timer(str, enum.Enum):
    RETRY = 'retry'                        # every entry failed: try the list again from the top
    SEEK_SPARE = 'seek a spare'
    SEEK_CANDIDATE = 'seek a fail-back candidate'
    FAILBACK = 'fail back'                 # the candidate ran a whole hold: show it


class IllegalTransition(RuntimeError):
    """A bug in the failover: a held source was moved along an edge the machine does not have."""


@dataclass(eq=False)
class Held:
    """An entry whose sensor runs, and its display (None: none yet, as for a warm spare)."""
    index: int
    choice: SensorChoice
    sensor_name: str
    resource_id: int
    topic: str
    display_id: Any
    role: Role = STARTING
    since: float = 0.0          # when it went on screen (time.monotonic())

    def move(self, to: Role) -> None:
        if to not in TRANSITIONS[self.role]:
            raise IllegalTransition('%s (%s): %s -> %s' % (self.sensor_name, self.choice.label, self.role, to))
        self.role = to


@dataclass
class Prepared:
    """What a helper thread brings the run loop: a spare or a candidate started, or why none."""
    role: Role
    held: Optional[Held]
    why: str
    failed: list = field(default_factory=list)     # the priority indexes that were tried and failed


class Port(Protocol):
    """What the machine needs of its action: the sources' managers, and the action's own outlets."""
    def activate(self, index: int) -> Held: ...       # sensor and display; raises after rolling back
    def hold(self, index: int, hidden: bool, avoid: frozenset) -> Held: ...
    def show(self, held: Held, hidden: bool = False) -> Any: ...
    def set_visible(self, display_id: Any, visible: bool) -> None: ...
    def hide_display(self, display_id: Any, what: str) -> None: ...    # logs its own errors
    def stop_sensor(self, held: Held) -> None: ...                       # logs its own errors
    def shown_topic(self, topic: str) -> None: ...
    def post(self, item: Any) -> None: ...
    def action_ok(self) -> bool: ...
    def event(self, kind: str, **fields: Any) -> None: ...
    def feedback(self, text: str) -> None: ...
    def log_info(self, msg: str) -> None: ...
    def log_warn(self, msg: str) -> None: ...
    def log_err(self, msg: str) -> None: ...


class ViewFailover:
    def __init__(self, priority: Sequence[SensorChoice], policy: FailoverConfig, port: Port) -> None:
        self.priority, self.policy, self.port = list(priority), policy, port
        self.held: dict[Role, Held] = {}                 # SHOWN, SPARE, CANDIDATE: at most one each
        self.timers: dict[Timer, float] = {}             # -> when (time.monotonic())
        self.seeking: dict[Role, threading.Thread] = {}  # SPARE, CANDIDATE: the helper starting one
        self.background: list[threading.Thread] = []     # hides and releases in flight
        self.retry_wait = policy.retry_initial_s
        self.spare_wait = policy.retry_initial_s
        self.source_backoff = [Backoff(policy.failback_check_s, policy.failback_max_s, policy.quarantine_after,
                                       policy.quarantine_s) for _ in self.priority]

    @property
    def shown(self) -> Optional[Held]:
        return self.held.get(SHOWN)

    # ------------------------------------------------------------------ the run loop's calls
    def start(self) -> None:
        self.activate_from(0, 'start')

    def wait_s(self) -> float:
        """How long the run loop may wait for an item before a timer is due."""
        due = min(self.timers.values(), default=None)
        return IDLE_WAIT_S if due is None else max(0.0, due - time.monotonic())

    def handle(self, item: Any) -> None:
        """One item from the action's mailbox (a status event, a Prepared, or None on a timeout), then the
        timers that are due."""
        if isinstance(item, Prepared):
            self.on_prepared(item)
        elif item is not None:
            self.on_status(item)
        now = time.monotonic()
        for timer in [t for t, due in self.timers.items() if due <= now]:
            if self.timers.pop(timer, None) is not None:     # else cancelled by an earlier handler in this pass
                self.on_timer(timer)

    def stop(self, drain: Callable[[], Any]) -> None:
        """Release everything held, and what a helper brings after the run loop ended (``drain`` returns the
        mailbox's next item, or None), then wait for the background releases."""
        for held in list(self.held.values()):
            self._release(held)
        self.held.clear()
        for thread in list(self.seeking.values()):
            thread.join(JOIN_S)
        for _ in range(len(self.seeking) + 1000):        # bounded: at most one Prepared per helper
            item = drain()
            if item is None:
                break
            if isinstance(item, Prepared) and item.held is not None:
                self._release(item.held)
        for thread in self.background:
            thread.join(JOIN_S)
            if thread.is_alive():
                self.port.log_warn('%s still running after %.0f s; the registrar releases what is left'
                                   % (thread.name, JOIN_S))

    # ------------------------------------------------------------------ transitions
    def on_status(self, ev: Any) -> None:
        held = next((h for h in self.held.values() if ev.resource_id in (h.resource_id, h.display_id)), None)
        if held is None:
            self.port.log_info('status %s for resource %s, which is not in use any more; ignored'
                               % (ev.code.name, ev.resource_id))
        elif not ev.failed:
            self.port.log_info('status %s for %s: %s' % (ev.code.name, held.sensor_name, ev.message))
        else:
            {SHOWN: self.fail_over, SPARE: self.spare_failed, CANDIDATE: self.candidate_failed}[held.role](held, ev)

    def on_timer(self, timer: Timer) -> None:
        if timer is Timer.RETRY:
            self.port.event('retry', backoff_s=self.retry_wait)
            self.activate_from(0, 'retry')
        elif timer is Timer.FAILBACK:
            self.fail_back()
        else:
            self.seek(SPARE if timer is Timer.SEEK_SPARE else CANDIDATE)

    def fail_over(self, a: Held, ev: Any) -> None:
        """The shown entry failed: the candidate or the spare if one is held, else the next that works."""
        display_only = ev.resource_id == a.display_id and ev.resource_id != a.resource_id
        self.port.event('sensor_failed', sensor_name=a.sensor_name, sensor_type=a.choice.sensor_type,
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
        del self.held[SHOWN]
        self.hide_in_background(a)
        for role in (CANDIDATE, SPARE):
            held = self.held.pop(role, None)
            if held is not None and self.promote(held, VIA[role]):
                break
        else:
            self.activate_from(a.index + 1, 'failover')
        if CANDIDATE not in self.held:
            self.timers.pop(Timer.FAILBACK, None)
        self.release_in_background(a)
        self.plan()

    def spare_failed(self, held: Held, ev: Any) -> None:
        del self.held[SPARE]
        self.port.event('standby_failed', sensor_name=held.sensor_name, label=held.choice.label,
                        priority_index=held.index, message=ev.message, standby=self.policy.standby.value)
        self.release_in_background(held)
        self._seek_spare_later()

    def candidate_failed(self, held: Held, ev: Any) -> None:
        """The candidate failed within its hold: it flapped."""
        del self.held[CANDIDATE]
        self.timers.pop(Timer.FAILBACK, None)
        backoff = self.source_backoff[held.index]
        wait = backoff.failed(time.monotonic(), flapped=True)
        self.port.event('failback_abandoned', sensor_name=held.sensor_name, label=held.choice.label,
                        priority_index=held.index, message=ev.message, retry_in_s=wait,
                        quarantined=backoff.quarantined)
        self.release_in_background(held)
        self.plan()

    def fail_back(self) -> None:
        """The candidate ran a whole hold: show it, and keep the one it replaces as the spare if that helps."""
        b, a = self.held.pop(CANDIDATE, None), self.held.get(SHOWN)
        if b is None:
            return
        if a is None or b.index >= a.index:
            self.release_in_background(b)
            self.plan()
            return
        del self.held[SHOWN]
        if not self.promote(b, 'failback'):
            self.held[SHOWN] = a
            self.plan()
            return
        self.source_backoff[b.index].succeeded()
        kept = self.keep_as_spare(a)
        if not kept:
            self.hide_in_background(a)
            self.release_in_background(a)
        self.port.event('failback', label=b.choice.label, sensor_name=b.sensor_name, priority_index=b.index,
                        from_label=a.choice.label, from_sensor=a.sensor_name, from_index=a.index,
                        kept_as_standby=kept, standby=self.policy.standby.value)
        self.plan()

    def keep_as_spare(self, a: Held) -> bool:
        """Under warm and hot, the entry a fail-back leaves is the best spare there is: keep it running."""
        previous = self.held.get(SPARE)
        if self.policy.standby is Standby.COLD or (previous is not None and previous.index < a.index):
            return False
        if self.policy.standby is Standby.HOT:
            try:
                self.port.set_visible(a.display_id, False)
            except Exception as e:
                self.port.log_warn('could not hide the display of %s to keep it as the standby: %s'
                                   % (a.choice.label, e))
                return False
        else:
            self.hide_in_background(a)
        self._assign(a, SPARE)
        if previous is not None:
            self.release_in_background(previous)
        return True

    def promote(self, held: Held, via: str) -> bool:
        """Put a held entry on screen: show its hidden display (hot), or add its display (warm)."""
        try:
            if held.display_id is not None:
                self.port.set_visible(held.display_id, True)
            else:
                held.display_id = self.port.show(held)
        except Exception as e:
            self.port.event('standby_failed', sensor_name=held.sensor_name, label=held.choice.label,
                            priority_index=held.index, message='could not show it: %s' % e,
                            standby=self.policy.standby.value)
            self.hide_in_background(held)
            self.release_in_background(held)
            return False
        self.now_shown(held, via)
        return True

    def reshow(self, a: Held, why: str) -> bool:
        """The display of a healthy sensor failed: show the same topic again (a new RViz host)."""
        failed_display, a.display_id = a.display_id, None
        self._hide_display_in_background(failed_display, a.choice.label)
        try:
            a.display_id = self.port.show(a)
        except Exception as e:
            self.port.event('display_failed', sensor_name=a.sensor_name, label=a.choice.label,
                            priority_index=a.index, message=str(e))
            return False
        self.port.event('display_restored', sensor_name=a.sensor_name, label=a.choice.label,
                        priority_index=a.index, topic=a.topic, message=why)
        self.port.feedback('the display of the %s failed (%s); showing it again' % (a.choice.label, why))
        return True

    def activate_from(self, start: int, via: str) -> None:
        """Bring up the first entry from ``start`` on that works (``via``: why, for the event); on none,
        schedule a retry."""
        try:
            _, shown = first_that_works(
                range(start, len(self.priority)), self.port.activate, what='the operator\'s view',
                subsystem=Subsystem.ACTION_ENGINE, name=lambda i: self.priority[i].label,
                on_failure=lambda tried: self.source_backoff[tried.candidate].failed(time.monotonic(), flapped=False),
                keep_going=self.port.action_ok, errors=(Exception,))
        except NoCandidateLeft:
            if self.port.action_ok():
                self._schedule_retry()
            return
        self.now_shown(shown, via)
        self.plan()

    def now_shown(self, a: Held, via: str) -> None:
        """``a`` is on screen: say so (event, output, feedback)."""
        a.since = time.monotonic()
        self._assign(a, SHOWN)
        self.port.shown_topic(a.topic)
        self.timers.pop(Timer.RETRY, None)
        self.retry_wait = self.policy.retry_initial_s
        if via in VIA.values():
            self.spare_wait = self.policy.retry_initial_s
        self.port.event('sensor_active', sensor_name=a.sensor_name, sensor_type=a.choice.sensor_type,
                        label=a.choice.label, priority_index=a.index, topic=a.topic,
                        display_type=a.choice.display_type, via=via, standby=self.policy.standby.value)
        said = {'failback': 'a better sensor is back: ', 'retry': 'a sensor is back: '}.get(via, '')
        self.port.feedback('%sshowing the %s (%s) as %s on %s' % (said, a.choice.label, a.sensor_name,
                                                                  a.choice.display_type, a.topic))

    def _schedule_retry(self) -> None:
        """Every entry failed: say so, keep watching with a bounded backoff."""
        delay = self.retry_wait
        self.timers[Timer.RETRY] = time.monotonic() + delay
        self.retry_wait = min(self.retry_wait * 2.0, self.policy.retry_max_s)
        labels = ', '.join(c.label for c in self.priority)
        self.port.event('all_failed', retry_in_s=delay, sensors=labels)
        self.port.log_err('every sensor failed (%s); the operator has no view; retrying in %.1f s' % (labels, delay))
        self.port.feedback('every sensor failed (%s); nothing to show. Retrying in %.0f s.' % (labels, delay))

    def _assign(self, held: Held, role: Role) -> None:
        held.move(role)
        self.held[role] = held

    # ------------------------------------------------------------------ spares and candidates
    def plan(self) -> None:
        """Arm what the shown entry needs next: a spare (warm, hot), and a look at better entries (fail-back)."""
        a = self.held.get(SHOWN)
        if a is None:
            return
        now = time.monotonic()
        spare, candidate = self.held.get(SPARE), self.held.get(CANDIDATE)
        if spare is not None and spare.index <= a.index:
            del self.held[SPARE]
            self.hide_in_background(spare)
            self.release_in_background(spare)
        if candidate is not None and candidate.index >= a.index:
            del self.held[CANDIDATE]
            self.timers.pop(Timer.FAILBACK, None)
            self.hide_in_background(candidate)
            self.release_in_background(candidate)
        if (self.policy.standby is not Standby.COLD and SPARE not in self.held and a.index + 1 < len(self.priority)
                and Timer.SEEK_SPARE not in self.timers and not self._seeking(SPARE)):
            self.timers[Timer.SEEK_SPARE] = now
        if (self.policy.failback and a.index > 0 and CANDIDATE not in self.held
                and Timer.SEEK_CANDIDATE not in self.timers and not self._seeking(CANDIDATE)):
            self.timers[Timer.SEEK_CANDIDATE] = max(now, min(self.source_backoff[i].not_before
                                                             for i in range(a.index)))

    def _seek_spare_later(self) -> None:
        self.timers[Timer.SEEK_SPARE] = time.monotonic() + self.spare_wait
        self.spare_wait = min(self.spare_wait * 2.0, self.policy.retry_max_s)

    def _seeking(self, role: Role) -> bool:
        thread = self.seeking.get(role)
        return thread is not None and thread.is_alive()

    def seek(self, role: Role) -> None:
        """Start a spare (entries after the shown one) or a candidate (entries before it) on a helper thread."""
        a = self.held.get(SHOWN)
        if a is None or self._seeking(role):
            return
        now = time.monotonic()
        if role is SPARE:
            indexes = list(range(a.index + 1, len(self.priority)))
        else:
            indexes = [i for i in range(a.index) if self.source_backoff[i].ready(now)]
        if not indexes:
            self.plan()
            return
        # a candidate is always hidden: showing it is then a visibility change, with no blank frame
        hidden = role is CANDIDATE or self.policy.standby is Standby.HOT
        avoid = frozenset(h.sensor_name for h in self.held.values())
        thread = threading.Thread(target=self._seek, args=(role, indexes, hidden, avoid), daemon=True,
                                  name='%s for the operator\'s view' % role)
        self.seeking[role] = thread
        thread.start()

    def _seek(self, role: Role, indexes: list, hidden: bool, avoid: frozenset) -> None:
        failed: list = []
        try:
            _, held = first_that_works(indexes, lambda i: self.port.hold(i, hidden, avoid), what='a %s' % role,
                                       subsystem=Subsystem.ACTION_ENGINE, name=lambda i: self.priority[i].label,
                                       on_failure=lambda tried: failed.append(tried.candidate),
                                       keep_going=self.port.action_ok, errors=(Exception,))
            why = ''
        except NoCandidateLeft as e:
            held, why = None, str(e)
        except Exception as e:          # handed to the run loop, which reports it
            held, why = None, 'starting a %s failed: %s' % (role, e)
        self.port.post(Prepared(role, held, why, failed))

    def on_prepared(self, p: Prepared) -> None:
        self.seeking.pop(p.role, None)
        now = time.monotonic()
        if p.role is CANDIDATE:
            for i in p.failed:
                self.source_backoff[i].failed(now, flapped=False)
        held, a = p.held, self.held.get(SHOWN)
        if held is None:
            if p.role is CANDIDATE:
                # each try is told, so the timeline shows the backoff at work (a flapping cable, a dead one)
                self.port.event('failback_unavailable', message=p.why, priority_indexes=list(p.failed),
                                retry_in_s=round(max(0.0, min((self.source_backoff[i].not_before for i in p.failed),
                                                              default=now) - now), 3))
            else:
                self.port.event('standby_unavailable', message=p.why, standby=self.policy.standby.value)
                self._seek_spare_later()
            self.plan()
            return
        in_use = {h.sensor_name for h in self.held.values()}
        wanted = a is not None and held.sensor_name not in in_use and p.role not in self.held and (
            held.index > a.index if p.role is SPARE else held.index < a.index)
        if not wanted:
            self.hide_in_background(held)
            self.release_in_background(held)
        elif p.role is SPARE:
            self._assign(held, SPARE)
            self.port.event('standby_ready', sensor_name=held.sensor_name, label=held.choice.label,
                            priority_index=held.index, topic=held.topic, standby=self.policy.standby.value,
                            display='hidden' if held.display_id is not None else 'none')
        else:
            self._assign(held, CANDIDATE)
            self.timers[Timer.FAILBACK] = now + self.policy.failback_hold_s
            self.port.event('failback_candidate', sensor_name=held.sensor_name, label=held.choice.label,
                            priority_index=held.index, hold_s=self.policy.failback_hold_s)
        self.plan()

    # ------------------------------------------------------------------ releases, off the run loop
    def _in_background(self, target: Callable, name: str, *args: Any) -> None:
        self.background = [t for t in self.background if t.is_alive()]
        thread = threading.Thread(target=target, args=args, daemon=True, name=name)
        self.background.append(thread)
        thread.start()

    def hide_in_background(self, a: Held) -> None:
        """Take a source's view off the screen now, without holding up the failover."""
        display_id, a.display_id = a.display_id, None
        self._hide_display_in_background(display_id, a.choice.label)

    def _hide_display_in_background(self, display_id: Any, label: str) -> None:
        if display_id is not None:
            self._in_background(self.port.hide_display, 'hide the display of %s' % label, display_id, label)

    def release_in_background(self, a: Held) -> None:
        """Release a source (and its display, unless hidden already) without holding up the run loop."""
        a.move(RELEASED)
        self._in_background(self._unload, 'release of %s (%s)' % (a.sensor_name, a.choice.label), a)

    def _release(self, a: Held) -> None:
        a.move(RELEASED)
        self._unload(a)

    def _unload(self, a: Held) -> None:
        if a.display_id is not None:
            self.port.hide_display(a.display_id, '%s (%s)' % (a.choice.label, a.sensor_name))
        self.port.stop_sensor(a)
