"""The view's failover state machine on its own: plain objects for the managers, no ROS.

The plugin's behaviour through the engine is in test_action_show_environment.py; these pin the
machine's guarded transitions and its bookkeeping (each source released exactly once).
"""
import queue
import threading
from types import SimpleNamespace

import pytest

from temoto_action_engine.failover_policy import FailoverConfig, Standby
from temoto_action_engine.view_failover import (CANDIDATE, RELEASED, SHOWN, SPARE, STARTING, TRANSITIONS, Held,
                                                IllegalTransition, Role, Timer, ViewFailover)
from temoto_action_engine.view_sources import DEFAULT_PRIORITY, parse_priority
from temoto_core.rr.status import Status, StatusEvent

PRIORITY = parse_priority(DEFAULT_PRIORITY)


class Port:
    """Sensors that start at once (resource ids from 1), displays with ids from 100, and a mailbox."""

    def __init__(self, broken=()):
        self.broken = set(broken)
        self.mailbox: queue.Queue = queue.Queue()
        self.events: list = []
        self.stopped: list = []
        self.hidden: list = []
        self.visible: dict = {}
        self.lock = threading.Lock()
        self.next_id = 0

    def _id(self, base):
        with self.lock:
            self.next_id += 1
            return base + self.next_id

    def activate(self, index):
        if index in self.broken:
            raise RuntimeError('entry %d is unplugged' % index)
        return Held(index, PRIORITY[index], 'sensor%d' % index, self._id(0), '/t%d' % index, self._id(100))

    def hold(self, index, hidden, avoid):
        held = self.activate(index)
        held.display_id = held.display_id if hidden else None
        return held

    def show(self, held, hidden=False):
        return self._id(100)

    def set_visible(self, display_id, visible):
        self.visible[display_id] = visible

    def hide_display(self, display_id, what):
        with self.lock:
            self.hidden.append(display_id)

    def stop_sensor(self, held):
        with self.lock:
            self.stopped.append(held.resource_id)

    def shown_topic(self, topic):
        self.topic = topic

    post = property(lambda self: self.mailbox.put)
    action_ok = staticmethod(lambda: True)

    def event(self, kind, **fields):
        self.events.append(SimpleNamespace(kind=kind, **fields))

    feedback = log_info = log_warn = log_err = staticmethod(lambda text: None)

    def drain(self):
        try:
            return self.mailbox.get_nowait()
        except queue.Empty:
            return None

    def kinds(self):
        return [e.kind for e in self.events]


def pump_until(view, port, done, steps=50):
    """Hand the machine its mailbox until ``done()``, bounded in count and in time."""
    for _ in range(steps):
        if done():
            return
        try:
            item = port.mailbox.get(timeout=min(view.wait_s(), 5.0))
        except queue.Empty:
            item = None
        view.handle(item)
    raise AssertionError('not done after %d steps; events: %s' % (steps, port.kinds()))


def failed(resource_id):
    return StatusEvent(resource_id=resource_id, code=Status.FAILED, message='unplugged', error_stack=[],
                       rr_name='test', server_name='test', namespace='temoto', stamp=0.0)


def test_a_held_source_moves_only_along_the_table():
    held = Held(0, PRIORITY[0], 's', 1, '/t', None)
    assert held.role is STARTING
    held.move(SPARE)
    with pytest.raises(IllegalTransition, match='spare -> fail-back candidate'):
        held.move(CANDIDATE)
    held.move(SHOWN)
    held.move(RELEASED)
    with pytest.raises(IllegalTransition, match='released -> released'):
        held.move(RELEASED)      # a second release is a bug, not a no-op
    assert set(TRANSITIONS) == set(Role) and all(RELEASED in TRANSITIONS[r] for r in Role if r is not RELEASED)


def test_a_failed_view_is_replaced_by_the_warm_spare_and_released_once():
    port = Port()
    view = ViewFailover(PRIORITY, FailoverConfig(standby=Standby.WARM, failback=False), port)
    view.start()
    first = view.shown
    assert first.index == 0 and first.role is SHOWN and Timer.SEEK_SPARE in view.timers
    pump_until(view, port, lambda: view.held.get(SPARE) is not None)
    spare = view.held[SPARE]
    assert spare.index == 1 and spare.display_id is None, 'a warm spare runs its driver only'
    view.handle(failed(first.resource_id))
    assert view.shown is spare and spare.role is SHOWN and first.role is RELEASED
    assert port.events[-1].kind == 'sensor_active' and port.events[-1].via == 'standby'
    view.stop(drain=port.drain)
    assert len(port.stopped) == len(set(port.stopped)), 'a source was released twice'
    assert first.resource_id in port.stopped and spare.resource_id in port.stopped
    assert port.mailbox.empty() and not view.held


def test_every_entry_failing_schedules_a_retry_that_brings_the_view_back():
    port = Port(broken={0, 1, 2})
    view = ViewFailover(PRIORITY, FailoverConfig(retry_initial_s=0.05, failback=False), port)
    view.start()
    assert view.shown is None and Timer.RETRY in view.timers and port.kinds() == ['all_failed']
    port.broken = {0}
    pump_until(view, port, lambda: view.shown is not None)
    assert view.shown.index == 1 and port.kinds()[-2:] == ['retry', 'sensor_active']
    assert port.events[-1].via == 'retry' and Timer.RETRY not in view.timers
    view.stop(drain=port.drain)


def test_a_better_source_back_is_held_as_a_candidate_then_shown():
    port = Port(broken={0})
    view = ViewFailover(PRIORITY, FailoverConfig(standby=Standby.COLD, failback_hold_s=0.05,
                                                 failback_check_s=0.05), port)
    view.start()
    assert view.shown.index == 1
    port.broken = set()
    pump_until(view, port, lambda: view.shown.index == 0)
    assert 'failback_candidate' in port.kinds() and port.events[-1].kind == 'failback'
    assert port.events[-1].kept_as_standby is False, 'cold keeps no spare'
    view.stop(drain=port.drain)
    assert len(port.stopped) == len(set(port.stopped)) == 2
