"""Receiving status: a FAILED (or UPDATE) from an owner, mapped to this registrar's own ids, forwarded up
every link, and handed to the holders' callbacks.

Forwarding comes first: the action at the top of the chain waits on it, and the
local policy (a reload, say) can come after. Holders' callbacks run in order on
one worker thread per registrar, so a slow policy never delays the forwarding of
the next status.

Fencing: a status carries its sender's incarnation. Once a newer incarnation of
a registrar has been heard, a status from an older one (a process that was
given up for dead, or a message that sat in a queue across a restart) is
dropped: it speaks of a registry that no longer exists.
"""
import queue
import threading
import time
from typing import Callable, Dict, List, Tuple

import rospy

from temoto_core.errors import ErrorCode, ErrorFrame
from temoto_core.msg import ResourceStatus
from temoto_core.rr.client_side import ClientSide
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.links import Links
from temoto_core.rr.messages import malformed_status
from temoto_core.rr.query import ACTIVE, FAILED, ServerQuery, Target, target_name
from temoto_core.rr.status import StatusEvent

# A status can overtake the service response that announces its resource; it is parked this long for the
# response to arrive.
PENDING_STATUS_TTL = 10.0

Forward = Callable[[ServerQuery, int, str, List[ErrorFrame], int], None]


class StatusReceiver:
    def __init__(self, core: RegistrarCore, links: Links, client: ClientSide, forward: Forward,
                 status_topic: str) -> None:
        self._core = core
        self._links = links
        self._client = client
        self._forward = forward          # the server side's propagate: up to the consumers of a parent
        self._status_topic = status_topic
        self._parked: List[Tuple[float, object]] = []
        self._incarnations: Dict[Tuple[str, str], int] = {}   # (namespace, registrar) -> newest heard
        self._callbacks: List[Callable[[StatusEvent], None]] = []
        self._queue: 'queue.Queue' = queue.Queue()
        self._thread = threading.Thread(target=self._run_callbacks, name='rr-%s-callbacks' % core.name, daemon=True)
        self._thread.start()
        client.take_parked = self._take_parked
        client.deliver = self.on_status_msg

    def add_callback(self, callback: Callable[[StatusEvent], None]) -> None:
        with self._core.lock:
            self._callbacks.append(callback)

    def on_status_msg(self, msg) -> None:
        core = self._core
        problem = malformed_status(msg)
        if problem:
            rospy.logerr('%s: ignoring malformed status on %s: %s', core.prefix, self._status_topic, problem)
            return
        if msg.status_code == ResourceStatus.OK:
            return
        target = (msg.temoto_namespace.strip('/'), msg.manager_name, msg.server_name)
        client = self._client
        with core.lock:
            if not self.current(target[:2], msg.incarnation):
                rospy.logwarn('%s: dropped a status from %s incarnation %d (incarnation %d has been heard): %s',
                              core.prefix, target_name(target), msg.incarnation, self._incarnations[target[:2]],
                              msg.message)
                return
            query = client.by_external.get((target, msg.resource_id))
            if query is None:
                if client.loading_from(target):
                    # the response announcing this resource is still on its way
                    self._parked.append((time.monotonic(), msg))
                else:
                    rospy.logwarn('%s: status for unknown resource %s:%d ignored', core.prefix,
                                  target_name(target), msg.resource_id)
                return
            if msg.status_code == ResourceStatus.FAILED and query.state is ACTIVE:
                query.move(FAILED)
                if client.by_key.get((query.target, query.key)) is query:
                    del client.by_key[(query.target, query.key)]
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
            self._forward(parent, msg.status_code, msg.message, stack + [hop], via)
        for local_id, status_cb in holders:
            event = StatusEvent(resource_id=local_id, code=msg.status_code, message=msg.message,
                                error_stack=stack, rr_name=msg.manager_name, server_name=msg.server_name,
                                namespace=target[0], stamp=msg.header.stamp.to_sec())
            for cb in ([status_cb] if status_cb else []) + callbacks:
                self._queue.put((cb, event))

    def lost(self, target: Target, external_id: int, message: str) -> None:
        """A held resource turned out failed or gone (found on recovery): handled as its FAILED arriving now."""
        with self._core.lock:
            incarnation = self._incarnations.get(target[:2], 0)
        msg = ResourceStatus(temoto_namespace=target[0], manager_name=target[1], server_name=target[2],
                             resource_id=external_id, status_code=ResourceStatus.FAILED, message=message,
                             incarnation=incarnation,
                             error_stack=[ErrorFrame(ErrorCode.RESOURCE_FAILED, self._core.subsystem, message,
                                                     self._core.prefix).to_msg()])
        msg.header.stamp = rospy.Time.now()
        self.on_status_msg(msg)

    def current(self, sender: Tuple[str, str], incarnation: int) -> bool:
        """Whether ``incarnation`` of ``sender`` is the newest heard (lock held); remembers a newer one."""
        known = self._incarnations.get(sender, 0)
        if incarnation < known:
            return False
        if incarnation > known:
            self._incarnations[sender] = incarnation
        return True

    def _take_parked(self, target: Target, external_id: int) -> list:
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

    def _run_callbacks(self) -> None:
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
