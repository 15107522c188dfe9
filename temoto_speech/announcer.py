"""What the operator hears: the action engine's events said as short sentences.

The engine's feedback topic carries sentences for reading (sensor names, topics, graph names). Spoken,
an operator needs less: what failed and what the robot does about it. ``sentence(event)`` maps the
events of ``/<ns>/action_engine/events`` to that, and says nothing about the others (a state change of
every node would be noise). ``Announcer`` queues the sentences and says them one after the other, each
also published on a topic (so that speech out can be off, and a bag keeps what was said), and written to
a WAV file when asked.
"""
from __future__ import annotations

import collections
import os
import threading
import time
from typing import Callable, Deque, Optional

from .voice import VoiceError, speak, synthesize

QUEUE = 5          # sentences waiting at most; older ones are dropped (a flapping cable says enough)
FAILURES_KEPT = 100   # actions whose failure was said, so that their FAILED state is not said again


def _label(ev: dict) -> str:
    return str(ev.get('label') or ev.get('sensor_type') or ev.get('sensor_name') or 'sensor')


def _words(name: str) -> str:
    return str(name).replace('_', ' ')


def sentence(ev: dict) -> Optional[str]:
    """The short sentence for an engine event, or None when it says nothing an operator must hear."""
    kind = ev.get('event')
    if kind == 'sensor_failed':
        part = 'display of the ' if ev.get('failed_part') == 'display' else ''
        return 'the %s%s failed' % (part, _label(ev))
    if kind == 'sensor_active':
        via = ev.get('via')
        if via in ('failover', 'standby'):
            return 'switching to the %s' % _label(ev)
        if via in ('failback', 'failback candidate'):
            return 'a better sensor is back: showing the %s' % _label(ev)
        if via == 'retry':
            return 'a sensor is back: showing the %s' % _label(ev)
        return 'showing the %s' % _label(ev)
    if kind == 'all_failed':
        return 'every sensor failed; nothing to show'
    if kind == 'tracker_failed':
        return 'the tracker of the %s failed' % ev.get('object', 'object')
    if kind == 'tracking':
        return 'tracking the %s' % ev.get('object', 'object')
    if kind == 'display_failed':
        return 'a display failed'
    if kind in ('failing', 'state') and (kind == 'failing' or ev.get('state') == 'FAILED'):
        return '%s failed' % _words(ev.get('action', 'an action'))
    return None


class Sentences:
    """``sentence`` over a stream of events, each failure said once: an action that fails says so at once
    (``failing``) and again when it has released what it held (its state FAILED); the second is not said."""

    def __init__(self) -> None:
        self._failing: Deque[tuple] = collections.deque(maxlen=FAILURES_KEPT)

    def of(self, ev: dict) -> Optional[str]:
        key = (ev.get('graph'), ev.get('action'), ev.get('instance_id'))
        if ev.get('event') == 'failing':
            self._failing.append(key)
        elif ev.get('event') == 'state' and ev.get('state') == 'FAILED' and key in self._failing:
            return None
        return sentence(ev)


class Announcer:
    """Says sentences in order on a thread of its own; ``publish`` gets each one first, always."""

    def __init__(self, publish: Callable[[str], None], voice: str, speed: int, audible: bool = True,
                 wav_dir: str = '', on_error: Callable[[str], None] = lambda text: None) -> None:
        self.publish = publish
        self.voice, self.speed = voice, speed
        self.audible = audible
        self.wav_dir = wav_dir
        self.on_error = on_error
        self._queue: Deque[str] = collections.deque(maxlen=QUEUE)
        self._wake = threading.Condition()
        self._stopped = False
        self._count = 0
        self._thread = threading.Thread(target=self._run, name='announcer', daemon=True)
        self._thread.start()

    def say(self, text: str) -> None:
        self.publish(text)
        if not (self.audible or self.wav_dir):
            return
        with self._wake:
            self._queue.append(text)
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._queue and not self._stopped:
                    self._wake.wait()
                if self._stopped:
                    return
                text = self._queue.popleft()
            self._voice(text)

    def _voice(self, text: str) -> None:
        if self.wav_dir:
            self._count += 1
            try:
                synthesize(text, os.path.join(self.wav_dir, '%s_%03d.wav' % (time.strftime('%H%M%S'), self._count)),
                           self.voice, self.speed)
            except VoiceError as e:
                self.on_error('could not write %r to %s: %s' % (text, self.wav_dir, e))
        if self.audible:
            try:
                speak(text, self.voice, self.speed)
            except VoiceError as e:
                # no loudspeaker (a headless robot): said once, then the announcements stay on their topic
                self.audible = False
                self.on_error('could not say %r aloud: %s; announcements stay on the topic only from now on'
                              % (text, e))

    def stop(self) -> None:
        with self._wake:
            self._stopped = True
            self._wake.notify()
        self._thread.join(5.0)
