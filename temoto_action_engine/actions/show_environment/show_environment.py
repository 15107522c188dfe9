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
- publishes each step (active, failed, unavailable, all_failed, retry) on
  /<ns>/action_engine/events so a bag shows when FAILED arrived and what replaced the sensor.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from temoto_action_engine.action_base import ActionBase, ActionError
from temoto_core.errors import Subsystem
from temoto_core.fallback import NoCandidateLeft, first_that_works
RELEASE_JOIN_S = 30.0   # on_stop waits this long for each background release (an unload is bounded itself)
GUESS_JOIN_S = 30.0     # how long the right guess may still take once the sensor is up
CATALOGUE_TIMEOUT_S = 0.5

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


@dataclass
class Active:
    index: int
    choice: SensorChoice
    sensor_name: str
    resource_id: int
    topic: str
    display_id: object


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
            import yaml
            config = yaml.safe_dump(config, default_flow_style=True).strip()
        elif not isinstance(config, str):
            raise ActionError('sensor_priority[%d].display_config must be a mapping of RViz properties or YAML, '
                              'got %r' % (i, config))
        out.append(SensorChoice(str(e.get('label', e['sensor_type'])), e['sensor_type'], tuple(keys),
                                e['display_type'], key, config))
    return out


class ShowEnvironment(ActionBase):
    def on_start(self):
        self.priority = parse_priority(self.config.get('sensor_priority', DEFAULT_PRIORITY))
        self.retry_initial = float(self.config.get('retry_initial_s', 2.0))
        self.retry_max = float(self.config.get('retry_max_s', 30.0))
        self.speculative = bool(self.config.get('speculative_display', True))
        self.backoff = self.retry_initial
        self.retry_at = None
        self.active: Active | None = None
        self.releases: list[threading.Thread] = []   # background releases of failed sensors
        self.smi = self.sensor_manager
        self.omi = self.output_manager
        self.activate_from(0)     # sets the output 'topic' when a sensor is up (children start after this)

    def execute(self):
        while self.action_ok():
            if self.active is None and self.retry_at is not None:
                timeout = max(0.0, self.retry_at - time.monotonic())
            else:
                timeout = 3600.0
            ev = self.next_item(timeout)
            if not self.action_ok():
                break
            if ev is not None:
                self.handle_status(ev)
            elif self.active is None and self.retry_at is not None and time.monotonic() >= self.retry_at:
                self.event('retry', backoff_s=self.backoff)
                self.activate_from(0)

    def on_stop(self):
        if self.active is not None:
            self.release_active()
        for thread in self.releases:
            thread.join(RELEASE_JOIN_S)
            if thread.is_alive():
                self.log_warn('%s still running after %.0f s; the registrar releases what is left'
                              % (thread.name, RELEASE_JOIN_S))

    # ------------------------------------------------------------------ steps
    def handle_status(self, ev) -> None:
        rid = ev.resource_id
        a = self.active
        if a is None or rid not in (a.resource_id, a.display_id):
            self.log_info('status %s for resource %s, which is not in use any more; ignored' % (ev.code.name, rid))
            return
        if not ev.failed:
            self.log_info('status %s for %s: %s' % (ev.code.name, a.sensor_name, ev.message))
            return
        display_only = rid == a.display_id and rid != a.resource_id
        self.event('sensor_failed', sensor_name=a.sensor_name, sensor_type=a.choice.sensor_type,
                   label=a.choice.label, priority_index=a.index, message=ev.message,
                   failed_part='display' if display_only else 'sensor')
        if display_only and self.reshow(a, ev.message):
            return
        # The failed view goes off screen at once; the substitute comes next; the failed sensor is
        # released once the substitute is up (or none is).
        self.active = None
        self.hide_in_background(a)
        self.activate_from(a.index + 1)
        self.release_in_background(a)

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

    def show(self, choice: SensorChoice, topic: str):
        """A display of ``topic`` whose failures come to this action's run loop."""
        return self.omi.show_in_rviz(choice.display_type, topic, name=choice.label, config=choice.display_config,
                                     on_status=self.post)

    def activate_from(self, start: int) -> None:
        """Bring up the first entry from ``start`` on that works; on none, schedule a retry."""
        try:
            _, self.active = first_that_works(
                range(start, len(self.priority)), self._activate, what='the operator\'s view',
                subsystem=Subsystem.ACTION_ENGINE, name=lambda i: self.priority[i].label,
                keep_going=self.action_ok, errors=(Exception,))
        except NoCandidateLeft:
            if self.action_ok():
                self._schedule_retry()
            return
        a = self.active
        self.set_output('topic', a.topic)       # the topic shown now (list_graphs reports it)
        recovered = self.retry_at is not None
        self.retry_at = None
        self.backoff = self.retry_initial
        self.event('sensor_active', sensor_name=a.sensor_name, sensor_type=a.choice.sensor_type,
                   label=a.choice.label, priority_index=a.index, topic=a.topic, display_type=a.choice.display_type)
        self.feedback('%sshowing the %s (%s) as %s on %s' % ('a sensor is back: ' if recovered else '',
                                                             a.choice.label, a.sensor_name,
                                                             a.choice.display_type, a.topic))

    def _activate(self, i: int) -> Active:
        """Entry ``i``: its sensor, then its display; raises (after rolling back) when either fails."""
        choice = self.priority[i]
        guess = SpeculativeDisplay(self, choice) if self.speculative else None
        try:
            result = self.smi.start_sensor(choice.sensor_type, output_topics={k: '' for k in choice.output_topics},
                                           on_status=self.post)
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
            self._stop_sensor(result.resource_id)
            raise
        return Active(i, choice, result.sensor_name, result.resource_id, topic, display_id)

    def _schedule_retry(self) -> None:
        """Every entry failed: say so, keep watching with a bounded backoff."""
        delay = self.backoff
        self.retry_at = time.monotonic() + delay
        self.backoff = min(self.backoff * 2.0, self.retry_max)
        labels = ', '.join(c.label for c in self.priority)
        self.event('all_failed', retry_in_s=delay, sensors=labels)
        self.log_err('every sensor failed (%s); the operator has no view; retrying in %.1f s' % (labels, delay))
        self.feedback('every sensor failed (%s); nothing to show. Retrying in %.0f s.' % (labels, delay))

    def release_active(self) -> None:
        a, self.active = self.active, None
        self._release(a)

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
        self._stop_sensor(a.resource_id)

    def hide_display(self, display_id, what: str) -> None:
        try:
            self.omi.hide(display_id)
        except Exception as e:
            self.log_warn('hiding the display of %s: %s' % (what, e))

    def likely_topic(self, choice: SensorChoice) -> str:
        """The topic ``choice``'s display will most likely show: the Sensor Manager's ranking, read
        from its catalogue (or from the sensor manager interface, when it offers ``likely_topics``)."""
        keys = list(choice.output_topics)
        guess = getattr(self.smi, 'likely_topics', None)
        if guess is not None:
            topics = guess(choice.sensor_type, keys)
        else:
            from temoto_sensor_manager.interface import fetch_catalogue
            from temoto_sensor_manager.selection import likely_topics
            namespace = self.manager_namespace('sensor_manager') or self.context.namespace
            topics = likely_topics(fetch_catalogue(namespace, CATALOGUE_TIMEOUT_S),
                                   choice.sensor_type, keys)
        return (topics or {}).get(choice.display_key, '')

    def _stop_sensor(self, resource_id) -> None:
        try:
            self.smi.stop_sensor(resource_id)
        except Exception as e:
            self.log_warn('stopping sensor resource %s: %s' % (resource_id, e))
