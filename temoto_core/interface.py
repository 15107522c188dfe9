"""The base of every manager interface that actions and other managers use.

A manager interface wraps one registrar (its own, or one it borrows from its
owner) and one manager's servers. It remembers each resource it loaded and the
failure policy that goes with it:

- a request may carry its own policy (``on_status``, a callable that receives
  every :class:`StatusEvent` of that resource): the holder decides, per request,
  what a failure means to it (fail over, end the action, ...);
- without one, the interface-wide callback (``register_update_callback``) gets it;
- without either, the original's default applies to FAILED: unload the failed
  resource and ask again with the same request (the "reload"); the manager's
  ranking then picks another device. When that reload gives up, the loss is
  handed to ``on_lost`` (an action sets it to end itself FAILED), so a failure
  is never only a log line.
"""
import itertools
import os
import threading
from typing import Callable, Dict, Optional

import rospy

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.rr import ResourceRegistrar, StatusEvent

_instance_counter = itertools.count(1)
LOAD_RACE_TIMEOUT = 5.0    # s a status for a new id waits for its load call to return


class ManagerInterface:
    """Client side of one manager. Subclasses set ``MANAGER`` (the manager's registrar name)."""

    MANAGER = ''
    SUBSYSTEM = Subsystem.CORE

    def __init__(self, rr: Optional[ResourceRegistrar] = None, namespace: Optional[str] = None) -> None:
        self._owns_rr = rr is None
        self.rr = rr or ResourceRegistrar('%s_interface_%d_%d' % (self.MANAGER, _pid(), next(_instance_counter)),
                                          namespace=namespace, subsystem=self.SUBSYSTEM)
        self.namespace = namespace
        self._lock = threading.Lock()
        self._requests: Dict[int, tuple] = {}      # local id -> (server, request)
        self._loaded = threading.Condition(self._lock)
        self._inflight = 0                          # loads whose call has not returned yet
        self._update_cb: Optional[Callable[[StatusEvent], None]] = None
        self._replaced: Dict[int, int] = {}         # failed id -> id of its reload
        # called with (failed resource id, why) when the default policy cannot replace a failed resource
        self.on_lost: Optional[Callable[[int, TemotoError], None]] = None

    # -- loading -------------------------------------------------------------------------------
    def _load(self, server: str, request, on_status: Optional[Callable[[StatusEvent], None]] = None):
        """Load through the registrar; ``on_status`` is this request's own failure policy.

        The policy travels with the call, so it is in place for a status that arrives before the
        call has even returned.
        """
        status_cb = self._on_status if on_status is None else on_status
        with self._lock:
            self._inflight += 1
        try:
            response = self.rr.call(self.MANAGER, server, request, status_cb=status_cb, namespace=self.namespace)
            with self._lock:
                self._requests[response.trr.resource_id] = (server, request)
        finally:
            with self._lock:
                self._inflight -= 1
                self._loaded.notify_all()
        return response

    def _unload(self, resource_id: int) -> None:
        with self._lock:
            if resource_id not in self._requests:
                raise TemotoError(ErrorCode.RESOURCE_NOT_FOUND, self.SUBSYSTEM,
                                  'this %s interface holds no resource %d' % (self.MANAGER, resource_id))
            del self._requests[resource_id]
        self.rr.unload(resource_id)

    def holds(self, resource_id: int) -> bool:
        with self._lock:
            return resource_id in self._requests

    # -- failures ------------------------------------------------------------------------------
    def register_update_callback(self, callback: Callable[[StatusEvent], None]) -> None:
        """Replace the default failure policy: ``callback(event)`` gets every status instead."""
        self._update_cb = callback

    def _on_status(self, event: StatusEvent) -> None:
        """Statuses of resources loaded without a policy of their own."""
        if self._update_cb is not None:
            self._update_cb(event)
        elif event.failed:
            with self._lock:
                # a FAILED can overtake the load call that announces its id
                self._loaded.wait_for(lambda: event.resource_id in self._requests or not self._inflight,
                                      LOAD_RACE_TIMEOUT)
                held = event.resource_id in self._requests
            if not held:        # released by its holder already: nothing was lost
                rospy.logdebug('%s: FAILED of released resource %d ignored', self.rr.prefix, event.resource_id)
                return
            try:
                self.reload(event.resource_id)
            except TemotoError as err:
                self._lost(event.resource_id, err)

    def _lost(self, resource_id: int, err: TemotoError) -> None:
        if self.on_lost is not None:
            self.on_lost(resource_id, err)
        else:
            rospy.logerr('%s: resource %d failed and could not be replaced, and nobody was told: %s',
                         self.rr.prefix, resource_id, err)

    def reload(self, resource_id: int):
        """The default policy: unload the failed resource and request the same thing again.

        Returns the new response (its id differs from the failed one), or raises
        the manager's error, for example when no candidate is left.
        """
        with self._lock:
            entry = self._requests.get(resource_id)
        if entry is None:
            raise TemotoError(ErrorCode.RESOURCE_NOT_FOUND, self.SUBSYSTEM,
                              'cannot reload %d: this interface does not hold it' % resource_id)
        server, request = entry
        try:
            self._unload(resource_id)
        except TemotoError as err:
            # the failed resource's owner may be gone with it; the reload must still go on
            rospy.logwarn('%s: releasing failed resource %d: %s', self.rr.prefix, resource_id, err)
        try:
            response = self._load(server, self.pinned_request(request))
        except TemotoError as err:
            rospy.logerr('%s: reload of failed resource %d gave up: %s', self.rr.prefix, resource_id, err)
            raise
        with self._lock:
            self._replaced[resource_id] = response.trr.resource_id
        rospy.loginfo('%s: resource %d failed and was replaced by %d', self.rr.prefix, resource_id,
                      response.trr.resource_id)
        return response

    def replacement_of(self, resource_id: int) -> Optional[int]:
        with self._lock:
            return self._replaced.get(resource_id)

    def pinned_request(self, request):
        """Hook: the request to send again on reload (the sensor interface pins its topics)."""
        return request

    # -- lifetime ------------------------------------------------------------------------------
    def shutdown(self) -> None:
        """Release everything this interface loaded; shut its registrar down if it owns it."""
        with self._lock:
            ids = list(self._requests)
            self._requests.clear()
        if self._owns_rr:
            self.rr.shutdown()
            return
        for resource_id in ids:
            try:
                self.rr.unload(resource_id)
            except TemotoError as err:
                rospy.logwarn('%s: shutdown: %s', self.rr.prefix, err)


def _pid() -> int:
    return os.getpid()
