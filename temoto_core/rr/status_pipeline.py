"""The status pipeline: how a resource's status, above all FAILED, travels from its owner to every holder.

One FAILED from a driver's exit to an action crosses several registrars, and in each it passes
the same three stages, all in this file:

1. **send** (:meth:`StatusPipeline.send`): an owner reports a change of one of its resources
   (``ResourceRegistrar.send_status``; the ER Manager does so when a process exits).
2. **forward** (:meth:`StatusPipeline.forward`): to every consumer of a served resource, on the
   status topic that consumer named in its request (:meth:`announce`). A FAILED marks the
   resource failed, so it is never shared again; during its load, it makes the load fail.
3. **receive** (:meth:`StatusPipeline.receive`): a status that arrives on this registrar's own
   topic. It is fenced (an older incarnation's status is dropped), mapped to this registrar's
   local ids, *forwarded* up every link (stage 2, one registrar up: a sensor's consumers hear of
   its process's FAILED), and then *delivered* to the holders' callbacks.

Forwarding comes before delivery: the action at the top of the chain waits on it, and a local
policy (a reload, say) can come after. Callbacks run in order on one worker thread per registrar
(``rr-<name>-callbacks``), so a slow policy never delays the forwarding of the next status.

A status can overtake the service response that announces its resource. It is *parked* until
that response arrives (the client side asks :meth:`take_parked`), for ``PENDING_STATUS_TTL``.
"""
import queue
import threading
import time
from typing import Callable, Dict, List, Optional, Tuple

import rospy

from temoto_core.errors import ErrorCode, ErrorFrame, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_core.rr.channels import StatusChannels
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.links import Links
from temoto_core.rr.messages import STATUS_CODES, malformed_status
from temoto_core.rr.query import ACTIVE, FAILED, LOADING, Consumer, HeldQueries, ServerQuery, Target, target_name
from temoto_core.rr.recorder import Recorder
from temoto_core.rr.status import StatusEvent

# A status that overtook the response announcing its resource is parked this long for the response to arrive.
PENDING_STATUS_TTL = 10.0


class StatusPipeline:
    def __init__(self, core: RegistrarCore, links: Links, held: HeldQueries, channels: StatusChannels,
                 recorder: Recorder, status_topic: str) -> None:
        self._core = core
        self._links = links
        self._held = held                  # the client side's tables: a status is mapped through them
        self._channels = channels
        self._recorder = recorder
        self._status_topic = status_topic
        self._parked: List[Tuple[float, ResourceStatus]] = []
        self._incarnations: Dict[Tuple[str, str], int] = {}   # (namespace, registrar) -> newest heard
        self._callbacks: List[Callable[[StatusEvent], None]] = []
        self._queue: 'queue.Queue' = queue.Queue()
        self._thread = threading.Thread(target=self._deliver, name='rr-%s-callbacks' % core.name, daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------------------------------ 1. send
    def send(self, query: Optional[ServerQuery], internal_id: int, code: int, message: str,
             error_stack: Optional[List[ErrorFrame]] = None) -> None:
        """The owner's own status of served resource ``internal_id`` (``query``: None if it serves none)."""
        core = self._core
        if code not in STATUS_CODES:
            raise core.error(ErrorCode.BAD_REQUEST, 'unknown status code %r (expected 0, 1 or 2)' % (code,))
        if query is None:
            raise core.error(ErrorCode.RESOURCE_NOT_FOUND, 'send_status: no resource with id %d in %s'
                             % (internal_id, core.name))
        if error_stack is None:
            stack = [ErrorFrame(ErrorCode.RESOURCE_FAILED if code == ResourceStatus.FAILED else ErrorCode.UNSPECIFIED,
                                core.subsystem, message, core.prefix)]
        else:
            stack = list(error_stack)
        self.forward(query, code, message, stack)

    # ------------------------------------------------------------------------------------------ 2. forward
    def forward(self, query: ServerQuery, code: int, message: str, stack: List[ErrorFrame],
                via_link: Optional[int] = None) -> None:
        """Tell every consumer of ``query``; a FAILED during its load makes the load fail instead."""
        with self._core.lock:
            if code == ResourceStatus.FAILED:
                if query.state is LOADING:
                    error = TemotoError.from_msgs([f.to_msg() for f in stack], message)
                    if via_link is not None:
                        query.link_failures.setdefault(via_link, error)
                    elif query.failure is None:
                        query.failure = error
                    return
                if query.state is ACTIVE:
                    query.move(FAILED)
                    if query.failure is None:        # why, for the registry (the consumers hear it now)
                        query.failure = TemotoError.from_msgs([f.to_msg() for f in stack], message)
                    self._recorder.failed(query)
                    if query.server.by_key.get(query.key) is query:
                        del query.server.by_key[query.key]
            elif query.state is not ACTIVE:
                return
            consumers = list(query.consumers.items())
        stack_msgs = [f.to_msg() for f in stack]
        for external_id, consumer in consumers:
            self.announce(consumer, query.server.name, external_id, code, message, stack_msgs)

    def announce(self, consumer: Consumer, server_name: str, external_id: int, code: int, message: str,
                 stack: list) -> None:
        """Publish one status to one consumer (``stack``: ErrorFrames or Error messages)."""
        if not consumer.status_topic:
            return
        core = self._core
        msg = ResourceStatus(temoto_namespace=core.namespace, manager_name=core.name, server_name=server_name,
                             resource_id=external_id, status_code=code, message=message,
                             incarnation=core.incarnation,
                             error_stack=[f.to_msg() if isinstance(f, ErrorFrame) else f for f in stack])
        msg.header.stamp = rospy.Time.now()
        try:
            self._channels.publisher(consumer.status_topic).publish(msg)
        except rospy.ROSException as err:     # rospy is shutting down: the consumer hears of it from the master
            rospy.logwarn('%s: status %d for %s:%d to %s not sent: %s', core.prefix, code, server_name,
                          external_id, consumer.status_topic, err)

    # ------------------------------------------------------------------------------------------ 3. receive
    def receive(self, msg: ResourceStatus) -> None:
        """A status on this registrar's topic (rospy's receive thread), or a parked one now placed."""
        core = self._core
        problem = malformed_status(msg)
        if problem:
            rospy.logerr('%s: ignoring malformed status on %s: %s', core.prefix, self._status_topic, problem)
            return
        if msg.status_code == ResourceStatus.OK:
            return
        target = (msg.temoto_namespace.strip('/'), msg.manager_name, msg.server_name)
        held = self._held
        with core.lock:
            if not self.current(target[:2], msg.incarnation):
                rospy.logwarn('%s: dropped a status from %s incarnation %d (incarnation %d has been heard): %s',
                              core.prefix, target_name(target), msg.incarnation, self._incarnations[target[:2]],
                              msg.message)
                return
            query = held.by_external.get((target, msg.resource_id))
            if query is None:
                if held.loading_from(target):
                    # the response announcing this resource is still on its way
                    self._parked.append((time.monotonic(), msg))
                else:
                    rospy.logwarn('%s: status for unknown resource %s:%d ignored', core.prefix,
                                  target_name(target), msg.resource_id)
                return
            if msg.status_code == ResourceStatus.FAILED and query.state is ACTIVE:
                query.move(FAILED)
                if held.by_key.get((query.target, query.key)) is query:
                    del held.by_key[(query.target, query.key)]
            holders = list(query.local_ids.items())
            parents = []          # (the query that links this resource, through which local id)
            for local_id, _ in holders:
                parent = self._links.parent_of(local_id)
                if parent is not None and all(p is not parent for p, _ in parents):
                    parents.append((parent, local_id))
            callbacks = list(self._callbacks)
        stack = [ErrorFrame.from_msg(e) for e in msg.error_stack]
        for parent, via in parents:
            hop = ErrorFrame(ErrorCode.RESOURCE_FAILED if msg.status_code == ResourceStatus.FAILED
                             else ErrorCode.UNSPECIFIED, core.subsystem,
                             'sub-resource %s:%d: %s' % (target_name(target), msg.resource_id, msg.message),
                             core.prefix)
            self.forward(parent, msg.status_code, msg.message, stack + [hop], via)
        for local_id, status_cb in holders:
            event = StatusEvent(resource_id=local_id, code=msg.status_code, message=msg.message,
                                error_stack=stack, rr_name=msg.manager_name, server_name=msg.server_name,
                                namespace=target[0], stamp=msg.header.stamp.to_sec())
            for cb in ([status_cb] if status_cb else []) + callbacks:
                self._queue.put((cb, event))

    def lost(self, target: Target, external_id: int, message: str) -> None:
        """A held resource turned out failed or gone (found on recovery, or in its owner's registry): handled
        as its FAILED arriving now."""
        with self._core.lock:
            incarnation = self._incarnations.get(target[:2], 0)
        msg = ResourceStatus(temoto_namespace=target[0], manager_name=target[1], server_name=target[2],
                             resource_id=external_id, status_code=ResourceStatus.FAILED, message=message,
                             incarnation=incarnation,
                             error_stack=[ErrorFrame(ErrorCode.RESOURCE_FAILED, self._core.subsystem, message,
                                                     self._core.prefix).to_msg()])
        msg.header.stamp = rospy.Time.now()
        self.receive(msg)

    def current(self, sender: Tuple[str, str], incarnation: int) -> bool:
        """Whether ``incarnation`` of ``sender`` is the newest heard (lock held); remembers a newer one.

        Fencing: once a newer incarnation of a registrar has been heard, a status from an older one (a
        process given up for dead, or a message that sat in a queue across a restart) speaks of a registry
        that no longer exists."""
        known = self._incarnations.get(sender, 0)
        if incarnation < known:
            return False
        if incarnation > known:
            self._incarnations[sender] = incarnation
        return True

    def take_parked(self, target: Target, external_id: int) -> List[ResourceStatus]:
        """The statuses parked for a resource whose response has just arrived (lock held)."""
        now = time.monotonic()
        keep, take = [], []
        for stamp, msg in self._parked:
            if now - stamp > PENDING_STATUS_TTL:
                continue
            matches = (msg.temoto_namespace.strip('/'), msg.manager_name, msg.server_name) == target and \
                msg.resource_id == external_id
            (take if matches else keep).append((stamp, msg))
        self._parked = keep
        return [msg for _, msg in take]

    # ------------------------------------------------------------------------------------------ delivery
    def add_callback(self, callback: Callable[[StatusEvent], None]) -> None:
        """``callback`` hears every status that reaches any held resource."""
        with self._core.lock:
            self._callbacks.append(callback)

    def _deliver(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            cb, event = item
            try:
                cb(event)
            except Exception as err:  # a policy bug must not stop later statuses
                rospy.logerr('%s: status callback %r raised %r', self._core.prefix, cb, err)

    def close(self) -> None:
        self._queue.put(None)
