"""What every part of one registrar shares: its identity, its lock, and its ids.

All registry state of a registrar is guarded by one lock, and every wait for a
change of state (an equal request waiting for the first one's load) is on one
condition of that lock. Callbacks into owner code never run with it held.
"""
import threading

import rosgraph.names
import rospy

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.ids import IdGenerator
from temoto_core.rr.messages import legal_name, node_uri

DEFAULT_NAMESPACE = 'temoto'


class RegistrarCore:
    """Identity, lock, condition and id generator of one registrar."""

    def __init__(self, name: str, namespace: str, subsystem: int, incarnation: int = 0, id_floor: int = 0) -> None:
        if not name or not rosgraph.names.is_legal_base_name(name):
            raise TemotoError(ErrorCode.BAD_REQUEST, subsystem, 'illegal registrar name %r' % name)
        self.name = name
        self.namespace = namespace.strip('/')
        self.subsystem = int(subsystem)
        self.prefix = '%s/%s' % (rospy.get_name(), name)
        self.incarnation = incarnation   # from the journal; 0 without one
        self.ids = IdGenerator(id_floor)
        self.lock = threading.RLock()
        self._changed = threading.Condition(self.lock)
        self._waiters = 0            # threads in wait_for_change: most state changes have none to wake
        self.closed = False

    def topic(self, leaf: str) -> str:
        """``/<ns>/<rr>/<leaf>``: where this registrar's services and status topic live."""
        return '/%s/%s/%s' % (self.namespace, self.name, leaf)

    def wait_for_change(self) -> None:
        """Wait (lock held) until another thread changes a query's state."""
        self._waiters += 1
        try:
            self._changed.wait()
        finally:
            self._waiters -= 1

    def notify_change(self) -> None:
        """Wake the waiters, if any (lock held): notify_all costs more than the check on the hot path."""
        if self._waiters:
            self._changed.notify_all()

    def error(self, code: int, message: str) -> TemotoError:
        return TemotoError(code, self.subsystem, message, prefix=self.prefix)

    def validate_header(self, trr) -> None:
        """Every field of a request's ``trr`` arrives from anyone on the network: check it before use."""
        for label, value in (('status_topic', trr.status_topic), ('client_name', trr.client_name)):
            if value and not legal_name(value):
                raise self.error(ErrorCode.BAD_REQUEST, 'trr.%s %r is not a legal ROS name' % (label, value))
        if trr.temoto_namespace and not legal_name(trr.temoto_namespace):
            raise self.error(ErrorCode.BAD_REQUEST, 'trr.temoto_namespace %r is not a legal ROS name'
                             % trr.temoto_namespace)
        if trr.client_uri and not node_uri(trr.client_uri):
            raise self.error(ErrorCode.BAD_REQUEST, 'trr.client_uri %r is not a node URI (http://host:port/)'
                             % trr.client_uri)
