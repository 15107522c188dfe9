"""Which held resource belongs to which served one: the link that gives cascade unload, rollback of a
failed load, and the upward path of every FAILED.

A load callback that asks another registrar for a resource makes that resource
part of the one being loaded. The registrar knows which load is running on a
thread (rospy gives each service request its own thread), so ``call`` links by
default; ``call(..., link=False)`` holds a resource on the registrar's own
account, and ``ResourceRegistrar.link`` attaches it to the running load later.
A linked resource is released when its parent is, and its FAILED is forwarded to
its parent's consumers.
"""
import contextlib
import threading
from typing import Dict, Iterator, Optional

from temoto_core.rr.query import ServerQuery


class Links:
    """The load running on each thread, and the parent of each linked local id (lock held for the table)."""

    def __init__(self) -> None:
        self._tls = threading.local()
        self._parent: Dict[int, ServerQuery] = {}

    @contextlib.contextmanager
    def loading(self, query: ServerQuery) -> Iterator[None]:
        """Mark ``query`` as the load running on this thread while its callback runs (loads may nest)."""
        stack = getattr(self._tls, 'stack', None)
        if stack is None:
            stack = self._tls.stack = []
        stack.append(query)
        try:
            yield
        finally:
            stack.pop()

    def current(self) -> Optional[ServerQuery]:
        """The load running on this thread, if any."""
        stack = getattr(self._tls, 'stack', None)
        return stack[-1] if stack else None

    def attach(self, local_id: int, parent: ServerQuery) -> None:
        parent.links.append(local_id)
        self._parent[local_id] = parent

    def detach(self, local_id: int) -> Optional[ServerQuery]:
        """Forget ``local_id``'s link; returns the parent it had."""
        parent = self._parent.pop(local_id, None)
        if parent is not None and local_id in parent.links:
            parent.links.remove(local_id)
        return parent

    def parent_of(self, local_id: int) -> Optional[ServerQuery]:
        return self._parent.get(local_id)

    def forget_parent(self, query: ServerQuery) -> None:
        """``query`` is leaving the registry: its links no longer lead anywhere."""
        for local_id in query.links:
            if self._parent.get(local_id) is query:
                del self._parent[local_id]
