"""A display asked for before its sensor is up, on the topic the sensor will most likely get.

Why: RViz then subscribes while the driver starts, and draws the driver's first message at
once, instead of connecting only after the sensor request returns. The guess is the Sensor
Manager's catalogue ranking; a wrong guess is hidden and the right topic shown, as without it.
"""
from __future__ import annotations

import threading
from typing import Any, Callable

GUESS_JOIN_S = 30.0     # how long the right guess may still take once the sensor is up


class SpeculativeDisplay:
    """A display requested, on a helper thread, on the topic a sensor will most likely be given.

    ``take(topic)`` returns its id when it shows ``topic`` (the caller then owns it); otherwise,
    and from ``discard()``, it is hidden exactly once, now or when its request returns (a
    discard can come while the request is still out, when the sensor request fails fast).
    """

    def __init__(self, label: str, likely_topic: Callable[[], str], show: Callable[[str], Any],
                 hide: Callable[[Any], None], log: Callable[[str], None]) -> None:
        self.label = label
        self._likely_topic, self._show, self._hide, self._log = likely_topic, show, hide, log
        self.topic = ''
        self.display_id = None
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._settled = False          # taken or discarded
        self._thread = threading.Thread(target=self._run, daemon=True, name='display guess for %s' % label)
        self._thread.start()

    def _run(self) -> None:
        did = None
        try:
            topic = self._likely_topic()
            if topic:
                with self._lock:
                    self.topic = topic
                    settled = self._settled
                if not settled:
                    did = self._show(topic)
        except Exception as e:          # only a guess: the display is requested after the sensor then
            self._log('no early display for %s: %s' % (self.label, e))
        with self._lock:
            self.display_id = did
            orphan = did if self._settled else None
        self._done.set()
        if orphan is not None:
            self._hide(orphan)

    def take(self, topic: str) -> Any:
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
            self._hide(did)
